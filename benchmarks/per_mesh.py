"""Seconds per mesh of each descriptor, end to end, against the default's in the same run.

    python benchmarks/per_mesh.py --data FOLDER [--every K] [--descriptors cf,intrinsic,...]
        [--repeat N] [--channels] [--vertices V] [--rank-rows R]

For the meshes ``FOLDER/<class>/<file>.off`` (every k-th in sorted order) and each descriptor
in turn (default: all):

- in this process, one BLAS/OpenMP thread: `cfsig.signature_file` of every mesh, from reading
  the file to the signature, in CPU seconds (``time.process_time``) and wall seconds, after one
  warm-up on the first mesh (imports and first calls are not per-mesh costs): the medians;
- the whole process a user waits for: ``python -m cfsig index`` of a folder holding those
  meshes into a new index, one job, interpreter start included, in wall seconds per mesh: the
  median of ``--repeat`` runs;
- ranking one query against ``--rank-rows`` signatures (the meshes' own, repeated), by the
  descriptor's distance (`cfsig.search.nearest.distances`, the full scan `cfsig evaluate`
  makes), in wall seconds: the median over the meshes as queries.

Each with its ratio to the default ``intrinsic``'s in the same run. With ``--channels``, only
``rigid``'s stages, in this process: reading and repair, then each channel on the repaired mesh,
wall seconds, medians over the meshes. ``--vertices V`` keeps
the meshes of V vertices, give or take 2%.
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

import numpy as np
from common import data_arguments, median, meshes, table

import cfsig
from cfsig.descriptors import NAMES, intrinsic, lf, panorama, rigid, sh
from cfsig.files.mesh import read_mesh
from cfsig.repair.stage import repair_mesh
from cfsig.search.nearest import distances

DEFAULT = cfsig.Params().descriptor


def vertex_count(path: Path) -> int:
    """Vertices of a mesh as read."""
    return len(read_mesh(path).vertices)


def timed(path, params: cfsig.Params) -> tuple[float, float]:
    """CPU and wall seconds of one `cfsig.signature_file`."""
    cpu, wall = time.process_time(), time.perf_counter()
    cfsig.signature_file(path, params)
    return time.process_time() - cpu, time.perf_counter() - wall


def channel_seconds(path: Path) -> dict[str, float]:
    """Wall seconds of each stage of ``rigid`` on one mesh (`rigid.rigid_vector`'s parts)."""
    params = cfsig.Params(descriptor="rigid")
    start = time.perf_counter()
    mesh = repair_mesh(cfsig.read_mesh(path), params.repair)
    seconds = {"reading and repair": time.perf_counter() - start}
    stages = {
        "heat and curvature": lambda: intrinsic.intrinsic_vector(mesh, params, None, "auto"),
        "panorama": lambda: panorama.panorama_features(
            *sh.surface_samples(mesh.vertices, mesh.faces, params.seed)
        ),
        f"lf ({rigid.FIELDS} light fields)": lambda: lf.light_field_features(mesh, rigid.FIELDS),
    }
    for name, stage in stages.items():
        start = time.perf_counter()
        stage()
        seconds[name] = time.perf_counter() - start
    return seconds


def whole_run(folder: Path, descriptor: str, index: Path) -> float:
    """Wall seconds of ``python -m cfsig index folder -o index --jobs 1 --descriptor ...``."""
    start = time.perf_counter()
    subprocess.run(
        [sys.executable, "-m", "cfsig", "index", str(folder), "-o", str(index), "--jobs", "1",
         "--descriptor", descriptor],
        check=True, capture_output=True,
    )  # fmt: skip
    return time.perf_counter() - start


def ranking(signatures: np.ndarray, descriptor: str, rows: int) -> float:
    """Median wall seconds of ranking each signature against ``rows`` of them, repeated."""
    indexed = np.resize(signatures, (rows, signatures.shape[1]))
    seconds = []
    for query in signatures:
        start = time.perf_counter()
        distances(descriptor, query[None], indexed)
        seconds.append(time.perf_counter() - start)
    return median(seconds)


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
    parser.add_argument("--channels", action="store_true", help="time rigid's stages only")
    parser.add_argument("--vertices", type=int, help="only meshes of this many vertices (±2%%)")
    parser.add_argument("--rank-rows", type=int, default=400, help="signatures a query ranks")
    args = parser.parse_args()
    files = meshes(args.data, args.every)
    if args.vertices:
        files = [f for f in files if abs(vertex_count(f) - args.vertices) <= args.vertices / 50]
    if args.channels:
        channel_seconds(files[0])
        stages = [channel_seconds(path) for path in files]
        rows = [[f"{name}", f"{median([s[name] for s in stages]):.4f}"] for name in stages[0]]
        rows.append(["all", f"{median([sum(s.values()) for s in stages]):.4f}"])
        print(f"{len(files)} meshes from {args.data}; `rigid`'s stages, medians, seconds:\n")
        print(table(["stage", "wall"], rows))
        return
    names = list(dict.fromkeys([DEFAULT, *args.descriptors.split(",")]))
    params = {d: cfsig.Params(descriptor=d) for d in names}
    for p in params.values():
        timed(files[0], p)
    times = {d: [timed(path, p) for path in files] for d, p in params.items()}
    signatures = {
        d: np.array([cfsig.signature_file(path, p).vector for path in files], np.float32)
        for d, p in params.items()
    }
    rank = {d: ranking(signatures[d], d, args.rank_rows) for d in names}
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
         f"{runs[d]:.4f}", f"{runs[d] / runs[DEFAULT]:.2f}", f"{rank[d]:.4f}"]
        for d in names
    ]  # fmt: skip
    headers = ["descriptor", "CPU", "wall", f"wall / `{DEFAULT}`", "whole run", "ratio",
               f"rank 1 vs {args.rank_rows}"]  # fmt: skip
    print(table(headers, rows))


if __name__ == "__main__":
    main()
