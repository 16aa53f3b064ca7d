"""Fine curvature cells: where each vertex's curvature lies at all scales at once.

The curvature channel of the intrinsic descriptor (`cfsig.descriptors.intrinsic`) holds joint
histograms of adjacent scales on 17 bins per axis. An index built with `Params.partial_cells`
also keeps, for partial queries, the joint histogram of all the
scales at once on finer bins: a vertex's cell is its first scale's bin and its steps from each
scale's bin to the next, each clipped to within ``band`` bins, ``bins * (2 band + 1)^(k - 1)``
cells for k scales (33 x 9^3 = 24,057 for the intrinsic descriptor's four). A whole occupies a few
hundred of
them, close to one per vertex of its simplified copy, so a part, a subset of its whole's
surface, finds its own whole by them far more often than by the coarse channel (docs/method.md).
They are kept sparse: the cells a surface occupies and the share of its area in each, in
integer units of ``1 / UNIT`` (`area_units`), at most `SLOTS` of them per row of the index.
"""

from __future__ import annotations

import numpy as np

CURVATURE_RANGE = 6.0  # bins span asinh(value / CURVATURE_UNIT) in [-6, 6]: +-2000 in value
CURVATURE_UNIT = 10.0  # about the sphere's 4 pi: the histogram is linear below, logarithmic above
SLOTS = 1024  # cells kept per whole: 709 a whole is the median on SHREC 2007, 1,070 the most
# Shares of an area are kept and summed as integers in units of 1/UNIT, 16 bits each: a row's
# SLOTS shares, each rounded by at most half a unit, still sum below 2^16.
UNIT = 65_000


def area_units(fractions: np.ndarray) -> np.ndarray:
    """Shares of a surface's area in integer units of ``1 / UNIT``.

    Parameters
    ----------
    fractions : array of float
        Shares of an area, in [0, 1].

    Returns
    -------
    units : uint16 array, the shape of ``fractions``
        ``fractions`` in float32 times `UNIT`, clipped to [0, UNIT] and rounded to the nearest
        integer (ties to even).
    """
    scaled = np.asarray(fractions, np.float32) * np.float32(UNIT)
    return np.rint(np.clip(scaled, 0, UNIT)).astype(np.uint16)


def curvature_bins(values: np.ndarray, bins: int) -> np.ndarray:
    """The bin of each curvature value on the axis of the curvature histograms.

    Parameters
    ----------
    values : (n, k) float64
        Curvature at k scales, dimensionless.
    bins : int
        Bins on the axis: ``asinh(value / CURVATURE_UNIT)`` on [-CURVATURE_RANGE,
        CURVATURE_RANGE], values beyond in the end bins.

    Returns
    -------
    bins : (n, k) intp
        In [0, bins).
    """
    position = np.arcsinh(values / CURVATURE_UNIT) + CURVATURE_RANGE
    position *= bins / (2 * CURVATURE_RANGE)
    return np.clip(position, 0, bins - 1).astype(np.intp)


def window_cells(values: np.ndarray, bins: int, band: int, joint: int) -> np.ndarray:
    """The cell of each vertex in each window of ``joint`` adjacent scales.

    Parameters
    ----------
    values : (n, k) float64
        Curvature at k scales (`cfsig.operators.curvature.smoothed_curvature`), dimensionless.
    bins : int
        Bins of the first scale of a window (`curvature_bins`).
    band : int
        Steps from one scale's bin to the next kept; larger steps are clipped to it.
    joint : int
        Scales per window, 2 to k: 2 gives the curvature channel's adjacent pairs (k - 1 windows),
        k one
        cell per vertex.

    Returns
    -------
    cells : (n, k - joint + 1) int64
        Cell numbers, distinct across windows: ``window * cells_per_window + cell``, with
        ``cells_per_window = bins * (2 band + 1)^(joint - 1)``.
    """
    index = curvature_bins(values, bins).astype(np.int64)
    width = 2 * band + 1
    windows = index.shape[1] - joint + 1
    out = np.empty((len(index), windows), np.int64)
    for w in range(windows):
        cell = index[:, w]
        for s in range(w + 1, w + joint):
            cell = cell * width + np.clip(index[:, s] - index[:, s - 1], -band, band) + band
        out[:, w] = w * bins * width ** (joint - 1) + cell
    return out


def cell_histogram(
    values: np.ndarray, areas: np.ndarray, bins: int, band: int, joint: int | None = None
) -> tuple[np.ndarray, np.ndarray]:
    """A surface's sparse histogram of curvature cells.

    Parameters
    ----------
    values : (n, k) float64
        Curvature at k scales, dimensionless.
    areas : (n,) float64
        Vertex areas, non-negative with a positive sum.
    bins, band : int
        As `window_cells`.
    joint : int, optional
        Scales per window, as `window_cells`; all k by default.

    Returns
    -------
    cells : (c,) int64
        The cells occupied, ascending.
    fractions : (c,) float64
        The share of the area in each, each window's summing to ``1 / windows``: 1 in all.
    """
    found = window_cells(values, bins, band, values.shape[1] if joint is None else joint)
    weights = np.repeat(areas / areas.sum() / found.shape[1], found.shape[1])
    cells, where = np.unique(found.ravel(), return_inverse=True)
    return cells, np.bincount(where, weights=weights)


def packed_cells(
    values: np.ndarray, areas: np.ndarray, bins: int, band: int, slots: int = SLOTS
) -> tuple[np.ndarray, np.ndarray]:
    """A whole's `cell_histogram` of all its scales jointly, in the fixed width an index stores.

    Parameters
    ----------
    values : (n, k) float64
        Curvature at k scales, dimensionless.
    areas : (n,) float64
        Vertex areas.
    bins, band : int
        As `window_cells`; ``bins * (2 band + 1)^(k - 1)`` must fit in 16 bits.
    slots : int
        Cells kept: a surface occupying more keeps its ``slots`` largest.

    Returns
    -------
    cells : (slots,) uint16
        The cells kept, ascending, then zeros.
    units : (slots,) uint16
        Their shares of the area in units of ``1 / UNIT`` (`area_units`), then zeros (an empty
        slot holds nothing).
    """
    cells, fractions = cell_histogram(values, areas, bins, band)
    if len(cells) > slots:
        kept = np.sort(np.argsort(-fractions, kind="stable")[:slots])
        cells, fractions = cells[kept], fractions[kept]
    out_cells, out_units = np.zeros(slots, np.uint16), np.zeros(slots, np.uint16)
    out_cells[: len(cells)], out_units[: len(cells)] = cells, area_units(fractions)
    return out_cells, out_units
