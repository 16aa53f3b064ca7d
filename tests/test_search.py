import os

import h5py
import numpy as np
import pytest

import cfsig.index.segments
import cfsig.search.l1
import cfsig.search.nearest
from cfsig.descriptors.signature import Signature
from cfsig.errors import IndexFileError
from cfsig.index.blocks import (
    load_block,
    map_file,
    plan_blocks,
    read_block,
    read_columns,
    read_rows,
)
from cfsig.index.store import Entry, IndexReader
from cfsig.search.l1 import choose_kernel, fast_kernel, l1_numpy
from cfsig.search.nearest import nearest, query
from tests.helpers import open_writer


def _histograms(n, seed, bins=200):
    h = np.random.default_rng(seed).random((n, bins))
    return (h / h.sum(axis=1, keepdims=True)).astype(np.float32)


def _brute(queries, rows):
    """L1 distances in float64, independently of the kernels."""
    q, r = np.asarray(queries, np.float32), np.asarray(rows, np.float32)
    return np.abs(q[:, None, :].astype(np.float64) - r[None, :, :]).sum(axis=2)


def _brute_nearest(queries, rows, k):
    """Row numbers of the k nearest, ties broken by row number."""
    d = _brute(queries, rows)
    order = np.lexsort((np.broadcast_to(np.arange(d.shape[1]), d.shape), d), axis=1)[:, :k]
    return order, np.take_along_axis(d, order, axis=1)


def _build(path, hists, chunk_rows, monkeypatch):
    monkeypatch.setattr(cfsig.index.segments, "_CHUNK_ROWS", chunk_rows)
    phi = np.zeros(1)
    with open_writer(path) as w:
        for i, h in enumerate(hists):
            sig = Signature(h, phi, 3, 1, 1, 0.0, (), 0.0, f"{i:064d}")
            w.add(Entry(f"m{i}.off", f"c{i % 4}", f"/d/m{i}.off"), sig)


@pytest.mark.parametrize("n_queries", [1, 3, 17])
@pytest.mark.parametrize("n_rows", [1, 255, 256, 257, 700, 2100])
def test_kernels_match_brute_force(n_queries, n_rows):
    queries, rows = _histograms(n_queries, 1), _histograms(n_rows, 2)
    kernels = [l1_numpy] + ([fast_kernel()] if fast_kernel() else [])
    for kernel in kernels:
        out = np.full((n_queries, n_rows), -1.0, np.float32)
        kernel(queries, rows, out)
        assert np.allclose(out, _brute(queries, rows), rtol=0, atol=2e-6)


def test_kernel_choice(monkeypatch):
    assert choose_kernel(10) is l1_numpy
    if fast_kernel() is not None:
        assert choose_kernel(cfsig.search.l1.FAST_MIN_WORK) is fast_kernel()
    monkeypatch.setattr(cfsig.search.l1, "fast_kernel", lambda: None)
    assert choose_kernel(10**12) is l1_numpy  # fallback when faiss is missing


def test_faiss_kernel_refuses_a_strided_output():
    kernel = pytest.importorskip("cfsig.search.l1_faiss").l1_rows
    out = np.zeros((2, 10), np.float32)[:, :5]
    with pytest.raises(ValueError, match="contiguous"):
        kernel(_histograms(2, 1), _histograms(5, 2), out)


@pytest.mark.parametrize("k", [1, 5, 23, 60, 80])
@pytest.mark.parametrize("n_queries", [1, 4])
def test_nearest_matches_brute_force(tmp_path, monkeypatch, kernel, k, n_queries):
    hists = _histograms(60, 3)
    _build(tmp_path / "i.h5", hists, 7, monkeypatch)  # 9 chunks, the last one partial
    queries = _histograms(n_queries, 4)
    with IndexReader(tmp_path / "i.h5") as r:
        rows, dist = nearest(r, queries, k)
    want_rows, want_dist = _brute_nearest(queries, hists, k)
    assert rows.shape == dist.shape == (n_queries, min(k, 60))
    assert rows.dtype == np.int64 and dist.dtype == np.float64
    assert np.array_equal(rows, want_rows)
    assert np.allclose(dist, want_dist, rtol=0, atol=2e-6)


@pytest.mark.parametrize("threads", [1, 2, 5])
def test_ties_broken_by_row_whatever_the_block_order(tmp_path, monkeypatch, kernel, threads):
    hists = _histograms(50, 5)
    twin = hists[20].copy()
    for row in (3, 10, 17, 40, 41):  # in four different chunks of 7 rows
        hists[row] = twin
    _build(tmp_path / "i.h5", hists, 7, monkeypatch)
    monkeypatch.setattr(cfsig.search.nearest, "_threads", lambda: threads)
    with IndexReader(tmp_path / "i.h5") as r:
        rows, dist = nearest(r, np.stack([twin, hists[0]]), 8)
    assert list(rows[0, :6]) == [3, 10, 17, 20, 40, 41]
    assert np.all(dist[0, :6] == 0)
    near_twins = [i for i in rows[1] if i in (3, 10, 17, 20, 40, 41)]
    assert near_twins == sorted(near_twins)  # equal distances, in row order
    assert np.array_equal(rows[1], _brute_nearest(hists[:1], hists, 8)[0][0])


def test_many_queries_in_small_groups(tmp_path, monkeypatch, kernel):
    hists, queries = _histograms(40, 6), _histograms(30, 7)
    _build(tmp_path / "i.h5", hists, 16, monkeypatch)
    monkeypatch.setattr(cfsig.search.nearest, "_OUT_CELLS", 40)  # 2 queries per kernel call
    with IndexReader(tmp_path / "i.h5") as r:
        rows, dist = nearest(r, queries, 5)
    want_rows, want_dist = _brute_nearest(queries, hists, 5)
    assert np.array_equal(rows, want_rows)
    assert np.allclose(dist, want_dist, rtol=0, atol=2e-6)


def _segment(index):
    """The one segment file of a small index."""
    (path,) = index.glob("seg-*.h5")
    return path


def _relayout(index, **create):
    """Rewrite the signatures dataset of an index's one segment with another HDF5 layout."""
    with h5py.File(_segment(index), "a") as f:
        data = f["signatures"][:]
        del f["signatures"]
        f.create_dataset("signatures", data=data, **create)


LAYOUTS = {
    "chunked": None,
    "contiguous": {},
    "gzip": {"chunks": (8, 200), "compression": "gzip"},
    "chunks across columns": {"chunks": (8, 50)},
    "float64": {"dtype": np.float64},
    "big-endian": {"dtype": ">f4"},
}


@pytest.mark.parametrize("layout", LAYOUTS)
def test_every_layout_gives_the_same_result(tmp_path, monkeypatch, layout):
    hists = _histograms(45, 8)
    path = tmp_path / "i.h5"
    _build(path, hists, 7, monkeypatch)
    if LAYOUTS[layout] is not None:
        _relayout(path, **LAYOUTS[layout])
    monkeypatch.setattr(cfsig.search.nearest, "BLOCK_ROWS", 10)
    with IndexReader(path) as r:
        data = r.segments[0].signatures
        blocks = plan_blocks(data, 10)
        buffer = np.empty((max(b.stop - b.start for b in blocks), 200), np.float32)
        parts = [read_block(data, b, buffer).copy() for b in blocks]
        columns = [read_columns(data, b, slice(30, 90), buffer) for b in blocks]
        rows, _ = nearest(r, hists[:2], 6)
        some, _ = nearest(r, hists[:2, 30:90], 6, slice(30, 90))
        scattered = r.signatures[np.array([44, 5, 30, 1, 5])]
    direct = [b.offset is not None for b in blocks]  # read from the file, not through HDF5
    assert all(direct) if layout in ("chunked", "contiguous") else not any(direct)
    assert all(b.stop - b.start <= 16 for b in blocks)
    assert np.array_equal(np.concatenate(parts), hists)
    assert np.array_equal(np.concatenate(columns), hists[:, 30:90])
    assert np.array_equal(scattered, hists[[44, 5, 30, 1, 5]].astype(np.float32))
    assert np.array_equal(rows, _brute_nearest(hists[:2], hists, 6)[0])
    assert np.array_equal(some, _brute_nearest(hists[:2, 30:90], hists[:, 30:90], 6)[0])


@pytest.mark.parametrize("layout", ["chunked", "contiguous", "compressed"])
def test_rows_read_alike_from_the_file_from_a_memory_map_and_through_hdf5(tmp_path, layout):
    path = tmp_path / "rows.h5"
    data = _histograms(700, 13)
    options = {
        "chunked": {"chunks": (300, 200)},
        "contiguous": {},
        "compressed": {"chunks": (300, 200), "compression": "gzip"},
    }[layout]
    with h5py.File(path, "w") as f:
        f.create_dataset("s", data=data, **options)
    rng = np.random.default_rng(14)
    # Sparse, runs and a block wanted whole: the memory map serves blocks of 64 rows or more.
    wanted = np.unique(np.r_[rng.choice(300, 5), 300 + rng.choice(300, 150), 600:700])
    with h5py.File(path, "r") as f:
        blocks = plan_blocks(f["s"], 300)
        mapped = map_file(f["s"])
        assert (layout == "compressed") == (blocks[0].offset is None) and mapped is not None
        buffer = np.empty((max(len(wanted), 300), 200), np.float32)
        read = read_rows(f["s"], blocks, wanted, buffer).copy()
        viewed = read_rows(f["s"], blocks, wanted, buffer, mapped).copy()
        loaded = [load_block(f["s"], b, buffer, mapped).copy() for b in blocks]
    assert np.array_equal(read, data[wanted]) and np.array_equal(viewed, data[wanted])
    assert np.array_equal(np.concatenate(loaded), data)


def test_small_compressed_chunks_are_read_many_at_a_time(tmp_path):
    path = tmp_path / "small-chunks.h5"
    data = _histograms(1000, 11)
    with h5py.File(path, "w") as f:
        f.create_dataset("s", data=data, chunks=(3, 200), compression="gzip")
    with h5py.File(path, "r") as f:
        blocks = plan_blocks(f["s"], 100)
        buffer = np.empty((102, 200), np.float32)
        parts = [read_block(f["s"], b, buffer).copy() for b in blocks]
    assert [b.stop - b.start for b in blocks[:2]] == [102, 102] and len(blocks) == 10
    assert np.array_equal(np.concatenate(parts), data)


def test_unwritten_chunks_are_read_through_hdf5(tmp_path):
    path = tmp_path / "sparse.h5"
    with h5py.File(path, "w") as f:
        d = f.create_dataset("s", (30, 4), np.float32, chunks=(8, 4))
        d[8:16] = 1.0
        d[24:30] = 2.0
    with h5py.File(path, "r") as f:
        blocks = plan_blocks(f["s"], 100)
        buffer = np.empty((8, 4), np.float32)
        parts = [read_block(f["s"], b, buffer).copy() for b in blocks]
        assert [b.offset is not None for b in blocks] == [False, True, False, True]
        assert np.array_equal(np.concatenate(parts), f["s"][:])


def test_a_file_cut_short_after_opening_is_a_clear_error(tmp_path, monkeypatch):
    path = tmp_path / "i.h5"
    _build(path, _histograms(40, 12), 8, monkeypatch)
    with IndexReader(path) as r:
        blocks = plan_blocks(r.segments[0].signatures, 8)
        os.truncate(_segment(path), blocks[-1].offset + 10)
        with pytest.raises(IndexFileError, match="ends inside /signatures"):
            nearest(r, _histograms(1, 4), 5)
        with pytest.raises(IndexFileError, match="ends inside /signatures"):
            nearest(r, _histograms(1, 4)[:, :50], 5, slice(0, 50))


def test_empty_index_and_k_zero(tmp_path):
    path = tmp_path / "i.h5"
    with open_writer(path):
        pass
    with IndexReader(path) as r:
        rows, dist = nearest(r, _histograms(2, 9), 5)
        assert rows.shape == dist.shape == (2, 0)
        assert query(r, _histograms(1, 9), 5) == [[]]


def test_nan_rows_rank_last(tmp_path, monkeypatch, kernel):
    hists = _histograms(10, 10)
    hists[2] = np.nan
    _build(tmp_path / "i.h5", hists, 4, monkeypatch)
    with IndexReader(tmp_path / "i.h5") as r:
        rows, dist = nearest(r, hists[:1], 10)
    assert rows[0, -1] == 2 and np.isnan(dist[0, -1])
    assert np.array_equal(rows, _brute_nearest(hists[:1], hists, 10)[0])
