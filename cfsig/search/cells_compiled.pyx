# cython: language_level=3, boundscheck=False, wraparound=False, cdivision=True, initializedcheck=False
"""The fine-cell kernel, compiled when cfsig is installed (Cython); see `cfsig.search.cells`.

The same scores as `cfsig.search.cells.cell_scores`, to the last bit, in one pass over each
row's cells. Each slot's cell finds its row of the part's table
(`cfsig.search.cells.part_table`: row 0, all zeros, for the cells the part lacks); the row's
``f p`` and ``p`` at each share take their minimum with the slot's share of the area, in units
of ``1 / UNIT`` (`cfsig.descriptors.cells.area_units`), and are summed as
16-bit integers (docs/method.md). The score is then computed from the integer sums in float64,
in `cell_scores`' order of operations (the build turns off fused multiply-adds, setup.py).
"""

from libc.math cimport INFINITY

import numpy as np

from cfsig.descriptors.cells import UNIT
from cfsig.search.cells import part_table

# Shares the kernel scores at once: 16 shares of ``f p`` and ``p`` in 16 bits are one 64-byte
# table row, and 32 sums the compiler keeps in vector registers. More shares: NumPy's kernel.
MAX_SHARES = 16
cdef enum:
    WIDTH = 32  # 2 * MAX_SHARES
cdef double PER_UNIT = 1.0 / UNIT  # float64, as `cell_scores` multiplies by it


def part_scorer(part, shares):
    """`cfsig.search.cells.cell_scores` of one part, compiled: one pass over each row's cells.

    The part's histograms are laid out once (`cfsig.search.cells.part_table`), for every block
    of rows the scorer is given.

    Parameters
    ----------
    part : sequence of (cells, fractions)
        The part's `cfsig.descriptors.cells.cell_histogram` at each share, cells below 65,536.
    shares : tuple of float
        The shares, one per histogram of ``part``; at most `MAX_SHARES`.

    Returns
    -------
    scorer : callable
        ``scorer(cells, units)``: the wholes' (m, slots) uint16 cells, ascending then zeros, and
        their (m, slots) uint16 shares of the area (`cfsig.descriptors.cells.packed_cells`) to
        their (m,) float64 scores, dimensionless; it releases the GIL while it scores.

    Raises
    ------
    ValueError
        More than `MAX_SHARES` shares.
    """
    if len(shares) > MAX_SHARES:
        raise ValueError(f"{len(shares)} shares: the compiled kernel takes {MAX_SHARES} at most")
    rows, table, masses, explained = part_table(part, shares, MAX_SHARES)
    table = np.ascontiguousarray(table.reshape(len(table), WIDTH))  # f p, then p
    masses = np.ascontiguousarray(masses[: len(shares)])  # the padding shares are not scored
    explained = np.ascontiguousarray(explained[: len(shares)])

    def scorer(cells, units):
        cells = np.ascontiguousarray(cells, np.uint16)
        units = np.ascontiguousarray(units, np.uint16)
        out = np.empty(len(cells))
        _scores(rows, table, masses, explained, cells, units, out)
        return out

    return scorer


cdef void _scores(
    const unsigned short[::1] rows,
    const unsigned short[:, ::1] table,
    const long long[::1] masses,
    const double[::1] explained,
    const unsigned short[:, ::1] cells,
    const unsigned short[:, ::1] units,
    double[::1] out,
) noexcept:
    """Score each row of ``cells`` and ``units`` into ``out``.

    ``rows`` (65536,): each cell's row of ``table`` (h + 1, WIDTH), 0 for the cells the part
    lacks; ``masses`` (s,) int64 and ``explained`` (s,) float64: the part's ``P`` and ``1 / F``
    at each of its s shares; ``out`` (m,): the least over the shares of
    ``(1 - E / F) + (P + W - 2 C) / UNIT``, dimensionless.
    """
    cdef Py_ssize_t i, s, k, j
    cdef unsigned short share, held_k
    cdef const unsigned short *held
    cdef long long whole, lost
    cdef double best, score
    # E at each share, then C: each sum stays below 2^16, a whole's shares summing to UNIT
    cdef unsigned short gained[WIDTH]
    with nogil:
        for i in range(cells.shape[0]):
            for k in range(WIDTH):
                gained[k] = 0
            whole = 0  # W
            for s in range(cells.shape[1]):
                if s > 0 and cells[i, s] == 0:  # past a row's cells, ascending, come zeros
                    break
                share = units[i, s]
                whole += share
                # Row 0 of the table is all zeros: the cells the part lacks add nothing,
                # without a branch that would stop the compiler from vectorising this loop.
                held = &table[rows[cells[i, s]], 0]
                for k in range(WIDTH):
                    held_k = held[k]
                    gained[k] += held_k if held_k < share else share
            best = INFINITY
            for j in range(masses.shape[0]):
                lost = masses[j] + whole - 2 * <long long>gained[WIDTH // 2 + j]
                score = (1.0 - <double>gained[j] * explained[j]) + <double>lost * PER_UNIT
                if score < best:
                    best = score
            out[i] = best
