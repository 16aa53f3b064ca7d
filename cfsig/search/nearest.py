"""Nearest neighbours: rank indexed signatures by their distance to query signatures (paper 2.3).

Most descriptors' vectors are built so that their L1 distance is the descriptor's distance, and
the search is the same for all of them (`nearest`). A descriptor that declares a distance of
its own (`cfsig.descriptors.base.Distance`) is searched by its lower bound and then exactly
(`nearest_by`); `query` and `distances` choose for the index's descriptor.
"""

from __future__ import annotations

import contextlib
import os
import threading
from collections.abc import Callable, Iterator
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass
from functools import partial
from typing import TypeVar

import h5py
import numpy as np

from cfsig import descriptors
from cfsig.descriptors.base import Distance
from cfsig.errors import IndexFileError
from cfsig.index.blocks import (
    BLOCK_ROWS,
    Block,
    load_block,
    map_file,
    plan_blocks,
    read_block,
    read_columns,
    read_rows,
)
from cfsig.index.sketch import adjust_bounds, query_sketches, threshold
from cfsig.index.store import REBUILD, Entry, IndexReader, SegmentView
from cfsig.search.l1 import Kernel, choose_kernel, fast_kernel, l1_numpy

_OUT_CELLS = 1 << 20  # distances computed per kernel call (4 MB): bounds memory for many queries
PRUNE_MIN_ROWS = 50_000  # rows with sketches from which a search prunes: docs/performance.md
_BOUND_CELLS = 1 << 27  # bounds held at once (512 MB): the queries of one scan of the sketches
_FIRST = 1024  # rows of smallest bounds evaluated first per query (at least 4 k)
_SAMPLE = 65536  # bounds sampled to find the cutoff of those rows
_SCAN_RATIO = 4  # a full scan when the candidates are a quarter of the rows or more
_EXACT_BATCH = 64  # rows of smallest bounds whose exact distances are computed at a time
# Queries from which a group is searched together, block by block (`_Pruned._many`): a group of
# as many reads the rows twice for all, fewer reads a query than one query at a time up to
# about 2,000,000 rows (groups of 64 or more; docs/method.md).
_MANY = 64
_FIRST_MANY = 64  # rows of smallest bounds evaluated first per query there (at least 4 k)
_SAMPLE_MANY = 8192  # bounds per query sampled there to find the cutoff of those rows
_PAIR_BLOCKS = 4  # blocks read at a time there for all the queries (4 chunks: 13 MB at 812)


@dataclass(frozen=True)
class Hit:
    """One search result.

    Attributes
    ----------
    rank : int
        1 for the nearest.
    distance : float
        L1 distance between the signature vectors (in [0, 2] for ``cf`` histograms), or the
        descriptor's own distance where it declares one.
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


def distances(descriptor: str, queries: np.ndarray, signatures: np.ndarray) -> np.ndarray:
    """A descriptor's distances between two sets of its signatures.

    Parameters
    ----------
    descriptor : str
        A name of `cfsig.descriptors.NAMES`.
    queries : (q, length) float
        Query signatures.
    signatures : (N, length) float
        Signatures to compare with.

    Returns
    -------
    distances : (q, N) float64
        `l1_distances`, or the descriptor's own distance where it declares one.
    """
    distance = descriptors.get(descriptor).distance
    if distance is None:
        return l1_distances(queries, signatures)
    queries, signatures = _float32(queries), _float32(signatures)
    return distance.exact(queries, signatures, fast_kernel() or l1_numpy)


Score = Callable[[np.ndarray], np.ndarray]


def nearest(
    reader: IndexReader,
    queries: np.ndarray,
    k: int,
    columns: slice | None = None,
    score: Score | None = None,
) -> tuple[np.ndarray, np.ndarray]:
    """The k nearest indexed signatures of each query, exactly, pruning by sketches.

    Segments with sketches (`cfsig.index.sketch`), once they hold `PRUNE_MIN_ROWS` rows or more, are
    searched in two steps per query: the sketches give a lower bound of every row's distance,
    and exact distances are computed only for rows whose bound does not exceed the k-th best
    distance found so far; the bounds account for every rounding, so the result is the one a
    full scan gives, row for row and bit for bit. When the bounds leave so many rows that
    reading them costs more than a scan, and for segments without sketches, the rows are
    scanned in full: all queries share one pass over them, by one thread per core. Memory
    stays bounded by a few blocks of rows and `_BOUND_CELLS` bounds, whatever the index size.
    Superseded rows are skipped. A search of some ``columns``, or by a ``score``, only scans in
    full.

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
    score : callable, optional
        Rank by ``score(distances)`` instead: it maps the L1 distances (q, m) float32 of all
        queries to some m rows to one score per row (m,), smallest best
        (`cfsig.search.partial.partial_scores`).

    Returns
    -------
    rows : (q, min(k, N)) int64
        Row numbers of the results, nearest first, ties broken by row number; with ``score``,
        one line (1, min(k, N)).
    distances : (q, min(k, N)) float64
        Their L1 distances, accumulated in float32, or their scores.
    """
    queries = _float32(np.atleast_2d(queries))
    n = len(reader)
    best = _Best(1 if score else len(queries), max(min(k, n), 0), reader.physical_rows)
    if best.k == 0 or len(queries) == 0:
        return best.result(reader)
    kernel = choose_kernel(len(queries) * n)
    pruned = columns is None and score is None
    sketched = [v for v in reader.segments if v.sketch is not None and pruned]
    if sum(v.signatures.shape[0] for v in sketched) < PRUNE_MIN_ROWS:
        sketched = []
    full = [v for v in reader.segments if all(v is not s for s in sketched)]
    if full:
        _scan(full, queries, kernel, best, 0, columns, score)
    if sketched:
        _Pruned(reader, sketched, kernel, best).search(queries)
    return best.result(reader)


def _scan(
    views: list[SegmentView],
    queries: np.ndarray,
    kernel: Kernel,
    best: _Best,
    first: int,
    columns: slice | None = None,
    score: Score | None = None,
) -> None:
    """Exact distances of every live row of some segments, merged into ``best``.

    ``queries`` are those of ``best`` from number ``first`` on; with ``columns``, they and the
    distances are of those columns of the rows only; with ``score``, the scores of all the
    queries' distances are merged, as ``best``'s one query.
    """
    sources = {id(view): _source(view, columns) for view in views}
    blocks = [(view, b) for view in views for b in plan_blocks(sources[id(view)][0], BLOCK_ROWS)]
    # Whole rows are viewed in place where plain (`load_block`); columns are copied.
    maps = {key: map_file(data) if cols is None else None for key, (data, cols) in sources.items()}
    block_rows = max((b.stop - b.start for _, b in blocks), default=1)
    group = len(queries) if score else max(1, _OUT_CELLS // block_rows)

    def work(task: tuple[SegmentView, Block], buffer: np.ndarray, lock: threading.Lock) -> None:
        view, block = task
        dataset, wanted = sources[id(view)]
        # The buffer fits a block of the widest dataset read; this one's rows are laid out in it.
        space = buffer.reshape(-1)[: buffer.shape[0] * dataset.shape[1]]
        space = space.reshape(buffer.shape[0], dataset.shape[1])
        if wanted is None:
            rows = load_block(dataset, block, space, maps[id(view)])
        else:
            rows = read_columns(dataset, block, wanted, space)
        dead = view.dead[(view.dead >= block.start) & (view.dead < block.stop)] - block.start
        live = None
        if len(dead):
            live = np.ones(len(rows), bool)
            live[dead] = False
        for q0 in range(0, len(queries), group):
            count = len(queries[q0 : q0 + group])
            dist = np.empty((count, len(rows)), np.float32)
            kernel(queries[q0 : q0 + group], rows, dist)
            if score:
                dist = score(dist)[None, :]
            with lock:
                best.merge(first + q0, view.start + block.start, dist, live)

    width = max((dataset.shape[1] for dataset, _ in sources.values()), default=1)
    parallel(blocks, work, partial(np.empty, (block_rows, width), np.float32))


def _source(view: SegmentView, columns: slice | None) -> tuple[h5py.Dataset, slice | None]:
    """What a scan of some columns of a segment reads: its copy of them if it has one."""
    for copy in view.copies:
        if copy.columns == columns:
            return copy.rows, None
    return view.signatures, columns


class _Pruned:
    """The search of some segments with sketches: bounds first, exact distances where needed."""

    def __init__(
        self, reader: IndexReader, views: list[SegmentView], kernel: Kernel, best: _Best
    ) -> None:
        self.views, self.kernel, self.best = views, kernel, best
        self.width = views[0].signatures.shape[1]
        self.plans = [plan_blocks(v.signatures, BLOCK_ROWS) for v in views]
        self.maps = [map_file(v.signatures) for v in views]
        n = reader.physical_rows
        self.excluded = np.ones(n, bool)  # superseded rows, and those of other segments
        for v in views:
            self.excluded[v.start : v.start + v.signatures.shape[0]] = False
            self.excluded[v.start + v.dead] = True
        self.live = int(n - self.excluded.sum())
        self.starts = np.array([v.start for v in views], np.int64)

    def search(self, queries: np.ndarray) -> None:
        """Merge the nearest rows of every query into ``best``, a group of queries at a time."""
        if max(_FIRST, 4 * self.best.k) * _SCAN_RATIO >= self.live:  # most rows would be read
            _scan(self.views, queries, self.kernel, self.best, 0)
            return
        n = len(self.excluded)
        group = max(1, _BOUND_CELLS // n)  # as `group_size`
        if min(len(queries), group) >= _MANY:
            for q0 in range(0, len(queries), group):
                self._many(q0, queries[q0 : q0 + group])
            return
        sketch_kernel = choose_kernel(len(queries) * self.live)
        for q0 in range(0, len(queries), group):
            some = queries[q0 : q0 + group]
            bounds = self._bounds(some, sketch_kernel)
            cutoffs = [self._first(q0 + j, some[j], bounds[j]) for j in range(len(some))]
            left = [self._candidates(q0 + j, bounds[j], cutoffs[j]) for j in range(len(some))]
            if sum(len(c) for c in left) * _SCAN_RATIO >= self.live * len(some):
                _scan(self.views, some, self.kernel, self.best, q0)  # reads less than they would
                continue
            for j, rows in enumerate(left):
                self._refine(q0 + j, some[j], bounds[j], rows)

    def _many(self, q0: int, queries: np.ndarray) -> None:
        """Merge the nearest rows of queries ``q0...`` into ``best``, all of them together.

        Many queries share each read of a block: the exact distances of each query's
        `_FIRST_MANY` rows of smallest bounds are computed first, then those of every row its
        k-th best distance does not rule out, a block at a time for all the queries.
        """
        bounds = self._bounds(queries, choose_kernel(len(queries) * self.live), by_row=True)
        bounds[self.excluded] = np.inf
        # About `_FIRST_MANY` rows a query: those whose bound is at most a cutoff estimated
        # from a sample of the bounds, twice as many as needed; the k-th best bounds the rest.
        step = max(1, len(bounds) // _SAMPLE_MANY)
        sample = np.ascontiguousarray(bounds[::step].T)
        nth = min(-(-2 * max(_FIRST_MANY, 4 * self.best.k) // step), sample.shape[1]) - 1
        cutoffs = np.partition(sample, nth, axis=1)[:, nth]
        # The masks are (rows, q) like the bounds: each is made in place, in one buffer each.
        picked = np.greater(bounds, cutoffs)
        np.logical_not(picked, out=picked)  # NaN bounds too: they rule nothing out
        picked[self.excluded] = False
        self._pairs(q0, queries, picked)
        limits = [threshold(self.best.kth(q0 + j), self.width) for j in range(len(queries))]
        left = np.greater(bounds, np.array(limits, np.float32))
        np.logical_or(left, picked, out=left)
        np.logical_not(left, out=left)
        left[self.excluded] = False
        if np.count_nonzero(left) * _SCAN_RATIO >= self.live * len(queries):
            _scan(self.views, queries, self.kernel, self.best, q0)  # reads less than they would
        else:
            self._pairs(q0, queries, left)

    def _pairs(self, q0: int, queries: np.ndarray, wanted: np.ndarray) -> None:
        """Exact distances of queries ``q0...`` to the rows ``wanted`` (physical rows, q) marks
        for each, merged into ``best`` once per query: each run of blocks read once for all."""
        marked, marks = np.nonzero(wanted)  # physical rows ascending, and the query of each
        runs = [
            (view, plan[i : i + _PAIR_BLOCKS])
            for view, plan in zip(self.views, self.plans, strict=True)
            for i in range(0, len(plan), _PAIR_BLOCKS)
        ]
        tasks = []
        for view, run in runs:
            lo, hi = np.searchsorted(marked, [view.start + run[0].start, view.start + run[-1].stop])
            if hi > lo:
                tasks.append((view, run, slice(int(lo), int(hi))))
        run_rows = max((run[-1].stop - run[0].start for _, run in runs), default=1)
        found: list[list[tuple[np.ndarray, np.ndarray]]] = [[] for _ in queries]

        def work(
            task: tuple[SegmentView, list[Block], slice], buffer: np.ndarray, lock: threading.Lock
        ) -> None:
            view, run, pairs = task
            first = view.start + run[0].start
            for block in run:
                at = block.start - run[0].start
                read_block(view.signatures, block, buffer[at : at + block.stop - block.start])
            rows = buffer[: run[-1].stop - run[0].start]
            order = np.argsort(marks[pairs], kind="stable")  # by query, rows ascending in each
            local, which = marked[pairs][order] - first, marks[pairs][order]
            cuts = np.flatnonzero(np.diff(which)) + 1
            done = []
            for mine, j in zip(np.split(local, cuts), which[np.r_[0, cuts]], strict=True):
                dist = np.empty((1, len(mine)), np.float32)
                self.kernel(queries[j][None], rows[mine], dist)
                done.append((int(j), first + mine, dist[0]))
            with lock:
                for j, at_rows, dist_j in done:
                    found[j].append((at_rows, dist_j))

        parallel(tasks, work, partial(np.empty, (run_rows, self.width), np.float32))
        for j, parts in enumerate(found):
            if parts:
                self.best.merge_rows(
                    q0 + j,
                    np.concatenate([r for r, _ in parts]),
                    np.concatenate([d for _, d in parts]),
                )

    def _bounds(self, queries: np.ndarray, kernel: Kernel, by_row: bool = False) -> np.ndarray:
        """(q, physical rows) lower bounds of the float32 distances (others left unset); or
        ``by_row``, (physical rows, q), each block's then written in place (L1 is symmetric)."""
        shape = (len(self.excluded), len(queries)) if by_row else (len(queries), len(self.excluded))
        bounds = np.empty(shape, np.float32)
        sketches = {id(v): query_sketches(queries, v.sketch) for v in self.views if v.sketch}
        blocks = [
            (v, b) for v in self.views if v.sketch for b in plan_blocks(v.sketch.rows, BLOCK_ROWS)
        ]
        block_rows = max((b.stop - b.start for _, b in blocks), default=1)

        def work(task: tuple[SegmentView, Block], buffer: np.ndarray, lock: threading.Lock) -> None:
            view, block = task
            assert view.sketch is not None
            rows = read_block(view.sketch.rows, block, buffer)
            at = slice(view.start + block.start, view.start + block.stop)
            sketch, margin = sketches[id(view)]
            if by_row:
                kernel(rows, sketch, bounds[at])
                adjust_bounds(bounds[at].T, margin, rows.shape[1])
                return
            one = len(queries) == 1  # then a slice of the bounds is C-contiguous: written to
            out = bounds[:, at] if one else np.empty((len(queries), len(rows)), np.float32)
            kernel(sketch, rows, out)
            adjust_bounds(out, margin, rows.shape[1])
            if not one:
                bounds[:, at] = out

        width = max(v.sketch.rows.shape[1] for v in self.views if v.sketch)
        parallel(blocks, work, partial(np.empty, (block_rows, width), np.float32))
        return bounds

    def _first(self, j: int, query: np.ndarray, bounds: np.ndarray) -> np.float32:
        """Exact distances of about the `_FIRST` rows of smallest bounds; return their cutoff.

        The rows evaluated are those whose bound is at most the cutoff, estimated from a
        sample of the bounds, and raised until k distances are known.
        """
        step = max(1, len(bounds) // _SAMPLE)
        sample = np.sort(bounds[::step][~self.excluded[::step]])
        nth = -(-max(_FIRST, 4 * self.best.k) // step)
        done = None
        while True:
            cutoff = sample[nth - 1] if nth <= len(sample) else np.float32(np.inf)
            chosen = ~(bounds > cutoff)  # NaN bounds too: they rule nothing out
            if done is not None:
                chosen &= bounds > done
            rows = np.flatnonzero(chosen)
            self._exact(j, query, rows[~self.excluded[rows]])
            if np.isfinite(self.best.kth(j)) or not np.isfinite(cutoff):
                return cutoff
            done, nth = cutoff, 4 * nth

    def _candidates(self, j: int, bounds: np.ndarray, cutoff: np.float32) -> np.ndarray:
        """The rows not evaluated yet that the k-th best distance of query j does not rule out."""
        limit = threshold(self.best.kth(j), self.width)
        if not limit > cutoff:
            return np.zeros(0, np.int64)
        rows = np.flatnonzero((bounds > cutoff) & ~(bounds > limit))
        return rows[~self.excluded[rows]]

    def _refine(self, j: int, query: np.ndarray, bounds: np.ndarray, rows: np.ndarray) -> None:
        """Exact distances of the candidates that the k-th best still leaves, block by block."""
        seg = np.searchsorted(self.starts, rows, side="right") - 1
        tasks = []
        for i in np.unique(seg):
            view, plan = self.views[i], self.plans[i]
            local = rows[seg == i] - view.start
            which = np.searchsorted([b.start for b in plan], local, side="right") - 1
            cut = np.flatnonzero(np.diff(which, prepend=-1)).tolist() + [len(local)]
            tasks += [(int(i), local[a:b]) for a, b in zip(cut[:-1], cut[1:], strict=True)]
        block_rows = max((b.stop - b.start for plan in self.plans for b in plan), default=1)

        def work(task: tuple[int, np.ndarray], buffer: np.ndarray, lock: threading.Lock) -> None:
            i, local = task
            start = self.views[i].start
            local = local[~(bounds[start + local] > threshold(self.best.kth(j), self.width))]
            if len(local):
                self._exact(j, query, start + local, buffer, lock)

        parallel(tasks, work, partial(np.empty, (block_rows, self.width), np.float32))

    def _exact(
        self,
        j: int,
        query: np.ndarray,
        rows: np.ndarray,
        buffer: np.ndarray | None = None,
        lock: threading.Lock | None = None,
    ) -> None:
        """Compute the float32 distances of query j to some rows (ascending) and merge them.

        At most ``len(buffer)`` rows (`BLOCK_ROWS` without one) are read at a time.
        """
        if buffer is None:
            buffer = np.empty((min(len(rows), BLOCK_ROWS), self.width), np.float32)
        seg = np.searchsorted(self.starts, rows, side="right") - 1
        for i in np.unique(seg):
            view, mine = self.views[i], rows[seg == i]
            for first in range(0, len(mine), len(buffer)):
                picked = mine[first : first + len(buffer)]
                local = picked - view.start
                values = read_rows(view.signatures, self.plans[i], local, buffer, self.maps[i])
                dist = np.empty((1, len(values)), np.float32)
                self.kernel(query[None], values, dist)
                with lock or contextlib.nullcontext():
                    self.best.merge_rows(j, picked, dist[0])


def nearest_by(
    reader: IndexReader, queries: np.ndarray, k: int, distance: Distance
) -> tuple[np.ndarray, np.ndarray]:
    """The k nearest indexed signatures of each query by a descriptor's own distance, exactly.

    Every live row's lower bound (``distance.bound``) is computed in one pass over the rows;
    then each query's rows are taken in order of their bounds and their exact distances
    computed, a batch at a time, until the next bound exceeds the k-th best distance found. No
    row left out could rank, so the result is the one a full scan of exact distances gives.

    Parameters
    ----------
    reader : IndexReader
        An open index with N entries.
    queries : (q, length) float
        Query signatures, made with the index's parameters.
    k : int
        Number of results per query; at most N are returned.
    distance : Distance
        The index's descriptor's distance.

    Returns
    -------
    rows : (q, min(k, N)) int64
        Row numbers of the results, nearest first, ties broken by row number.
    distances : (q, min(k, N)) float64
        Their exact distances, as ``distance.exact`` computes them in float32 (rounded to
        float32 here, as `nearest` returns).
    """
    queries = _float32(np.atleast_2d(queries))
    best = _Best(len(queries), max(min(k, len(reader)), 0), reader.physical_rows)
    if best.k == 0 or len(queries) == 0:
        return best.result(reader)
    kernel = fast_kernel() or l1_numpy  # many image pairs per row: faiss repays its import
    bounds = np.full((len(queries), reader.physical_rows), np.inf)
    plans = [plan_blocks(view.signatures, BLOCK_ROWS) for view in reader.segments]
    for view, plan in zip(reader.segments, plans, strict=True):
        buffer = np.empty((min(BLOCK_ROWS, view.signatures.shape[0]), queries.shape[1]), np.float32)
        for block in plan:
            rows = read_block(view.signatures, block, buffer)
            at = slice(view.start + block.start, view.start + block.stop)
            bounds[:, at] = distance.bound(queries, np.ascontiguousarray(rows), kernel)
        bounds[:, view.start + view.dead] = np.inf
    starts = np.array([view.start for view in reader.segments], np.int64)
    batch = max(best.k, _EXACT_BATCH)
    for j, query in enumerate(queries):
        order = np.argsort(bounds[j], kind="stable")
        order = order[np.isfinite(bounds[j, order])]
        for first in range(0, len(order), batch):
            kth = best.kth(j)
            if bounds[j, order[first]] > kth:  # False while fewer than k are held (NaN)
                break
            picked = np.sort(order[first : first + batch])
            seg = np.searchsorted(starts, picked, side="right") - 1
            for i in np.unique(seg):
                view, mine = reader.segments[i], picked[seg == i]
                buffer = np.empty((len(mine), queries.shape[1]), np.float32)
                values = read_rows(view.signatures, plans[i], mine - view.start, buffer)
                exact = distance.exact(query[None], np.ascontiguousarray(values), kernel)
                best.merge_rows(j, mine, exact[0].astype(np.float32))
    return best.result(reader)


def check_layout(reader: IndexReader) -> None:
    """Refuse an index whose rows an earlier version of its descriptor made.

    Parameters
    ----------
    reader : IndexReader
        An open index.

    Raises
    ------
    IndexFileError
        Its layout is not the one its descriptor declares now; the message says how to rebuild.
    """
    current = descriptors.layout(reader.params)
    if reader.layout != current:
        raise IndexFileError(
            f"{reader.path}: made by an earlier {reader.params.descriptor} descriptor "
            f"({reader.layout.length} entries a row, now {current.length}); {REBUILD}"
        )


def group_size(reader: IndexReader) -> int:
    """How many queries a search of this index takes at a time: as many as `_BOUND_CELLS`
    bounds hold. A caller with many queries gives them in multiples of it.

    Parameters
    ----------
    reader : IndexReader
        An open index.

    Returns
    -------
    queries : int
    """
    return max(1, _BOUND_CELLS // max(1, reader.physical_rows))


def search(reader: IndexReader, queries: np.ndarray, k: int) -> tuple[np.ndarray, np.ndarray]:
    """The k nearest rows of each query by the index's descriptor's distance, exactly.

    Parameters
    ----------
    reader : IndexReader
        An open index with N entries.
    queries : (q, length) float
        Query signatures, made with the index's parameters.
    k : int
        Results per query.

    Returns
    -------
    rows, distances : (q, min(k, N)) int64 and float64
        As `nearest` (L1) or `nearest_by` (a descriptor that declares its own distance).

    Raises
    ------
    IndexFileError
        As `check_layout`.
    """
    check_layout(reader)
    distance = descriptors.get(reader.params.descriptor).distance
    if distance is None:
        return nearest(reader, queries, k)
    return nearest_by(reader, queries, k, distance)


def hits(reader: IndexReader, rows: np.ndarray, dists: np.ndarray) -> list[list[Hit]]:
    """Results as `Hit` lists: the entries of some rows (q, k) and their distances (q, k)."""
    entries = iter(reader.entries(rows.ravel()) if rows.size else [])
    return [[Hit(rank + 1, float(d), next(entries)) for rank, d in enumerate(row)] for row in dists]


def query(reader: IndexReader, queries: np.ndarray, k: int = 20) -> list[list[Hit]]:
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
        One list per query, nearest first: by L1 distance (`nearest`), or by the descriptor's
        own distance where it declares one (`nearest_by`).

    Raises
    ------
    IndexFileError
        As `check_layout`.
    """
    return hits(reader, *search(reader, queries, k))


def query_names(reader: IndexReader, names: list[str], k: int = 20) -> list[list[Hit]]:
    """The k nearest other entries of some indexed entries, by their stored signatures.

    Parameters
    ----------
    reader : IndexReader
        An open index.
    names : list of str
        Entry names: each is the query, and is left out of its own results.
    k : int
        Results per query.

    Returns
    -------
    hits : list of list of Hit
        As `query` gives for the entries' files, less each entry itself.

    Raises
    ------
    UnknownNameError
        A name is not in the index.
    """
    rows = reader.find(names)
    found, dists = search(reader, reader.signatures[rows], k + 1)
    return hits(reader, *without_self(rows, found, dists, k))


def without_self(
    rows: np.ndarray, found: np.ndarray, dists: np.ndarray, k: int
) -> tuple[np.ndarray, np.ndarray]:
    """The k results of queries that are rows of the index, each row left out of its own.

    Parameters
    ----------
    rows : (q,) int
        The queries' rows.
    found, dists : (q, k + 1) int64 and float64
        Their nearest rows and distances, as `search` gives them for k + 1.
    k : int
        Results to keep.

    Returns
    -------
    found, dists : (q, min(k, N - 1))
        Without each query's own row (or the last, when other rows tie with it at its rank).
    """
    own = found == np.asarray(rows)[:, None]
    own[~own.any(axis=1), -1] = True  # then it ranked below k + 1 others (ties at 0)
    keep = ~own
    width = min(k, found.shape[1] - 1)
    return found[keep].reshape(len(rows), -1)[:, :width], dists[keep].reshape(len(rows), -1)[
        :, :width
    ]


class _Best:
    """The k smallest distances seen so far for each query, ties broken by row number."""

    def __init__(self, n_queries: int, k: int, n_rows: int) -> None:
        self.k = k
        # NaN sorts after every distance, and the row number n after every row: the placeholders
        # are the first to go, and every row is a candidate until k are held.
        self.dist = np.full((n_queries, k), np.nan, np.float32)
        self.rows = np.full((n_queries, k), n_rows, np.int64)

    def kth(self, query: int) -> float:
        """The k-th smallest distance of a query so far: NaN while fewer than k are held."""
        return float(self.dist[query, -1])

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
            self._take(first_query + int(j), dist[j, new], new + first_row)

    def merge_rows(self, query: int, rows: np.ndarray, dist: np.ndarray) -> None:
        """Take in distances (m,) from one query to some rows (m,)."""
        new = ~(dist > self.dist[query, -1])
        if new.any():
            self._take(query, dist[new], rows[new])

    def _take(self, query: int, dist: np.ndarray, rows: np.ndarray) -> None:
        """Keep the k best of those held and some candidates; a row held already is not added."""
        fresh = ~np.isin(rows, self.rows[query])
        d = np.concatenate([self.dist[query], dist[fresh]])
        r = np.concatenate([self.rows[query], rows[fresh]])
        keep = np.lexsort((r, d))[: self.k]
        self.dist[query], self.rows[query] = d[keep], r[keep]

    def result(self, reader: IndexReader) -> tuple[np.ndarray, np.ndarray]:
        """Row numbers of the reader and distances, nearest first."""
        return reader.logical_rows(self.rows.ravel()).reshape(self.rows.shape), self.dist.astype(
            np.float64
        )


Task = TypeVar("Task")
Buffer = TypeVar("Buffer")


def parallel(
    tasks: list[Task],
    work: Callable[[Task, Buffer, threading.Lock], None],
    make_buffer: Callable[[], Buffer],
) -> None:
    """Run ``work(task, buffer, lock)`` on every task, one thread per core, each with a buffer.

    Parameters
    ----------
    tasks : list
        The tasks, taken in order by whichever thread is free.
    work : callable
        ``work(task, buffer, lock)``: the buffer is its thread's own, reused from task to task;
        the lock is shared, and ``work`` holds it while it changes shared state.
    make_buffer : callable
        Makes a thread's buffer, once per thread.
    """
    if not tasks:
        return
    todo, lock = iter(tasks), threading.Lock()

    def run() -> None:
        buffer = make_buffer()
        while (task := _next(todo, lock)) is not None:
            work(task, buffer, lock)

    threads = min(_threads(), len(tasks))
    if threads == 1:
        run()
        return
    with ThreadPoolExecutor(threads) as pool:
        for done in [pool.submit(run) for _ in range(threads)]:
            done.result()


def _next(tasks: Iterator[Task], lock: threading.Lock) -> Task | None:
    """The next task, shared by the threads."""
    with lock:
        return next(tasks, None)


def _threads() -> int:
    """Number of cores this process may run on."""
    if hasattr(os, "sched_getaffinity"):
        return len(os.sched_getaffinity(0))
    return os.cpu_count() or 1


def _float32(a: np.ndarray) -> np.ndarray:
    """A C-contiguous float32 copy or view."""
    return np.ascontiguousarray(a, dtype=np.float32)
