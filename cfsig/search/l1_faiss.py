"""The L1 kernel of faiss (optional extra ``cfsig[fast]``); see `cfsig.search.l1`."""

from __future__ import annotations

import faiss
import numpy as np

_PIECE_ROWS = 1024  # 800 KB of float32 rows at 200 bins: stays in the L2 cache for all queries
# faiss spreads more than 10 queries over OpenMP threads; the search already runs one thread per
# core, so groups of 10 keep each call on its own thread.
_GROUP = 10


def l1_rows(queries: np.ndarray, rows: np.ndarray, out: np.ndarray) -> None:
    """L1 distances with faiss's vectorised kernel, accumulated in float32; releases the GIL.

    Parameters
    ----------
    queries : (q, bins) float32, C-contiguous
        Query signatures.
    rows : (m, bins) float32, C-contiguous
        Stored signatures (may be read-only).
    out : (q, m) float32, C-contiguous
        Filled with ``out[j, i] = sum_b |rows[i, b] - queries[j, b]|``.

    Raises
    ------
    ValueError
        ``out`` is not C-contiguous (faiss writes through its data pointer).
    """
    if not out.flags.c_contiguous:
        raise ValueError("out must be C-contiguous")
    bins, width = rows.shape[1], out.shape[1]
    flat = out.reshape(-1)  # a view: faiss writes at an offset with row stride ``width``
    for start in range(0, len(rows), _PIECE_ROWS):
        piece = rows[start : start + _PIECE_ROWS]
        for first in range(0, len(queries), _GROUP):
            group = queries[first : first + _GROUP]
            faiss.pairwise_extra_distances(
                bins, len(group), faiss.swig_ptr(group), len(piece), faiss.swig_ptr(piece),
                faiss.METRIC_L1, 0.0, faiss.swig_ptr(flat[first * width + start :]),
                bins, bins, width,
            )  # fmt: skip
