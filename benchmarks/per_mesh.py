"""Seconds per mesh of the two descriptors, end to end, and their ratio in the same run.

    python benchmarks/per_mesh.py --data FOLDER [--every K]

For every mesh ``FOLDER/<class>/<file>.off`` (every k-th in sorted order), in one process with
one BLAS/OpenMP thread: `cfsig.signature_file` with ``cf`` then with ``intrinsic``, from
reading the file to the signature, in CPU seconds (``time.process_time``) and wall seconds.
Prints the medians and the ratio ``intrinsic`` / ``cf`` of the medians, after one warm-up of
each descriptor on the first mesh (imports and first calls are not per-mesh costs).
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

DESCRIPTORS = ("cf", "intrinsic")


def timed(path, params: cfsig.Params) -> tuple[float, float]:
    """CPU and wall seconds of one `cfsig.signature_file`."""
    cpu, wall = time.process_time(), time.perf_counter()
    cfsig.signature_file(path, params)
    return time.process_time() - cpu, time.perf_counter() - wall


def main() -> None:
    """Time every mesh with each descriptor and print the medians and the ratio."""
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    data_arguments(parser)
    args = parser.parse_args()
    files = meshes(args.data, args.every)
    params = {d: cfsig.Params(descriptor=d) for d in DESCRIPTORS}
    for p in params.values():
        timed(files[0], p)
    times = {d: [timed(path, p) for path in files] for d, p in params.items()}
    cpu = {d: median([c for c, _ in t]) for d, t in times.items()}
    wall = {d: median([w for _, w in t]) for d, t in times.items()}
    print(f"{len(files)} meshes from {args.data}, one thread, medians:\n")
    rows = [[f"`{d}`", f"{cpu[d]:.4f}", f"{wall[d]:.4f}"] for d in DESCRIPTORS]
    rows.append(
        ["`intrinsic` / `cf`", f"{cpu['intrinsic'] / cpu['cf']:.2f}",
         f"{wall['intrinsic'] / wall['cf']:.2f}"]
    )  # fmt: skip
    print(table(["descriptor", "CPU s per mesh", "wall s per mesh"], rows))


if __name__ == "__main__":
    main()
