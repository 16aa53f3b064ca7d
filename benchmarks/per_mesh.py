"""Seconds per mesh of each descriptor, end to end, against the default's in the same run.

    python benchmarks/per_mesh.py --data FOLDER [--every K] [--descriptors cf,intrinsic,...]

For every mesh ``FOLDER/<class>/<file>.off`` (every k-th in sorted order), in one process with
one BLAS/OpenMP thread: `cfsig.signature_file` with each descriptor in turn (default: all), from
reading the file to the signature, in CPU seconds (``time.process_time``) and wall seconds.
Prints the medians and each one's ratio to the default ``intrinsic``'s median, after one
warm-up of each descriptor on the first mesh (imports and first calls are not per-mesh costs).
"""

from __future__ import annotations

import os

# One BLAS/OpenMP thread, set before NumPy loads its libraries.
os.environ.update(
    dict.fromkeys(["OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS"], "1")
)

import argparse
import time

from common import data_arguments, median, meshes, table

import cfsig
from cfsig.descriptors import NAMES

DEFAULT = cfsig.Params().descriptor


def timed(path, params: cfsig.Params) -> tuple[float, float]:
    """CPU and wall seconds of one `cfsig.signature_file`."""
    cpu, wall = time.process_time(), time.perf_counter()
    cfsig.signature_file(path, params)
    return time.process_time() - cpu, time.perf_counter() - wall


def main() -> None:
    """Time every mesh with each descriptor and print the medians and the ratio."""
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    data_arguments(parser)
    parser.add_argument("--descriptors", default=",".join(NAMES), help="comma-separated")
    args = parser.parse_args()
    files = meshes(args.data, args.every)
    names = list(dict.fromkeys([DEFAULT, *args.descriptors.split(",")]))
    params = {d: cfsig.Params(descriptor=d) for d in names}
    for p in params.values():
        timed(files[0], p)
    times = {d: [timed(path, p) for path in files] for d, p in params.items()}
    cpu = {d: median([c for c, _ in t]) for d, t in times.items()}
    wall = {d: median([w for _, w in t]) for d, t in times.items()}
    print(f"{len(files)} meshes from {args.data}, one thread, medians:\n")
    rows = [
        [f"`{d}`", f"{cpu[d]:.4f}", f"{wall[d]:.4f}", f"{wall[d] / wall[DEFAULT]:.2f}"]
        for d in names
    ]
    print(table(["descriptor", "CPU s per mesh", "wall s per mesh", f"wall / `{DEFAULT}`"], rows))


if __name__ == "__main__":
    main()
