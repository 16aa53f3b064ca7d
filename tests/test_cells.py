"""Fine curvature cells (cfsig.descriptors.cells): the histograms, their scores (cfsig.search.cells
and the compiled kernel), the signatures that keep them and their storage in an index."""

import functools
import os
import sys
from dataclasses import replace

import h5py
import numpy as np
import pytest

from cfsig.descriptors import intrinsic, layout
from cfsig.descriptors.cells import (
    SLOTS,
    UNIT,
    area_units,
    cell_histogram,
    packed_cells,
    window_cells,
)
from cfsig.descriptors.intrinsic import curvature_histograms
from cfsig.descriptors.parts import FINE_SHARES, Part, measure_part
from cfsig.descriptors.signature import compute_signature
from cfsig.errors import IndexFileError
from cfsig.files.mesh import clean_mesh
from cfsig.index.blocks import plan_blocks
from cfsig.index.store import Entry, IndexReader, check_index
from cfsig.params import Params
from cfsig.search.cells import cell_scores
from cfsig.search.partial import (
    FAST_MIN_ROWS,
    part_scorer,
    partial_distances,
    query_part,
)
from tests.helpers import open_writer, random_signature, torus

V10 = Params(partial_cells=True)


def _values(n, seed=0):
    """Curvature-like values at four scales, smooth from one scale to the next."""
    rng = np.random.default_rng(seed)
    first = rng.normal(0, 20, n)
    return np.cumsum(np.column_stack([first, rng.normal(0, 3, (n, 3))]), axis=1)


def test_pairs_of_scales_are_the_descriptors_joint_histograms():
    values, areas = _values(500), np.random.default_rng(1).random(500)
    cells, fractions = cell_histogram(values, areas, intrinsic.BINS, intrinsic.BAND, joint=2)
    dense = curvature_histograms(values, areas).ravel() / 3  # three windows of mass 1/3
    assert np.array_equal(cells, np.flatnonzero(dense)) and np.allclose(fractions, dense[cells])


def test_all_scales_jointly_one_cell_per_vertex():
    values = _values(300)
    cells = window_cells(values, 33, 4, 4)
    assert cells.shape == (300, 1) and cells.min() >= 0 and cells.max() < 33 * 9**3
    moved = values.copy()
    moved[:, 3] += 1000.0  # a far step to the last scale is clipped, not wrapped
    steps = window_cells(moved, 33, 4, 4)[:, 0] % 9
    assert np.all(steps <= 8)


def test_packed_cells_keep_the_largest_in_fixed_width():
    values, areas = _values(2000), np.random.default_rng(2).random(2000)
    cells, fractions = cell_histogram(values, areas, 33, 4)
    packed, packed_units = packed_cells(values, areas, 33, 4, slots=len(cells) // 2)
    assert packed.dtype == np.uint16 and packed_units.dtype == np.uint16
    assert np.all(np.diff(packed.astype(int)) > 0)
    kept = np.isin(cells, packed)
    assert fractions[kept].min() >= fractions[~kept].max()
    wide, wide_units = packed_cells(values, areas, 33, 4, slots=len(cells) + 5)
    assert np.array_equal(wide[: len(cells)], cells) and not wide_units[len(cells) :].any()
    # Each share rounded to the nearest unit (scaled in float32): off by half a unit at most.
    assert np.abs(wide_units[: len(cells)] - fractions * UNIT).max() <= 0.51
    assert abs(int(wide_units.sum(dtype=np.int64)) - UNIT) <= len(cells) / 2


def _dense_scores(part, shares, cells, fractions, size):
    """The partial distance written out on dense histograms."""
    wholes = np.zeros((len(cells), size))
    for row, (c, w) in enumerate(zip(cells, fractions, strict=True)):
        np.add.at(wholes[row], c, w)
    out = []
    for share, (c, p) in zip(shares, part, strict=True):
        dense = np.zeros(size)
        dense[c] = p
        unexplained = np.maximum(share * dense - wholes, 0).sum(axis=1) / share
        out.append(unexplained + np.abs(dense - wholes).sum(axis=1))
    return np.min(out, axis=0)


def _histogram(rng, count, size=3000):
    """A random sparse histogram of mass 1: ``count`` of ``size`` cells, ascending."""
    c = np.sort(rng.choice(size, count, replace=False))
    w = rng.random(count)
    return c, w / w.sum()


def test_cell_scores_of_many_rows_are_each_rows():
    rng = np.random.default_rng(4)
    shares = (1.0, 0.5)
    part = [_histogram(rng, 40, 200) for _ in shares]
    cells = np.zeros((1100, 60), np.uint16)  # more rows than are scored at a time
    fractions = np.zeros((1100, 60))
    for row in range(len(cells)):
        c, w = _histogram(rng, int(rng.integers(1, 60)), 200)
        cells[row, : len(c)], fractions[row, : len(c)] = c, w
    units = area_units(fractions)
    each = [cell_scores(part, shares, cells[i : i + 1], units[i : i + 1])[0] for i in range(1100)]
    assert np.array_equal(cell_scores(part, shares, cells, units), each)


def test_cell_scores_are_the_partial_distance():
    rng = np.random.default_rng(3)
    size, shares = 60, (1.0, 0.5, 0.25)
    part = [_histogram(rng, 10, size) for _ in shares]
    wholes = [_histogram(rng, 25, size) for _ in range(6)]
    cells = np.zeros((6, 32), np.uint16)
    fractions = np.zeros((6, 32))
    for row, (c, w) in enumerate(wholes):
        cells[row, : len(c)], fractions[row, : len(c)] = c, w
    got = cell_scores(part, shares, cells, area_units(fractions))
    # Shares rounded to units of 1/UNIT: each of the 35 cells moves a sum by half a unit at most.
    dense = _dense_scores(part, shares, cells, fractions, size)
    assert np.allclose(got, dense, atol=35 / UNIT / min(shares)) and np.ptp(dense) > 0.1
    units = area_units(fractions[2:3])
    same = cell_scores([(c, w) for c, w in [wholes[2]]], (1.0,), cells[2:3], units)
    assert same[0] == 0.0  # a whole is its own part at share 1


def test_area_units_round_to_nearest():
    units = area_units(np.array([0.0, 0.5 / UNIT, 1.5 / UNIT, 0.25, 1.0, 1.5, -0.1]))
    assert units.dtype == np.uint16
    assert list(units) == [0, 0, 2, UNIT // 4, UNIT, UNIT, 0]  # ties to even; clipped to [0, 1]


@pytest.mark.parametrize(("slots", "shares"), [(400, FINE_SHARES), (407, FINE_SHARES[:5])])
def test_compiled_scores_are_numpys(slots, shares):
    pytest.importorskip("cfsig.search.cells_compiled", reason="built when cfsig is installed")
    rng = np.random.default_rng(5)
    part = [_histogram(rng, 200) for _ in shares]
    cells = np.zeros((300, slots), np.uint16)
    fractions = np.zeros((300, slots))
    for row in range(len(cells)):
        c, w = _histogram(rng, int(rng.integers(1, slots)))
        if row % 3 == 0:  # some of them the part's own cells, so that the scores spread
            c, w = part[row % len(shares)]
        w = w.copy()
        w[rng.random(len(w)) < 0.05] = 0  # occupied slots of no area, among the others
        if row % 7 == 1:  # 32 slots of no area, between held ones
            w[16:48] = 0
        cells[row, : len(c)], fractions[row, : len(c)] = c, w
    units = area_units(fractions)
    fast = part_scorer(part, shares, FAST_MIN_ROWS)
    assert not isinstance(fast, functools.partial)  # compiled, not cell_scores
    expected = cell_scores(part, shares, cells, units)
    got = fast(cells, units)
    assert got.dtype == np.float64 and got.shape == (300,)
    assert np.array_equal(got, expected)  # the same sums in integers, the same float64 steps
    compiled = sys.modules["cfsig.search.cells_compiled"]
    for avx2 in {False, compiled.AVX2}:  # the portable loop, and the AVX2 one where it runs
        assert np.array_equal(compiled.part_scorer(part, shares, avx2=avx2)(cells, units), expected)
    assert np.ptp(got) > 1  # spread: the part's own cells and unrelated ones
    assert np.array_equal(fast(cells[:0], units[:0]), np.zeros(0))
    empty = fast(cells[:2, :0], units[:2, :0])  # no slots: all of the part is unexplained
    assert np.array_equal(empty, cell_scores(part, shares, cells[:2, :0], units[:2, :0]))
    assert empty == pytest.approx([2.0, 2.0], abs=1e-2)


def test_the_avx2_loop_is_refused_without_avx2(monkeypatch):
    compiled = pytest.importorskip("cfsig.search.cells_compiled", reason="built when installed")
    monkeypatch.setattr(compiled, "AVX2", False)
    with pytest.raises(ValueError, match="no AVX2"):
        compiled.part_scorer([(np.array([1]), np.array([1.0]))], (1.0,), avx2=True)


@pytest.mark.parametrize("case", ["small search", "not built", "too many shares"])
def test_numpy_scores_where_the_compiled_kernel_does_not_serve(monkeypatch, case):
    shares = (1.0,) * (17 if case == "too many shares" else 1)
    part = [(np.array([1, 2]), np.array([0.5, 0.5]))] * len(shares)
    rows = FAST_MIN_ROWS - 1 if case == "small search" else FAST_MIN_ROWS
    if case == "not built":
        monkeypatch.setitem(sys.modules, "cfsig.search.cells_compiled", None)  # import fails
        monkeypatch.delattr("cfsig.search.cells_compiled", raising=False)
    scorer = part_scorer(part, shares, rows)
    cells, units = np.array([[1, 2]], np.uint16), area_units(np.array([[0.5, 0.5]]))
    assert isinstance(scorer, functools.partial) and scorer.func is cell_scores
    assert scorer(cells, units)[0] == 0.0


def test_partial_cells_keep_the_vector_and_add_the_cells():
    mesh = clean_mesh(*torus())
    sig = compute_signature(mesh, V10)
    assert np.array_equal(sig.vector, compute_signature(mesh, Params()).vector)
    assert compute_signature(mesh, Params()).cells is None
    cells, units = sig.cells
    assert cells.shape == units.shape == (SLOTS,) == (layout(V10).cells,)
    used = units > 0
    assert abs(int(units.sum(dtype=np.int64)) - UNIT) <= used.sum() / 2 and used.sum() > 1
    # The whole measured as a part at share 1 finds the same cells, the same shares.
    ((part_cells, part_fractions), *_) = measure_part(mesh, V10).cells
    assert FINE_SHARES[0] == 1.0 and len(measure_part(mesh, V10).cells) == len(FINE_SHARES)
    assert np.array_equal(part_cells, cells[used])
    assert np.array_equal(area_units(part_fractions), units[used])


def _signature(seed):
    """A signature with fine cells, of random values with random cells."""
    rng = np.random.default_rng(seed)
    cells = np.zeros(SLOTS, np.uint16)
    fractions = np.zeros(SLOTS)
    count = int(rng.integers(1, 50))
    cells[:count] = np.sort(rng.choice(30000, count, replace=False))
    fractions[:count] = rng.random(count)
    vector = random_signature(seed, layout(V10).length).vector
    cells_and_units = (cells, area_units(fractions / fractions.sum()))
    return replace(random_signature(seed), vector=vector, cells=cells_and_units)


def test_an_index_keeps_the_cells_through_merges(tmp_path):
    index, want = tmp_path / "i", {}
    with open_writer(index, V10) as w:
        for commit in range(3):
            for i in range(5):
                name = f"c{i % 2}/{(commit * 3 + i) % 8}.off"  # some names again: superseded
                sig = _signature(100 * commit + i)
                w.add(Entry(name, name[:2], f"/d/{name}"), sig)
                want[name] = sig.cells
            w.commit()
        assert len(w.segments) > 1
        with pytest.raises(ValueError, match="x/y.off: no fine cells"):
            w.add(Entry("x/y.off", "x", "/x/y.off"), random_signature(0, layout(V10).length))
    for step in ("committed", "compacted"):
        if step == "compacted":
            with open_writer(index, V10) as w:
                w.compact()
                assert len(w.segments) == 1
        with IndexReader(index) as r:
            cells, units = r.cells()
            names = list(r.column("names"))
        assert sorted(names) == sorted(want)
        for row, name in enumerate(names):
            assert np.array_equal(cells[row], want[name][0])
            assert np.array_equal(units[row], want[name][1])
    assert check_index(index) == []


def test_damaged_or_missing_cells_are_named(tmp_path):
    index = tmp_path / "i"
    with open_writer(index, V10) as w:
        for i in range(4):
            w.add(Entry(f"c/{i}.off", "c", f"/c/{i}.off"), _signature(i))
    (segment,) = index.glob("seg-*.h5")
    with h5py.File(segment, "r") as f:
        offset = f["cell_units"].id.get_chunk_info(0).byte_offset + 4
    data = bytearray(segment.read_bytes())
    data[offset] ^= 0xFF
    segment.write_bytes(bytes(data))
    assert any("column cell_units: checksum mismatch" in p for p in check_index(index))
    with h5py.File(segment, "a") as f:
        del f["cells"]
    with pytest.raises(IndexFileError, match="fine curvature cells are missing"):
        IndexReader(index)


@pytest.fixture(params=["numpy", "compiled"])
def kernel(request, monkeypatch):
    """The fine cells scored by NumPy's kernel, or by the compiled one (skipped where it was
    not built)."""
    if request.param == "compiled":
        pytest.importorskip("cfsig.search.cells_compiled", reason="built when cfsig is installed")
    fast_min_rows = 0 if request.param == "compiled" else 1 << 62
    monkeypatch.setattr("cfsig.search.partial.FAST_MIN_ROWS", fast_min_rows)
    return request.param


def _search_finds_the_nearest(reader, cells):
    """`query_part` of a part of even fractions on ``cells`` at every share finds the whole
    of the smallest `partial_distances`, at that distance."""
    part = Part(cells=((cells, np.full(len(cells), 1 / len(cells))),) * len(FINE_SHARES))
    expected = partial_distances(part, reader.signatures[:], V10, reader.cells())
    hits, distance = query_part(reader, part, 3)
    assert hits[0].entry.name == reader.column("names")[np.argmin(expected)]
    assert distance == pytest.approx(expected.min(), abs=1e-5)


def test_partial_search_reads_every_live_rows_cells(tmp_path, kernel):
    index = tmp_path / "i"
    with open_writer(index, V10) as w:
        for commit in range(3):
            for i in range(6):
                name = f"c{i % 2}/{(commit * 4 + i) % 10}.off"  # some again: dead rows
                w.add(Entry(name, name[:2], f"/d/{name}"), _signature(50 * commit + i))
            w.commit()
    rng = np.random.default_rng(8)
    with IndexReader(index) as reader:
        assert len(reader.segments) > 1 and any(len(v.dead) for v in reader.segments)
        # The cells are read from the file directly (cfsig.index.blocks), not through h5py.
        assert all(b.offset is not None for b in plan_blocks(reader.segments[0].cells[0], 4))
        stored, fractions = reader.cells()
        view = next(v for v in reader.segments if len(v.dead))
        dead = (view.cells[0][view.dead[0]], view.cells[1][view.dead[0]])  # superseded
        for query_cells, query_fractions in [dead, *zip(stored[:4], fractions[:4], strict=True)]:
            own = query_cells[query_fractions > 0].astype(np.int64)
            _search_finds_the_nearest(
                reader, np.sort(rng.choice(own, max(1, len(own) // 2), replace=False))
            )


def test_partial_search_reads_compressed_cells_through_h5py(tmp_path, kernel):
    index = tmp_path / "i"
    with open_writer(index, V10) as w:
        for i in range(12):
            w.add(Entry(f"c/{i}.off", "c", f"/d/c/{i}.off"), _signature(i))
    (segment,) = index.glob("seg-*.h5")
    with h5py.File(segment, "a") as f:  # as another writer of HDF5 might store them
        for name in ("cells", "cell_units"):
            data = f[name][:]
            del f[name]
            f.create_dataset(name, data=data, chunks=(5, data.shape[1]), compression="gzip")
    with IndexReader(index) as reader:
        assert all(b.offset is None for b in plan_blocks(reader.segments[0].cells[0], 4))
        stored, units = reader.cells()
        for row in (3, 7):
            _search_finds_the_nearest(reader, stored[row][units[row] > 0].astype(np.int64)[::2])


def test_partial_search_without_memory_maps_reads_the_blocks(tmp_path, monkeypatch):
    index = tmp_path / "i"
    with open_writer(index, V10) as w:
        for i in range(8):
            w.add(Entry(f"c/{i}.off", "c", f"/d/c/{i}.off"), _signature(i))

    def refuse(*args, **kwargs):
        raise OSError("this file system has no memory maps")

    monkeypatch.setattr("cfsig.index.blocks.mmap.mmap", refuse)
    with IndexReader(index) as reader:
        stored, units = reader.cells()
        for row in (2, 5):
            _search_finds_the_nearest(reader, stored[row][units[row] > 0].astype(np.int64)[::3])


def test_cells_cut_short_after_opening_are_a_clear_error(tmp_path):
    index = tmp_path / "i"
    with open_writer(index, V10) as w:
        for i in range(6):
            w.add(Entry(f"c/{i}.off", "c", f"/d/c/{i}.off"), _signature(i))
    with IndexReader(index) as reader:
        (segment,) = index.glob("seg-*.h5")
        units = reader.segments[0].cells[1]
        (block,) = plan_blocks(units, 4096)
        os.truncate(segment, block.offset + 10)
        part = Part(cells=((np.array([1, 2]), np.array([0.5, 0.5])),) * len(FINE_SHARES))
        with pytest.raises(IndexFileError, match="ends inside /cell_units"):
            query_part(reader, part, 3)
