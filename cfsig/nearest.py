"""Nearest neighbours: rank indexed signatures by L1 distance to query signatures (paper 2.3).

Every descriptor's vector is built so that its L1 distance is the descriptor's distance
(`signature.signature_of`), so the search is the same for all.
"""

from __future__ import annotations

import os
import threading
from collections.abc import Callable, Iterator
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass
from typing import TypeVar

import numpy as np

from .blocks import Block, plan_blocks, read_block, read_rows
from .codes import encode, sad
from .index import Entry, IndexReader, SegmentView
from .l1 import choose_kernel

_BLOCK_ROWS = 16384  # rows per block of a dataset that is not chunked
_OUT_CELLS = 1 << 20  # distances computed per kernel call (4 MB): bounds memory for many queries
# Up to this many queries scan the 8-bit codes (a byte per value, one pass per query); more scan
# the float32 rows, where faiss computes ten queries per pass (docs/index-scale.md).
CODES_MAX_QUERIES = 4
_MARGIN = 1e-4  # relative: float32 sums of a few hundred terms are far closer than this
_T = TypeVar("_T")


@dataclass(frozen=True)
class Hit:
    """One search result.

    Attributes
    ----------
    rank : int
        1 for the nearest.
    distance : float
        L1 distance between the signature vectors (in [0, 2] for ``cf`` histograms).
    entry : Entry
        Name, label and path of the indexed mesh.
    """

    rank: int
    distance: float
    entry: Entry


def l1_distances(queries: np.ndarray, signatures: np.ndarray) -> np.ndarray:
    """L1 distances between two sets of signatures, ``d(S1, S2) = sum_i |S1_i - S2_i|``.

    Parameters
    ----------
    queries : (q, length) float
        Query signatures.
    signatures : (N, length) float
        Signatures to compare with.

    Returns
    -------
    distances : (q, N) float64
        Between 0 and 2 for histograms that sum to 1; computed in float32 like `nearest`.
    """
    queries, signatures = _float32(queries), _float32(signatures)
    out = np.empty((len(queries), len(signatures)), np.float32)
    choose_kernel(out.size)(queries, signatures, out)
    return out.astype(np.float64)


def nearest(reader: IndexReader, queries: np.ndarray, k: int) -> tuple[np.ndarray, np.ndarray]:
    """The k nearest indexed signatures of each query, streaming the index in blocks.

    All queries share one pass over the segments, made by one thread per core; memory stays
    bounded by a few blocks of rows whatever the index size. Superseded rows are skipped.

    Parameters
    ----------
    reader : IndexReader
        An open index with N entries.
    queries : (q, length) float
        Query signatures, made with the index's parameters (and so its descriptor).
    k : int
        Number of results per query; at most N are returned.

    Returns
    -------
    rows : (q, min(k, N)) int64
        Row numbers of the results, nearest first, ties broken by row number.
    distances : (q, min(k, N)) float64
        Their L1 distances, accumulated in float32.
    """
    queries = _float32(np.atleast_2d(queries))
    n = len(reader)
    best = _Best(len(queries), max(min(k, n), 0), reader.physical_rows)
    if best.k == 0 or len(queries) == 0:
        return best.result(reader)
    coded = all(view.codes is not None for view in reader.segments)
    if coded and len(queries) <= CODES_MAX_QUERIES:
        _scan_codes(reader, queries, best)
    else:
        _scan_rows(reader, queries, best)
    return best.result(reader)


def _scan_rows(reader: IndexReader, queries: np.ndarray, best: _Best) -> None:
    """`nearest` by the float32 rows: every distance computed, queries in groups."""
    blocks = [
        (view, b) for view in reader.segments for b in plan_blocks(view.signatures, _BLOCK_ROWS)
    ]
    kernel = choose_kernel(len(queries) * len(reader))
    todo = iter(blocks)
    lock = threading.Lock()

    def work() -> None:
        block_rows = max(b.stop - b.start for _, b in blocks)
        buffer = np.empty((block_rows, queries.shape[1]), np.float32)
        group = max(1, _OUT_CELLS // block_rows)
        out = np.empty(min(group, len(queries)) * block_rows, np.float32)
        while (task := _next(todo, lock)) is not None:
            view, block = task
            rows = read_block(view.signatures, block, buffer)
            live = _live(view, block)
            for q0 in range(0, len(queries), group):
                count = len(queries[q0 : q0 + group])
                dist = out[: count * len(rows)].reshape(count, len(rows))  # C-contiguous
                kernel(queries[q0 : q0 + group], rows, dist)
                with lock:
                    best.merge(q0, view.start + block.start, dist, live)

    _in_threads(work, len(blocks))


def _scan_codes(reader: IndexReader, queries: np.ndarray, best: _Best) -> None:
    """`nearest` by the 8-bit codes: bounds on every distance, then the candidates exactly.

    A row is a candidate while the lower bound of its distance (`cfsig.codes`) is within the
    k-th smallest upper bound seen; the distances of the candidates left at the end are then
    computed from their float32 rows, so the result is that of `_scan_rows`.
    """
    views = reader.segments
    grids = [view.grid for view in views if view.grid is not None]
    coded = [encode(queries, *g) for g in grids]
    blocks = [(i, b) for i, view in enumerate(views) for b in plan_blocks(view.codes, _BLOCK_ROWS)]
    code_errors = [view.signatures.file["code_error"][:] for view in views]  # 8 bytes a row
    bounds = _Bounds(len(queries), best.k)
    todo = iter(blocks)
    lock = threading.Lock()

    def work() -> None:
        block_rows = max(b.stop - b.start for _, b in blocks)
        buffer = np.empty((block_rows, coded[0][0].shape[1]), np.uint8)
        while (task := _next(todo, lock)) is not None:
            i, block = task
            view, (query_codes, query_errors) = views[i], coded[i]
            codes = read_block(view.codes, block, buffer)
            errors = code_errors[i][block.start : block.stop]
            live = _live(view, block)
            for j in range(len(queries)):
                approx = sad(codes, query_codes[j]) * grids[i][1]
                slack = errors + query_errors[j]
                low = np.where(np.isfinite(slack), approx - slack, -np.inf)
                high = approx + slack
                if live is not None:  # never candidates (NaN is within no limit)
                    low[~live], high[~live] = np.nan, np.inf
                with lock:
                    bounds.take(j, view.start + block.start, low, high)

    _in_threads(work, len(blocks))
    starts = np.array([view.start for view in views])
    plans = [plan_blocks(view.signatures, _BLOCK_ROWS) for view in views]
    for j in range(len(queries)):
        rows = bounds.candidates(j)
        vectors = np.empty((len(rows), queries.shape[1]), np.float32)
        which = np.searchsorted(starts, rows, "right") - 1
        for i in np.unique(which):
            mine = which == i
            local = rows[mine] - views[i].start
            vectors[mine] = read_rows(views[i].signatures, plans[i], local, vectors[mine])
        dist = np.empty((1, len(rows)), np.float32)
        choose_kernel(len(rows))(queries[j : j + 1], vectors, dist)
        best.take(j, rows, dist[0])


def search(reader: IndexReader, queries: np.ndarray, k: int = 20) -> list[list[Hit]]:
    """The k nearest indexed meshes of each query, with their names and labels.

    Parameters
    ----------
    reader : IndexReader
        An open index.
    queries : (q, length) float
        Query signatures, made with the index's parameters (and so its descriptor).
    k : int
        Results per query.

    Returns
    -------
    hits : list of list of Hit
        One list per query, nearest first.
    """
    rows, dists = nearest(reader, queries, k)
    entries = reader.entries(rows.ravel()) if rows.size else []
    it = iter(entries)
    return [[Hit(rank + 1, float(d), next(it)) for rank, d in enumerate(row)] for row in dists]


class _Best:
    """The k smallest distances seen so far for each query, ties broken by row number."""

    def __init__(self, n_queries: int, k: int, n_rows: int) -> None:
        self.k = k
        # NaN sorts after every distance, and the row number n after every row: the placeholders
        # are the first to go, and every row is a candidate until k are held.
        self.dist = np.full((n_queries, k), np.nan, np.float32)
        self.rows = np.full((n_queries, k), n_rows, np.int64)

    def merge(
        self, first_query: int, first_row: int, dist: np.ndarray, live: np.ndarray | None
    ) -> None:
        """Take in distances (q, m) from queries ``first_query...`` to rows ``first_row...``.

        Rows where ``live`` (m,) is false, superseded ones, are left out.
        """
        held = slice(first_query, first_query + len(dist))
        candidates = ~(dist > self.dist[held, -1:])  # also true for NaN
        if live is not None:
            candidates &= live
        for j in np.flatnonzero(candidates.any(axis=1)):
            new = np.flatnonzero(candidates[j])
            self.take(first_query + j, new + first_row, dist[j, new])

    def take(self, query: int, rows: np.ndarray, dist: np.ndarray) -> None:
        """Take in the distances (m,) from one query to some rows (m,)."""
        d = np.concatenate([self.dist[query], dist])
        r = np.concatenate([self.rows[query], rows])
        keep = np.lexsort((r, d))[: self.k]
        self.dist[query], self.rows[query] = d[keep], r[keep]

    def result(self, reader: IndexReader) -> tuple[np.ndarray, np.ndarray]:
        """Row numbers of the reader and distances, nearest first."""
        return reader.logical_rows(self.rows.ravel()).reshape(self.rows.shape), self.dist.astype(
            np.float64
        )


class _Bounds:
    """Per query: the k smallest upper bounds seen, and the rows whose lower bound is within."""

    def __init__(self, n_queries: int, k: int) -> None:
        self.upper = np.full((n_queries, k), np.inf)
        self.found: list[list[tuple[np.ndarray, np.ndarray]]] = [[] for _ in range(n_queries)]

    def limit(self, query: int) -> float:
        """The largest distance a row among the k nearest can have, with a margin for float32."""
        return float(self.upper[query].max()) * (1 + _MARGIN) + _MARGIN

    def take(self, query: int, first_row: int, low: np.ndarray, high: np.ndarray) -> None:
        """Take in the bounds (m,) of the distances from one query to rows ``first_row...``."""
        k = self.upper.shape[1]
        both = np.concatenate([self.upper[query], high])
        self.upper[query] = np.partition(both, k - 1)[:k]
        keep = np.flatnonzero(low <= self.limit(query))
        if len(keep):
            self.found[query].append((keep + first_row, low[keep]))

    def candidates(self, query: int) -> np.ndarray:
        """The rows whose lower bound is within the final limit, sorted."""
        if not self.found[query]:
            return np.zeros(0, np.int64)
        rows, lows = (np.concatenate(parts) for parts in zip(*self.found[query], strict=True))
        return np.sort(rows[lows <= self.limit(query)])


def _live(view: SegmentView, block: Block) -> np.ndarray | None:
    """Which rows of a block are not superseded, or None when all are."""
    dead = view.dead[(view.dead >= block.start) & (view.dead < block.stop)] - block.start
    if not len(dead):
        return None
    live = np.ones(block.stop - block.start, bool)
    live[dead] = False
    return live


def _in_threads(work: Callable[[], None], tasks: int) -> None:
    """Run ``work`` in one thread per core (at most one per task) and wait for all."""
    threads = min(_threads(), tasks)
    with ThreadPoolExecutor(threads) as pool:
        for done in [pool.submit(work) for _ in range(threads)]:
            done.result()


def _next(blocks: Iterator[_T], lock: threading.Lock) -> _T | None:
    """The next block to scan (with its segment), shared by the threads."""
    with lock:
        return next(blocks, None)


def _threads() -> int:
    """Number of cores this process may run on."""
    if hasattr(os, "sched_getaffinity"):
        return len(os.sched_getaffinity(0))
    return os.cpu_count() or 1


def _float32(a: np.ndarray) -> np.ndarray:
    """A C-contiguous float32 copy or view."""
    return np.ascontiguousarray(a, dtype=np.float32)
