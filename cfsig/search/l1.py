"""L1 kernels: distances between query signatures and a block of stored signatures.

Two implementations fill the same output. The numpy one works everywhere and reads the block
once per query in cache-sized pieces, three ufunc passes each. The faiss one (optional extra
``cfsig[fast]``) is one vectorised C++ loop, about twice as fast for one query and ten times for
a batch, but importing faiss costs about 50 ms: it is used only when installed and the scan is
large enough to repay that (studied at commit 35f8114, docs/query-options.md).
"""

from __future__ import annotations

import importlib
from collections.abc import Callable

import numpy as np

Kernel = Callable[[np.ndarray, np.ndarray, np.ndarray], None]

_PIECE_ROWS = 256  # 200 KB of float32 rows at 200 bins: stays in the L2 cache between passes
FAST_MIN_WORK = 500_000  # query-row pairs: where faiss's saving (~0.1 µs each) repays its import


def l1_numpy(queries: np.ndarray, rows: np.ndarray, out: np.ndarray) -> None:
    """L1 distances with numpy, accumulated in float32.

    Parameters
    ----------
    queries : (q, bins) float32
        Query signatures.
    rows : (m, bins) float32
        Stored signatures.
    out : (q, m) float32
        Filled with ``out[j, i] = sum_b |rows[i, b] - queries[j, b]|``.
    """
    piece_rows = min(_PIECE_ROWS, len(rows))
    diff = np.empty((piece_rows, rows.shape[1]), np.float32)
    for query, dist in zip(queries, out, strict=True):
        tiled = np.tile(query, (piece_rows, 1))  # a same-shape operand: no broadcasting per row
        for start in range(0, len(rows), piece_rows):
            piece = rows[start : start + piece_rows]
            scratch = diff[: len(piece)]
            np.subtract(piece, tiled[: len(piece)], out=scratch)
            np.abs(scratch, out=scratch)
            np.einsum("ij->i", scratch, out=dist[start : start + len(piece)])


def fast_kernel() -> Kernel | None:
    """The faiss kernel (same contract as `l1_numpy`), or None when faiss is not installed.

    Returns
    -------
    kernel : callable or None
    """
    try:
        return importlib.import_module("cfsig.search.l1_faiss").l1_rows
    except ImportError:
        return None


def choose_kernel(work: int) -> Kernel:
    """The kernel for a scan of ``work`` query-row pairs: faiss for large scans if installed.

    Parameters
    ----------
    work : int
        Number of queries times number of rows.

    Returns
    -------
    kernel : callable
        ``kernel(queries, rows, out)`` as `l1_numpy`.
    """
    fast = fast_kernel() if work >= FAST_MIN_WORK else None
    return fast or l1_numpy
