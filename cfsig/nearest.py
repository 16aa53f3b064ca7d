"""Nearest neighbours: rank indexed signatures by L1 distance to query signatures (paper 2.3).

Every descriptor's vector is built so that its L1 distance is the descriptor's distance
(`signature.signature_of`), so the search is the same for all.
"""

from __future__ import annotations

import os
import threading
from collections.abc import Iterator
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass

import numpy as np

from .blocks import Block, plan_blocks, read_block
from .index import Entry, IndexReader, SegmentView
from .l1 import choose_kernel

_BLOCK_ROWS = 16384  # rows per block of a dataset that is not chunked
_OUT_CELLS = 1 << 20  # distances computed per kernel call (4 MB): bounds memory for many queries


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


def nearest(
    reader: IndexReader, queries: np.ndarray, k: int, columns: slice | None = None
) -> tuple[np.ndarray, np.ndarray]:
    """The k nearest indexed signatures of each query, streaming the index in blocks.

    All queries share one pass over the segments, made by one thread per core; memory stays
    bounded by a few blocks of rows whatever the index size. Superseded rows are skipped.

    Parameters
    ----------
    reader : IndexReader
        An open index with N entries.
    queries : (q, length) float
        Query signatures, made with the index's parameters (and so its descriptor); with
        ``columns``, only those columns of them.
    k : int
        Number of results per query; at most N are returned.
    columns : slice, optional
        Compare only these columns of the stored signatures (one channel of a descriptor).

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
    blocks = [
        (view, b) for view in reader.segments for b in plan_blocks(view.signatures, _BLOCK_ROWS)
    ]
    kernel = choose_kernel(len(queries) * n)
    todo = iter(blocks)
    lock = threading.Lock()

    def work() -> None:
        block_rows = max(b.stop - b.start for _, b in blocks)
        buffer = np.empty((block_rows, reader.signatures.shape[1]), np.float32)
        group = max(1, _OUT_CELLS // block_rows)
        out = np.empty(min(group, len(queries)) * block_rows, np.float32)
        while (task := _next(todo, lock)) is not None:
            view, block = task
            rows = read_block(view.signatures, block, buffer)
            if columns is not None:
                rows = np.ascontiguousarray(rows[:, columns])
            dead = view.dead[(view.dead >= block.start) & (view.dead < block.stop)] - block.start
            live = None
            if len(dead):
                live = np.ones(len(rows), bool)
                live[dead] = False
            for q0 in range(0, len(queries), group):
                count = len(queries[q0 : q0 + group])
                dist = out[: count * len(rows)].reshape(count, len(rows))  # C-contiguous
                kernel(queries[q0 : q0 + group], rows, dist)
                with lock:
                    best.merge(q0, view.start + block.start, dist, live)

    threads = min(_threads(), len(blocks))
    with ThreadPoolExecutor(threads) as pool:
        for done in [pool.submit(work) for _ in range(threads)]:
            done.result()
    return best.result(reader)


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
            d = np.concatenate([self.dist[first_query + j], dist[j, new]])
            r = np.concatenate([self.rows[first_query + j], new + first_row])
            keep = np.lexsort((r, d))[: self.k]
            self.dist[first_query + j], self.rows[first_query + j] = d[keep], r[keep]

    def result(self, reader: IndexReader) -> tuple[np.ndarray, np.ndarray]:
        """Row numbers of the reader and distances, nearest first."""
        return reader.logical_rows(self.rows.ravel()).reshape(self.rows.shape), self.dist.astype(
            np.float64
        )


def _next(
    blocks: Iterator[tuple[SegmentView, Block]], lock: threading.Lock
) -> tuple[SegmentView, Block] | None:
    """The next block to scan and its segment, shared by the threads."""
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
