"""cfsig against ShapeDNA (lapy, 50 Laplace-Beltrami eigenvalues) on the same meshes.

For every mesh, in one process with one BLAS/OpenMP thread and no CHOLMOD on either side (lapy's
shift-invert eigensolver factorises with SciPy's SuperLU; cfsig runs with ``solver="scipy"``, the
same SuperLU, and with ``solver="eigen"``, its fastest solver without CHOLMOD): the CPU seconds
of lapy's ``Solver(TriaMesh(v, f)).eigs(k=50)`` on the mesh already in memory, and of cfsig's
``signature_file`` end to end, reading the file included. Prints medians and the speed-up
(lapy time / cfsig time) per mesh, overall and by vertex count. Needs the ``bench`` extra.

    python benchmarks/shapedna.py [--every K] [--json out.json]
"""

from __future__ import annotations

import os

# One BLAS/OpenMP thread, set before NumPy loads its libraries.
os.environ.update(
    dict.fromkeys(["OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS"], "1")
)

import argparse
import json
import time
from collections import defaultdict
from pathlib import Path

import common

from cfsig.mesh import read_mesh
from cfsig.params import Params
from cfsig.signature import signature_file

EIGENVALUES = 50
SOLVERS = ("scipy", "eigen")  # SuperLU as lapy uses, and cfsig's fastest solver without CHOLMOD


def measure(path: Path, params: Params) -> dict:
    """CPU seconds of ShapeDNA and of cfsig (with each solver without CHOLMOD) on one mesh."""
    from lapy import Solver, TriaMesh

    mesh = read_mesh(path)
    start = time.process_time()
    Solver(TriaMesh(mesh.vertices, mesh.faces)).eigs(k=EIGENVALUES, rng=0)
    row = {"mesh": f"{path.parent.name}/{path.name}", "vertices": len(mesh.vertices),
           "shapedna": time.process_time() - start}  # fmt: skip
    for solver in SOLVERS:
        start = time.process_time()
        signature_file(path, params, solver)
        row[solver] = time.process_time() - start
        row[f"speedup {solver}"] = row["shapedna"] / row[solver]
    return row


def main() -> None:
    """Parse the options, time both on every mesh, print the tables."""
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    common.data_arguments(parser)
    parser.add_argument("--json", type=Path, help="also write every measurement here")
    args = parser.parse_args()
    files, params = common.meshes(args), Params()
    measure(files[0], params)  # warm up imports
    rows = [measure(path, params) for path in files]
    med = common.median
    groups: dict = defaultdict(list)
    for r in rows:
        groups[common.vertex_bin(r["vertices"])].append(r)

    def line(label: str, rs: list[dict]) -> list:
        cells = [label, len(rs), med([r["shapedna"] for r in rs])]
        for solver in SOLVERS:
            speedups = [r[f"speedup {solver}"] for r in rs]
            cells += [med([r[solver] for r in rs]), med(speedups), min(speedups)]
        return cells

    body = [line(label, rs) for (_, label), rs in sorted(groups.items())]
    body.append(line("all", rows))
    head = ["vertices", "meshes", f"ShapeDNA k={EIGENVALUES} CPU s"]
    for solver in SOLVERS:
        head += [f"cfsig {solver} CPU s", f"speed-up {solver} (median)", "(min)"]
    print(f"{len(files)} meshes from {args.data}, one thread\n")
    print(common.table(head, body))
    for solver in SOLVERS:
        total = sum(r["shapedna"] for r in rows) / sum(r[solver] for r in rows)
        print(f"\nSpeed-up of the total CPU time, cfsig {solver}: {total:.3g}")
    if args.json:
        args.json.write_text(json.dumps(rows, indent=1))


if __name__ == "__main__":
    main()
