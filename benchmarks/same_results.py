"""Check that two versions of cfsig give the same results bit for bit on a data set.

``dump`` writes, for every mesh and solver family, phi, the signature vector and the curvature
error, and per mesh the checked vertices and faces, the Laplacian (its CSC arrays), the
curvature and the vector of each ``cfhks`` version of ``--cfhks``, to an ``.npz`` file; run it
once per version of cfsig (each with its own ``PYTHONPATH``).
``compare`` prints, per quantity, whether the two dumps are identical, and for one that is not
its largest difference relative to its range over a mesh (phi's always).

    python benchmarks/same_results.py dump OUT.npz [--every K] [--solvers cholmod scipy]
        [--cfhks 1 2 3 4]
    python benchmarks/same_results.py compare A.npz B.npz
"""

from __future__ import annotations

import os

# One BLAS/OpenMP thread, set before NumPy loads its libraries.
os.environ.update(
    dict.fromkeys(["OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS"], "1")
)

import argparse
from pathlib import Path

import common
import numpy as np

from cfsig.descriptors.signature import mesh_and_signature
from cfsig.operators.conformal import available_solvers, operators
from cfsig.params import Params


def dump(args: argparse.Namespace) -> None:
    """Compute and write every result of every mesh."""
    solvers = [s for s in args.solvers if s in available_solvers()]
    out: dict[str, np.ndarray] = {}
    for path in common.meshes(args):
        key = f"{path.parent.name}_{path.stem}"
        for solver in solvers:
            mesh, sig = mesh_and_signature(path, Params(), solver)
            out[f"{key}/{solver}/phi"] = sig.phi
            # this script compares versions: before issue 13 the vector was named `histogram`
            vector = sig.vector if hasattr(sig, "vector") else sig.histogram
            out[f"{key}/{solver}/vector"] = vector
            out[f"{key}/{solver}/curvature_error"] = np.array(sig.curvature_error)
        ops = operators(mesh)
        lap = ops.laplacian
        out[f"{key}/vertices"], out[f"{key}/faces"] = mesh.vertices, mesh.faces
        out[f"{key}/laplacian"] = np.concatenate([lap.indptr, lap.indices]).astype(float)
        out[f"{key}/laplacian_data"], out[f"{key}/curvature"] = lap.data, ops.curvature
        for version in args.cfhks:
            params = Params(descriptor="cfhks", version=version)
            out[f"{key}/cfhks {version}"] = mesh_and_signature(path, params)[1].vector
    np.savez(args.out, **out)
    print(f"{len(out)} arrays written to {args.out}")


def compare(args: argparse.Namespace) -> None:
    """Print, per quantity, whether two dumps agree bit for bit, and how far they differ."""
    a, b = np.load(args.a), np.load(args.b)
    if set(a.files) != set(b.files):
        raise SystemExit("the dumps hold different meshes or solvers")
    identical: dict[str, bool] = {}
    change: dict[str, float] = {}
    for name in sorted(a.files):
        quantity = name.split("/", 1)[1]
        x, y = a[name], b[name]
        same = x.shape == y.shape and np.array_equal(x, y)
        identical[quantity] = identical.get(quantity, True) and same
        if x.shape == y.shape and x.size and (quantity.endswith("phi") or not same):
            relative = float(np.abs(x - y).max() / max(np.ptp(x), np.finfo(float).tiny))
            change[quantity] = max(change.get(quantity, 0.0), relative)
    for quantity, same in identical.items():
        extra = f", max |difference| / range {change[quantity]:.3g}" if quantity in change else ""
        print(f"{quantity}: {'identical' if same else 'DIFFERENT'}{extra}")


def main() -> None:
    """Parse the command and run it."""
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    commands = parser.add_subparsers(dest="command", required=True)
    run = commands.add_parser("dump", help="compute and write the results")
    run.add_argument("out", type=Path)
    common.data_arguments(run)
    run.add_argument("--solvers", nargs="+", default=["cholmod", "scipy"])
    run.add_argument("--cfhks", nargs="*", type=int, default=[], help="cfhks versions to dump")
    check = commands.add_parser("compare", help="compare two dumps")
    check.add_argument("a", type=Path)
    check.add_argument("b", type=Path)
    args = parser.parse_args()
    dump(args) if args.command == "dump" else compare(args)


if __name__ == "__main__":
    main()
