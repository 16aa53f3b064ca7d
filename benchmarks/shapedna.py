"""cfsig against ShapeDNA (lapy, 50 Laplace-Beltrami eigenvalues) on the same meshes.

For every mesh, in one process with one BLAS/OpenMP thread and no CHOLMOD on either side (lapy's
shift-invert eigensolver factorises with SciPy's SuperLU; cfsig runs with ``solver="scipy"``, the
same SuperLU, and with ``solver="eigen"``, its fastest solver without CHOLMOD), CPU seconds of
two like-for-like comparisons:

- from memory: lapy's ``Solver(TriaMesh(v, f)).eigs(k=50)`` against cfsig's
  ``compute_signature(mesh)``, both given the same checked mesh;
- from the file: the same plus each package's own reader (lapy's ``TriaMesh.read_off``, cfsig's
  reading, checking and hashing inside ``signature_file``).

Also, with each solver, the bare factorisation and solve of the mesh's pinned system alone: the
speed-up over ShapeDNA that no implementation of the method with that solver can pass.

Prints medians and the speed-up (lapy time / cfsig time) per mesh, overall and by vertex count.
Needs the ``bench`` extra.

    python benchmarks/shapedna.py [--every K] [--json out.json]
"""

from __future__ import annotations

import os

# One BLAS/OpenMP thread, set before NumPy loads its libraries.
os.environ.update(
    dict.fromkeys(["OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS"], "1")
)

import contextlib
import io
from collections import defaultdict
from functools import partial
from pathlib import Path

import common

from cfsig.descriptors.signature import compute_signature, signature_file
from cfsig.files.mesh import read_mesh
from cfsig.operators.conformal import factorize, operators, pinned_system
from cfsig.params import Params

EIGENVALUES = 50
SOLVERS = ("scipy", "eigen")  # SuperLU as lapy uses, and cfsig's fastest solver without CHOLMOD
PROTOCOLS = ("memory", "file")


def measure(path: Path, params: Params) -> dict:
    """CPU seconds of ShapeDNA and of cfsig (each solver without CHOLMOD) on one mesh."""
    from lapy import Solver, TriaMesh

    with contextlib.redirect_stdout(io.StringIO()):  # lapy's reader prints what it read
        lapy_read = common.timed(partial(TriaMesh.read_off, str(path)))[1]
    mesh = read_mesh(path)
    shapedna = common.timed(
        lambda: Solver(TriaMesh(mesh.vertices, mesh.faces)).eigs(k=EIGENVALUES, rng=0)
    )[1]
    row = {"mesh": f"{path.parent.name}/{path.name}", "vertices": len(mesh.vertices),
           "shapedna memory": shapedna, "shapedna file": lapy_read + shapedna}  # fmt: skip
    ops = operators(mesh, params.mollify)
    system, keep = pinned_system(ops.laplacian, ops.labels)
    rhs = (ops.curvature - ops.target)[keep]
    for solver in SOLVERS:
        row[f"{solver} memory"] = common.timed(partial(compute_signature, mesh, params, solver))[1]
        row[f"{solver} file"] = common.timed(partial(signature_file, path, params, solver))[1]
        row[f"{solver} bare"] = common.timed(lambda s=solver: factorize(system, s)(rhs))[1]
        for start in (*PROTOCOLS, "bare"):
            base = "shapedna file" if start == "file" else "shapedna memory"
            row[f"speedup {solver} {start}"] = row[base] / row[f"{solver} {start}"]
    return row


def main() -> None:
    """Parse the options, time both on every mesh, print the tables."""
    args = common.arguments(__doc__.splitlines()[0]).parse_args()
    files, params = common.meshes(args), Params()
    measure(files[0], params)  # warm up imports
    rows = [measure(path, params) for path in files]
    med = common.median
    groups: dict = defaultdict(list)
    for r in rows:
        groups[common.vertex_bin(r["vertices"])].append(r)

    def line(label: str, rs: list[dict], start: str) -> list:
        cells = [label, len(rs), med([r[f"shapedna {start}"] for r in rs])]
        for solver in SOLVERS:
            speedups = [r[f"speedup {solver} {start}"] for r in rs]
            cells += [med([r[f"{solver} {start}"] for r in rs]), med(speedups), min(speedups)]
        return cells

    print(f"{len(files)} meshes from {args.data}, one thread")
    for start in PROTOCOLS:
        body = [line(label, rs, start) for (_, label), rs in sorted(groups.items())]
        body.append(line("all", rows, start))
        head = ["vertices", "meshes", f"ShapeDNA k={EIGENVALUES} CPU s"]
        for solver in SOLVERS:
            head += [f"cfsig {solver} CPU s", f"speed-up {solver} (median)", "(min)"]
        print(f"\n### From {start}\n\n{common.table(head, body)}\n")
        for solver in SOLVERS:
            cfsig_total = sum(r[f"{solver} {start}"] for r in rows)
            total = sum(r[f"shapedna {start}"] for r in rows) / cfsig_total
            print(f"Speed-up of the total CPU time from {start}, cfsig {solver}: {total:.3g}")
    body = []
    for solver in SOLVERS:
        ceiling = [r[f"speedup {solver} bare"] for r in rows]
        body.append([solver, med([r[f"{solver} bare"] for r in rows]), med(ceiling), max(ceiling)])
    head = ["solver", "bare solve CPU s", "ShapeDNA / bare solve (median)", "(max)"]
    print("\n### The ceiling: the bare solve alone against ShapeDNA from memory\n")
    print(common.table(head, body))
    common.save_rows(args.json, rows)


if __name__ == "__main__":
    main()
