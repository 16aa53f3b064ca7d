"""Sketches: a short vector per stored row whose L1 distance is a lower bound of the row's.

A row's sketch is the sums of its coordinates in groups of `GROUP` adjacent ones, less a
centre that its segment stores. For any two rows a and b and any groups,
``sum_g |sum_{i in g} a_i - sum_{i in g} b_i| <= sum_i |a_i - b_i|``: the L1 distance of two
sketches is at most that of their rows. A search scans the sketches (51 float32 a row for the
812 of the ``intrinsic`` descriptor), then computes exact distances only for the rows whose
bound does not exceed the k-th best exact distance found (`cfsig.search.nearest`). Most of
that descriptor's coordinates are sorted quantile functions, adjacent ones nearly equal, so
their differences keep their sign within a group and the bound is tight (docs/method.md says
how the group size was chosen).

Every rounding is accounted for, so that the pruning never drops a row that the full float32
scan would rank: the sketches are stored in float32, and each segment records the largest
error that rounding made on any of its rows (`sketch_rows`); the bounds are computed in float32
(`adjust_bounds`), and the exact distances they are compared with are float32 sums
(`threshold`).
"""

from __future__ import annotations

from dataclasses import dataclass

import h5py
import numpy as np

GROUP = 16  # coordinates summed per sketch entry: docs/performance.md
_U = 2.0**-24  # unit roundoff of float32
_TINY = 2.0**-40  # bounds the float64 error of a group sum, relative to the sum of magnitudes
_ROWS = 8192  # rows sketched at a time


@dataclass(frozen=True)
class Sketch:
    """What a search needs of a segment's sketches.

    Attributes
    ----------
    rows : h5py.Dataset
        (n, groups) float32: each stored row's group sums less ``center``.
    groups : (groups,) int64
        First coordinate of each group, ascending from 0.
    center : (groups,) float64
        Subtracted from every group sum before rounding, so the stored values are small.
    error : float
        At most the sum over groups of the rounding error of any row's stored sketch.
    """

    rows: h5py.Dataset
    groups: np.ndarray
    center: np.ndarray
    error: float


def sketch_groups(width: int) -> np.ndarray:
    """The groups of a signature length: runs of `GROUP` adjacent coordinates.

    Parameters
    ----------
    width : int
        Signature length.

    Returns
    -------
    groups : (ceil(width / GROUP),) int64
        First coordinate of each group.
    """
    return np.arange(0, width, GROUP, dtype=np.int64)


def sketch_center(rows: np.ndarray, groups: np.ndarray) -> np.ndarray:
    """A segment's centre: the mean group sums of some of its rows with finite values.

    Parameters
    ----------
    rows : (m, width) float32
        Signatures (the first piece of a segment).
    groups : (g,) int64
        First coordinate of each group.

    Returns
    -------
    center : (g,) float64
        Zeros when no row is finite.
    """
    sums = group_sums(rows, groups)
    finite = sums[np.isfinite(sums).all(axis=1)]
    return finite.mean(axis=0) if len(finite) else np.zeros(len(groups))


def group_sums(rows: np.ndarray, groups: np.ndarray) -> np.ndarray:
    """The sums of each row's coordinates in each group, in float64.

    Parameters
    ----------
    rows : (m, width) float
        Signatures.
    groups : (g,) int64
        First coordinate of each group.

    Returns
    -------
    sums : (m, g) float64
    """
    rows = np.asarray(rows).reshape(len(rows), -1)
    if not len(rows):
        return np.zeros((0, len(groups)))
    return np.add.reduceat(rows, groups, axis=1, dtype=np.float64)


def sketch_rows(
    rows: np.ndarray, groups: np.ndarray, center: np.ndarray
) -> tuple[np.ndarray, float]:
    """The sketches of some rows, and the largest rounding error among them.

    Parameters
    ----------
    rows : (m, width) float32
        Signatures.
    groups : (g,) int64
        First coordinate of each group.
    center : (g,) float64
        Subtracted from the group sums.

    Returns
    -------
    sketches : (m, g) float32
    error : float
        The largest, over the rows with finite values, of the sum over groups of
        ``|stored - exact|``, plus a margin for the float64 sums; 0 for no such rows.
    """
    stored = np.empty((len(rows), len(groups)), np.float32)
    error = 0.0
    for start in range(0, len(rows), _ROWS):  # bounds the float64 temporaries
        some = rows[start : start + _ROWS]
        exact = group_sums(some, groups) - center
        stored[start : start + len(some)] = exact
        magnitude = np.abs(some).sum(axis=1, dtype=np.float64) + np.abs(center).sum()
        with np.errstate(invalid="ignore"):  # infinity less infinity
            errors = np.abs(stored[start : start + len(some)] - exact).sum(axis=1)
        errors += _TINY * magnitude
        finite = errors[np.isfinite(errors)]  # a row with NaN or infinity: a NaN or inf bound
        error = max(error, float(finite.max()) if len(finite) else 0.0)
    return stored, error


def query_sketches(queries: np.ndarray, sketch: Sketch) -> tuple[np.ndarray, np.ndarray]:
    """The sketches of some queries on a segment's groups and centre, with their errors.

    Parameters
    ----------
    queries : (q, width) float32
        Query signatures.
    sketch : Sketch
        The segment's.

    Returns
    -------
    sketches : (q, g) float32, C-contiguous
    margins : (q,) float32
        What `adjust_bounds` subtracts for each query: its own rounding error and the
        segment's, rounded up.
    """
    exact = group_sums(queries, sketch.groups) - sketch.center
    stored = np.ascontiguousarray(exact, np.float32)
    magnitude = np.abs(np.asarray(queries, np.float64)).sum(axis=1) + np.abs(sketch.center).sum()
    with np.errstate(invalid="ignore"):  # infinity less infinity: NaN, which prunes nothing
        error = np.abs(stored - exact).sum(axis=1) + _TINY * magnitude + sketch.error
    return stored, _up(error * (1 + 4 * _U))


def adjust_bounds(bounds: np.ndarray, margin: np.ndarray, groups: int) -> None:
    """Turn float32 L1 distances of sketches into lower bounds of the rows' exact distances.

    Parameters
    ----------
    bounds : (q, m) float32
        L1 distances between the queries' sketches and rows' sketches, as a kernel computed
        them; changed in place.
    margin : (q,) float32
        From `query_sketches`.
    groups : int
        Sketch length (the number of terms each distance summed).
    """
    bounds *= np.float32(1 - 2 * (groups + 2) * _U)
    bounds -= margin[:, None]


def threshold(kth: float, width: int) -> np.float32:
    """The largest bound a row may have and still be nearer than a float32 distance ``kth``.

    A row whose adjusted bound exceeds it has a float32 distance (a sum of ``width`` rounded
    terms) greater than ``kth``, so a full scan would not rank it before the k-th.

    Parameters
    ----------
    kth : float
        The k-th best float32 distance so far; NaN or infinity when fewer than k are known.
    width : int
        Signature length.

    Returns
    -------
    threshold : float32
        Infinite when nothing may be pruned yet.
    """
    if not np.isfinite(kth):
        return np.float32(np.inf)
    return _up(np.array([kth * (1 + 2 * (width + 2) * _U)]))[0]


def _up(values: np.ndarray) -> np.ndarray:
    """float64 values as float32, rounded up."""
    low = np.asarray(values, np.float32)
    return np.where(low < values, np.nextafter(low, np.float32(np.inf)), low).astype(np.float32)
