"""Wall time of ``cfsig index`` over a folder: one local job, two local jobs, and a Dask cluster.

Each run builds a fresh index of the same folder by running the command line in a new process
(interpreter start and imports included); the kinds of run take turns, and the median of each
kind is reported. The Dask runs use local clusters started once beforehand with Dask's command
line (a scheduler and a nanny with two one-thread workers, all on 127.0.0.1), not counted: one
with Dask's default worker environment, one without its malloc setting. Each Dask index must
hold the same signatures, bit for bit, as the local one. Needs the ``dask`` extra.

    python benchmarks/index_jobs.py [--every K] [--repeat R] [--descriptor cf|cfhks] [--no-dask]
"""

from __future__ import annotations

import argparse
import json
import os
import signal
import subprocess
import sys
import tempfile
import time
from collections.abc import Iterator
from contextlib import ExitStack, contextmanager
from pathlib import Path

import common
import numpy as np

from cfsig.index.store import IndexReader

COMMAND = "import sys; from cfsig.cli import main; sys.exit(main())"
DESCRIPTOR: list[str] = []  # --descriptor, when given
# Dask's nanny starts workers with MALLOC_TRIM_THRESHOLD_=65536, which also fixes glibc's mmap
# threshold: every large NumPy temporary is then mapped and unmapped anew. Measured both ways.
CLUSTERS = {
    "--scheduler (Dask, 2 workers, default nanny environment)": "",
    "--scheduler (Dask, 2 workers, MALLOC_TRIM_THRESHOLD_ unset)": (
        "distributed:\n  nanny:\n    pre-spawn-environ:\n      MALLOC_TRIM_THRESHOLD_: null\n"
    ),
}


@contextmanager
def dask_cluster(folder: Path, config: str) -> Iterator[str]:
    """Start a scheduler and two one-thread workers as processes on 127.0.0.1; its address.

    ``config`` is YAML for the Dask configuration of the workers (empty: Dask's defaults).
    """
    env = {k: v for k, v in os.environ.items() if k != "MALLOC_TRIM_THRESHOLD_"}
    if config:
        (folder / "dask.yaml").write_text(config)
        env["DASK_CONFIG"] = str(folder)
    local = ["--host", "127.0.0.1", "--dashboard-address", "127.0.0.1:0"]
    info = folder / "scheduler.json"
    scheduler = ["distributed.cli.dask_scheduler", "--port", "0", "--scheduler-file", str(info)]
    procs = [start([*scheduler, *local], env)]
    try:
        while not info.exists():
            time.sleep(0.1)
        time.sleep(0.2)
        address = json.loads(info.read_text())["address"]
        worker = ["distributed.cli.dask_worker", address, "--nworkers", "2", "--nthreads", "1"]
        procs.append(start([*worker, *local], env))
        from distributed import Client

        with Client(address) as client:
            client.wait_for_workers(2, timeout=120)
        yield address
    finally:
        for proc in procs:
            os.killpg(proc.pid, signal.SIGTERM)
        for proc in procs:
            proc.wait()


def start(args: list[str], env: dict) -> subprocess.Popen:
    """A Dask command in a process group of its own, quiet."""
    return subprocess.Popen(
        [sys.executable, "-m", *args], env=env, start_new_session=True,
        stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL,
    )  # fmt: skip


def index(folder: Path, output: Path, *options: str) -> float:
    """Run ``cfsig index`` once; its wall seconds."""
    args = [sys.executable, "-c", COMMAND, "index", str(folder), "-o", str(output), *options]
    if DESCRIPTOR:
        args += ["--descriptor", DESCRIPTOR[0]]
    start = time.perf_counter()
    subprocess.run(args, check=True, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    return time.perf_counter() - start


def signatures(path: Path) -> tuple[list[str], np.ndarray]:
    """The names and signatures of an index, sorted by name."""
    with IndexReader(path) as reader:
        names = reader.column("names")
        order = np.argsort(names)
        return list(names[order]), reader.signatures[:][order]


def subset(files: list[Path], folder: Path) -> None:
    """Link the chosen meshes into a folder of the same class layout."""
    for path in files:
        (folder / path.parent.name).mkdir(exist_ok=True)
        (folder / path.parent.name / path.name).symlink_to(path)


def main() -> None:
    """Parse the options, time the runs, check the Dask index, print the table."""
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    common.data_arguments(parser)
    parser.add_argument("--no-dask", action="store_true", help="skip the Dask cluster run")
    parser.add_argument("--repeat", type=int, default=3, help="runs of each kind (median)")
    parser.add_argument("--descriptor", choices=["cf", "cfhks"], help="default: the command's")
    args = parser.parse_args()
    if args.descriptor:
        DESCRIPTOR.append(args.descriptor)
    files = common.meshes(args)
    with tempfile.TemporaryDirectory() as tmp:
        tmp = Path(tmp)
        folder = args.data
        if args.every > 1:
            folder = tmp / "meshes"
            folder.mkdir()
            subset(files, folder)
        runs: dict[str, list[float]] = {"--jobs 1": [], "--jobs 2": []}
        with ExitStack() as stack:
            clusters = {}
            for i, (mode, config) in enumerate({} if args.no_dask else CLUSTERS.items()):
                (tmp / f"c{i}").mkdir()
                clusters[mode] = stack.enter_context(dask_cluster(tmp / f"c{i}", config))
            for _ in range(args.repeat):  # interleaved, so that load changes hit all alike
                for name in (tmp / "j1.h5", tmp / "j2.h5", *(tmp / f"d{i}.h5" for i in range(2))):
                    name.unlink(missing_ok=True)
                runs["--jobs 1"].append(index(folder, tmp / "j1.h5", "--jobs", "1"))
                runs["--jobs 2"].append(index(folder, tmp / "j2.h5", "--jobs", "2"))
                for i, (mode, address) in enumerate(clusters.items()):
                    seconds = index(folder, tmp / f"d{i}.h5", "--scheduler", address)
                    runs.setdefault(mode, []).append(seconds)
        names, local = signatures(tmp / "j1.h5")
        assert signatures(tmp / "j2.h5")[0] == names
        for i in range(len(clusters)):
            dask_names, remote = signatures(tmp / f"d{i}.h5")
            assert names == dask_names and np.array_equal(local, remote), "Dask index differs"
    rows = [[mode, common.median(seconds)] for mode, seconds in runs.items()]
    base = rows[0][1]
    body = [[mode, seconds, len(files) / seconds, base / seconds] for mode, seconds in rows]
    what = args.descriptor or "the command's default"
    print(f"{len(files)} meshes from {args.data}, descriptor {what}, fresh index each run, "
          f"median of {args.repeat}\n")  # fmt: skip
    print(common.table(["run", "wall s", "meshes per s", "speed-up over --jobs 1"], body))
    if not args.no_dask:
        print("\nEach Dask index holds the same signatures as the local one, bit for bit.")


if __name__ == "__main__":
    main()
