"""The L1 kernel compiled by numba (optional extra ``cfsig[fast]``); see `cfsig.l1`."""

from __future__ import annotations

import numba
import numpy as np


@numba.njit(nogil=True, fastmath=True, cache=True)
def l1_rows(queries: np.ndarray, rows: np.ndarray, out: np.ndarray) -> None:
    """L1 distances in one pass over ``rows``, accumulated in float32; releases the GIL.

    Parameters
    ----------
    queries : (q, bins) float32
        Query signatures.
    rows : (m, bins) float32
        Stored signatures.
    out : (q, m) float32
        Filled with ``out[j, i] = sum_b |rows[i, b] - queries[j, b]|``.
    """
    for i in range(rows.shape[0]):
        row = rows[i]
        for j in range(queries.shape[0]):
            query = queries[j]
            total = np.float32(0.0)
            for b in range(row.shape[0]):
                total += abs(row[b] - query[b])
            out[j, i] = total
