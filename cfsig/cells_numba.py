"""The fine-cell kernel of numba (optional extra ``cfsig[fast]``); see `cfsig.cells`."""

from __future__ import annotations

from collections.abc import Callable, Sequence

import numba
import numpy as np

_LANES = 16  # float32 values in one AVX-512 vector: shares are padded to a multiple


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
    slot = np.zeros(1 << 16, np.uint32)  # a cell's row of the table; 0 for the cells it lacks
    slot[held] = np.arange(1, len(held) + 1)
    lanes = -(-len(shares) // _LANES) * _LANES  # whole vectors; a padding share gains nothing
    table = np.zeros((len(held) + 1, lanes), np.float32)
    for j, (c, p) in enumerate(part):
        table[slot[c], j] = p
    inverse = np.ones(lanes, np.float32)
    inverse[: len(shares)] = 1 / np.asarray(shares)
    flat = table.ravel()  # the kernel finds a cell's row at ``slot * lanes``

    def scorer(cells: np.ndarray, fractions: np.ndarray) -> np.ndarray:
        out = np.empty(len(cells))
        _scores(slot, flat, inverse, cells, fractions, out, lanes)
        return out

    return scorer


@numba.njit(nogil=True, fastmath=True, boundscheck=False, cache=True)
def _scores(slot, table, inverse, cells, fractions, out, lanes):
    """``out[i]``: row i's partial distance. The row's cells that the part holds are listed
    first, padded to a multiple of four by the table's empty row 0; then every four cells add
    their gains at all shares to a vector of them, so that the vector is loaded and stored once
    per four cells. The compiler vectorises that loop because its length, ``lanes``, is not a
    constant it would unroll."""
    width = cells.shape[1]
    found = np.zeros(width + 4, np.uint64)  # where each listed cell's row of the table starts
    whole = np.zeros(width + 4, np.float32)
    gained = np.empty(lanes, np.float32)
    two = np.float32(2)
    for i in range(cells.shape[0]):
        count = 0
        for s in range(width):
            k = slot[cells[i, s]]
            found[count] = np.uint64(k) * np.uint64(lanes)
            whole[count] = fractions[i, s]
            count += (k != 0) & (fractions[i, s] != 0)  # an empty slot has no fraction
        found[count : count + 4] = 0
        whole[count : count + 4] = 0
        gained[:] = 0
        for e in range(0, count, 4):
            a, b, c, d = found[e], found[e + 1], found[e + 2], found[e + 3]
            wa, wb, wc, wd = whole[e], whole[e + 1], whole[e + 2], whole[e + 3]
            for j in range(lanes):
                # 3 - score, summed cell by cell: min(f p, w) / f + 2 min(p, w)
                at, to = np.uint64(j), inverse[j]  # 1 / f
                pa, pb, pc, pd = table[a + at], table[b + at], table[c + at], table[d + at]
                gained[j] += (
                    min(pa, wa * to) + two * min(pa, wa) + min(pb, wb * to) + two * min(pb, wb)
                ) + (min(pc, wc * to) + two * min(pc, wc) + min(pd, wd * to) + two * min(pd, wd))
        best = np.float32(0)
        for j in range(lanes):
            best = max(best, gained[j])
        out[i] = 3.0 - best
