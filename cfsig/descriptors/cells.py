"""Fine curvature cells: where each vertex's curvature lies at all scales at once.

Version 9's curvature channel (`cfsig.descriptors.intrinsic`) holds joint histograms of adjacent scales on 17
bins per axis. Version 10 also keeps, for partial queries, the joint histogram of all the
scales at once on finer bins: a vertex's cell is its first scale's bin and its steps from each
scale's bin to the next, each clipped to within ``band`` bins, ``bins * (2 band + 1)^(k - 1)``
cells for k scales (33 x 9^3 = 24,057 for version 10). A whole occupies a few hundred of
them, close to one per vertex of its simplified copy, so a part, a subset of its whole's
surface, finds its own whole by them far more often than by the coarse channel (docs/partial.md,
"Four scales jointly, on finer bins"). They are kept sparse: the cells a surface occupies and
the share of its area in each, at most `SLOTS` of them per row of the index.
"""

from __future__ import annotations

import functools
import importlib
from collections.abc import Callable, Sequence

import numpy as np

CURVATURE_RANGE = 6.0  # bins span asinh(value / CURVATURE_UNIT) in [-6, 6]: +-2000 in value
CURVATURE_UNIT = 10.0  # about the sphere's 4 pi: the histogram is linear below, logarithmic above
SLOTS = 1024  # cells kept per whole: 709 a whole is the median on SHREC 2007, 1,070 the most
# The kernels sum shares of an area as integers in units of 1/UNIT, 16 bits each: a row's SLOTS
# fractions, each rounded by at most half a unit, still sum below 2^16 (method.md, section 19).
UNIT = 65_000
# Rows from which the compiled kernel repays compiling it (about 0.07 s) in a process's first
# query: docs/partial.md, "Scale", "Compiled with llvmlite".
FAST_MIN_ROWS = 500
# A whole's `packed_cells`: (SLOTS,) uint16 cells and (SLOTS,) float32 fractions.
Cells = tuple[np.ndarray, np.ndarray]
# A part's scores of blocks of wholes: ``scorer(cells, fractions)`` as `cell_scores`.
Scorer = Callable[[np.ndarray, np.ndarray], np.ndarray]


def curvature_bins(values: np.ndarray, bins: int) -> np.ndarray:
    """The bin of each curvature value on the axis of `cfsig.descriptors.intrinsic.curvature_histograms`.

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
        Scales per window, 2 to k: 2 gives version 9's adjacent pairs (k - 1 windows), k one
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
    fractions : (slots,) float32
        Their shares of the area, then zeros (an empty slot holds nothing).
    """
    cells, fractions = cell_histogram(values, areas, bins, band)
    if len(cells) > slots:
        kept = np.sort(np.argsort(-fractions, kind="stable")[:slots])
        cells, fractions = cells[kept], fractions[kept]
    out_cells, out_fractions = np.zeros(slots, np.uint16), np.zeros(slots, np.float32)
    out_cells[: len(cells)], out_fractions[: len(cells)] = cells, fractions
    return out_cells, out_fractions


def area_units(fractions: np.ndarray) -> np.ndarray:
    """Shares of a surface's area in the kernels' integer units of ``1 / UNIT``.

    Parameters
    ----------
    fractions : array of float
        Shares of an area, in [0, 1].

    Returns
    -------
    units : uint16 array, the shape of ``fractions``
        ``fractions * UNIT`` in float32, rounded to the nearest integer (ties to even), as
        `cfsig.search.cells_llvm` rounds them.
    """
    scaled = np.asarray(fractions, np.float32) * np.float32(UNIT)
    return np.rint(np.clip(scaled, 0, UNIT)).astype(np.uint16)


def part_table(
    part: Sequence[tuple[np.ndarray, np.ndarray]], shares: tuple[float, ...], lanes: int
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """A part's histograms at its shares, laid out as the kernels read them.

    Parameters
    ----------
    part : sequence of (cells, fractions)
        The part's `cell_histogram` at each share, cells below 65,535.
    shares : tuple of float
        The shares, one per histogram of ``part``.
    lanes : int
        Columns per share in the table, at least ``len(shares)``; the columns past the shares
        are 0.

    Returns
    -------
    rows : (65536,) uint16
        Each cell's row of ``table``: row 0, all zeros, for the cells the part lacks.
    table : (h + 1, 2, lanes) uint16
        For the h cells the part holds, at each share ``f``: `area_units` of ``f p``, then of
        ``p``, its histogram at that share.
    masses : (lanes,) int64
        The part's mass at each share, the sum of its ``p`` in units.
    explained : (lanes,) float64
        1 over the sum of its ``f p`` in units at each share; 0 past the shares.
    """
    held = np.unique(np.concatenate([np.asarray(c, np.int64) for c, _ in part]))
    rows = np.zeros(1 << 16, np.uint16)  # 24,057 cells in version 10: rows fit in 16 bits
    rows[held] = np.arange(1, len(held) + 1)
    table = np.zeros((len(held) + 1, 2, lanes), np.uint16)
    for j, ((c, p), share) in enumerate(zip(part, shares, strict=True)):
        table[rows[c], 0, j] = area_units(share * np.asarray(p, np.float64))
        table[rows[c], 1, j] = area_units(p)
    totals = table.sum(axis=0, dtype=np.int64)
    explained = np.zeros(lanes)
    explained[: len(shares)] = 1 / totals[0, : len(shares)]
    return rows, table, totals[1], explained


def cell_scores(
    part: Sequence[tuple[np.ndarray, np.ndarray]],
    shares: tuple[float, ...],
    cells: np.ndarray,
    fractions: np.ndarray,
) -> np.ndarray:
    """The partial distance of a part to some wholes by their cells.

    For a share ``f``, with the part's histogram ``p`` and a whole's ``w`` (each of mass 1),
    ``(1 - sum(min(f p, w)) / f) + sum(|p - w|)``: the unexplained share plus the L1 distance,
    `cfsig.search.partial.partial_scores` with weight 1; the smallest over the shares. Both terms are
    summed in integers, on the fractions in units of ``1 / UNIT`` (`area_units`; method.md,
    section 19): ``1 - E / F`` and ``(P + W - 2 C) / UNIT``, with ``E`` and ``C`` the sums of
    ``min(f p, w)`` and ``min(p, w)``, ``F`` and ``P`` those of ``f p`` and ``p``, ``W`` that
    of ``w``; `cfsig.search.cells_llvm` computes the same numbers.

    Parameters
    ----------
    part : sequence of (cells, fractions)
        The part's `cell_histogram` at each share.
    shares : tuple of float
        The shares, one per histogram of ``part``.
    cells : (m, slots) int
        The wholes' `packed_cells`, below 65,536.
    fractions : (m, slots) float
        Their fractions.

    Returns
    -------
    scores : (m,) float64
        Dimensionless, in [0, 3] up to the rounding to units: 0 for a whole that is its own
        part at share 1.
    """
    rows, table, masses, explained = part_table(part, shares, len(shares))
    at = rows[cells]
    units = area_units(fractions)
    both = (at > 0) & (units > 0)
    counts = both.sum(axis=1)
    gained = np.minimum(table[at[both]], units[both][:, None, None])  # (entries, 2, shares)
    totals = np.zeros((len(cells), 2, len(shares)), np.int64)
    filled = np.flatnonzero(counts)
    if len(filled):
        starts = np.concatenate([[0], np.cumsum(counts[filled])[:-1]])
        totals[filled] = np.add.reduceat(gained, starts, axis=0, dtype=np.int64)
    wholes = units.sum(axis=1, dtype=np.int64)[:, None]
    lost = masses + wholes - 2 * totals[:, 1]
    return ((1 - totals[:, 0] * explained) + lost * (1 / UNIT)).min(axis=1)


def part_scorer(
    part: Sequence[tuple[np.ndarray, np.ndarray]], shares: tuple[float, ...], rows: int
) -> Scorer:
    """`cell_scores` of one part, by the compiled kernel (extra ``cfsig[fast]``) where it pays.

    Parameters
    ----------
    part, shares
        As `cell_scores`.
    rows : int
        Rows the search will score: from `FAST_MIN_ROWS`, the compiled kernel if llvmlite is
        installed and the system lets it run code it compiles (`cfsig.search.cells_llvm.part_scorer`,
        8 to 125 times as fast), else `cell_scores`: the same scores.

    Returns
    -------
    scorer : callable
        ``scorer(cells, fractions)``: the wholes' (m, slots) `packed_cells` and fractions to
        their (m,) float64 scores, as `cell_scores`.
    """
    if rows >= FAST_MIN_ROWS:
        try:
            fast = importlib.import_module("cfsig.search.cells_llvm")
            scorer: Scorer = fast.part_scorer(part, shares)
        except (ImportError, OSError):  # no llvmlite, or no executable memory (SELinux)
            pass
        else:
            return scorer
    return functools.partial(cell_scores, part, shares)
