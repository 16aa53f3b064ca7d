"""Partial queries: rank the whole shapes that a measured part (`cfsig.descriptors.parts`)
comes from.

A whole's partial distance, over the shares a part was measured at, is the smallest sum of two
terms (`partial_scores`): the share of the part's histograms that the whole's cannot hold (a
part is a subset of its whole's surface), and their L1 distance. With fine cells
(`Params.partial_cells`) every row's cells are read and scored (`cfsig.search.cells`).

The whole that stands for the part is the one of least `fused_scores` among the `CANDIDATES`
nearest by partial distance and the `CANDIDATES` nearest to the part with its holes closed
(`cfsig.descriptors.parts.closed_vector`) by whole-shape distance: the closer the closed part
lies to some whole, the more that distance counts, and the more nearly the part is a single
view, the less its partial distance does. That whole then stands for the part (query
expansion): the others are ranked by their whole-shape distance to it, so a part finds the
relatives of its whole as a whole would.
"""

from __future__ import annotations

import mmap
import threading
from collections.abc import Callable, Sequence
from functools import partial

import numpy as np

from cfsig.descriptors.parts import FINE_SHARES, SHARES, Part, curvature_columns
from cfsig.errors import PartialError
from cfsig.index.blocks import Block, load_block, map_file, plan_blocks
from cfsig.index.store import IndexReader, SegmentView
from cfsig.params import Params
from cfsig.search.cells import cell_scores
from cfsig.search.nearest import Hit, l1_distances, nearest, parallel

# The L1 distance's weight beside the unexplained share in `partial_scores`: chosen on SHREC 2007
# alone, the best mean NN of its three kinds of parts (docs/method.md, "Partial queries").
HISTOGRAM_WEIGHT = 1.0
# Wholes that each of the two measures puts forward to `fused_scores` (`candidates`).
CANDIDATES = 32
# The closed part's whole-shape distance counts CLOSED_WEIGHT * exp(-d / CLOSED_SCALE) beside
# its partial distance, d the closed part's distance to its nearest whole: chosen on SHREC 2007
# alone (docs/method.md, "Partial queries").
CLOSED_WEIGHT = 1.0
CLOSED_SCALE = 1.1
# Rows from which the compiled kernel repays laying out the part's table for it.
FAST_MIN_ROWS = 500
# A part's scores of blocks of wholes: ``scorer(cells, units)`` as `cell_scores`.
Scorer = Callable[[np.ndarray, np.ndarray], np.ndarray]
_FLOOR = 1e-9  # the least distance `fused_scores` divides by: a part equal to a whole scores 0
_CELL_BLOCK_ROWS = 4096  # rows of fine cells read at a time, as a segment stores them
# A thread's space for a block of fine cells: (rows, slots) uint16 cells and shares.
_CellBuffers = tuple[np.ndarray, np.ndarray]
# A block of fine cells to score: its segment, its blocks of cells and of shares, and the
# memory map of the segment's file (None where it cannot be mapped).
_CellTask = tuple[SegmentView, Block, Block, mmap.mmap | None]


def query_part(reader: IndexReader, part: Part, k: int = 20) -> tuple[list[Hit], float]:
    """The whole shapes related to a part: the one that stands for it, then its relatives.

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
        The whole of least `fused_scores` among the `candidates` first, then the indexed
        meshes nearest to that whole; each ``distance`` is the whole-shape distance to the
        first.
    distance : float
        The part's partial distance to the first hit.

    Raises
    ------
    PartialError
        As `curvature_columns`.
    """
    columns = curvature_columns(reader.params)
    if part.cells is not None:
        rows, _ = _nearest_by_cells(reader, part.cells, CANDIDATES)
    else:
        assert part.vectors is not None  # a Part holds one or the other
        score = partial(partial_scores, mass=float(part.vectors[0].sum()))
        rows = nearest(reader, share_queries(part.vectors), CANDIDATES, columns, score)[0][0]
    if not len(rows):
        return [], float("nan")
    if part.closed is not None:
        rows = np.union1d(rows, nearest(reader, part.closed[None], CANDIDATES)[0][0])
    signatures, cells = reader.signatures[rows], reader.cells_at(rows)
    fits = partial_distances(part, signatures, reader.params, cells)
    closed = _closed_distances(part, signatures)
    at = int(np.argmin(fused_scores(fits, closed, part.one_sided)))
    first, fit = int(rows[at]), float(fits[at])
    near, near_dists = nearest(reader, signatures[at : at + 1], k)
    others = [(int(r), float(d)) for r, d in zip(near[0], near_dists[0], strict=True) if r != first]
    ranked = [(first, 0.0), *others][:k]
    entries = reader.entries(np.array([r for r, _ in ranked]))
    hits = [Hit(i + 1, d, e) for i, ((_, d), e) in enumerate(zip(ranked, entries, strict=True))]
    return hits, fit


def _nearest_by_cells(
    reader: IndexReader, cells: tuple[tuple[np.ndarray, np.ndarray], ...], k: int
) -> tuple[np.ndarray, np.ndarray]:
    """The k rows of the smallest partial distances by fine cells, nearest first (ties by row),
    and those distances; none for an empty index. Reads every live row's cells, chunk by chunk
    (`cfsig.index.blocks`), one thread per core: in place from a memory map of each segment file
    where they are plain bytes, else through a buffer."""
    tasks: list[_CellTask] = []
    for view in reader.segments:
        if view.cells is None:
            raise PartialError(f"{reader.path}: this index keeps no fine curvature cells")
        plans = [plan_blocks(data, _CELL_BLOCK_ROWS) for data in view.cells]
        mapped = map_file(view.cells[0])
        tasks += [(view, *pair, mapped) for pair in zip(*plans, strict=True)]
    score = part_scorer(cells, FINE_SHARES, sum(v.signatures.shape[0] for v in reader.segments))
    # Space for the blocks not viewed in place; np.empty commits no memory until it is written.
    rows = max((b.stop - b.start for _, b, _, _ in tasks), default=0)
    slots = max((v.cells[0].shape[1] for v in reader.segments if v.cells), default=1)
    found: list[tuple[np.ndarray, np.ndarray]] = []

    def work(task: _CellTask, buffers: _CellBuffers, lock: threading.Lock) -> None:
        view, block, same, mapped = task
        assert view.cells is not None and block.start == same.start  # one chunking: index.py
        stored = load_block(view.cells[0], block, buffers[0], mapped)
        units = load_block(view.cells[1], same, buffers[1], mapped)
        scores = score(stored, units)
        start, stop = block.start, block.stop
        scores[view.dead[(view.dead >= start) & (view.dead < stop)] - start] = np.inf
        best = np.argsort(scores, kind="stable")[:k]
        best = best[np.isfinite(scores[best])]
        with lock:
            found.append((scores[best], view.start + start + best))

    def make_buffers() -> _CellBuffers:
        return np.empty((rows, slots), np.uint16), np.empty((rows, slots), np.uint16)

    parallel(tasks, work, make_buffers)
    scores = np.concatenate([np.zeros(0), *(f[0] for f in found)])
    physical = np.concatenate([np.zeros(0, np.int64), *(f[1] for f in found)])
    best = np.lexsort((physical, scores))[:k]
    return reader.logical_rows(physical[best]), scores[best]


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
    cells : ((N, slots) uint16, (N, slots) uint16), optional
        The wholes' fine cells and their shares (`cfsig.descriptors.signature.Signature.cells`),
        needed when ``params`` keep them.

    Returns
    -------
    distances : (N,) float64
        `partial_scores` of the wholes, or by their fine cells `part_scorer`.

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
    cells : ((N, slots) uint16, (N, slots) uint16), optional
        As `partial_distances`.

    Returns
    -------
    distances : (N,) float64
        -1 for the whole of least `fused_scores` among the `candidates`, the whole-shape
        distance to it for the others.
    """
    fits = partial_distances(part, signatures, params, cells)
    closed = _closed_distances(part, signatures)
    rows = candidates(fits, closed)
    picked = None if closed is None else closed[rows]
    first = int(rows[np.argmin(fused_scores(fits[rows], picked, part.one_sided))])
    distances = l1_distances(signatures[first : first + 1], signatures)[0]
    distances[first] = -1.0
    return distances


def candidates(partial: np.ndarray, closed: np.ndarray | None) -> np.ndarray:
    """The rows `fused_scores` chooses among: the `CANDIDATES` nearest by each measure.

    Parameters
    ----------
    partial : (N,) float
        Partial distances of N wholes.
    closed : (N,) float or None
        Whole-shape distances of the closed part to them (`_closed_distances`).

    Returns
    -------
    rows : (c,) int64
        Ascending; c at most ``2 * CANDIDATES``. Ties go to the lower row, as `nearest` breaks
        them.
    """
    nearest_first = [np.argsort(partial, kind="stable")[:CANDIDATES]]
    if closed is not None:
        nearest_first.append(np.argsort(closed, kind="stable")[:CANDIDATES])
    return np.unique(np.concatenate(nearest_first)).astype(np.int64)


def fused_scores(
    partial: np.ndarray, closed: np.ndarray | None, one_sided: float = 0.0
) -> np.ndarray:
    """The score by which a part's candidate wholes are ranked: partial and closed distances.

    Each distance is taken relative to its smallest over the candidates (which hold the
    smallest over all wholes), so that the two add without a unit. The closed part's distance
    weighs ``CLOSED_WEIGHT * exp(-d / CLOSED_SCALE)``, ``d`` its smallest: a part that closes into
    the likeness of some whole (a shape with holes, most of a shape) is told by its whole-shape
    distance, a half mostly by its partial distance. The partial distance weighs
    ``1 - one_sided``: the curvature of a single view, a half-surface of every limb, is unlike
    that of any part of its whole.

    Parameters
    ----------
    partial : (c,) float
        Partial distances of the candidates (`partial_distances`).
    closed : (c,) float or None
        Whole-shape distances of the closed part to them; None for a part without one.
    one_sided : float
        The part's `cfsig.descriptors.parts.one_sidedness`, in [0, 1].

    Returns
    -------
    scores : (c,) float64
        Smallest best; the partial distances themselves when ``closed`` is None.
    """
    partial = np.asarray(partial, np.float64)
    if closed is None:
        return partial
    closed = np.asarray(closed, np.float64)
    least = float(closed.min())
    weight = CLOSED_WEIGHT * np.exp(-least / CLOSED_SCALE)
    relative = partial / max(float(partial.min()), _FLOOR)
    return (1 - one_sided) * relative + weight * closed / max(least, _FLOOR)


def _closed_distances(part: Part, signatures: np.ndarray) -> np.ndarray | None:
    """Whole-shape distances of the closed part to some wholes; None for a part without one."""
    if part.closed is None:
        return None
    return l1_distances(part.closed[None], np.asarray(signatures, np.float32))[0]


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
        ``scorer(cells, units)``: the wholes' (m, slots) cells and shares to their (m,) float64
        scores.
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
