"""Scoring a part's fine curvature cells against every whole's (`cfsig.descriptors.cells`).

A part's score against a whole is, at the best of its shares, the share of the part's cells
that the whole's cannot hold plus the area the two do not share (docs/method.md, "Partial
queries"). The shares of an area are summed as integers in units of ``1 / UNIT``
(`cfsig.descriptors.cells.area_units`), as the index keeps them, so that the NumPy reference
`cell_scores` and the compiled kernel (`cfsig.search.cells_compiled`) give the same scores to the
last bit.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from cfsig.descriptors.cells import UNIT, area_units

_ROWS = 512  # rows `cell_scores` scores at a time: bounds its scratch memory


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
    rows = np.zeros(1 << 16, np.uint16)  # 24,057 cells with partial cells: rows fit in 16 bits
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
    units: np.ndarray,
) -> np.ndarray:
    """The partial distance of a part to some wholes by their cells.

    For a share ``f``, with the part's histogram ``p`` and a whole's ``w`` (each of mass 1),
    ``(1 - sum(min(f p, w)) / f) + sum(|p - w|)``: the unexplained share plus the L1 distance,
    `cfsig.search.partial.partial_scores` with weight 1; the smallest over the shares. Both terms
    are summed in integers, on the shares in units of ``1 / UNIT`` (`area_units`;
    docs/method.md, "Fine curvature cells"): ``1 - E / F`` and ``(P + W - 2 C) / UNIT``, with
    ``E`` and ``C`` the sums of ``min(f p, w)`` and ``min(p, w)``, ``F`` and ``P`` those of
    ``f p`` and ``p``, ``W`` that of ``w``; `cfsig.search.cells_compiled` computes the same
    numbers.

    Parameters
    ----------
    part : sequence of (cells, fractions)
        The part's `cell_histogram` at each share.
    shares : tuple of float
        The shares, one per histogram of ``part``.
    cells : (m, slots) int
        The wholes' `packed_cells`, below 65,536.
    units : (m, slots) uint16
        Their shares of the area in units of ``1 / UNIT``.

    Returns
    -------
    scores : (m,) float64
        Dimensionless, in [0, 3] up to the rounding to units: 0 for a whole that is its own
        part at share 1.
    """
    laid_out = part_table(part, shares, len(shares))
    scores = [
        _scores(*laid_out, cells[i : i + _ROWS], units[i : i + _ROWS])
        for i in range(0, len(cells), _ROWS)
    ]
    return np.concatenate([np.zeros(0), *scores])


def _scores(
    rows: np.ndarray,
    table: np.ndarray,
    masses: np.ndarray,
    explained: np.ndarray,
    cells: np.ndarray,
    units: np.ndarray,
) -> np.ndarray:
    """`cell_scores` of some rows, from the part's `part_table`."""
    at = rows[cells]
    both = (at > 0) & (units > 0)
    counts = both.sum(axis=1)
    gained = np.minimum(table[at[both]], units[both][:, None, None])  # (entries, 2, shares)
    totals = np.zeros((len(cells), 2, len(masses)), np.int64)
    filled = np.flatnonzero(counts)
    if len(filled):
        starts = np.concatenate([[0], np.cumsum(counts[filled])[:-1]])
        totals[filled] = np.add.reduceat(gained, starts, axis=0, dtype=np.int64)
    wholes = units.sum(axis=1, dtype=np.int64)[:, None]
    lost = masses + wholes - 2 * totals[:, 1]
    return ((1 - totals[:, 0] * explained) + lost * (1 / UNIT)).min(axis=1)
