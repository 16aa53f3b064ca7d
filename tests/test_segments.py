"""Format 2: segments and merges, superseded rows, checksums and `cfsig check`, kills during a
commit and a compaction, older formats refused."""

import json
import signal
import subprocess
import sys
import textwrap
import time

import h5py
import numpy as np
import pytest
from click.testing import CliRunner

import cfsig.index.store
from cfsig.cli import main
from cfsig.errors import IndexFileError
from cfsig.index.store import Entry, IndexReader, IndexWriter, check_index
from cfsig.params import Params
from cfsig.search.nearest import l1_distances, nearest
from tests.helpers import icosphere, open_writer, random_signature, write_off


def _add(writer, names, seed=0):
    """Add random signatures under some names; return them by name."""
    sigs = {name: random_signature(seed + i) for i, name in enumerate(names)}
    for name, sig in sigs.items():
        writer.add(Entry(name, name.split("/")[0], f"/d/{name}"), sig)
    return {name: sig.vector for name, sig in sigs.items()}


def _contents(index):
    """Name -> stored signature of every entry, checking that each name is there once."""
    with IndexReader(index) as r:
        names = list(r.column("names"))
        assert len(names) == len(set(names)) == len(r)
        return dict(zip(names, r.signatures[:], strict=True))


def test_commits_append_segments_merge_and_supersede(tmp_path, monkeypatch):
    monkeypatch.setattr(cfsig.index.store, "MERGE_FANOUT", 3)
    index, want = tmp_path / "i", {}
    with open_writer(index) as w:
        for c in range(10):  # one segment per commit, merged three at a time
            want.update(_add(w, [f"c{c % 3}/{c}-{i}.off" for i in range(4)], seed=100 * c))
            if c % 4 == 3:  # names of older segments again: their new rows supersede the old
                want.update(_add(w, ["c0/0-1.off", f"c{(c - 1) % 3}/{c - 1}-2.off"], seed=999 + c))
            w.commit()
            assert len(w) == len(want)
        assert 1 < len(w.segments) < 10
        w.merge = False  # so that the rows this commit supersedes stay stored
        want.update(_add(w, ["c1/1-0.off", "c2/8-3.off"], seed=5000))
    got = _contents(index)
    assert got.keys() == want.keys()
    assert all(np.allclose(got[n], want[n], atol=1e-7) for n in want)
    names, rows = list(got), np.array(list(got.values()))
    queries = rows[[0, 5, 17]] + 0.001
    with IndexReader(index) as r:
        assert any(len(view.dead) for view in r.segments)  # superseded rows are still stored
        found, dist = nearest(r, queries, 7)
        hits = [[e.name for e in r.entries(row)] for row in found]
    brute = l1_distances(queries, rows)
    assert [[names[i] for i in np.argsort(b, kind="stable")[:7]] for b in brute] == hits
    assert np.allclose(dist, np.sort(brute, axis=1)[:, :7], atol=1e-5)
    with (
        IndexReader(index) as before,
        open_writer(index) as w,
    ):
        w.compact()
        assert len(w.segments) == 1 and w.segments[0].rows == len(want)
        assert np.array_equal(nearest(before, queries, 7)[0], found)  # still the old files
    assert _contents(index).keys() == want.keys()
    with IndexReader(index) as r:
        assert [[e.name for e in r.entries(row)] for row in nearest(r, queries, 7)[0]] == hits
    assert check_index(index) == []


def _flip(path, offset):
    data = bytearray(path.read_bytes())
    data[offset] ^= 0xFF
    path.write_bytes(bytes(data))


@pytest.mark.parametrize("part", ["signatures", "n_faces", "names", "manifest"])
def test_check_names_what_is_damaged(tmp_path, part, build_index):
    index = tmp_path / "i"
    build_index(index, 30)
    (segment,) = index.glob("seg-*.h5")
    assert check_index(index) == []
    ok = CliRunner().invoke(main, ["check", str(index)])
    assert ok.exit_code == 0 and "healthy (30 entries in 1 segment(s))" in ok.output
    if part == "manifest":
        with h5py.File(index / "manifest.h5", "r") as f:
            offset = f["segment_rows"].id.get_offset()
        _flip(index / "manifest.h5", offset)
        with pytest.raises(IndexFileError, match="manifest is damaged"):
            check_index(index)
        with pytest.raises(IndexFileError, match="manifest is damaged"):
            IndexReader(index)
        return
    with h5py.File(segment, "r") as f:
        data = f[part]
        if part == "signatures":
            offset = data.id.get_chunk_info(0).byte_offset + 4 * 200 * 3 + 1  # row 3
        elif part == "names":  # the strings themselves, in the global heap
            offset = segment.read_bytes().index(b"c1/13.off")
        else:
            offset = data.id.get_offset() + 8 * 7 + 2
    _flip(segment, offset)
    problems = check_index(index)
    assert problems and all(line.startswith(str(segment)) for line in problems)
    want = "signatures rows 0-29" if part == "signatures" else f"column {part}"
    assert any(f"{want}: checksum mismatch" in line for line in problems), problems
    bad = CliRunner().invoke(main, ["check", str(index)])
    assert bad.exit_code == 1 and want in bad.output and "Traceback" not in bad.output
    with open_writer(index) as w:
        _add(w, ["new/x.off"])
        with pytest.raises(IndexFileError, match="checksum mismatch"):
            w.compact()  # a merge does not copy damage into a new segment
    assert check_index(index) == problems  # and leaves the index as it was


_WRITE = textwrap.dedent(
    """
    import sys
    from cfsig.index.store import Entry
    from cfsig.params import Params
    from tests.helpers import open_writer, random_signature
    index, what = sys.argv[1], sys.argv[2]
    params = Params(descriptor="cf", bins=16)
    with open_writer(index, params, merge=False) as w:
        if what == "compact":
            w.compact()
        else:
            sig = random_signature(0, 16)
            for i in range(int(what)):
                w.add(Entry(f"m/{i}.off", "m", f"/m/{i}.off"), sig)
                if w.pending == 4000:
                    w.commit()
    """
)


def _writer(index, what):
    return subprocess.Popen([sys.executable, "-c", _WRITE, str(index), str(what)])


def _wait_for(condition, timeout=60):
    deadline = time.monotonic() + timeout
    while not condition():
        assert time.monotonic() < deadline, "timed out"
        time.sleep(0.005)


def _segments_made(index):
    """How many segments the index's commits and merges have made (its manifest's next id)."""
    try:
        return cfsig.index.store.read_manifest(index).next_id
    except IndexFileError:  # not created yet
        return 0


def _merging(index):
    """Whether a writer is writing a segment that the manifest does not list yet."""
    next_id = cfsig.index.store.read_manifest(index).next_id
    return any(int(p.stem.split("-")[1]) >= next_id for p in index.glob("seg-*.h5"))


def test_sigkill_during_commits_and_compaction_loses_nothing(tmp_path):
    index, total = tmp_path / "i", 40_000
    everything = {f"m/{i}.off" for i in range(total)}
    for delay in (0.0, 0.01, 0.03):  # a commit of 4,000 rows takes about 30 ms
        before = set(_contents(index)) if index.exists() else set()
        made = _segments_made(index)
        proc = _writer(index, total)
        _wait_for(lambda made=made: _segments_made(index) > made)  # this run has committed
        time.sleep(delay)
        proc.send_signal(signal.SIGKILL)
        proc.wait()
        assert before <= set(_contents(index))  # nothing committed is lost
        assert check_index(index) == []
    assert len(_contents(index)) < total, "a run finished before it was killed"
    assert _writer(index, total).wait() == 0  # the re-run completes it
    assert set(_contents(index)) == everything
    with IndexReader(index) as r:
        assert len(r.segments) > 2
    for delay in (0.0, 0.1):  # the merge takes about 0.5 s
        proc = _writer(index, "compact")
        _wait_for(lambda: _merging(index))
        time.sleep(delay)
        proc.send_signal(signal.SIGKILL)
        proc.wait()
        assert _merging(index)  # killed while writing the merged segment
        assert set(_contents(index)) == everything
        assert check_index(index) == []
    assert _writer(index, "compact").wait() == 0
    with IndexReader(index) as r:
        assert len(r.segments) == 1
    assert set(_contents(index)) == everything
    assert {p.name for p in index.iterdir()} == {
        "manifest.h5",
        "lock",
        f"seg-{_last(index):08d}.h5",
    }


def _last(index):
    return cfsig.index.store.read_manifest(index).segments[-1].id


def _format_1(path):
    """An index of the one-file format 1, as cfsig 0.1 wrote them before format 2: only its
    header is read."""
    with h5py.File(path, "w") as f:
        f.attrs.update(format="cfsig-index", format_version=1, params='{"bins": 200}')
        f.create_dataset("signatures", data=np.zeros((2, 200), np.float32))


def _format_2(folder, params, version=2):
    """An index folder of format 2 (or ``version``), as cfsig 0.1 wrote them, made with
    ``params``."""
    folder.mkdir()
    with h5py.File(folder / "manifest.h5", "w") as f:
        f.attrs.update(format="cfsig-index", format_version=version, params=json.dumps(params))


V10 = {"descriptor": "cfhks", "version": 10, "bins": 200, "repair": "auto"}


@pytest.mark.parametrize(
    ("make", "named"),
    [
        (_format_1, "descriptor cf that"),
        (lambda path: _format_2(path, V10), "descriptor cfhks version 10"),
        (lambda path: _format_2(path, dict(V10, descriptor="cf", version=1)), "cf version 1"),
        (lambda path: _format_2(path, json.loads(Params().to_json()), 3), "in index format 3"),
        (lambda path: _format_2(path, json.loads(Params().to_json()), 4), "in index format 4"),
        (lambda path: _format_2(path, json.loads(Params().to_json()), 5), "in index format 5"),
    ],
    ids=[
        "format 1",
        "format 2, a removed version",
        "format 2, cf",
        "format 3",
        "format 4",
        "format 5",
    ],
)
def test_older_indexes_are_refused_with_the_command_that_rebuilds_them(tmp_path, make, named):
    old = tmp_path / "old"
    make(old)
    before = sorted(p.name for p in old.iterdir()) if old.is_dir() else old.read_bytes()
    rebuild = "rebuild it: cfsig index FOLDER -o NEW_INDEX"
    for open_it in (IndexReader, check_index, lambda p: IndexWriter(p, Params())):
        with pytest.raises(IndexFileError, match=f"made by an older cfsig.*{named}.*{rebuild}"):
            open_it(old)
    mesh = tmp_path / "m" / "c" / "s.off"
    write_off(mesh, *icosphere(2))
    for args in (["query", old, mesh], ["index", mesh.parent, "-o", old], ["check", old]):
        result = CliRunner().invoke(main, [str(a) for a in args])
        assert result.exit_code == 1 and "Traceback" not in result.output
        (line,) = result.output.strip().splitlines()
        assert line.startswith(f"Error: {old}: made by an older cfsig") and line.endswith(rebuild)
    after = sorted(p.name for p in old.iterdir()) if old.is_dir() else old.read_bytes()
    assert after == before  # nothing written into it, no lock file left
