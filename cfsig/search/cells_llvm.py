"""The fine-cell kernel, compiled by LLVM (optional extra ``cfsig[fast]``); see `cfsig.descriptors.cells`.

One pass over each row's slots, written as LLVM vector code with llvmlite and compiled for this
CPU once a process (docs/partial.md, "Version 10: vector code"). A group of 16 slots has its
fractions rounded to units (`cfsig.descriptors.cells.area_units`), or is skipped when they are all 0 (a
row's padding); each slot's cell then finds its row of the part's table (row 0, all zeros, for
the cells the part lacks), whose 32 lanes of 16 bits, ``f p`` and ``p`` at each share, take
their minimum with the slot's units and are summed in registers. The sums are integers, so the
scores are `cfsig.descriptors.cells.cell_scores`' to the last bit. Each group prefetches the slots `_AHEAD`
on. Loads bound the kernel, not arithmetic: the cells are read four at a time and the table's
rows are found through 16-bit numbers. Listing the held slots first, as an earlier kernel did,
cost more than scoring the slots a part lacks. Importing llvmlite and compiling take about
0.07 s, a few times less than importing numba, which wrapped the same code before, and loading
it (docs/partial.md, "Compiled with llvmlite").
"""

from __future__ import annotations

import contextlib
import ctypes
import functools
from collections.abc import Callable, Iterator, Sequence
from dataclasses import dataclass

import llvmlite.binding as llvm
import numpy as np
from llvmlite import ir

from cfsig.descriptors.cells import UNIT, part_table

_LANES = 16  # shares a table row holds: a part has at most that many, padded
_ALIGN = 64  # bytes: a table row is one cache line
_FLOAT = ir.FloatType()
_DOUBLE = ir.DoubleType()
_SHORT = ir.IntType(16)
_INT = ir.IntType(32)
_WIDE = ir.IntType(64)
_BYTES = ir.IntType(8).as_pointer()
_FLOATS = ir.VectorType(_FLOAT, _LANES)
_UNITS = ir.VectorType(_SHORT, _LANES)  # a group's fractions in units
_ROW = ir.VectorType(_SHORT, 2 * _LANES)  # a table row: f p, then p, at each share
# Slots ahead whose fractions and cells are asked for before they are read: rows come from the
# page cache in pages of 4 KB, across which the hardware's own prefetching stops
# (docs/partial.md, "Version 10: vector code"; 256 to 4,096 measured alike).
_AHEAD = 512
# scores(rows, table, masses, explained, cells, fractions, out, count, width): the addresses of
# `cfsig.descriptors.cells.part_table`'s arrays and the wholes', then two counts; ctypes releases the GIL.
_Kernel = Callable[..., None]


def part_scorer(
    part: Sequence[tuple[np.ndarray, np.ndarray]], shares: tuple[float, ...]
) -> Callable[[np.ndarray, np.ndarray], np.ndarray]:
    """`cfsig.descriptors.cells.cell_scores` of one part, compiled: one pass over each row's cells.

    The part's histograms are laid out once (`cfsig.descriptors.cells.part_table`), for every block of rows
    the scorer is given. The scores are `cfsig.descriptors.cells.cell_scores`' to the last bit.

    Parameters
    ----------
    part : sequence of (cells, fractions)
        The part's `cfsig.descriptors.cells.cell_histogram` at each share, cells below 65,536.
    shares : tuple of float
        The shares, one per histogram of ``part``, at most 16.

    Returns
    -------
    scorer : callable
        ``scorer(cells, fractions)``: the wholes' (m, slots) uint16 `cfsig.descriptors.cells.packed_cells`
        and their (m, slots) float32 fractions to their (m,) float64 scores; releases the GIL.

    Raises
    ------
    ValueError
        More than 16 shares.
    """
    if len(shares) > _LANES:
        raise ValueError(f"{len(shares)} shares: the compiled kernel takes at most {_LANES}")
    rows, table, masses, explained = part_table(part, shares, _LANES)
    table = _aligned(table)
    # A padding share's mass is far above any other's: its score, about 16,500, is never the least.
    masses = np.where(np.arange(_LANES) < len(shares), masses, 1 << 30).astype(np.int32)
    kernel = _kernel()

    def scorer(cells: np.ndarray, fractions: np.ndarray) -> np.ndarray:
        cells = np.ascontiguousarray(cells, np.uint16)
        fractions = np.ascontiguousarray(fractions, np.float32)
        out = np.empty(len(cells))
        arrays = (rows, table, masses, explained, cells, fractions, out)
        kernel(*(a.ctypes.data for a in arrays), *cells.shape)
        return out

    return scorer


def _aligned(array: np.ndarray) -> np.ndarray:
    """A copy of ``array`` starting on a cache line."""
    spare = np.zeros(array.nbytes + _ALIGN, np.uint8)
    skip = -spare.ctypes.data % _ALIGN
    out = spare[skip : skip + array.nbytes].view(array.dtype).reshape(array.shape)
    out[...] = array
    return out


@functools.cache
def _kernel(cpu: str | None = None) -> _Kernel:
    """The kernel compiled for this CPU (or for the one LLVM names ``cpu``), once a process;
    the engine that holds its code lives as long as the function does. Raises OSError where the
    system forbids running code compiled in memory, which would otherwise crash the process."""
    llvm.check_jit_execution()
    llvm.initialize_native_target()
    llvm.initialize_native_asmprinter()
    features = llvm.get_host_cpu_features().flatten() if cpu is None else ""
    machine = llvm.Target.from_default_triple().create_target_machine(
        cpu=cpu or llvm.get_host_cpu_name(), features=features, opt=3
    )
    module = llvm.parse_assembly(str(_module()))
    passes = llvm.create_pass_builder(machine, llvm.create_pipeline_tuning_options(speed_level=3))
    passes.getModulePassManager().run(module, passes)
    engine = llvm.create_mcjit_compiler(module, machine)
    engine.finalize_object()
    arguments = [ctypes.c_void_p] * 7 + [ctypes.c_int64] * 2
    function = ctypes.CFUNCTYPE(None, *arguments)(engine.get_function_address("scores"))
    function.engine = engine  # type: ignore[attr-defined]
    return function


def _module() -> ir.Module:
    """``scores``: ``out[i]``, the score of row i of ``count`` rows of ``width`` slots."""
    module = ir.Module(name="cells")
    shorts, words = _SHORT.as_pointer(), _INT.as_pointer()
    doubles = _DOUBLE.as_pointer()
    arguments = [shorts, shorts, words, doubles, shorts, _FLOAT.as_pointer(), doubles, _WIDE, _WIDE]
    function = ir.Function(module, ir.FunctionType(ir.VoidType(), arguments), "scores")
    rows, table, masses, explained, cells, fractions, out, count, width = function.args
    builder = ir.IRBuilder(function.append_basic_block("entry"))
    room = _Room(
        sums=(builder.alloca(_ROW), builder.alloca(_ROW)),
        whole=builder.alloca(_UNITS),
        units=builder.alloca(_UNITS),
    )
    constants = (
        _load(builder, masses, _WIDE(0), _LANES),
        _load(builder, explained, _WIDE(0), _LANES),
    )
    with _loop(builder, _WIDE(0), count, 1) as i:
        sums, whole = _row_sums(builder, room, rows, table, cells, fractions, i, width)
        score = _row_score(builder, sums, whole, *constants)
        builder.store(score, builder.gep(out, [i]))
    builder.ret_void()
    return module


@dataclass(frozen=True)
class _Room:
    """Stack room of the kernel: the row's two sums of table rows, its sum of the whole's units
    in 16 lanes, and a group's units, read back slot by slot."""

    sums: tuple[ir.AllocaInstr, ir.AllocaInstr]
    whole: ir.AllocaInstr
    units: ir.AllocaInstr


@contextlib.contextmanager
def _loop(builder: ir.IRBuilder, start, stop, step: int) -> Iterator[ir.Value]:
    """``for index in range(start, stop, step)``: the body is built inside the ``with``."""
    before = builder.block
    test = builder.append_basic_block("test")
    body = builder.append_basic_block("body")
    done = builder.append_basic_block("done")
    builder.branch(test)
    builder.position_at_end(test)
    index = builder.phi(start.type)
    index.add_incoming(start, before)
    builder.cbranch(builder.icmp_signed("<", index, stop), body, done)
    builder.position_at_end(body)
    yield index
    index.add_incoming(builder.add(index, start.type(step)), builder.block)
    builder.branch(test)
    builder.position_at_end(done)


def _load(builder, pointer, at, lanes: int):
    """The ``lanes`` values at ``pointer + at``, as a vector."""
    kind = ir.VectorType(pointer.type.pointee, lanes)
    return builder.load(builder.bitcast(builder.gep(pointer, [at]), kind.as_pointer()), align=2)


def _splat(builder, value, lanes: int):
    """``lanes`` copies of a value."""
    kind = ir.VectorType(value.type, lanes)
    one = builder.insert_element(ir.Constant(kind, ir.Undefined), value, _INT(0))
    return builder.shuffle_vector(one, one, ir.Constant(ir.VectorType(_INT, lanes), [0] * lanes))


def _call(builder, name: str, result, *values):
    """Call the LLVM intrinsic ``name`` on ``values``."""
    kind = ir.FunctionType(result, [v.type for v in values])
    found = builder.module.globals.get(name) or ir.Function(builder.module, kind, name)
    return builder.call(found, list(values))


def _units(builder, fractions):
    """`cfsig.descriptors.cells.area_units` of a <16 x float>: scaled in float32, clipped to [0, UNIT],
    rounded to the nearest (ties to even, as NumPy's ``rint``)."""
    low, high = (ir.Constant(_FLOATS, [v] * _LANES) for v in (0.0, float(UNIT)))
    scaled = builder.fmul(fractions, high)
    scaled = builder.select(builder.fcmp_ordered("<", scaled, low), low, scaled)
    scaled = builder.select(builder.fcmp_ordered(">", scaled, high), high, scaled)
    return builder.fptoui(_call(builder, "llvm.rint.v16f32", _FLOATS, scaled), _UNITS)


def _row_sums(builder, room, rows, table, cells, fractions, row, width):
    """Row ``row``'s sums, slot by slot: of ``min(f p, w)`` and ``min(p, w)`` in the 32 lanes of
    a table row (two sums, alternate slots), and of ``w`` in 16 lanes, all in units of 16 bits.
    Groups of 16 slots, then the last ``width % 16`` one by one."""
    for total, kind in ((room.sums[0], _ROW), (room.sums[1], _ROW), (room.whole, _UNITS)):
        builder.store(ir.Constant(kind, [0] * kind.count), total)
    # An empty asm statement hides that a group's slots read back the units just stored: else
    # LLVM takes each from the group's vector by a shuffle, on a port the arithmetic needs,
    # rather than by a load.
    units = builder.bitcast(room.units, _SHORT.as_pointer())
    hidden = builder.asm(ir.FunctionType(units.type, [units.type]), "", "=r,0", [units], False)

    def add(total, value):
        builder.store(builder.add(builder.load(total), value), total)

    def gain(cell, total, w):
        at = builder.zext(builder.load(builder.gep(rows, [cell])), _WIDE)
        held = _load(builder, table, builder.shl(at, _WIDE(5)), 2 * _LANES)  # 32 units a row
        add(total, builder.select(builder.icmp_unsigned("<", held, w), held, w))

    start = builder.mul(row, width)
    stop = builder.add(start, width)
    groups = builder.sub(stop, builder.srem(width, width.type(_LANES)))
    with _loop(builder, start, groups, _LANES) as g:
        for data in (fractions, cells):  # a read, kept in every cache, of data
            ahead = builder.gep(data, [builder.add(g, g.type(_AHEAD))])
            _call(
                builder,
                "llvm.prefetch.p0",
                ir.VoidType(),
                builder.bitcast(ahead, _BYTES),
                *map(_INT, (0, 3, 1)),
            )
        group = _load(builder, fractions, g, _LANES)
        held = builder.fcmp_unordered("!=", group, ir.Constant(_FLOATS, [0.0] * _LANES))
        any_held = builder.icmp_unsigned(
            "!=", builder.bitcast(held, ir.IntType(_LANES)), ir.IntType(_LANES)(0)
        )
        with builder.if_then(any_held, likely=True):
            group_units = _units(builder, group)
            add(room.whole, group_units)
            builder.store(group_units, room.units)
            # The cells four at a time, split by shifts: loads are the kernel's bound.
            quads = builder.bitcast(builder.gep(cells, [g]), _WIDE.as_pointer())
            for e in range(_LANES):
                if e % 4 == 0:
                    quad = builder.load(builder.gep(quads, [_WIDE(e // 4)]), align=2)
                shifted = builder.lshr(quad, _WIDE(16 * (e % 4)))
                cell = builder.and_(shifted, _WIDE(0xFFFF))
                w = _splat(builder, builder.load(builder.gep(hidden, [_WIDE(e)])), 2 * _LANES)
                gain(cell, room.sums[e % 2], w)
    with _loop(builder, groups, stop, 1) as e:
        one = builder.insert_element(
            ir.Constant(_FLOATS, [0.0] * _LANES), builder.load(builder.gep(fractions, [e])), _INT(0)
        )
        one_units = _units(builder, one)
        add(room.whole, one_units)
        w = _splat(builder, builder.extract_element(one_units, _INT(0)), 2 * _LANES)
        gain(builder.zext(builder.load(builder.gep(cells, [e])), _WIDE), room.sums[0], w)
    return (builder.load(room.sums[0]), builder.load(room.sums[1])), builder.load(room.whole)


def _row_score(builder, sums, whole, masses, explained):
    """The row's score from its sums: the least over the shares of ``(1 - E / F) + (P + W -
    2 C) / UNIT``, in float64 and in `cfsig.descriptors.cells.cell_scores`' order of operations."""
    lanes, wide = ir.VectorType(_INT, _LANES), ir.VectorType(_INT, 2 * _LANES)
    both = builder.add(builder.zext(sums[0], wide), builder.zext(sums[1], wide))
    explained_sums, common = (
        builder.shuffle_vector(both, both, ir.Constant(lanes, list(range(at, at + _LANES))))
        for at in (0, _LANES)
    )
    w = _call(builder, "llvm.vector.reduce.add.v16i32", _INT, builder.zext(whole, lanes))
    lost = builder.sub(builder.add(masses, _splat(builder, w, _LANES)), builder.add(common, common))
    reals = ir.VectorType(_DOUBLE, _LANES)
    one = ir.Constant(reals, [1.0] * _LANES)
    unit = ir.Constant(reals, [1 / UNIT] * _LANES)
    unexplained = builder.fsub(one, builder.fmul(builder.uitofp(explained_sums, reals), explained))
    scores = builder.fadd(unexplained, builder.fmul(builder.sitofp(lost, reals), unit))
    best = builder.extract_element(scores, _INT(0))
    for j in range(1, _LANES):
        lane = builder.extract_element(scores, _INT(j))
        best = builder.select(builder.fcmp_ordered("<", lane, best), lane, best)
    return best
