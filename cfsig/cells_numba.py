"""The fine-cell kernel of numba (optional extra ``cfsig[fast]``); see `cfsig.cells`."""

from __future__ import annotations

from collections.abc import Callable, Sequence

import numba
import numpy as np


def part_scorer(
    part: Sequence[tuple[np.ndarray, np.ndarray]], shares: tuple[float, ...]
) -> Callable[[np.ndarray, np.ndarray], np.ndarray]:
    """`cfsig.cells.cell_scores` of one part, compiled: one pass over each row's cells.

    The part's histograms are laid out once, for every block of rows the scorer is given. It
    sums in float32 where the NumPy kernel sums in float64: the two differ by about 1e-6.

    Parameters
    ----------
    part : sequence of (cells, fractions)
        The part's `cfsig.cells.cell_histogram` at each share, cells below 65,536.
    shares : tuple of float
        The shares, one per histogram of ``part``.

    Returns
    -------
    scorer : callable
        ``scorer(cells, fractions)``: the wholes' (m, slots) uint16 `cfsig.cells.packed_cells`
        and their (m, slots) float32 fractions to their (m,) float64 scores, in [0, 3];
        releases the GIL.
    """
    held = np.unique(np.concatenate([np.asarray(c, np.int64) for c, _ in part]))
    slot = np.full(1 << 16, -1, np.int32)
    slot[held] = np.arange(len(held))
    table = np.zeros((len(shares), len(held)), np.float32)
    for j, (c, p) in enumerate(part):
        table[j, slot[c]] = p
    inverse = (1 / np.asarray(shares)).astype(np.float32)

    def scorer(cells: np.ndarray, fractions: np.ndarray) -> np.ndarray:
        out = np.empty(len(cells))
        _scores(slot, table, inverse, cells, fractions, out)
        return out

    return scorer


@numba.njit(nogil=True, fastmath=True, boundscheck=False, cache=True)
def _scores(slot, table, inverse, cells, fractions, out):
    """``out[i]``: row i's partial distance. Its cells the part holds are gathered first, then
    summed share by share over those alone, a loop the compiler vectorises."""
    width = cells.shape[1]
    found = np.empty(width, np.int32)
    whole = np.empty(width, np.float32)
    two = np.float32(2)
    for i in range(cells.shape[0]):
        count = 0
        for s in range(width):
            w = fractions[i, s]
            if w == 0:  # an empty slot
                continue
            k = slot[cells[i, s]]
            if k >= 0:
                found[count] = k
                whole[count] = w
                count += 1
        best = 0.0
        for j in range(table.shape[0]):
            row = table[j]
            scale = inverse[j]
            # 3 - score, summed cell by cell: min(f p, w) / f + 2 min(p, w)
            gained = np.float32(0)
            for s in range(count):
                p = row[found[s]]
                w = whole[s]
                gained += min(p, w * scale) + two * min(p, w)
            best = max(best, np.float64(gained))
        out[i] = 3.0 - best
