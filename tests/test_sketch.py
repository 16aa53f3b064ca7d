"""Sketches: their bounds, and the pruned search giving exactly the full scan's results, on
random and structured rows, with ties, superseded rows, several segments, segments without
sketches; `cfsig check` on sketches; indexes written before sketches. The copy of the curvature
columns, which a search of those columns reads instead of the rows, checked in the same ways."""

from dataclasses import replace

import h5py
import numpy as np
import pytest

import cfsig.index.segments
import cfsig.index.store
import cfsig.search.nearest
from cfsig.descriptors import layout
from cfsig.descriptors.signature import Signature
from cfsig.errors import IndexFileError
from cfsig.index.sketch import (
    Sketch,
    adjust_bounds,
    group_sums,
    query_sketches,
    sketch_center,
    sketch_groups,
    sketch_rows,
    threshold,
)
from cfsig.index.store import Entry, IndexReader, check_index, compact_index, file_crc
from cfsig.params import Params
from cfsig.search.nearest import nearest
from tests.helpers import open_writer

DEFAULT = Params()
WIDTH = layout(DEFAULT).length


def _structured(n, seed, width=WIDTH):
    """Rows like ``cfhks`` ones: runs of sorted values (quantile functions), mixed and noisy."""
    rng = np.random.default_rng(seed)
    base = np.sort(rng.normal(size=(12, width // 64 + 1, 64)), axis=2).reshape(12, -1)[:, :width]
    i, j = rng.integers(0, 12, (2, n))
    t = rng.random((n, 1))
    rows = t * base[i] + (1 - t) * base[j] + 0.002 * rng.normal(size=(n, width))
    return rows.astype(np.float32)


def _random(n, seed, width=WIDTH):
    return np.random.default_rng(seed).random((n, width), dtype=np.float32)


def _ties(n, seed, width=WIDTH):
    """Small integers: L1 distances are integers, and many rows are equally far."""
    rows = np.random.default_rng(seed).integers(0, 2, (n, width)).astype(np.float32)
    rows[n // 2 :] = rows[: n - n // 2]  # every row twice
    return rows


def _write(index, rows, names, seed=0):
    phi = np.zeros(1)
    with open_writer(index, DEFAULT, merge=False) as w:
        for name, row in zip(names, rows, strict=True):
            sig = Signature(row, phi, 1, 1, 1, 0.0, (), "clean", 0.0, "")
            w.add(Entry(name, "c", f"/d/{name}"), sig)


@pytest.fixture
def small_blocks(monkeypatch):
    """Chunks of 64 rows and sketch chunks of 96, so that a few hundred rows make many blocks;
    and pruning from any size, with few rows evaluated first."""
    monkeypatch.setattr(cfsig.index.segments, "_CHUNK_ROWS", 64)
    monkeypatch.setattr(cfsig.index.segments, "_SKETCH_CHUNK_ROWS", 96)
    monkeypatch.setattr(cfsig.search.nearest, "PRUNE_MIN_ROWS", 0)
    monkeypatch.setattr(cfsig.search.nearest, "_FIRST", 8)
    monkeypatch.setattr(cfsig.search.nearest, "_SAMPLE", 50)


def _both(reader, queries, k, monkeypatch):
    """nearest() pruned and by the full scan, and how many full scans the pruned one made."""
    scans = []
    real = cfsig.search.nearest._scan
    monkeypatch.setattr(cfsig.search.nearest, "_scan", lambda *a: scans.append(1) or real(*a))
    pruned = nearest(reader, queries, k)
    scanned = len(scans)
    monkeypatch.setattr(cfsig.search.nearest, "PRUNE_MIN_ROWS", 10**12)
    full = nearest(reader, queries, k)
    monkeypatch.setattr(cfsig.search.nearest, "PRUNE_MIN_ROWS", 0)
    return pruned, full, scanned


@pytest.mark.parametrize("data", ["structured", "random", "ties"])
@pytest.mark.parametrize("k", [1, 7, 40, 2000])
def test_pruned_search_is_the_full_scan(tmp_path, monkeypatch, small_blocks, kernel, data, k):
    make = {"structured": _structured, "random": _random, "ties": _ties}[data]
    rows, others = np.split(make(903, 1), [900])
    index = tmp_path / "i"
    names = [f"c/{i}.off" for i in range(900)]
    for part in range(3):  # three segments, the third superseding rows of the first two
        _write(index, rows[300 * part : 300 * (part + 1)], names[300 * part : 300 * (part + 1)])
    again = rows[100:200] if data == "ties" else np.vstack([rows[:50], rows[350:400]]) + 0.25
    _write(index, again, names[:50] + names[350:400])
    queries = np.vstack([others, rows[[5, 420, 899]]])
    with IndexReader(index) as r:
        assert len(r.segments) == 4 and all(v.sketch is not None for v in r.segments)
        assert sum(len(v.dead) for v in r.segments) == 100
        (rows_p, dist_p), (rows_f, dist_f), scans = _both(r, queries, k, monkeypatch)
        stored = r.signatures[:]
    assert np.array_equal(rows_p, rows_f) and np.array_equal(dist_p, dist_f)
    assert rows_p.shape == (6, min(k, 900))
    brute = np.abs(queries[:, None].astype(np.float64) - stored[None]).sum(axis=2)
    assert np.allclose(dist_p, np.sort(brute, axis=1)[:, : min(k, 900)], rtol=1e-5, atol=1e-4)
    if data == "structured" and k <= 40:
        assert scans == 0  # the sketches pruned: no full scan was needed
    if data == "random" or k == 2000:
        assert scans == 1  # most rows candidates: the rows were scanned


def test_many_queries_in_groups_and_a_segment_without_sketches(tmp_path, monkeypatch, small_blocks):
    rows, queries = np.split(_structured(607, 3), [600])
    index = tmp_path / "i"
    _write(index, rows[:300], [f"a/{i}.off" for i in range(300)])
    _strip_sketches(index)  # as code from before sketches wrote it
    _write(index, rows[300:], [f"b/{i}.off" for i in range(300)])
    monkeypatch.setattr(
        cfsig.search.nearest, "_BOUND_CELLS", 1300
    )  # two queries per scan of sketches
    with IndexReader(index) as r:
        assert [v.sketch is None for v in r.segments] == [True, False]
        (rows_p, dist_p), (rows_f, dist_f), _ = _both(r, queries, 9, monkeypatch)
    assert np.array_equal(rows_p, rows_f) and np.array_equal(dist_p, dist_f)
    assert check_index(index) == []  # a segment without sketches is healthy
    compact_index(index)  # writes sketches for every row
    with IndexReader(index) as r:
        assert len(r.segments) == 1 and r.segments[0].sketch is not None
        assert np.array_equal(nearest(r, queries, 9)[1], dist_f)
    assert check_index(index) == []


def _strip_sketches(index):
    """Remove the sketches of an index's last segment, and record its new checksum."""
    _strip(index, ("sketch", *cfsig.index.segments.SKETCH_EXTRA))


def _strip(index, keys):
    """Remove some datasets of an index's last segment, as code from before them wrote it."""
    manifest = cfsig.index.store.read_manifest(index)
    last = manifest.segments[-1]
    with h5py.File(index / last.file, "r+") as f:
        for key in keys:
            del f[key]
            del f.attrs[f"crc32_{key}"]
    segments = (*manifest.segments[:-1], replace(last, crc32=file_crc(index / last.file)))
    cfsig.index.store.write_manifest(index, replace(manifest, segments=segments))


def test_bounds_are_lower_bounds_whatever_the_rounding():
    rng = np.random.default_rng(5)
    rows = (_structured(500, 6) * 1e3 + 1e4).astype(np.float32)  # large values, small gaps
    groups = sketch_groups(WIDTH)
    assert list(groups[:3]) == [0, 16, 32] and len(groups) == -(-WIDTH // 16)
    center = sketch_center(rows[:100], groups)
    stored, error = sketch_rows(rows, groups, center)
    assert stored.dtype == np.float32 and error > 0
    sums = group_sums(rows, groups) - center
    assert np.abs(stored - sums).sum(axis=1).max() <= error
    queries = rows[rng.integers(0, 500, 20)] + rng.normal(0, 1e-3, (20, WIDTH)).astype(np.float32)
    sketch = Sketch(stored, groups, center, error)
    q_sketch, margin = query_sketches(queries, sketch)
    bounds = np.abs(q_sketch[:, None] - stored[None]).sum(axis=2, dtype=np.float32)
    adjust_bounds(bounds, margin, len(groups))
    exact = np.abs(queries[:, None].astype(np.float64) - rows[None]).sum(axis=2)
    assert (bounds <= exact).all()
    tight = bounds / np.maximum(exact, 1e-30)
    assert np.median(tight) > 0.5  # sorted runs: the bound is close
    f32 = np.abs(queries[:, None] - rows[None]).sum(axis=2, dtype=np.float32)
    kth = np.sort(f32, axis=1)[:, 3]
    limits = np.array([threshold(float(t), WIDTH) for t in kth])
    pruned = bounds > limits[:, None]
    assert pruned.any() and (f32 > kth[:, None])[pruned].all()  # a row pruned is farther
    assert threshold(np.nan, WIDTH) == np.inf and threshold(0.0, WIDTH) == 0


def test_rows_with_nan_or_infinity_are_not_lost(tmp_path, monkeypatch, small_blocks, kernel):
    rows = _structured(200, 7)
    rows[3] = np.nan
    rows[150, 10] = np.inf
    _write(tmp_path / "i", rows, [f"c/{i}.off" for i in range(200)])
    with IndexReader(tmp_path / "i") as r:
        (rows_p, dist_p), (rows_f, dist_f), _ = _both(r, rows[[0, 1]], 200, monkeypatch)
        assert np.array_equal(rows_p, rows_f)
        assert np.array_equal(dist_p, dist_f, equal_nan=True)
        assert rows_p[0, -1] == 3 and rows_p[0, -2] == 150  # NaN last, then infinity
        assert np.array_equal(nearest(r, rows[[0]], 5)[0], rows_f[:1, :5])


@pytest.mark.parametrize(
    "part", ["sketch", "sketch_center", "sketch_error", "curvature", "curvature_columns"]
)
def test_check_finds_a_flipped_byte_in_the_sketches_and_the_copy(tmp_path, part):
    _write(tmp_path / "i", _structured(40, 8), [f"c/{i}.off" for i in range(40)])
    (segment,) = (tmp_path / "i").glob("seg-*.h5")
    assert check_index(tmp_path / "i") == []
    with h5py.File(segment, "r") as f:
        data = f[part]
        offset = data.id.get_chunk_info(0).byte_offset if data.chunks else data.id.get_offset()
    data = bytearray(segment.read_bytes())
    data[offset + 5] ^= 0xFF
    segment.write_bytes(bytes(data))
    problems = check_index(tmp_path / "i")
    assert any(f"column {part}: checksum mismatch" in line for line in problems), problems


@pytest.mark.parametrize(
    ("key", "what"),
    [("sketch_center", "sketches"), ("curvature_columns", "copy of the columns 'curvature'")],
)
def test_derived_data_that_does_not_fit_its_rows_is_refused(tmp_path, key, what):
    _write(tmp_path / "i", _structured(40, 9), [f"c/{i}.off" for i in range(40)])
    (segment,) = (tmp_path / "i").glob("seg-*.h5")
    with h5py.File(segment, "r+") as f:
        shorter = f[key][:-1]
        del f[key]
        f[key] = shorter
    with pytest.raises(IndexFileError, match=f"{what} do(es)? not match its signatures"):
        IndexReader(tmp_path / "i")
    with h5py.File(segment, "r+") as f:
        del f[key]
    with pytest.raises(IndexFileError, match=f"{what} (is|are) incomplete"):
        IndexReader(tmp_path / "i")


def test_a_search_of_the_curvature_reads_the_copy(tmp_path, monkeypatch, small_blocks, kernel):
    rows, queries = np.split(_structured(305, 10), [300])
    index, columns = tmp_path / "i", layout(DEFAULT).group("curvature")
    _write(index, rows[:150], [f"a/{i}.off" for i in range(150)])
    _write(
        index, rows[150:] + 0.5, [f"a/{i}.off" for i in range(20)] + [f"b/{i}" for i in range(130)]
    )
    read = []
    real = cfsig.search.nearest.read_columns
    monkeypatch.setattr(
        cfsig.search.nearest,
        "read_columns",
        lambda d, *a: read.append(d.file.filename) or real(d, *a),
    )
    with IndexReader(index) as r:
        for view in r.segments:
            (copy,) = view.copies
            assert np.array_equal(copy.rows[:], view.signatures[:, columns])
        got_rows, got = nearest(r, queries[:, columns], 9, columns)
        stored = r.signatures[:]
    assert read == []  # the copies only, never the rows
    brute = np.abs(queries[:, None, columns] - stored[None, :, columns]).sum(axis=2)
    assert np.allclose(got, np.sort(brute, axis=1)[:, :9], rtol=1e-5)
    assert np.allclose(got, np.take_along_axis(brute, got_rows, axis=1), rtol=1e-5)
    assert check_index(index) == []
    compact_index(index)  # the merged segment has a copy of every row
    with IndexReader(index) as r:
        (only,) = r.segments
        assert np.array_equal(only.copies[0].rows[:], only.signatures[:, columns])
        assert np.array_equal(nearest(r, queries[:, columns], 9, columns)[1], got)
