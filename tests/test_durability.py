"""The index survives kills, concurrent writers and readers, and refuses files it cannot use."""

import fcntl
import os
import shutil
import signal
import subprocess
import sys
import time
from pathlib import Path

import h5py
import numpy as np
import pytest
from click.testing import CliRunner

from cfsig.cli import main
from cfsig.files.demo import make_demo_collection
from cfsig.index.store import FORMAT_VERSION, Entry, IndexReader, check_index
from cfsig.params import Params
from tests.helpers import open_writer, random_signature


@pytest.fixture(scope="module")
def meshes(tmp_path_factory):
    folder = tmp_path_factory.mktemp("kill") / "meshes"
    make_demo_collection(folder, per_class=5)
    return folder


def _index_cmd(folder, index):
    return [sys.executable, "-m", "cfsig", "index", str(folder), "-o", str(index), "-j", "1",
            "--commit-every", "1"]  # fmt: skip


def _children(pid):
    """Process ids whose parent is ``pid``."""
    found = []
    for stat in os.listdir("/proc"):
        try:
            fields = open(f"/proc/{stat}/stat").read().rsplit(")", 1)[1].split()
        except (OSError, IndexError):
            continue
        if stat.isdigit() and int(fields[1]) == pid:
            found.append(int(stat))
    return found


def _alive(pid):
    try:
        state = open(f"/proc/{pid}/stat").read().rsplit(")", 1)[1].split()[0]
    except OSError:
        return False
    return state != "Z"


def _rows(index):
    with IndexReader(index) as reader:
        return list(reader.column("names"))


@pytest.mark.skipif(
    not Path("/proc/self/stat").exists(),
    reason="finds the killed run's worker processes through /proc (Linux)",
)
def test_sigkill_mid_run_then_resume(meshes, tmp_path):
    index = tmp_path / "i.h5"
    total = len(list(meshes.rglob("*.off")))
    committed_before = []
    for delay in (0.2, 0.05):  # two kills at different moments of the run
        proc = subprocess.Popen(_index_cmd(meshes, index), stderr=subprocess.DEVNULL)
        deadline = time.monotonic() + 60
        target = len(committed_before) + 3  # this run has computed and committed some
        while time.monotonic() < deadline and len(_rows(index) if index.exists() else []) < target:
            time.sleep(0.05)
        time.sleep(delay)
        workers = _children(proc.pid)
        proc.send_signal(signal.SIGKILL)
        proc.wait()
        deadline = time.monotonic() + 10
        while time.monotonic() < deadline and any(map(_alive, workers)):
            time.sleep(0.1)
        assert workers and not any(map(_alive, workers))  # no orphaned worker keeps running
        names = _rows(index)  # the index opens after the kill
        assert len(names) == len(set(names)) and len(names) >= len(committed_before)
        assert names[: len(committed_before)] == committed_before  # nothing committed is lost
        committed_before = names
    assert len(committed_before) < total, "the run finished before it was killed"
    done = subprocess.run(_index_cmd(meshes, index), capture_output=True, text=True)
    assert done.returncode == 0, done.stderr
    assert f"{total - len(committed_before)} meshes added" in done.stdout  # no recomputation
    names = _rows(index)
    assert sorted(names) == sorted(p.relative_to(meshes).as_posix() for p in meshes.rglob("*.off"))
    with IndexReader(index) as reader:
        assert np.isfinite(reader.signatures[:]).all()
        listed = {Path(view.signatures.file.filename).name for view in reader.segments}
    assert {p.name for p in index.iterdir()} == listed | {"manifest.h5", "lock"}  # no leftovers
    assert check_index(index) == []


def test_second_writer_gets_clear_error(meshes, tmp_path):
    index = tmp_path / "i"
    index.mkdir()
    lock = open(index / "lock", "a+")  # noqa: SIM115
    fcntl.flock(lock, fcntl.LOCK_EX)  # as a running `cfsig index` holds it
    try:
        result = CliRunner().invoke(main, ["index", str(meshes), "-o", str(index)])
    finally:
        lock.close()
    assert result.exit_code == 1
    assert "another process is writing this index" in result.output
    assert {p.name for p in index.iterdir()} == {"lock"}  # nothing but the first writer's lock


def test_reader_sees_committed_state_while_writer_commits(tmp_path, build_index):
    index = tmp_path / "i.h5"
    build_index(index, 5)
    with IndexReader(index) as reader:
        with open_writer(index) as writer:
            writer.add(Entry("new.off", "x", "/new.off"), random_signature(50))
            writer.commit()
            assert len(reader) == 5  # the open reader keeps the state it opened
            assert reader.entries([4])[0].name == "c1/4.off"
    assert len(_rows(index)) == 6


@pytest.mark.parametrize("kind", ["corrupt", "foreign", "newer", "params"])
def test_unusable_index_one_line_error(meshes, tmp_path, kind, build_index):
    index = tmp_path / "i.h5"
    if kind == "corrupt":
        build_index(index, 3)
        manifest = index / "manifest.h5"
        data = bytearray(manifest.read_bytes())
        data[: len(data) // 2] = os.urandom(len(data) // 2)
        manifest.write_bytes(bytes(data))
    elif kind == "foreign":
        with h5py.File(index, "w") as f:
            f["data"] = np.arange(3)
    else:
        # six entries: two per class, so that evaluate has something to retrieve
        build_index(index, 6, Params(descriptor="cf", seed=7) if kind == "params" else None)
        if kind == "newer":
            with h5py.File(index / "manifest.h5", "a") as f:
                f.attrs["format_version"] = FORMAT_VERSION + 1
    mesh = next(meshes.rglob("*.off"))
    for args in (["query", str(index), str(mesh)], ["evaluate", "--index", str(index)]):
        result = CliRunner().invoke(main, args)
        if kind == "params":  # another seed is a valid index for query and evaluate
            assert result.exit_code == 0, result.output
            assert "Error" not in result.output
            continue
        assert result.exit_code == 1, result.output
        lines = result.output.strip().splitlines()
        assert len(lines) == 1 and lines[0].startswith(f"Error: {index}")
    if kind == "params":
        result = CliRunner().invoke(main, ["index", str(mesh), "-o", str(index), "--seed", "0"])
        assert result.exit_code == 1 and "other parameters" in result.output


_REMOVE = """
import sys
from cfsig.index.store import IndexWriter, read_manifest
from pathlib import Path
index = Path(sys.argv[1])
print("ready", flush=True)
with IndexWriter(index, read_manifest(index).params) as writer:
    writer.remove(sys.argv[2:])
"""


def test_sigkill_during_a_removal_leaves_it_undone_or_done(tmp_path):
    base = tmp_path / "base"
    with open_writer(base, merge=False) as writer:  # in seven segments
        for i in range(1400):
            writer.add(Entry(f"c/{i}.off", f"c{i % 3}", f"/c/{i}.off"), random_signature(i))
            if i % 200 == 199:
                writer.commit()
    every = set(_rows(base))
    gone = [f"c/{i}.off" for i in range(0, 1400, 7)]

    def start(index):
        command = [sys.executable, "-c", _REMOVE, str(index), *gone]
        proc = subprocess.Popen(command, stdout=subprocess.PIPE)
        assert proc.stdout.readline() == b"ready\n"
        return proc

    took = []  # how long the removal takes once the interpreter has started
    for _ in range(3):
        index = tmp_path / "timed"
        shutil.rmtree(index, ignore_errors=True)
        shutil.copytree(base, index)
        proc = start(index)
        begin = time.monotonic()
        assert proc.wait() == 0
        took.append(time.monotonic() - begin)
    assert set(_rows(index)) == every - set(gone)
    rng, outcomes = np.random.default_rng(0), []
    for attempt in range(50):
        index = tmp_path / f"killed-{attempt}"
        shutil.copytree(base, index)
        proc = start(index)
        time.sleep(rng.uniform(0, max(took)))
        proc.send_signal(signal.SIGKILL)
        proc.wait()
        assert check_index(index) == []
        names = set(_rows(index))
        assert names in (every, every - set(gone))  # all of it or none of it
        outcomes.append(names == every)
        shutil.rmtree(index)
    assert 0 < sum(outcomes) < 50  # some kills came before the commit, some after
