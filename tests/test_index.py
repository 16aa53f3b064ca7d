import h5py
import numpy as np
import pytest

from cfsig.descriptors import layout
from cfsig.errors import IndexFileError
from cfsig.index.store import Entry, IndexReader, IndexWriter
from cfsig.params import Params
from cfsig.search.nearest import l1_distances, nearest, query
from tests.helpers import build_index as _build
from tests.helpers import open_writer
from tests.helpers import random_signature as _sig


def test_round_trip(tmp_path):
    hists = _build(tmp_path / "i.h5")
    with IndexReader(tmp_path / "i.h5") as r:
        assert len(r) == 10 and r.params == Params(descriptor="cf")
        assert np.allclose(r.signatures[:], hists, atol=1e-7)
        assert r.entries([4, 1]) == [
            Entry("c1/4.off", "c1", "/data/c1/4.off"),
            Entry("c1/1.off", "c1", "/data/c1/1.off"),
        ]
        assert list(r.column("labels")) == [f"c{i % 3}" for i in range(10)]


def test_update_replaces_by_name(tmp_path):
    path = tmp_path / "i.h5"
    _build(path, 4)
    with open_writer(path) as w:
        w.add(Entry("c1/1.off", "c1", "/x"), _sig(99))
        w.add(Entry("new.off", "z", "/y"), _sig(5))
    with IndexReader(path) as r:  # the new row of c1/1.off supersedes the old one
        names = list(r.column("names"))
        assert len(r) == 5 and sorted(names) == sorted(
            ["new.off"] + [f"c{i % 3}/{i}.off" for i in range(4)]
        )
        assert np.allclose(r.signatures[names.index("c1/1.off")], _sig(99).vector, atol=1e-7)
        assert np.allclose(r.signatures[names.index("c0/0.off")], _sig(0).vector, atol=1e-7)
        assert r.entries([names.index("c1/1.off")])[0].path == "/x"


def test_other_params_refused(tmp_path):
    _build(tmp_path / "i.h5", 2)
    with pytest.raises(IndexFileError, match="other parameters"):
        IndexWriter(
            tmp_path / "i.h5",
            Params(descriptor="cf", seed=1),
            layout(Params(descriptor="cf", seed=1)),
        )


def test_second_writer_refused(tmp_path):
    with open_writer(tmp_path / "i.h5"):
        with pytest.raises(IndexFileError, match="another process"):
            open_writer(tmp_path / "i.h5")


@pytest.mark.parametrize(
    "kind", ["missing", "garbage", "foreign", "newer", "empty folder", "garbage manifest"]
)
def test_bad_index_files(tmp_path, kind):
    path = tmp_path / "i.h5"
    if kind == "garbage":
        path.write_bytes(b"not hdf5 at all" * 100)
    elif kind == "foreign":
        with h5py.File(path, "w") as f:
            f["x"] = [1, 2, 3]
    elif kind == "newer":
        _build(path, 2)
        with h5py.File(path / "manifest.h5", "a") as f:
            f.attrs["format_version"] = 99
    elif kind == "empty folder":
        path.mkdir()
    elif kind == "garbage manifest":
        _build(path, 2)
        (path / "manifest.h5").write_bytes(b"not hdf5 at all" * 100)
    with pytest.raises(IndexFileError, match=str(path)):
        IndexReader(path)
    if kind not in ("missing", "empty folder"):  # a writer makes an index in an empty folder
        with pytest.raises(IndexFileError, match=str(path)):
            open_writer(path)


def test_nearest_matches_brute_force(tmp_path, monkeypatch):
    import cfsig.index.segments

    monkeypatch.setattr(cfsig.index.segments, "_CHUNK_ROWS", 7)  # several blocks
    hists = np.array(_build(tmp_path / "i.h5", 30))
    queries = np.array([_sig(100).vector, _sig(101).vector])
    with IndexReader(tmp_path / "i.h5") as r:
        rows, dist = nearest(r, queries, 5)
        hits = query(r, queries[:1], 3)
    brute = l1_distances(queries, hists)
    for q in range(2):
        assert list(rows[q]) == list(np.argsort(brute[q])[:5])
        assert np.allclose(dist[q], np.sort(brute[q])[:5], atol=1e-5)
    assert [h.rank for h in hits[0]] == [1, 2, 3]
    assert hits[0][0].entry.name == f"c{rows[0][0] % 3}/{rows[0][0]}.off"


def test_l1_distance():
    a = np.array([[0.5, 0.5, 0.0]])
    b = np.array([[0.0, 0.5, 0.5], [0.5, 0.5, 0.0]])
    assert np.allclose(l1_distances(a, b), [[1.0, 0.0]])
