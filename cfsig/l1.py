"""L1 kernels: distances between query signatures and a block of stored signatures.

Two implementations fill the same output. The numpy one works everywhere and reads the block
once per query in cache-sized pieces. The numba one (optional extra ``cfsig[fast]``) makes one
pass over the block for all queries, several times faster, but importing numba and loading its
compiled kernel takes over half a second and over 100 MB resident: it is used only when installed
and the scan is large enough to repay that (measured in `docs/query-options.md`).
"""

from __future__ import annotations

import importlib
from collections.abc import Callable

import numpy as np

Kernel = Callable[[np.ndarray, np.ndarray, np.ndarray], None]

_PIECE_ROWS = 256  # 200 KB of float32 rows at 200 bins: stays in the L2 cache between passes
NUMBA_MIN_WORK = 4_000_000  # query-row pairs: where numba's saving passes its loading time


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


def numba_kernel() -> Kernel | None:
    """The numba kernel (same contract as `l1_numpy`), or None when numba is not installed.

    Returns
    -------
    kernel : callable or None
    """
    try:
        return importlib.import_module("cfsig.l1_numba").l1_rows
    except ImportError:
        return None


def choose_kernel(work: int) -> Kernel:
    """The kernel for a scan of ``work`` query-row pairs: numba for large batches if installed.

    Parameters
    ----------
    work : int
        Number of queries times number of rows.

    Returns
    -------
    kernel : callable
        ``kernel(queries, rows, out)`` as `l1_numpy`.
    """
    fast = numba_kernel() if work >= NUMBA_MIN_WORK else None
    return fast or l1_numpy
