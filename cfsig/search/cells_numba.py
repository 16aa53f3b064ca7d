"""The fine-cell kernel, compiled by numba (optional extra); see `cfsig.search.cells`.

The same scores as `cfsig.search.cells.cell_scores`, to the last bit, in one pass over each row's
slots. Each slot's fraction is rounded to units of ``1 / UNIT`` as `cfsig.search.cells.area_units`
rounds it; its cell finds its row of the part's table (`cfsig.search.cells.part_table`: row 0, all
zeros, for the cells the part lacks); the row's ``f p`` and ``p`` at every share take their
minimum with the slot's units and are summed as integers (docs/method.md). The score is
then computed from the integer sums in float64, in `cell_scores`' order of operations: no
``fastmath``, which could fuse or reorder those steps.

The compiled code is cached on disk (``cache=True``): in the ``__pycache__`` folder beside this
file, or numba's user-wide cache where that is not writable, or ``NUMBA_CACHE_DIR``. Importing
this module raises ImportError without numba; the caller then falls back to NumPy's kernel.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence

import numpy as np
from numba import njit

from cfsig.search.cells import UNIT, part_table

# Shares a table row holds, padded to a multiple of this: 16 shares of ``f p`` and ``p`` in
# 16 bits fill one 64-byte row, which the compiler sums in a few vector instructions.
_LANES = 16
_UNIT32 = np.float32(UNIT)  # fractions are scaled in float32, as `area_units` scales them
_ZERO32 = np.float32(0.0)
_PER_UNIT = 1 / UNIT  # float64, as `cell_scores` multiplies by it


def part_scorer(
    part: Sequence[tuple[np.ndarray, np.ndarray]], shares: tuple[float, ...]
) -> Callable[[np.ndarray, np.ndarray], np.ndarray]:
    """`cfsig.search.cells.cell_scores` of one part, compiled: one pass over each row's cells.

    The part's histograms are laid out once (`cfsig.search.cells.part_table`), for every block of
    rows
    the scorer is given. The scores are `cfsig.search.cells.cell_scores`' to the last bit.

    Parameters
    ----------
    part : sequence of (cells, fractions)
        The part's `cfsig.descriptors.cells.cell_histogram` at each share, cells below 65,536.
    shares : tuple of float
        The shares, one per histogram of ``part``.

    Returns
    -------
    scorer : callable
        ``scorer(cells, fractions)``: the wholes' (m, slots) uint16
        `cfsig.descriptors.cells.packed_cells`
        and their (m, slots) float32 fractions to their (m,) float64 scores, dimensionless;
        releases the GIL while it scores.
    """
    lanes = -(-len(shares) // _LANES) * _LANES
    rows, table, masses, explained = part_table(part, shares, lanes)
    table = np.ascontiguousarray(table.reshape(len(table), 2 * lanes))  # f p, then p
    masses = np.ascontiguousarray(masses[: len(shares)])  # the padding shares are not scored
    explained = np.ascontiguousarray(explained[: len(shares)])

    def scorer(cells: np.ndarray, fractions: np.ndarray) -> np.ndarray:
        cells = np.ascontiguousarray(cells, np.uint16)
        fractions = np.ascontiguousarray(fractions, np.float32)
        out = np.empty(len(cells))
        _scores(rows, table, masses, explained, cells, fractions, out)
        return out

    return scorer


@njit(cache=True, nogil=True)
def _scores(
    rows: np.ndarray,
    table: np.ndarray,
    masses: np.ndarray,
    explained: np.ndarray,
    cells: np.ndarray,
    fractions: np.ndarray,
    out: np.ndarray,
) -> None:
    """Score each row of ``cells`` and ``fractions`` into ``out``.

    Parameters
    ----------
    rows : (65536,) uint16
        Each cell's row of ``table``, 0 for the cells the part lacks
        (`cfsig.search.cells.part_table`).
    table : (h + 1, 2 lanes) uint16
        For each cell the part holds, in units: ``f p`` at each of ``lanes`` shares, then ``p``.
    masses : (s,) int64
        The part's mass ``P`` at each of its s shares, in units.
    explained : (s,) float64
        ``1 / F`` at each share, with ``F`` the sum of ``f p`` in units.
    cells : (m, slots) uint16
        The wholes' cells.
    fractions : (m, slots) float32
        Their shares of the whole's area, dimensionless.
    out : (m,) float64
        Filled with the scores: the least over the shares of ``(1 - E / F) + (P + W - 2 C) /
        UNIT``, dimensionless.
    """
    lanes = table.shape[1] // 2
    # E at each share, then C, in 16 bits as the table: each sum stays below 2^16 (`UNIT`), and
    # 16-bit lanes let the compiler take a table row in two vector instructions.
    gained = np.zeros(table.shape[1], np.uint16)
    for i in range(cells.shape[0]):
        gained[:] = 0
        whole = 0  # W
        for s in range(cells.shape[1]):
            if s and cells[i, s] == 0:  # past a row's cells, ascending, come zeros only
                break
            units = _area_units(fractions[i, s])
            if units == 0:  # an empty slot adds nothing
                continue
            whole += units
            row = rows[cells[i, s]]
            if row == 0:  # a cell the part lacks adds nothing to E or C
                continue
            held = table[row]
            for k in range(table.shape[1]):
                gained[k] += held[k] if held[k] < units else units
        best = np.inf
        for j in range(len(masses)):
            lost = masses[j] + whole - 2 * np.int64(gained[lanes + j])
            best = min(best, (1.0 - np.int64(gained[j]) * explained[j]) + lost * _PER_UNIT)
        out[i] = best


@njit(cache=True, nogil=True, inline="always")
def _area_units(fraction: np.float32) -> np.uint16:
    """`cfsig.search.cells.area_units` of one float32 fraction: scaled in float32, clipped to
    [0, UNIT], rounded to the nearest unit (ties to even)."""
    scaled = min(max(fraction * _UNIT32, _ZERO32), _UNIT32)
    return np.uint16(np.rint(scaled))
