"""The fine-cell kernel, compiled by LLVM (optional extra ``cfsig[fast]``); see `cfsig.cells`.

One pass over each row's slots, written as LLVM vector code with llvmlite and compiled for this
CPU once a process (docs/partial.md, "Version 10: vector code"): each slot's cell finds its row
of the part's table (row 0, all zeros, for the cells the part lacks), and its gains at all 16
lanes of shares are summed in registers, four slots a pass. A group of 16 slots whose fractions
are all 0 (a row's padding) gains nothing and is skipped; each group prefetches the slots
`_AHEAD` on. Listing the held slots first, as an earlier kernel did, cost more than scoring the
slots a part lacks. Importing llvmlite and compiling take about 0.07 s, a few times less than
importing numba, which wrapped the same code before, and loading it (docs/partial.md,
"Compiled with llvmlite").
"""

from __future__ import annotations

import contextlib
import ctypes
import functools
from collections.abc import Callable, Iterator, Sequence

import llvmlite.binding as llvm
import numpy as np
from llvmlite import ir

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
# scores(offset, table, inverse, cells, fractions, out, rows, width): the addresses of the
# arrays `part_scorer` lays out, then two counts; ctypes releases the GIL while it runs.
_Kernel = Callable[..., None]


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
        raise ValueError(f"{len(shares)} shares: the compiled kernel takes at most {_LANES}")
    held = np.unique(np.concatenate([np.asarray(c, np.int64) for c, _ in part]))
    # Where a cell's row of the table starts, in floats; 0 for the cells the part lacks.
    offset = np.zeros(1 << 16, np.uint32)
    offset[held] = np.arange(1, len(held) + 1) * _LANES
    table = _aligned_zeros((len(held) + 1) * _LANES).reshape(-1, _LANES)
    for j, (c, p) in enumerate(part):
        table[offset[c] // _LANES, j] = p
    inverse = np.ones(_LANES, np.float32)  # a padding share's table is 0: it gains nothing
    inverse[: len(shares)] = 1 / np.asarray(shares)
    kernel = _kernel()

    def scorer(cells: np.ndarray, fractions: np.ndarray) -> np.ndarray:
        cells = np.ascontiguousarray(cells, np.uint16)
        fractions = np.ascontiguousarray(fractions, np.float32)
        out = np.empty(len(cells))
        addresses = (a.ctypes.data for a in (offset, table, inverse, cells, fractions, out))
        kernel(*addresses, *cells.shape)
        return out

    return scorer


def _aligned_zeros(count: int) -> np.ndarray:
    """(count,) float32 zeros starting on a cache line."""
    spare = np.zeros(count + _ALIGN // 4, np.float32)
    skip = (-spare.ctypes.data % _ALIGN) // 4
    return spare[skip : skip + count]


@functools.cache
def _kernel(cpu: str | None = None) -> _Kernel:
    """The kernel compiled for this CPU (or for the one LLVM names ``cpu``), once a process;
    the engine that holds its code lives as long as the function does."""
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
    arguments = [ctypes.c_void_p] * 6 + [ctypes.c_int64] * 2
    function = ctypes.CFUNCTYPE(None, *arguments)(engine.get_function_address("scores"))
    function.engine = engine  # type: ignore[attr-defined]
    return function


def _module() -> ir.Module:
    """``scores``: ``out[i] = 3 - gain`` of row i of ``rows`` rows of ``width`` slots."""
    module = ir.Module(name="cells")
    floats, cells_type, words = _FLOAT.as_pointer(), ir.IntType(16).as_pointer(), _INT.as_pointer()
    signature = ir.FunctionType(
        ir.VoidType(),
        [words, floats, floats, cells_type, floats, ir.DoubleType().as_pointer(), _WIDE, _WIDE],
    )
    function = ir.Function(module, signature, "scores")
    offsets, table, inverses, cells, fractions, out, rows, width = function.args
    builder = ir.IRBuilder(function.append_basic_block("entry"))
    sums = [builder.alloca(_FLOATS) for _ in range(2)]
    inverse = _load_vector(builder, inverses, _WIDE(0))
    with _loop(builder, _WIDE(0), rows, 1) as i:
        gain = _row_gain(builder, offsets, table, inverse, cells, fractions, sums, i, width)
        score = builder.fsub(ir.DoubleType()(3.0), builder.fpext(gain, ir.DoubleType()))
        builder.store(score, builder.gep(out, [i]))
    builder.ret_void()
    return module


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


def _row_gain(builder, offsets, table, inverse, cells, fractions, sums, row, width):
    """The largest over the shares of ``3 - score`` of row ``row``, summed slot by slot:
    ``min(f p, w) / f + 2 min(p, w)``. Groups of 16 slots, then the last ``width % 16`` one by
    one; ``sums``: two vectors' room for the sums."""
    two = ir.Constant(_FLOATS, [2.0] * _LANES)
    nothing = ir.Constant(_FLOATS, [0.0] * _LANES)
    for total in sums:  # two sums, each of two slots a pass of four: kept in registers
        builder.store(nothing, total)

    def gain(at):
        cell = builder.zext(builder.load(builder.gep(cells, [at])), _WIDE)
        where = builder.zext(builder.load(builder.gep(offsets, [cell])), _WIDE)
        p = _load_vector(builder, table, where)
        w = _splat(builder, builder.load(builder.gep(fractions, [at])))
        explained = _minimum(builder, p, builder.fmul(w, inverse))
        common = builder.fmul(two, _minimum(builder, p, w), flags=_FUSE)
        return builder.fadd(explained, common, flags=_FUSE)

    def add(total, value):
        builder.store(builder.fadd(builder.load(total), value), total)

    # An empty asm statement hides that the test of a group reads the fractions that its slots
    # then read one by one: else LLVM takes each slot's fraction from the test's vector by a
    # shuffle, on a port the arithmetic needs, rather than by a load.
    hidden = builder.asm(
        ir.FunctionType(fractions.type, [fractions.type]), "", "=r,0", [fractions], False
    )
    prefetch = ir.Function(
        builder.module,
        ir.FunctionType(ir.VoidType(), [_BYTES, _INT, _INT, _INT]),
        "llvm.prefetch.p0",
    )
    start = builder.mul(row, width)
    stop = builder.add(start, width)
    groups = builder.sub(stop, builder.srem(width, width.type(_LANES)))
    with _loop(builder, start, groups, _LANES) as g:
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
    with _loop(builder, groups, stop, 1) as e:
        add(sums[0], gain(e))
    gained = builder.fadd(builder.load(sums[0]), builder.load(sums[1]))
    best = builder.extract_element(gained, _INT(0))
    for j in range(1, _LANES):
        lane = builder.extract_element(gained, _INT(j))
        best = builder.select(builder.fcmp_ordered(">", lane, best), lane, best)
    return best
