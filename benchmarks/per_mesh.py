"""Per-mesh time of cfsig, stage by stage, against the bare factorisation and solve alone.

For every mesh and solver family, in one process with one BLAS/OpenMP thread: the end-to-end
``signature_file`` (read, operators, solve, curvature error, sampling, histogram); the same
stages timed one by one; and the bare factorisation and solve of the same pinned system, on its
own. Prints Markdown tables of medians (CPU seconds from ``time.process_time``, wall seconds from
``time.perf_counter``) and the ratio end to end / bare solve.

    python benchmarks/per_mesh.py [--every K] [--solvers scipy cholmod] [--json out.json]
"""

from __future__ import annotations

import os

# One BLAS/OpenMP thread, set before NumPy loads its libraries.
os.environ.update(
    dict.fromkeys(["OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS"], "1")
)

import hashlib
from collections import defaultdict
from pathlib import Path

import common
import numpy as np

from cfsig.descriptors.signature import signature_file, signature_of
from cfsig.files.mesh import clean_mesh, parse_mesh, read_bytes
from cfsig.operators.conformal import (
    ConformalFactor,
    available_solvers,
    curvature_error,
    factorize,
    factorize_laplacian,
    operators,
    pinned_system,
)
from cfsig.operators.geometry import cotan_laplacian
from cfsig.params import Params

STAGES = ("read", "operators", "solve", "curvature error", "sampling+histogram")


def measure(path: Path, params: Params, solver: str) -> dict:
    """End-to-end, per-stage and bare-solve times of one mesh with one solver family."""
    row: dict = {"mesh": f"{path.parent.name}/{path.name}", "solver": solver}
    sig, row["e2e_cpu"], row["e2e_wall"] = common.timed(
        lambda: signature_file(path, params, solver)
    )
    row["vertices"], row["curvature_error"] = sig.n_vertices, sig.curvature_error

    def read():
        data = read_bytes(path)
        hashlib.sha256(data).hexdigest()
        return parse_mesh(data, path)

    stages = {}
    mesh, *stages["read"] = common.timed(read)
    ops, *stages["operators"] = common.timed(lambda: operators(mesh, params.mollify))
    rhs = ops.target - ops.curvature

    def solve():
        factorized = factorize_laplacian(ops.laplacian, ops.labels, solver)
        return factorized, factorized(rhs)

    (factorized, phi), *stages["solve"] = common.timed(solve)
    error, *stages["curvature error"] = common.timed(
        lambda: curvature_error(ops.lengths, mesh.faces, ops.boundary, phi, ops.target)
    )
    cf = ConformalFactor(phi, ops.curvature, ops.target, ops.face_areas, ops.n_components,
                         ops.mollified, error, ops.laplacian, ops.vertex_area, ops.labels,
                         factorized)  # fmt: skip
    hist, *stages["sampling+histogram"] = common.timed(
        lambda: signature_of(mesh, cf.operators, params, cf)
    )
    assert np.array_equal(hist, sig.vector), f"{path}: stages disagree with signature_file"
    for stage, (cpu, wall) in stages.items():
        row[f"{stage}_cpu"], row[f"{stage}_wall"] = cpu, wall
    # Two parts of those stages, timed again on their own: checking and repairing the mesh
    # (of "read") and assembling the Laplacian from the edges that check sorted (of "operators").
    _, row["clean_mesh_cpu"], _ = common.timed(lambda: clean_mesh(mesh.vertices, mesh.faces))
    _, row["laplacian_cpu"], _ = common.timed(
        lambda: cotan_laplacian(
            ops.lengths, mesh.faces, len(mesh.vertices), ops.face_areas, mesh.edges
        )
    )

    system, keep = pinned_system(ops.laplacian, ops.labels)
    b = -rhs[keep]
    _, row["bare_cpu"], row["bare_wall"] = common.timed(lambda: factorize(system, solver)(b))
    row["ratio_cpu"] = row["e2e_cpu"] / row["bare_cpu"]
    row["ratio_wall"] = row["e2e_wall"] / row["bare_wall"]
    return row


def report(rows: list[dict], solvers: list[str]) -> str:
    """Markdown tables of the medians, per solver family and per vertex-count bin."""
    med, out = common.median, []
    by_solver = {s: [r for r in rows if r["solver"] == s] for s in solvers}
    head = ["solver", "meshes", "end to end CPU s", "bare solve CPU s", "ratio (median)",
            "ratio (max)", "ratio of totals", "end to end wall s", "bare wall s",
            "ratio wall (median)"]  # fmt: skip
    body = []
    for s, rs in by_solver.items():
        body.append([
            s, len(rs), med([r["e2e_cpu"] for r in rs]), med([r["bare_cpu"] for r in rs]),
            med([r["ratio_cpu"] for r in rs]), max(r["ratio_cpu"] for r in rs),
            sum(r["e2e_cpu"] for r in rs) / sum(r["bare_cpu"] for r in rs),
            med([r["e2e_wall"] for r in rs]), med([r["bare_wall"] for r in rs]),
            med([r["ratio_wall"] for r in rs]),
        ])  # fmt: skip
    out += ["### End to end against the bare solve", "", common.table(head, body), ""]
    head = ["solver", *(f"{stage} CPU s" for stage in STAGES), "max end to end CPU s"]
    body = [
        [s, *(med([r[f"{stage}_cpu"] for r in rs]) for stage in STAGES),
         max(r["e2e_cpu"] for r in rs)]
        for s, rs in by_solver.items()
    ]  # fmt: skip
    out += ["### Median CPU seconds per stage", "", common.table(head, body), ""]
    rs = by_solver[solvers[0]]
    parts = (f"Of these, timed on their own (median CPU s): check and repair (`clean_mesh`) "
             f"{med([r['clean_mesh_cpu'] for r in rs]):.3g} of reading, Laplacian assembly "
             f"{med([r['laplacian_cpu'] for r in rs]):.3g} of the operators.")  # fmt: skip
    out += [parts, ""]
    bins: dict = defaultdict(list)
    for r in rows:
        bins[common.vertex_bin(r["vertices"]), r["solver"]].append(r)
    head = ["vertices", "solver", "meshes", "end to end CPU s", "bare solve CPU s", "ratio"]
    body = [
        [label, s, len(rs), med([r["e2e_cpu"] for r in rs]), med([r["bare_cpu"] for r in rs]),
         med([r["ratio_cpu"] for r in rs])]
        for ((_, label), s), rs in sorted(bins.items())
    ]  # fmt: skip
    out += ["### By vertex count (medians)", "", common.table(head, body), ""]
    errors = [r["curvature_error"] for r in by_solver[solvers[0]]]
    out += [f"Curvature error (paper section 3.4, units of pi): median {med(errors):.3g}, "
            f"max {max(errors):.3g}."]  # fmt: skip
    return "\n".join(out)


def main() -> None:
    """Parse the options, measure every mesh with every solver family, print the tables."""
    parser = common.arguments(__doc__.splitlines()[0])
    parser.add_argument("--solvers", nargs="+", default=["scipy", "eigen", "cholmod"])
    args = parser.parse_args()
    solvers = [s for s in args.solvers if s in available_solvers()]
    files, params = common.meshes(args), Params()
    for s in solvers:  # warm up: imports and first-call costs are not per-mesh costs
        measure(files[0], params, s)
    rows = [measure(path, params, s) for path in files for s in solvers]
    print(f"{len(files)} meshes from {args.data}, solvers {', '.join(solvers)}, one thread\n")
    print(report(rows, solvers))
    common.save_rows(args.json, rows)


if __name__ == "__main__":
    main()
