"""Sparse solvers for the pinned system -L' x = b, side by side on the same meshes.

For every mesh: the pinned cotangent-Laplacian system of cfsig, then each method's
factorisation (or preconditioner set-up) and solve, timed in CPU seconds with one BLAS/OpenMP
thread, and its relative residual ||A x - b|| / ||b||. Methods whose package is missing are
left out. Prints a Markdown table of medians and the ratio to SciPy's SuperLU with COLAMD (what
``scipy.sparse.linalg.spsolve`` does).

    python benchmarks/solvers.py [--every K] [--json out.json]
"""

from __future__ import annotations

import os

# One BLAS/OpenMP thread, set before NumPy loads its libraries.
os.environ.update(
    dict.fromkeys(["OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS"], "1")
)

import multiprocessing
import subprocess
import sys
from collections.abc import Callable
from concurrent.futures import ProcessPoolExecutor
from pathlib import Path

import common
import numpy as np
import scipy.sparse as sp
import scipy.sparse.linalg as spla

from cfsig.files.mesh import read_mesh
from cfsig.operators.conformal import factorize, operators, pinned_system
from cfsig.params import Params

Solve = Callable[[sp.csc_matrix, np.ndarray], np.ndarray]
BASELINE = "SuperLU COLAMD"


def superlu(permc_spec: str, **options: object) -> Solve:
    """SciPy's SuperLU with a column ordering and options."""

    def solve(a: sp.csc_matrix, b: np.ndarray) -> np.ndarray:
        return spla.splu(a, permc_spec=permc_spec, **options).solve(b)

    return solve


def amg_cg(a: sp.csc_matrix, b: np.ndarray) -> np.ndarray:
    """Conjugate gradients preconditioned by pyamg's smoothed aggregation, rtol 1e-10."""
    import pyamg

    ml = pyamg.smoothed_aggregation_solver(a.tocsr(), symmetry="symmetric")
    return ml.solve(b, tol=1e-10, accel="cg", maxiter=200)


def cholmod(a: sp.csc_matrix, b: np.ndarray) -> np.ndarray:
    """CHOLMOD through sksparse-minimal (simplicial/supernodal chosen by CHOLMOD)."""
    from sksparse_minimal import SparseCholesky

    return SparseCholesky(a).solve_A(b)


def eigen(a: sp.csc_matrix, b: np.ndarray) -> np.ndarray:
    """Eigen's simplicial Cholesky with AMD ordering, through libigl (cfsig's "eigen")."""
    return factorize(a, "eigen")(b)


def cholespy_solve(a: sp.csc_matrix, b: np.ndarray) -> np.ndarray:
    """CHOLMOD through cholespy."""
    from cholespy import CholeskySolverD, MatrixType

    # Given CSC arrays, cholespy 2.2 reallocs NumPy's own buffers and crashes: pass COO.
    coo = a.tocoo()
    rows, cols = coo.row.astype(np.int32), coo.col.astype(np.int32)
    solver = CholeskySolverD(a.shape[0], rows, cols, coo.data, MatrixType.COO)
    x = np.empty_like(b)
    solver.solve(np.ascontiguousarray(b), x)
    return x


# name: (module it needs, solve). cholespy and sksparse-minimal both register a nanobind type
# named CholeskySolverD, so cholespy runs in a child process of its own (see ISOLATED).
METHODS: dict[str, tuple[str | None, Solve]] = {
    BASELINE: (None, superlu("COLAMD")),
    "SuperLU MMD_AT_PLUS_A symmetric": (
        None, superlu("MMD_AT_PLUS_A", options={"SymmetricMode": True})
    ),
    "SuperLU MMD_AT_PLUS_A symmetric, no pivoting": (
        None, superlu("MMD_AT_PLUS_A", diag_pivot_thresh=0.0, options={"SymmetricMode": True})
    ),
    "pyamg SA + CG": ("pyamg", amg_cg),
    "Eigen simplicial Cholesky AMD (libigl)": ("igl", eigen),
    "CHOLMOD (sksparse-minimal)": ("sksparse_minimal", cholmod),
    "CHOLMOD (cholespy)": ("cholespy", cholespy_solve),
}  # fmt: skip
ISOLATED = {"CHOLMOD (cholespy)"}


def installed(module: str | None, isolated: bool = False) -> bool:
    """Whether a method's package can be imported (in a fresh interpreter if ``isolated``)."""
    if module is None:
        return True
    if isolated:
        check = [sys.executable, "-c", f"import {module}"]
        return subprocess.run(check, capture_output=True).returncode == 0
    try:
        __import__(module)
    except ImportError:
        return False
    return True


def timed_solve(name: str, a: sp.csc_matrix, b: np.ndarray) -> tuple[float, float]:
    """CPU seconds and relative residual of one method on one system."""
    x, seconds, _ = common.timed(lambda: METHODS[name][1](a, b))
    return seconds, float(np.linalg.norm(a @ x - b) / np.linalg.norm(b))


def measure(path: Path, names: list[str], child: ProcessPoolExecutor) -> dict:
    """CPU seconds and relative residual of every method on one mesh's pinned system."""
    ops = operators(read_mesh(path), Params().mollify)
    a, keep = pinned_system(ops.laplacian, ops.labels)
    b = (ops.curvature - ops.target)[keep]
    row: dict = {"mesh": f"{path.parent.name}/{path.name}", "unknowns": a.shape[0]}
    for name in names:
        if name in ISOLATED:
            result = child.submit(timed_solve, name, a, b).result()
        else:
            result = timed_solve(name, a, b)
        row[name], row[f"{name} residual"] = result
    return row


def main() -> None:
    """Parse the options, time every installed method on every mesh, print the table."""
    args = common.arguments(__doc__.splitlines()[0]).parse_args()
    isolated = [name for name in ISOLATED if installed(METHODS[name][0], isolated=True)]
    names = [
        n for n, (m, _) in METHODS.items() if n in isolated or (n not in ISOLATED and installed(m))
    ]
    files = common.meshes(args)
    with ProcessPoolExecutor(1, mp_context=multiprocessing.get_context("spawn")) as child:
        measure(files[0], names, child)  # warm up imports
        rows = [measure(path, names, child) for path in files]
    med = common.median
    body = [
        [name, med([r[name] for r in rows]),
         med([r[BASELINE] / r[name] for r in rows]), sum(r[name] for r in rows),
         max(r[name] for r in rows), max(r[f"{name} residual"] for r in rows)]
        for name in names
    ]  # fmt: skip
    head = ["method", "median CPU s", f"speed-up over {BASELINE} (median)", "total CPU s",
            "max CPU s", "max relative residual"]  # fmt: skip
    print(f"{len(files)} meshes from {args.data}, median {med([r['unknowns'] for r in rows])} "
          f"unknowns, one thread\n")  # fmt: skip
    print(common.table(head, body))
    big = [r for r in rows if r["unknowns"] >= 20_000]
    if big:
        print(f"\nMeshes with 20k unknowns or more ({len(big)}), median CPU s:\n")
        print(common.table(["method", "median CPU s"],
                           [[name, med([r[name] for r in big])] for name in names]))  # fmt: skip
    common.save_rows(args.json, rows)


if __name__ == "__main__":
    main()
