import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest
from click.testing import CliRunner

import cfsig
import cfsig.index.store
from cfsig import batch
from cfsig.batch import compute_many, index_meshes
from cfsig.cli import main
from cfsig.descriptors.signature import signature_file
from cfsig.errors import ClusterError
from cfsig.index.store import IndexReader
from cfsig.params import Params
from tests.crashing import signature_or_crash
from tests.helpers import icosphere, open_writer, torus, write_off


@pytest.fixture
def meshes(tmp_path):
    """Five small meshes in two class folders, and one file that cannot be read."""
    v, f = icosphere(2)
    shapes = {
        "round/a.off": (v, f),
        "round/b.off": (v * [1, 0.8, 0.6], f),
        "round/c.off": (v * [1.5, 1, 1], f),
        "ring/d.off": torus(nu=24, nv=8),
        "ring/e.off": torus(r=0.2, nu=24, nv=8),
    }
    for name, (verts, faces) in shapes.items():
        (tmp_path / name).parent.mkdir(exist_ok=True)
        write_off(tmp_path / name, verts, faces)
    (tmp_path / "ring" / "broken.off").write_text("OFF\n3 1 0\n0 0 0\n")
    return tmp_path


def _by_name(outcomes):
    return {Path(o.path).name: o for o in outcomes}


def test_a_crashing_worker_costs_only_its_file(meshes):
    crash = meshes / "round" / "crash.off"
    crash.write_bytes((meshes / "round" / "a.off").read_bytes())
    paths = sorted(meshes.glob("*/*.off"))
    outcomes = _by_name(
        compute_many(paths, Params(descriptor="cf"), jobs=2, compute=signature_or_crash)
    )
    assert sorted(outcomes) == sorted(p.name for p in paths)
    assert "crashed" in outcomes["crash.off"].error
    assert outcomes["broken.off"].signature is None and "truncated" in outcomes["broken.off"].error
    for path in paths:
        if path.name not in ("crash.off", "broken.off"):
            expected = signature_file(path, Params(descriptor="cf")).vector
            assert np.array_equal(outcomes[path.name].signature.vector, expected)


def test_index_meshes_adds_new_and_changed_files_only(meshes, tmp_path):
    index = tmp_path / "library.h5"
    seen = []

    def progress(outcomes, total):  # the total grows as the folder is scanned
        yield from outcomes
        seen.append(total())

    with open_writer(index) as writer:
        done = index_meshes(writer, [meshes], jobs=2, progress=progress)
        added, failures = done.added, done.failures
    assert added == 5 and seen == [6]
    assert len(failures) == 1 and failures[0].startswith(f"{meshes / 'ring' / 'broken.off'}: ")
    with IndexReader(index) as reader:
        names, labels = list(reader.column("names")), list(reader.column("labels"))
        entry = reader.entries(np.array([names.index("ring/d.off")]))[0]
    assert sorted(names) == ["ring/d.off", "ring/e.off"] + [f"round/{c}.off" for c in "abc"]
    assert sorted(set(labels)) == ["ring", "round"]
    assert entry.path == os.path.abspath(meshes / "ring" / "d.off")  # links not resolved
    write_off(meshes / "round" / "a.off", *torus(nu=20, nv=8))  # changed contents
    with open_writer(index) as writer:
        done = index_meshes(writer, [meshes], jobs=1, progress=progress)
        added, failures = done.added, done.failures
    assert added == 1 and len(failures) == 1 and seen == [6, 2]  # a.off and broken.off again
    with IndexReader(index) as reader:
        assert len(reader) == 5
        row = list(reader.column("names")).index("round/a.off")
        stored = reader.signatures[row]
    expected = signature_file(meshes / "round" / "a.off", Params(descriptor="cf")).vector
    assert np.allclose(stored, expected, atol=1e-6)


def test_index_meshes_strict_and_taken_names(meshes, tmp_path):
    with open_writer(tmp_path / "strict.h5") as writer:
        done = index_meshes(writer, [meshes], jobs=1, strict=True)
        added, failures = done.added, done.failures
    assert added == 0 and len(failures) == 1  # ring/broken.off is the first file computed
    with open_writer(tmp_path / "twice.h5") as writer:
        done = index_meshes(writer, [meshes / "round", meshes / "round"], jobs=1)
        added, failures = done.added, done.failures
    assert added == 3 and len(failures) == 3
    assert all("is already taken by another file" in line for line in failures)


def test_missing_scheduler_is_a_cluster_error(meshes, monkeypatch):
    pytest.importorskip("distributed")
    monkeypatch.setattr(batch, "_CONNECT_TIMEOUT", "1s")
    with pytest.raises(ClusterError, match="cannot connect"):
        list(
            compute_many(
                [meshes / "round" / "a.off"], Params(descriptor="cf"), scheduler="tcp://127.0.0.1:9"
            )
        )


def _start(args: list[str], env: dict) -> subprocess.Popen:
    """Start a Dask command in a process group of its own (a nanny and its worker die together)."""
    return subprocess.Popen(
        [sys.executable, "-m", *args], env=env, start_new_session=True,
        stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL,
    )  # fmt: skip


def _stop(procs: list[subprocess.Popen]) -> None:
    """Terminate the process groups, then kill what is left after a grace period (a nanny
    restarting a crashed worker can ignore SIGTERM for many seconds)."""
    for proc in procs:
        os.killpg(proc.pid, signal.SIGTERM)
    for proc in procs:
        try:
            proc.wait(timeout=2)
        except subprocess.TimeoutExpired:
            os.killpg(proc.pid, signal.SIGKILL)
            proc.wait()


def _scheduler_address(info: Path, deadline: float) -> str:
    """The address in the scheduler's file, once the scheduler has written the file whole."""
    while time.monotonic() < deadline:
        try:
            return json.loads(info.read_text())["address"]
        except (OSError, ValueError, KeyError):  # not there yet, or still being written
            time.sleep(0.05)
    raise TimeoutError(f"the Dask scheduler wrote no address to {info}")


@pytest.fixture
def dask_cluster(tmp_path):
    """A Dask scheduler and two one-thread workers, separate processes, all on loopback."""
    pytest.importorskip("distributed")
    env = dict(os.environ)
    root = str(Path(cfsig.__file__).resolve().parents[1])
    env["PYTHONPATH"] = os.pathsep.join(filter(None, [root, env.get("PYTHONPATH")]))
    env["DASK_DISTRIBUTED__SCHEDULER__ALLOWED_FAILURES"] = "1"  # a crashing task fails sooner
    info = tmp_path / "scheduler.json"
    local = ["--host", "127.0.0.1", "--dashboard-address", "127.0.0.1:0"]
    procs = [_start(["distributed.cli.dask_scheduler", "--port", "0", *local,
                     "--scheduler-file", str(info)], env)]  # fmt: skip
    try:
        deadline = time.monotonic() + 60
        address = _scheduler_address(info, deadline)
        worker = ["distributed.cli.dask_worker", address, "--nthreads", "1", "--nanny-port", "0"]
        procs += [_start([*worker, "--worker-port", "0", *local], env) for _ in range(2)]
        from distributed import Client

        with Client(address, timeout="30s") as client:
            client.wait_for_workers(2, timeout=60)
        yield address
    finally:
        _stop(procs)


def test_dask_cluster_gives_the_local_results(meshes, dask_cluster):
    paths = sorted(meshes.glob("*/*.off"))
    remote = _by_name(compute_many(paths, Params(descriptor="cf"), scheduler=dask_cluster))
    local = _by_name(compute_many(paths, Params(descriptor="cf"), jobs=1))
    assert sorted(remote) == sorted(local) == sorted(p.name for p in paths)
    assert remote["broken.off"].signature is None and "truncated" in remote["broken.off"].error
    for name, outcome in local.items():
        if outcome.signature is not None:
            assert np.array_equal(remote[name].signature.vector, outcome.signature.vector)
            assert np.array_equal(remote[name].signature.phi, outcome.signature.phi)

    runner = CliRunner()
    on_cluster = runner.invoke(main, ["index", str(meshes), "-o", str(meshes / "c.h5"),
                                      "--scheduler", dask_cluster])  # fmt: skip
    here = runner.invoke(main, ["index", str(meshes), "-o", str(meshes / "l.h5"), "-j", "1"])
    assert on_cluster.exit_code == here.exit_code == 3  # the broken file is skipped
    with IndexReader(meshes / "c.h5") as a, IndexReader(meshes / "l.h5") as b:
        order_a, order_b = np.argsort(a.column("names")), np.argsort(b.column("names"))
        assert list(a.column("names")[order_a]) == list(b.column("names")[order_b])
        assert np.array_equal(a.signatures[:][order_a], b.signatures[:][order_b])


def test_dask_batches_lose_only_their_bad_files(meshes, dask_cluster, monkeypatch):
    for name in ("crash.off", "oops.off", "f.off", "g.off"):
        (meshes / "round" / name).write_bytes((meshes / "round" / "a.off").read_bytes())
    paths = sorted(meshes.glob("*/*.off"), key=lambda p: p.name[0] in "co")  # bad files last
    sizes = []
    real_islice = batch.islice
    monkeypatch.setattr(batch, "islice", lambda it, n: sizes.append(n) or real_islice(it, n))
    monkeypatch.setattr(batch, "_TASK_SECONDS", 1e6)  # the largest batches once one is back
    outcomes = list(compute_many(paths, Params(descriptor="cf"), scheduler=dask_cluster,
                                 compute=signature_or_crash))  # fmt: skip
    by_name = _by_name(outcomes)
    assert len(outcomes) == len(paths) and sorted(by_name) == sorted(p.name for p in paths)
    assert max(sizes) == batch._MAX_BATCH  # the bad files came in a batch with good ones
    crash, oops = by_name["crash.off"], by_name["oops.off"]
    assert crash.signature is None
    assert crash.error.startswith(f"{meshes / 'round' / 'crash.off'}: failed on the cluster: ")
    assert oops.signature is None
    want = f"{meshes / 'round' / 'oops.off'}: failed on the cluster: not a cfsig error"
    assert oops.error == want
    assert "truncated" in by_name["broken.off"].error
    for path in paths:
        if path.name not in ("crash.off", "oops.off", "broken.off"):
            expected = signature_file(path, Params(descriptor="cf")).vector
            assert np.array_equal(by_name[path.name].signature.vector, expected)


def test_jobs_and_scheduler_are_exclusive(meshes):
    result = CliRunner().invoke(main, ["index", str(meshes), "-o", str(meshes / "x.h5"),
                                       "-j", "2", "--scheduler", "tcp://127.0.0.1:9"])  # fmt: skip
    assert result.exit_code == 2 and "not both" in result.output


def test_index_meshes_computes_while_the_folder_is_scanned(meshes, tmp_path, monkeypatch):
    found, at_first_outcome, totals = [], [], []
    real_find = batch.find_meshes

    def slow_scan(paths):  # records how far the scan has gone
        for item in real_find(paths):
            found.append(item)
            yield item

    def progress(outcomes, total):
        for outcome in outcomes:
            at_first_outcome.append(len(found))
            totals.append(total())
            yield outcome

    monkeypatch.setattr(batch, "find_meshes", slow_scan)
    with open_writer(tmp_path / "i") as writer:
        index_meshes(writer, [meshes], jobs=1, progress=progress)
    assert at_first_outcome[0] < 6  # the first signature came before the scan ended
    assert totals == sorted(totals) and totals[0] < totals[-1] == 6  # the total grew
    (meshes / "round" / "new.off").write_bytes((meshes / "ring" / "d.off").read_bytes())
    hashed = []
    real_sha256 = cfsig.index.store.hashlib.sha256
    monkeypatch.setattr(
        cfsig.index.store.hashlib, "sha256", lambda data: hashed.append(data) or real_sha256(data)
    )
    with open_writer(tmp_path / "i") as writer:
        added = index_meshes(writer, [meshes], jobs=1).added
    assert added == 1 and len(hashed) == 5  # only the files whose names are indexed
