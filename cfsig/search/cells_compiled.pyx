# cython: language_level=3, boundscheck=False, wraparound=False, cdivision=True, initializedcheck=False
"""The fine-cell kernel, compiled when cfsig is installed (Cython); see `cfsig.search.cells`.

The same scores as `cfsig.search.cells.cell_scores`, to the last bit, in one pass over each
row's cells. Each slot's cell finds its row of the part's table
(`cfsig.search.cells.part_table`: row 0, all zeros, for the cells the part lacks); the row's
``f p`` and ``p`` at each share take their minimum with the slot's share of the area, in units
of ``1 / UNIT`` (`cfsig.descriptors.cells.area_units`), and are summed as
16-bit integers (docs/method.md). The score is then computed from the integer sums in float64,
in `cell_scores`' order of operations (the build turns off fused multiply-adds, setup.py).

The loop is C, twice: a portable one that the compiler vectorises for the build's baseline, and
on x86-64 one of 256-bit AVX2 instructions, taken where the processor has them. A table row's
32 lanes are then two registers, each taken with its minimum straight from memory: half the
instructions a cell, the cost that bounds this loop (docs/performance.md).
"""

from libc.stdint cimport int64_t, uint16_t

import numpy as np

from cfsig.descriptors.cells import UNIT
from cfsig.search.cells import part_table

cdef extern from *:
    """
    #include <math.h>
    #include <stdint.h>

    #define CELLS_WIDTH 32  /* 2 * MAX_SHARES lanes: f p at each share, then p */
    /* The AVX2 loop is built for x86-64, by compilers that take a function's target. */
    #if defined(__x86_64__) && (defined(__GNUC__) || defined(__clang__))
    #define CELLS_AVX2 1
    #else
    #define CELLS_AVX2 0
    #endif

    /* The least over the shares of (1 - E / F) + (P + W - 2 C) / UNIT, from the integer sums. */
    static inline double cells_best(const uint16_t *gained, int64_t whole, const int64_t *masses,
                                    const double *explained, int n_shares, double per_unit)
    {
        double best = INFINITY;
        for (int j = 0; j < n_shares; j++) {
            int64_t lost = masses[j] + whole - 2 * (int64_t)gained[CELLS_WIDTH / 2 + j];
            double score = (1.0 - (double)gained[j] * explained[j]) + (double)lost * per_unit;
            if (score < best) best = score;
        }
        return best;
    }

    static void cells_score_portable(
        const uint16_t *rows, const uint16_t *table, const int64_t *masses,
        const double *explained, int n_shares, const uint16_t *cells, const uint16_t *units,
        int64_t m, int64_t slots, double per_unit, double *out)
    {
        for (int64_t i = 0; i < m; i++) {
            const uint16_t *cell = cells + i * slots, *unit = units + i * slots;
            uint16_t gained[CELLS_WIDTH] = {0};  /* E at each share, then C: below 2^16 */
            int64_t whole = 0;  /* W */
            /* Slot 0 may hold cell 0; past it, the row's cells (ascending) end at a zero. */
            int64_t s = 0;
            if (slots > 0) do {
                uint16_t share = unit[s];
                /* Row 0 is all zeros: the cells the part lacks add nothing, without a branch
                   that would stop the compiler from vectorising this loop. */
                const uint16_t *held = table + CELLS_WIDTH * (int64_t)rows[cell[s]];
                whole += share;
                for (int k = 0; k < CELLS_WIDTH; k++)
                    gained[k] += held[k] < share ? held[k] : share;
            } while (++s < slots && cell[s] != 0);
            out[i] = cells_best(gained, whole, masses, explained, n_shares, per_unit);
        }
    }

    #if CELLS_AVX2
    #include <immintrin.h>

    static int cells_have_avx2(void)
    {
        __builtin_cpu_init();
        return __builtin_cpu_supports("avx2");
    }

    __attribute__((target("avx2")))
    static void cells_score_avx2(
        const uint16_t *rows, const uint16_t *table, const int64_t *masses,
        const double *explained, int n_shares, const uint16_t *cells, const uint16_t *units,
        int64_t m, int64_t slots, double per_unit, double *out)
    {
        for (int64_t i = 0; i < m; i++) {
            const uint16_t *cell = cells + i * slots, *unit = units + i * slots;
            __m256i low = _mm256_setzero_si256(), high = _mm256_setzero_si256();
            int64_t whole = 0, s = 0;
            if (slots > 0) do {  /* as in the portable loop */
                uint16_t share = unit[s];
                const __m256i *held = (const __m256i *)(table + CELLS_WIDTH * (int64_t)rows[cell[s]]);
                __m256i spread = _mm256_set1_epi16((short)share);
                whole += share;
                low = _mm256_add_epi16(low, _mm256_min_epu16(_mm256_loadu_si256(held), spread));
                high = _mm256_add_epi16(high, _mm256_min_epu16(_mm256_loadu_si256(held + 1), spread));
            } while (++s < slots && cell[s] != 0);
            uint16_t gained[CELLS_WIDTH];
            _mm256_storeu_si256((__m256i *)gained, low);
            _mm256_storeu_si256((__m256i *)(gained + CELLS_WIDTH / 2), high);
            out[i] = cells_best(gained, whole, masses, explained, n_shares, per_unit);
        }
    }
    #else
    static int cells_have_avx2(void) { return 0; }
    #endif

    /* The AVX2 loop where asked (where `cells_have_avx2`), else the portable one. */
    static void cells_score(
        int avx2, const uint16_t *rows, const uint16_t *table, const int64_t *masses,
        const double *explained, int n_shares, const uint16_t *cells, const uint16_t *units,
        int64_t m, int64_t slots, double per_unit, double *out)
    {
    #if CELLS_AVX2
        if (avx2) {
            cells_score_avx2(rows, table, masses, explained, n_shares, cells, units, m, slots,
                             per_unit, out);
            return;
        }
    #endif
        cells_score_portable(rows, table, masses, explained, n_shares, cells, units, m, slots,
                             per_unit, out);
    }
    """
    int CELLS_WIDTH
    int cells_have_avx2()
    void cells_score(
        int avx2, const uint16_t *rows, const uint16_t *table, const int64_t *masses,
        const double *explained, int n_shares, const uint16_t *cells, const uint16_t *units,
        int64_t m, int64_t slots, double per_unit, double *out,
    ) nogil

# Shares the kernel scores at once: 16 shares of ``f p`` and ``p`` in 16 bits are one 64-byte
# table row, and 32 sums the compiler keeps in vector registers. More shares: NumPy's kernel.
MAX_SHARES = 16
# Whether this processor runs the AVX2 loop (x86-64 with AVX2); else the portable one serves.
AVX2 = bool(cells_have_avx2())


def part_scorer(part, shares, avx2=AVX2):
    """`cfsig.search.cells.cell_scores` of one part, compiled: one pass over each row's cells.

    The part's histograms are laid out once (`cfsig.search.cells.part_table`), for every block
    of rows the scorer is given.

    Parameters
    ----------
    part : sequence of (cells, fractions)
        The part's `cfsig.descriptors.cells.cell_histogram` at each share, cells below 65,536.
    shares : tuple of float
        The shares, one per histogram of ``part``; at most `MAX_SHARES`.
    avx2 : bool
        Score by the AVX2 loop (where `AVX2`) or by the portable one: the same scores.

    Returns
    -------
    scorer : callable
        ``scorer(cells, units)``: the wholes' (m, slots) uint16 cells, ascending then zeros, and
        their (m, slots) uint16 shares of the area (`cfsig.descriptors.cells.packed_cells`) to
        their (m,) float64 scores, dimensionless; it releases the GIL while it scores.

    Raises
    ------
    ValueError
        More than `MAX_SHARES` shares, or the AVX2 loop asked for where the processor lacks it.
    """
    if len(shares) > MAX_SHARES:
        raise ValueError(f"{len(shares)} shares: the compiled kernel takes {MAX_SHARES} at most")
    if avx2 and not AVX2:
        raise ValueError("this processor has no AVX2")
    rows, table, masses, explained = part_table(part, shares, MAX_SHARES)
    table = np.ascontiguousarray(table.reshape(len(table), CELLS_WIDTH))  # f p, then p
    masses = np.ascontiguousarray(masses[: len(shares)])  # the padding shares are not scored
    explained = np.ascontiguousarray(explained[: len(shares)])

    def scorer(cells, units):
        cells = np.ascontiguousarray(cells, np.uint16)
        units = np.ascontiguousarray(units, np.uint16)
        out = np.empty(len(cells))
        _scores(rows, table, masses, explained, cells, units, out, avx2)
        return out

    return scorer


cdef void _scores(
    const uint16_t[::1] rows,
    const uint16_t[:, ::1] table,
    const int64_t[::1] masses,
    const double[::1] explained,
    const uint16_t[:, ::1] cells,
    const uint16_t[:, ::1] units,
    double[::1] out,
    bint avx2,
) noexcept:
    """Score each row of ``cells`` and ``units`` into ``out``, without the GIL.

    ``rows`` (65536,): each cell's row of ``table`` (h + 1, CELLS_WIDTH), 0 for the cells the
    part lacks; ``masses`` (s,) int64 and ``explained`` (s,) float64: the part's ``P`` and
    ``1 / F`` at each of its s shares; ``out`` (m,): the least over the shares of
    ``(1 - E / F) + (P + W - 2 C) / UNIT``, dimensionless.
    """
    cdef int64_t m = cells.shape[0], slots = cells.shape[1]
    if m == 0:
        return
    cdef double per_unit = 1.0 / UNIT  # float64, as `cell_scores` multiplies by it
    cdef const uint16_t *cell_data = &cells[0, 0] if slots else NULL
    cdef const uint16_t *unit_data = &units[0, 0] if slots else NULL
    with nogil:
        cells_score(
            avx2, &rows[0], &table[0, 0], &masses[0], &explained[0], <int>masses.shape[0],
            cell_data, unit_data, m, slots, per_unit, &out[0],
        )
