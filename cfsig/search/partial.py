"""Partial queries: rank the whole shapes that a measured part (`cfsig.descriptors.parts`)
comes from.

A whole's partial distance, over the shares a part was measured at, is the smallest sum of two
terms (`partial_scores`): the share of the part's histograms that the whole's cannot hold (a
part is a subset of its whole's surface), and their L1 distance. With fine cells
(`Params.partial_cells`) every row's cells are read and scored (`cfsig.search.cells`).

The nearest whole then stands for the part (query expansion): the others are ranked by their
whole-shape distance to it, so a part finds the relatives of its whole as a whole would.
"""

from __future__ import annotations

import mmap
import threading
from collections.abc import Callable, Sequence
from functools import partial

import numpy as np

from cfsig.descriptors.parts import FINE_SHARES, SHARES, Part, curvature_columns
from cfsig.errors import PartialError
from cfsig.index.blocks import Block, map_file, mapped_block, plan_blocks, read_block
from cfsig.index.store import IndexReader, SegmentView
from cfsig.params import Params
from cfsig.search.cells import cell_scores
from cfsig.search.nearest import Hit, l1_distances, nearest, parallel

# The L1 distance's weight beside the unexplained share in `partial_scores`: chosen on SHREC 2007
# alone, the best mean NN of its three kinds of parts (docs/method.md, "Partial queries").
HISTOGRAM_WEIGHT = 1.0
# Rows from which the compiled kernel repays laying out the part's table for it.
FAST_MIN_ROWS = 500
# A part's scores of blocks of wholes: ``scorer(cells, fractions)`` as `cell_scores`.
Scorer = Callable[[np.ndarray, np.ndarray], np.ndarray]
_CELL_BLOCK_ROWS = 4096  # rows of fine cells read at a time, as a segment stores them
_SCORE_ROWS = 512  # rows of fine cells scored at a time: bounds NumPy's scratch memory
# A thread's space for a block of fine cells: (rows, slots) uint16 cells, float32 fractions.
_CellBuffers = tuple[np.ndarray, np.ndarray]
# A block of fine cells to score: its segment, its blocks of cells and of fractions, and the
# memory map of the segment's file where they are plain bytes.
_CellTask = tuple[SegmentView, Block, Block, mmap.mmap | None]


def query_part(reader: IndexReader, part: Part, k: int = 20) -> tuple[list[Hit], float]:
    """The whole shapes related to a part: the nearest by its curvature, then its relatives.

    Parameters
    ----------
    reader : IndexReader
        An open index of the ``intrinsic`` descriptor.
    part : Part
        The part, measured with the index's parameters (`measure_part`).
    k : int
        Results.

    Returns
    -------
    hits : list of Hit
        The nearest whole by partial distance first, then the indexed meshes nearest to that
        whole; each ``distance`` is the whole-shape distance to the first.
    distance : float
        The part's partial distance to the first hit.

    Raises
    ------
    PartialError
        As `curvature_columns`.
    """
    columns = curvature_columns(reader.params)
    if part.cells is not None:
        found = _nearest_by_cells(reader, part.cells)
    else:
        assert part.vectors is not None  # a Part holds one or the other
        score = partial(partial_scores, mass=float(part.vectors[0].sum()))
        rows, dists = nearest(reader, share_queries(part.vectors), 1, columns, score)
        found = (int(rows[0, 0]), float(dists[0, 0])) if rows.size else None
    if found is None:
        return [], float("nan")
    first, fit = found
    near, near_dists = nearest(reader, reader.signatures[np.array([first])], k)
    others = [(int(r), float(d)) for r, d in zip(near[0], near_dists[0], strict=True) if r != first]
    ranked = [(first, 0.0), *others][:k]
    entries = reader.entries(np.array([r for r, _ in ranked]))
    hits = [Hit(i + 1, d, e) for i, ((_, d), e) in enumerate(zip(ranked, entries, strict=True))]
    return hits, fit


def _nearest_by_cells(
    reader: IndexReader, cells: tuple[tuple[np.ndarray, np.ndarray], ...]
) -> tuple[int, float] | None:
    """The row of the smallest partial distance by fine cells, and that distance; the first
    such row on ties; None for an empty index. Reads every live row's cells, chunk by chunk
    (`cfsig.index.blocks`), one thread per core: in place from a memory map of each segment file
    where they are plain bytes, else through a buffer."""
    tasks: list[_CellTask] = []
    for view in reader.segments:
        if view.cells is None:
            raise PartialError(f"{reader.path}: this index keeps no fine curvature cells")
        plans = [plan_blocks(data, _CELL_BLOCK_ROWS) for data in view.cells]
        plain = all(b.offset is not None for plan in plans for b in plan)
        mapped = map_file(view.cells[0]) if plain and plans[0] else None
        tasks += [(view, *pair, mapped) for pair in zip(*plans, strict=True)]
    score = part_scorer(cells, FINE_SHARES, sum(v.signatures.shape[0] for v in reader.segments))
    rows = max((b.stop - b.start for _, b, _, m in tasks if m is None), default=0)
    slots = max((v.cells[0].shape[1] for v in reader.segments if v.cells), default=1)
    found: list[tuple[float, int]] = []

    def work(task: _CellTask, buffers: _CellBuffers, lock: threading.Lock) -> None:
        view, block, same, mapped = task
        assert view.cells is not None and block.start == same.start  # one chunking: index.py
        if mapped is None:
            stored = read_block(view.cells[0], block, buffers[0])
            fractions = read_block(view.cells[1], same, buffers[1])
        else:
            stored = mapped_block(view.cells[0], block, mapped)
            fractions = mapped_block(view.cells[1], same, mapped)
        scores = np.concatenate(
            [
                score(stored[i : i + _SCORE_ROWS], fractions[i : i + _SCORE_ROWS])
                for i in range(0, len(stored), _SCORE_ROWS)
            ]
        )
        start, stop = block.start, block.stop
        scores[view.dead[(view.dead >= start) & (view.dead < stop)] - start] = np.inf
        at = int(np.argmin(scores))
        if np.isfinite(scores[at]):
            with lock:
                found.append((float(scores[at]), view.start + start + at))

    def make_buffers() -> _CellBuffers:
        return np.empty((rows, slots), np.uint16), np.empty((rows, slots), np.float32)

    parallel(tasks, work, make_buffers)
    if not found:
        return None
    best, physical = min(found)
    return int(reader.logical_rows(np.array([physical]))[0]), best


def partial_distances(
    part: Part,
    signatures: np.ndarray,
    params: Params,
    cells: tuple[np.ndarray, np.ndarray] | None = None,
) -> np.ndarray:
    """The partial distance of a part to every whole of a collection held in memory.

    Parameters
    ----------
    part : Part
        The part, measured with ``params`` (`measure_part`).
    signatures : (N, length) float
        The wholes' signatures, made with ``params``.
    params : Params
        Their parameters.
    cells : ((N, slots) uint16, (N, slots) float32), optional
        The wholes' fine cells and fractions (`cfsig.descriptors.signature.Signature.cells`),
        needed when
        ``params`` keep them.

    Returns
    -------
    distances : (N,) float64
        `partial_scores` of the wholes, or by their fine cells
        `cfsig.descriptors.cells.part_scorer`.

    Raises
    ------
    ValueError
        The part has fine cells and ``cells`` is None.
    """
    if part.cells is not None:
        if cells is None:
            raise ValueError("a part measured by fine cells needs the wholes' cells")
        return part_scorer(part.cells, FINE_SHARES, len(cells[0]))(*cells)
    assert part.vectors is not None  # a Part holds one or the other
    stored = np.asarray(signatures, np.float32)[:, curvature_columns(params)]
    distances = l1_distances(share_queries(part.vectors), stored)
    return partial_scores(distances, float(part.vectors[0].sum()))


def share_queries(vectors: np.ndarray) -> np.ndarray:
    """The rows whose L1 distances to the wholes `partial_scores` takes.

    Parameters
    ----------
    vectors : (len(SHARES), columns) float
        `partial_vectors` of a part.

    Returns
    -------
    queries : (2 * len(SHARES), columns) float64
        Each share's vector times the share, then the vectors as they are.
    """
    return np.concatenate([np.asarray(SHARES)[:, None] * vectors, vectors])


def partial_scores(
    distances: np.ndarray, mass: float, weight: float = HISTOGRAM_WEIGHT
) -> np.ndarray:
    """The partial distance of each whole: unexplained share plus L1 distance, at the best share.

    For a part ``p`` measured as the share ``f`` of a whole ``w`` (histograms of equal mass
    ``m``), the part's histograms scaled by ``f`` lie under its whole's, bin for bin, as its
    surface lies within the whole's. The unexplained share ``sum(max(f p - w, 0)) / (f m)``, in
    [0, 1], measures how far they do not; alone it would favour the smallest shares, which
    explain least, so ``weight`` times the L1 distance ``sum|p - w| / m``, in [0, 2],
    is added. Since ``sum|f p - w| = 2 sum(max(f p - w, 0)) + (1 - f) m``, both terms come
    from L1 distances, which the blockwise search computes.

    Parameters
    ----------
    distances : (2 * len(SHARES), N) float
        L1 distances of the part's `share_queries` to the curvature columns of N wholes.
    mass : float
        The sum of one of the part's `partial_vectors`, which equals a whole's.
    weight : float
        The L1 distance's weight (`HISTOGRAM_WEIGHT`).

    Returns
    -------
    scores : (N,) float, of ``distances``'s type
        The smallest sum over the shares, dimensionless, in [0, 3].
    """
    shares = np.asarray(SHARES, distances.dtype)[:, None]
    scaled, plain = distances[: len(SHARES)], distances[len(SHARES) :]
    unexplained = np.maximum(scaled - (1 - shares) * mass, 0) / (2 * shares * mass)
    return (unexplained + weight * plain / mass).min(axis=0)


def expanded_distances(
    part: Part,
    signatures: np.ndarray,
    params: Params,
    cells: tuple[np.ndarray, np.ndarray] | None = None,
) -> np.ndarray:
    """Distances that rank a collection held in memory as `query_part` ranks an index.

    Parameters
    ----------
    part : Part
        The part, measured with ``params`` (`measure_part`).
    signatures : (N, length) float
        The wholes' signatures, made with ``params``.
    params : Params
        Their parameters.
    cells : ((N, slots) uint16, (N, slots) float32), optional
        As `partial_distances`.

    Returns
    -------
    distances : (N,) float64
        -1 for the nearest whole by partial distance, the whole-shape distance to it for the
        others.
    """
    first = int(np.argmin(partial_distances(part, signatures, params, cells)))
    distances = l1_distances(signatures[first : first + 1], signatures)[0]
    distances[first] = -1.0
    return distances


def part_scorer(
    part: Sequence[tuple[np.ndarray, np.ndarray]], shares: tuple[float, ...], rows: int
) -> Scorer:
    """`cfsig.search.cells.cell_scores` of one part, by the compiled kernel where it pays.

    Parameters
    ----------
    part, shares
        As `cfsig.search.cells.cell_scores`.
    rows : int
        Rows the search will score: from `FAST_MIN_ROWS`, the kernel compiled when cfsig was
        installed (`cfsig.search.cells_compiled`) for parts of at most its ``MAX_SHARES``
        shares; else, or where it was not built, NumPy's: the same scores.

    Returns
    -------
    scorer : callable
        ``scorer(cells, fractions)``: the wholes' (m, slots) cells and fractions to their (m,)
        float64 scores.
    """
    if rows >= FAST_MIN_ROWS:
        try:
            import cfsig.search.cells_compiled as cells_compiled
        except ImportError:  # installed without a C compiler
            pass
        else:
            if len(shares) <= cells_compiled.MAX_SHARES:
                scorer: Scorer = cells_compiled.part_scorer(part, shares)
                return scorer
    return partial(cell_scores, part, shares)
