"""Seconds per mesh of each descriptor, end to end, against the default's in the same run.

    python benchmarks/per_mesh.py --data FOLDER [--every K] [--descriptors cf,intrinsic,...]
        [--repeat N]

For the meshes ``FOLDER/<class>/<file>.off`` (every k-th in sorted order) and each descriptor
in turn (default: all):

- in this process, one BLAS/OpenMP thread: `cfsig.signature_file` of every mesh, from reading
  the file to the signature, in CPU seconds (``time.process_time``) and wall seconds, after one
  warm-up on the first mesh (imports and first calls are not per-mesh costs): the medians;
- the whole process a user waits for: ``python -m cfsig index`` of a folder holding those
  meshes into a new index, one job, interpreter start included, in wall seconds per mesh: the
  median of ``--repeat`` runs.

Each with its ratio to the default ``intrinsic``'s in the same run.
"""

from __future__ import annotations

import os

# One BLAS/OpenMP thread, set before NumPy loads its libraries.
os.environ.update(
    dict.fromkeys(["OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS"], "1")
)

import argparse
import subprocess
import sys
import tempfile
import time
from pathlib import Path

from common import data_arguments, median, meshes, table

import cfsig
from cfsig.descriptors import NAMES

DEFAULT = cfsig.Params().descriptor


def timed(path, params: cfsig.Params) -> tuple[float, float]:
    """CPU and wall seconds of one `cfsig.signature_file`."""
    cpu, wall = time.process_time(), time.perf_counter()
    cfsig.signature_file(path, params)
    return time.process_time() - cpu, time.perf_counter() - wall


def whole_run(folder: Path, descriptor: str, index: Path) -> float:
    """Wall seconds of ``python -m cfsig index folder -o index --jobs 1 --descriptor ...``."""
    start = time.perf_counter()
    subprocess.run(
        [sys.executable, "-m", "cfsig", "index", str(folder), "-o", str(index), "--jobs", "1",
         "--descriptor", descriptor],
        check=True, capture_output=True,
    )  # fmt: skip
    return time.perf_counter() - start


def linked(files: list[Path], folder: Path) -> Path:
    """A folder ``<class>/<file>`` of links to ``files``."""
    for path in files:
        (folder / path.parent.name).mkdir(parents=True, exist_ok=True)
        (folder / path.parent.name / path.name).symlink_to(path.resolve())
    return folder


def main() -> None:
    """Time every mesh with each descriptor and print the medians and the ratio."""
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    data_arguments(parser)
    parser.add_argument("--descriptors", default=",".join(NAMES), help="comma-separated")
    parser.add_argument("--repeat", type=int, default=3, help="whole runs per descriptor")
    args = parser.parse_args()
    files = meshes(args.data, args.every)
    names = list(dict.fromkeys([DEFAULT, *args.descriptors.split(",")]))
    params = {d: cfsig.Params(descriptor=d) for d in names}
    for p in params.values():
        timed(files[0], p)
    times = {d: [timed(path, p) for path in files] for d, p in params.items()}
    cpu = {d: median([c for c, _ in t]) for d, t in times.items()}
    wall = {d: median([w for _, w in t]) for d, t in times.items()}
    with tempfile.TemporaryDirectory() as tmp:
        folder = linked(files, Path(tmp) / "meshes")
        runs = {
            d: median([whole_run(folder, d, Path(tmp) / f"{d}-{k}") for k in range(args.repeat)])
            / len(files)
            for d in names
        }
    print(f"{len(files)} meshes from {args.data}; medians, seconds per mesh:\n")
    rows = [
        [f"`{d}`", f"{cpu[d]:.4f}", f"{wall[d]:.4f}", f"{wall[d] / wall[DEFAULT]:.2f}",
         f"{runs[d]:.4f}", f"{runs[d] / runs[DEFAULT]:.2f}"]
        for d in names
    ]  # fmt: skip
    headers = ["descriptor", "CPU", "wall", f"wall / `{DEFAULT}`", "whole run", "ratio"]
    print(table(headers, rows))


if __name__ == "__main__":
    main()
