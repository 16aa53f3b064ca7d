"""The fine-cell kernel of numba (optional extra ``cfsig[fast]``); see `cfsig.cells`.

Each row takes two steps, both written as LLVM vector code (`numba.extending.intrinsic`):
numba's own loops checked, for every four cells, that the sums did not overlap the part's
table, and listed the cells one slot at a time; this kernel takes half their time
(docs/partial.md, "Version 10: vector code").

- `_list_held`, 16 slots at a time: each cell's row of the part's table, then the slots the
  part holds (a row other than 0, a fraction other than 0) stored one after another with
  their fractions (a compress store).
- `_best_gain`: the gains of the listed cells at all 16 lanes of shares, summed in registers
  four cells a pass; their largest.
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
_FLOATS = ir.VectorType(_FLOAT, _LANES)
_INTS = ir.VectorType(_INT, _LANES)
_MASK = ir.VectorType(ir.IntType(1), _LANES)
# A multiplication and an addition may fuse, but no sum is reordered: each waits on one addition
# a pass of four cells, where a free reordering chained three.
_FUSE = ("contract",)


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
    slot = np.zeros(1 << 16, np.uint32)  # a cell's row of the table; 0 for the cells it lacks
    slot[held] = np.arange(1, len(held) + 1)
    table = _aligned_zeros((len(held) + 1) * _LANES).reshape(-1, _LANES)
    for j, (c, p) in enumerate(part):
        table[slot[c], j] = p
    inverse = np.ones(_LANES, np.float32)  # a padding share's table is 0: it gains nothing
    inverse[: len(shares)] = 1 / np.asarray(shares)
    flat = table.ravel()

    def scorer(cells: np.ndarray, fractions: np.ndarray) -> np.ndarray:
        out = np.empty(len(cells))
        cells, fractions = np.ascontiguousarray(cells), np.ascontiguousarray(fractions)
        _scores(slot, flat, inverse, cells.reshape(-1), fractions.reshape(-1), out)
        return out

    return scorer


def _aligned_zeros(count: int) -> np.ndarray:
    """(count,) float32 zeros starting on a cache line."""
    spare = np.zeros(count + _ALIGN // 4, np.float32)
    skip = (-spare.ctypes.data % _ALIGN) // 4
    return spare[skip : skip + count]


@numba.njit(nogil=True, boundscheck=False, cache=True)
def _scores(slot, table, inverse, cells, fractions, out):
    """``out[i]``: row i's partial distance; ``cells`` and ``fractions`` hold the rows one after
    another. The slots past the last whole vector of 16 are listed one by one."""
    width = len(cells) // max(len(out), 1)
    found = np.zeros(width + 4, np.uint32)  # the listed cells' rows of the table, then 0s
    whole = np.zeros(width + 4, np.float32)
    vectors = width - width % _LANES
    for i in range(len(out)):
        start = i * width
        count = 0
        for s in range(start, start + vectors, _LANES):
            count = _list_held(slot, cells, fractions, s, found, whole, count)
        for s in range(start + vectors, start + width):
            k = slot[cells[s]]
            found[count], whole[count] = k, fractions[s]
            count += (k != 0) & (fractions[s] != 0)
        found[count : count + 4] = 0  # padding: the table's row 0 gains nothing
        whole[count : count + 4] = 0
        out[i] = 3.0 - _best_gain(table, inverse, found, whole, count)


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
def _list_held(typingctx, slot, cells, fractions, at, found, whole, count):
    """List the slots ``at`` to ``at + 16`` that the part holds after the ``count`` listed:
    their table rows in ``found``, their fractions in ``whole``; the new count."""

    def codegen(context, builder, signature, args):
        slots, cells, fractions, at, listed, wholes, count = (
            _pointer(context, builder, t, a) if isinstance(t, types.Array) else a
            for t, a in zip(signature.args, args, strict=True)
        )
        held = ir.Constant(_INTS, ir.Undefined)
        for j in range(_LANES):
            cell = builder.load(builder.gep(cells, [builder.add(at, at.type(j))]))
            k = builder.load(builder.gep(slots, [builder.zext(cell, _WIDE)]))
            held = builder.insert_element(held, k, _INT(j))
        fraction = _load_vector(builder, fractions, at)
        keep = builder.and_(
            builder.icmp_unsigned("!=", held, ir.Constant(_INTS, [0] * _LANES)),
            builder.fcmp_unordered("!=", fraction, ir.Constant(_FLOATS, [0.0] * _LANES)),
        )
        for values, into, kind in ((held, listed, "i32"), (fraction, wholes, "f32")):
            store = cgutils.get_or_insert_function(
                builder.module,
                ir.FunctionType(ir.VoidType(), [values.type, into.type, _MASK]),
                f"llvm.masked.compressstore.v{_LANES}{kind}",
            )
            builder.call(store, [values, builder.gep(into, [count]), keep])
        kept = builder.ctpop(builder.bitcast(keep, ir.IntType(_LANES)))
        return builder.add(count, builder.zext(kept, _WIDE))

    return types.int64(slot, cells, fractions, at, found, whole, count), codegen


@intrinsic
def _best_gain(typingctx, table, inverse, found, whole, count):
    """The largest over the shares of ``3 - score``, summed cell by cell over the ``count``
    listed cells (padded to a multiple of 4): ``min(f p, w) / f + 2 min(p, w)``."""

    def codegen(context, builder, signature, args):
        table, inverses, listed, wholes, count = (
            _pointer(context, builder, t, a) if isinstance(t, types.Array) else a
            for t, a in zip(signature.args, args, strict=True)
        )
        inverse = _load_vector(builder, inverses, _WIDE(0))
        two = ir.Constant(_FLOATS, [2.0] * _LANES)
        # Two sums, each of two cells a pass: LLVM keeps them in registers.
        sums = [
            cgutils.alloca_once_value(builder, ir.Constant(_FLOATS, [0.0] * _LANES))
            for _ in range(2)
        ]
        with cgutils.for_range_slice(builder, count.type(0), count, count.type(4)) as (e, _):
            for half, total in enumerate(sums):
                gains = []
                for q in (2 * half, 2 * half + 1):
                    at = builder.add(e, e.type(q))
                    k = builder.zext(builder.load(builder.gep(listed, [at])), _WIDE)
                    p = _load_vector(builder, table, builder.mul(k, _WIDE(_LANES)))
                    w = _splat(builder, builder.load(builder.gep(wholes, [at])))
                    explained = _minimum(builder, p, builder.fmul(w, inverse))
                    common = builder.fmul(two, _minimum(builder, p, w), flags=_FUSE)
                    gains.append(builder.fadd(explained, common, flags=_FUSE))
                pair = builder.fadd(gains[0], gains[1])
                builder.store(builder.fadd(builder.load(total), pair), total)
        gained = builder.fadd(builder.load(sums[0]), builder.load(sums[1]))
        best = builder.extract_element(gained, _INT(0))
        for j in range(1, _LANES):
            lane = builder.extract_element(gained, _INT(j))
            best = builder.select(builder.fcmp_ordered(">", lane, best), lane, best)
        return best

    return types.float32(table, inverse, found, whole, count), codegen
