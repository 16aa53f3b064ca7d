"""The fine-cell kernel of numba (optional extra ``cfsig[fast]``); see `cfsig.cells`.

One pass over each row's slots, written as LLVM vector code (`numba.extending.intrinsic`,
docs/partial.md, "Version 10: vector code"): each slot's cell finds its row of the part's table
(row 0, all zeros, for the cells the part lacks), and its gains at all 16 lanes of shares are
summed in registers, four slots a pass. A group of 16 slots whose fractions are all 0 (a row's
padding) gains nothing and is skipped; each group prefetches the slots `_AHEAD` on. Listing the
held slots first, as an earlier kernel did, cost more than scoring the slots a part lacks.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence

import numba
import numpy as np
from llvmlite import ir
from numba import types
from numba.core import cgutils
from numba.extending import intrinsic

_LANES = 16  # shares a vector holds: a part has at most that many, padded
_ALIGN = 64  # bytes: a table row is one cache line
_FLOAT = ir.FloatType()
_INT = ir.IntType(32)
_WIDE = ir.IntType(64)
_BYTES = ir.IntType(8).as_pointer()
_FLOATS = ir.VectorType(_FLOAT, _LANES)
_INTS = ir.VectorType(_INT, _LANES)
# A multiplication and an addition may fuse, but no sum is reordered: each waits on one addition
# a pass of four cells, where a free reordering chained three.
_FUSE = ("contract",)
# Slots ahead whose fractions and cells are asked for before they are read: rows come from the
# page cache in pages of 4 KB, across which the hardware's own prefetching stops
# (docs/partial.md, "Version 10: vector code"; 256 to 4,096 measured alike).
_AHEAD = 512


def part_scorer(
    part: Sequence[tuple[np.ndarray, np.ndarray]], shares: tuple[float, ...]
) -> Callable[[np.ndarray, np.ndarray], np.ndarray]:
    """`cfsig.cells.cell_scores` of one part, compiled: one pass over each row's cells.

    The part's histograms are laid out once, for every block of rows the scorer is given. It
    sums in float32 where the NumPy kernel sums in float64: the two differ by about 1e-6.

    Parameters
    ----------
    part : sequence of (cells, fractions)
        The part's `cfsig.cells.cell_histogram` at each share, cells below 65,536.
    shares : tuple of float
        The shares, one per histogram of ``part``, at most 16.

    Returns
    -------
    scorer : callable
        ``scorer(cells, fractions)``: the wholes' (m, slots) uint16 `cfsig.cells.packed_cells`
        and their (m, slots) float32 fractions to their (m,) float64 scores, in [0, 3];
        releases the GIL.

    Raises
    ------
    ValueError
        More than 16 shares.
    """
    if len(shares) > _LANES:
        raise ValueError(f"{len(shares)} shares: numba's kernel takes at most {_LANES}")
    held = np.unique(np.concatenate([np.asarray(c, np.int64) for c, _ in part]))
    # Where a cell's row of the table starts, in floats; 0 for the cells the part lacks.
    offset = np.zeros(1 << 16, np.uint32)
    offset[held] = np.arange(1, len(held) + 1) * _LANES
    table = _aligned_zeros((len(held) + 1) * _LANES).reshape(-1, _LANES)
    for j, (c, p) in enumerate(part):
        table[offset[c] // _LANES, j] = p
    inverse = np.ones(_LANES, np.float32)  # a padding share's table is 0: it gains nothing
    inverse[: len(shares)] = 1 / np.asarray(shares)
    flat = table.ravel()

    def scorer(cells: np.ndarray, fractions: np.ndarray) -> np.ndarray:
        out = np.empty(len(cells))
        cells, fractions = np.ascontiguousarray(cells), np.ascontiguousarray(fractions)
        _scores(offset, flat, inverse, cells.reshape(-1), fractions.reshape(-1), out)
        return out

    return scorer


def _aligned_zeros(count: int) -> np.ndarray:
    """(count,) float32 zeros starting on a cache line."""
    spare = np.zeros(count + _ALIGN // 4, np.float32)
    skip = (-spare.ctypes.data % _ALIGN) // 4
    return spare[skip : skip + count]


@numba.njit(nogil=True, boundscheck=False, cache=True)
def _scores(offset, table, inverse, cells, fractions, out):
    """``out[i]``: row i's partial distance; ``cells`` and ``fractions`` hold the rows one after
    another."""
    width = len(cells) // max(len(out), 1)
    for i in range(len(out)):
        out[i] = 3.0 - _row_gain(offset, table, inverse, cells, fractions, i * width, width)


def _pointer(context, builder, array_type, array):
    """The data pointer of a numba array."""
    return context.make_array(array_type)(context, builder, array).data


def _load_vector(builder, pointer, at):
    """The 16 float32 at ``pointer + at``."""
    start = builder.bitcast(builder.gep(pointer, [at]), _FLOATS.as_pointer())
    return builder.load(start, align=4)


def _splat(builder, value):
    """16 copies of a float32."""
    one = builder.insert_element(ir.Constant(_FLOATS, ir.Undefined), value, _INT(0))
    return builder.shuffle_vector(one, one, ir.Constant(_INTS, [0] * _LANES))


def _minimum(builder, a, b):
    """Lane by lane: one instruction."""
    return builder.select(builder.fcmp_ordered("<", a, b), a, b)


@intrinsic
def _row_gain(typingctx, offset, table, inverse, cells, fractions, start, width):
    """The largest over the shares of ``3 - score`` of the row of ``width`` slots from
    ``start``, summed slot by slot: ``min(f p, w) / f + 2 min(p, w)``. Groups of 16 slots, then
    the last ``width % 16`` one by one."""

    def codegen(context, builder, signature, args):
        offsets, table, inverses, cells, fractions, start, width = (
            _pointer(context, builder, t, a) if isinstance(t, types.Array) else a
            for t, a in zip(signature.args, args, strict=True)
        )
        inverse = _load_vector(builder, inverses, _WIDE(0))
        two = ir.Constant(_FLOATS, [2.0] * _LANES)
        nothing = ir.Constant(_FLOATS, [0.0] * _LANES)
        # Two sums, each of two slots a pass of four: LLVM keeps them in registers.
        sums = [cgutils.alloca_once_value(builder, nothing) for _ in range(2)]

        def gain(at):
            cell = builder.zext(builder.load(builder.gep(cells, [at])), _WIDE)
            row = builder.zext(builder.load(builder.gep(offsets, [cell])), _WIDE)
            p = _load_vector(builder, table, row)
            w = _splat(builder, builder.load(builder.gep(fractions, [at])))
            explained = _minimum(builder, p, builder.fmul(w, inverse))
            common = builder.fmul(two, _minimum(builder, p, w), flags=_FUSE)
            return builder.fadd(explained, common, flags=_FUSE)

        def add(total, value):
            builder.store(builder.fadd(builder.load(total), value), total)

        # An empty asm statement hides that the test of a group reads the fractions that its
        # slots then read one by one: else LLVM takes each slot's fraction from the test's
        # vector by a shuffle, on a port the arithmetic needs, rather than by a load.
        hidden = builder.asm(
            ir.FunctionType(fractions.type, [fractions.type]), "", "=r,0", [fractions], False
        )
        stop = builder.add(start, width)
        groups = builder.sub(stop, builder.srem(width, width.type(_LANES)))
        prefetch = cgutils.get_or_insert_function(
            builder.module,
            ir.FunctionType(ir.VoidType(), [_BYTES, _INT, _INT, _INT]),
            "llvm.prefetch.p0i8",
        )
        with cgutils.for_range_slice(builder, start, groups, start.type(_LANES)) as (g, _):
            for data in (hidden, cells):  # a read, kept in every cache, of data
                ahead = builder.gep(data, [builder.add(g, g.type(_AHEAD))])
                builder.call(prefetch, [builder.bitcast(ahead, _BYTES), *map(_INT, (0, 3, 1))])
            held = builder.fcmp_unordered("!=", _load_vector(builder, hidden, g), nothing)
            any_held = builder.icmp_unsigned(
                "!=", builder.bitcast(held, ir.IntType(_LANES)), ir.IntType(_LANES)(0)
            )
            with builder.if_then(any_held, likely=True):
                for e in range(0, _LANES, 4):
                    for half, total in enumerate(sums):
                        at = builder.add(g, g.type(e + 2 * half))
                        add(total, builder.fadd(gain(at), gain(builder.add(at, at.type(1)))))
        with cgutils.for_range_slice(builder, groups, stop, start.type(1)) as (e, _):
            add(sums[0], gain(e))
        gained = builder.fadd(builder.load(sums[0]), builder.load(sums[1]))
        best = builder.extract_element(gained, _INT(0))
        for j in range(1, _LANES):
            lane = builder.extract_element(gained, _INT(j))
            best = builder.select(builder.fcmp_ordered(">", lane, best), lane, best)
        return best

    return types.float32(offset, table, inverse, cells, fractions, start, width), codegen
