"""Search: rank indexed signatures by L1 distance to query signatures (paper section 2.3)."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .index import Entry, IndexReader

_BLOCK_ROWS = 16384


@dataclass(frozen=True)
class Hit:
    """One search result.

    Attributes
    ----------
    rank : int
        1 for the nearest.
    distance : float
        L1 distance between the histograms, in [0, 2].
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
    queries : (q, bins) float
        Query signatures.
    signatures : (N, bins) float
        Signatures to compare with.

    Returns
    -------
    distances : (q, N) float64
        Between 0 and 2 for histograms that sum to 1.
    """
    signatures = np.asarray(signatures, dtype=np.float32)
    out = np.empty((len(queries), len(signatures)))
    for i, query in enumerate(np.asarray(queries, dtype=np.float32)):
        out[i] = np.abs(signatures - query).sum(axis=1, dtype=np.float64)
    return out


def nearest(reader: IndexReader, queries: np.ndarray, k: int) -> tuple[np.ndarray, np.ndarray]:
    """The k nearest indexed signatures of each query, streaming the index in blocks.

    Memory stays bounded by one block of rows whatever the index size; all queries share one
    pass over the file.

    Parameters
    ----------
    reader : IndexReader
        An open index with N entries.
    queries : (q, bins) float
        Query signatures, made with the index's parameters.
    k : int
        Number of results per query; at most N are returned.

    Returns
    -------
    rows : (q, min(k, N)) int64
        Row numbers of the results, nearest first, ties broken by row number.
    distances : (q, min(k, N)) float64
        Their L1 distances.
    """
    queries = np.atleast_2d(queries)
    k = min(k, len(reader))
    rows = np.empty((len(queries), 0), dtype=np.int64)
    dist = np.empty((len(queries), 0))
    for start in range(0, len(reader), _BLOCK_ROWS):
        block = reader.signatures[start : start + _BLOCK_ROWS]
        block_rows = np.arange(start, start + len(block))
        dist = np.hstack([dist, l1_distances(queries, block)])
        rows = np.hstack([rows, np.broadcast_to(block_rows, (len(queries), len(block)))])
        if dist.shape[1] > k:
            keep = np.argpartition(dist, k - 1, axis=1)[:, :k]
            dist = np.take_along_axis(dist, keep, axis=1)
            rows = np.take_along_axis(rows, keep, axis=1)
    order = np.lexsort((rows, dist), axis=-1)
    return np.take_along_axis(rows, order, axis=1), np.take_along_axis(dist, order, axis=1)


def search(reader: IndexReader, queries: np.ndarray, k: int = 20) -> list[list[Hit]]:
    """The k nearest indexed meshes of each query, with their names and labels.

    Parameters
    ----------
    reader : IndexReader
        An open index.
    queries : (q, bins) float
        Query signatures, made with the index's parameters.
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
