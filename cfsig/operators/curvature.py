"""Gaussian curvature at several scales: the angle defect smoothed by heat diffusion.

The angle defect (paper section 2.2) is the curvature of each vertex, concentrated there. One
implicit step of the heat equation, ``(M + tau (-L)) u = K``, spreads it over a neighbourhood
whose radius grows like ``sqrt(tau)`` and keeps its integral (``sum(M u) = sum(K)``, since the
Laplacian's rows sum to zero), so ``u`` is a curvature density at the scale ``tau``. With
``tau = s * area`` and the density multiplied by the area, the result is dimensionless and
invariant to scale, rigid motion and (as far as the mesh's curvature is) isometric bending.

Unlike the spectrum it needs no eigenproblem. Each scale's system is solved by conjugate
gradients with a diagonal preconditioner, started from the previous scale's solution: ``M +
tau (-L)`` is well conditioned at scales near the mesh's resolution, so this costs a fraction
of a sparse factorisation (docs/method.md, "How it is computed"); a system it does not solve
within `CG_ITERATIONS` is factorised instead.
"""

from __future__ import annotations

import numpy as np
import scipy.sparse as sp

from cfsig.errors import SolverError
from cfsig.operators.conformal import Operators, factorize

# Relative residual at which the conjugate gradients stop: the loosest power of ten at which the
# histograms of the intrinsic descriptor move, on average over SHREC 2007's and FAUST's meshes,
# by at most 5% of the median distance between two meshes' histograms (docs/method.md).
CG_TOLERANCE = 1e-3
# About as many iterations as a factorisation costs: a system that needs more is factorised, and
# so is every larger scale's, worse conditioned.
CG_ITERATIONS = 150


def smoothed_curvature(
    ops: Operators,
    scales: tuple[float, ...],
    tolerance: float = CG_TOLERANCE,
) -> np.ndarray:
    """The area times the curvature density after diffusing the angle defect, per scale.

    Parameters
    ----------
    ops : Operators
        The mesh's operators (`cfsig.operators.conformal.operators`): its angle defects, boundary,
        vertex areas and cotangent Laplacian.
    scales : tuple of float
        Diffusion times divided by the surface area (dimensionless); ``sqrt(s)`` is about the
        smoothing radius relative to ``sqrt(area)``.
    tolerance : float
        Relative residual at which the conjugate gradients stop. A scale is factorised at once,
        without trying them, when the previous scale took more than half of `CG_ITERATIONS`:
        a scale at most four times the previous at most doubles the condition number's square
        root, and so about the iterations.

    Returns
    -------
    curvature : (n, len(scales)) float64
        ``area * u`` per vertex and scale, dimensionless: ``4 pi`` everywhere on a round sphere.
        A boundary vertex's defect is its boundary's turning, not curvature, and counts as 0.

    Raises
    ------
    SolverError
        A factorisation or solve failed or gave non-finite values.
    """
    area = float(ops.vertex_area.sum())
    defect = np.where(ops.boundary, 0.0, ops.curvature)
    mass, stiffness = sp.diags(ops.vertex_area, format="csr"), sp.csr_matrix(-ops.laplacian)
    out = np.empty((len(defect), len(scales)))
    guess = defect / ops.vertex_area  # the limit of a vanishing scale
    hard = np.inf  # the smallest scale left to the factorisation
    for j, scale in enumerate(scales):
        system = mass + (scale * area) * stiffness
        solved, iterations = None, CG_ITERATIONS
        if scale < hard:
            solved, iterations = _conjugate_gradients(system, defect, guess, tolerance)
        if solved is None:
            hard = min(hard, scale)
            solved = _factorised(system, defect)
        elif 2 * iterations > CG_ITERATIONS and j + 1 < len(scales):
            hard = min(hard, scales[j + 1])
        guess = out[:, j] = solved
    out *= area
    if not np.all(np.isfinite(out)):
        raise SolverError("curvature diffusion gave non-finite values")
    return out


def _conjugate_gradients(
    system: sp.csr_matrix, rhs: np.ndarray, guess: np.ndarray, tolerance: float
) -> tuple[np.ndarray | None, int]:
    """Solve ``system u = rhs`` by diagonally preconditioned conjugate gradients to a relative
    residual of ``tolerance``: the solution, or None when they do not converge within
    `CG_ITERATIONS`, and the iterations made.

    The iteration of `scipy.sparse.linalg.cg`, step for step (the same values), written out
    without its operator wrappers, which weigh on systems of a few thousand vertices.
    """
    norm = np.linalg.norm(rhs)
    if norm == 0:
        return np.zeros_like(rhs), 0
    inverse = 1.0 / system.diagonal()
    u = guess.copy()
    residual = rhs - system @ u
    direction, previous = np.empty_like(rhs), 1.0
    for iteration in range(CG_ITERATIONS):
        if np.linalg.norm(residual) < tolerance * norm:
            return u, iteration
        preconditioned = inverse * residual
        current = np.dot(residual, preconditioned)
        if iteration:
            direction *= current / previous
            direction += preconditioned
        else:
            direction[:] = preconditioned
        image = system @ direction
        step = current / np.dot(direction, image)
        u += step * direction
        residual -= step * image
        previous = current
    return None, CG_ITERATIONS


def _factorised(system: sp.csr_matrix, rhs: np.ndarray) -> np.ndarray:
    """Solve ``system u = rhs`` by a sparse factorisation, the best installed backend."""
    try:
        return factorize(system.tocsc(), "auto")(rhs)
    except (RuntimeError, ValueError, ArithmeticError) as exc:
        raise SolverError(f"curvature diffusion failed: {exc}") from None
