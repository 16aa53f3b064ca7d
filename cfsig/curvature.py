"""Gaussian curvature at several scales: the angle defect smoothed by heat diffusion.

The angle defect (paper section 2.2) is the curvature of each vertex, concentrated there. One
implicit step of the heat equation, ``(M + tau (-L)) u = K``, spreads it over a neighbourhood
whose radius grows like ``sqrt(tau)`` and keeps its integral (``sum(M u) = sum(K)``, since the
Laplacian's rows sum to zero), so ``u`` is a curvature density at the scale ``tau``. With
``tau = s * area`` and the density multiplied by the area, the result is dimensionless and
invariant to scale, rigid motion and (as far as the mesh's curvature is) isometric bending.

Unlike the spectrum it needs no eigenproblem: one sparse Cholesky factorisation per scale.
"""

from __future__ import annotations

import numpy as np
import scipy.sparse as sp

from .conformal import Operators, factorize
from .errors import SolverError


def smoothed_curvature(ops: Operators, scales: tuple[float, ...]) -> np.ndarray:
    """The area times the curvature density after diffusing the angle defect, per scale.

    Parameters
    ----------
    ops : Operators
        The mesh's operators (`cfsig.conformal.operators`): its angle defects, boundary,
        vertex areas and cotangent Laplacian.
    scales : tuple of float
        Diffusion times divided by the surface area (dimensionless); ``sqrt(s)`` is about the
        smoothing radius relative to ``sqrt(area)``.

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
    mass = sp.diags(ops.vertex_area)
    out = np.empty((len(defect), len(scales)))
    for j, scale in enumerate(scales):
        system = sp.csc_matrix(mass - (scale * area) * ops.laplacian)
        try:
            out[:, j] = factorize(system, "auto")(defect)
        except (RuntimeError, ValueError, ArithmeticError) as exc:
            raise SolverError(f"curvature diffusion failed: {exc}") from None
    out *= area
    if not np.all(np.isfinite(out)):
        raise SolverError("curvature diffusion gave non-finite values")
    return out
