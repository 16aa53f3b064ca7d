"""8-bit codes of signatures: a quarter of the bytes to scan, with a bound that keeps results exact.

Each segment stores, beside its float32 rows, a code per value on one grid for the segment,
``x ~ offset[i] + step * code`` (``offset`` the minimum of each column, ``step`` the largest
column range over 255), and per row the L1 error of its codes, ``sum_i |x_i - decoded_i|``. A
query coded on the same grid gives, by the triangle inequality,

    |L1(q, x) - step * SAD(codes(q), codes(x))| <= error(q) + error(x),

so a scan of the codes (`sad`) bounds every distance from both sides; only the rows whose lower
bound can reach the k best are then compared exactly in float32 (`cfsig.nearest`). The results
are those of a float32 scan, bit for bit, at the cost of scanning a byte per value instead of
four (docs/index-scale.md has the measurements).
"""

from __future__ import annotations

import numpy as np

_WORDS = 128  # uint64 words summed at a time: 16-bit lanes hold 2 * 255 * 128 < 65536
_PIECE_ROWS = 1024  # rows of codes per pass: 360 KB at 350 values, in the L2 cache
_MASK = np.uint64(0x00FF00FF00FF00FF)


def code_width(length: int) -> int:
    """Bytes per row of codes: the signature length rounded up to whole uint64 words.

    Parameters
    ----------
    length : int
        Signature length.

    Returns
    -------
    width : int
    """
    return -(-length // 8) * 8


def grid(rows: np.ndarray) -> tuple[np.ndarray, float]:
    """The grid of a set of rows: each column's minimum, and the largest range over 255.

    Parameters
    ----------
    rows : (m, length) float32
        Rows; non-finite values are ignored.

    Returns
    -------
    offset : (length,) float32
    step : float
        Positive.
    """
    finite = np.where(np.isfinite(rows), rows, np.nan)
    if not len(rows) or np.isnan(finite).all():
        return np.zeros(rows.shape[1], np.float32), 1.0
    low, high = np.nanmin(finite, axis=0), np.nanmax(finite, axis=0)
    low = np.where(np.isnan(low), 0, low).astype(np.float32)
    span = float(np.nanmax(high - low)) if not np.isnan(high - low).all() else 0.0
    return low, span / 255 if span > 0 else 1.0


def encode(rows: np.ndarray, offset: np.ndarray, step: float) -> tuple[np.ndarray, np.ndarray]:
    """The codes of some rows on a grid, and the L1 error of each row's codes.

    Parameters
    ----------
    rows : (m, length) float
        Signatures.
    offset : (length,) float32
        The grid's offset (`grid`).
    step : float
        The grid's step.

    Returns
    -------
    codes : (m, code_width(length)) uint8
        Zero beyond ``length``.
    error : (m,) float64
        ``sum_i |rows_i - (offset_i + step * codes_i)|`` rounded up; infinite for a row with a
        non-finite value (such a row is always compared exactly).
    """
    rows = np.asarray(rows, np.float64)
    q = np.rint((rows - offset) / step)
    q = np.clip(np.nan_to_num(q, nan=0.0, posinf=255, neginf=0), 0, 255)
    codes = np.zeros((len(rows), code_width(rows.shape[1])), np.uint8)
    codes[:, : rows.shape[1]] = q
    error = np.abs(rows - (offset + step * q)).sum(axis=1)
    error = np.where(np.isfinite(error), error * (1 + 1e-6) + 1e-12, np.inf)
    return codes, error


def sad(codes: np.ndarray, query: np.ndarray) -> np.ndarray:
    """Sums of absolute differences between rows of codes and one query's codes.

    Parameters
    ----------
    codes : (m, w) uint8, w a multiple of 8, C-contiguous
        Rows of codes.
    query : (w,) uint8
        The query's codes on the same grid.

    Returns
    -------
    sums : (m,) uint64
        ``sum_i |codes[j, i] - query[i]|``, exactly: |a - b| as max - min in uint8, then eight
        bytes at a time in the 16-bit lanes of uint64 words; in pieces of rows that stay in
        the L2 cache, against a tiled query (numpy is faster without broadcasting).
    """
    rows = min(_PIECE_ROWS, len(codes))
    tiled = np.tile(query, (rows, 1))
    high, low = np.empty_like(tiled), np.empty_like(tiled)
    lanes = np.empty((rows, codes.shape[1] // 8), np.uint64)
    shifted = np.empty_like(lanes)
    total = np.zeros(len(codes), np.uint64)
    for start in range(0, len(codes), rows):
        piece = codes[start : start + rows]
        m = len(piece)
        diff, other = high[:m], low[:m]
        np.maximum(piece, tiled[:m], out=diff)
        np.minimum(piece, tiled[:m], out=other)
        np.subtract(diff, other, out=diff)
        words, pairs, spare = diff.view(np.uint64), lanes[:m], shifted[:m]
        np.bitwise_and(words, _MASK, out=pairs)
        np.right_shift(words, np.uint64(8), out=spare)
        np.bitwise_and(spare, _MASK, out=spare)
        np.add(pairs, spare, out=pairs)
        for first in range(0, pairs.shape[1], _WORDS):
            sums = pairs[:, first : first + _WORDS].sum(axis=1)
            for shift in (0, 16, 32, 48):
                total[start : start + m] += (sums >> np.uint64(shift)) & np.uint64(0xFFFF)
    return total


def union_grid(grids: list[tuple[np.ndarray, float]]) -> tuple[np.ndarray, float]:
    """A grid covering the ranges of several grids (each column from its offset to 255 steps).

    Parameters
    ----------
    grids : list of ((length,) float32, float)
        At least one.

    Returns
    -------
    offset : (length,) float32
    step : float
    """
    low = np.min([offset for offset, _ in grids], axis=0).astype(np.float32)
    high = np.max([offset + 255 * step for offset, step in grids], axis=0)
    span = float(np.max(high - low))
    return low, span / 255 if span > 0 else 1.0
