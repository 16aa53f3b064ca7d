"""The low Laplace-Beltrami spectrum and the heat kernel signature, from the conformal solve.

The generalised eigenproblem ``-L x = lambda M x`` (cotangent Laplacian L, lumped barycentric
mass matrix M) is solved for its smallest nonzero eigenvalues by Lanczos iteration on the
inverse operator, each step one solve with the Cholesky (or LU) factorisation that the conformal
factor's solve already made: no second factorisation is needed. With ``u = M^(1/2) x`` the
problem is the symmetric ``M^(-1/2) (-L) M^(-1/2) u = lambda u``, whose pseudo-inverse on the
complement of its null space (the square roots of the vertex areas, one vector per connected
component) has the eigenvalues ``1 / lambda``, largest first.
"""

from __future__ import annotations

import itertools
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np
import scipy.linalg
import scipy.sparse as sp
import scipy.sparse.linalg as spla

from .errors import SolverError

_TOLERANCE = 1e-8
_CHECK_TOLERANCE = 1e-3  # the quick search for a missed copy of a repeated eigenvalue
_CHECK_VECTORS = 8  # Lanczos vectors of that search
_DENSE_BELOW = 64  # vertices, and 3 per eigenpair: smaller problems are solved densely


@dataclass(frozen=True)
class Spectrum:
    """The smallest nonzero eigenpairs of a mesh's Laplace-Beltrami operator.

    Attributes
    ----------
    eigenvalues : (k,) float64
        Ascending, in 1 / squared length units; the constant functions (eigenvalue 0, one per
        connected component) are left out.
    eigenvectors : (n, k) float64
        M-orthonormal: ``eigenvectors.T @ (vertex_area[:, None] * eigenvectors)`` is the
        identity; in 1 / length units.
    vertex_area : (n,) float64
        The lumped mass matrix's diagonal, squared length units.
    labels : (n,) int
        Connected component of each vertex.
    """

    eigenvalues: np.ndarray
    eigenvectors: np.ndarray
    vertex_area: np.ndarray
    labels: np.ndarray

    @property
    def area(self) -> float:
        """Total surface area."""
        return float(self.vertex_area.sum())


def laplace_spectrum(
    laplacian: sp.spmatrix,
    vertex_area: np.ndarray,
    labels: np.ndarray,
    solve: Callable[[np.ndarray], np.ndarray],
    count: int,
) -> Spectrum:
    """The ``count`` smallest nonzero eigenpairs of ``-L x = lambda M x``.

    Parameters
    ----------
    laplacian : (n, n) sparse float64
        Cotangent Laplacian, negative semidefinite (`geometry.cotan_laplacian`).
    vertex_area : (n,) float64
        Diagonal of the lumped mass matrix M, positive.
    labels : (n,) int
        Connected component of each vertex, numbered from 0.
    solve : callable
        ``solve(b)`` returns an ``x`` with ``L x = b``, up to a constant per component, for
        any ``b`` that sums to zero on every component (`conformal.laplacian_solver`, or
        `conformal.factorize_laplacian`); used for large meshes only.
    count : int
        Number of eigenpairs k wanted. A mesh with fewer nonzero eigenvalues gets all it has.

    Returns
    -------
    spectrum : Spectrum

    Raises
    ------
    SolverError
        The Lanczos iteration did not converge or gave non-positive eigenvalues.
    """
    n = len(vertex_area)
    n_components = int(labels.max()) + 1
    count = min(count, n - n_components)
    root = np.sqrt(vertex_area)
    null = np.zeros((n, n_components))
    null[np.arange(n), labels] = root
    null /= np.linalg.norm(null, axis=0)
    if n < max(_DENSE_BELOW, 3 * count):
        values, vectors = _dense_eigenpairs(laplacian, root, null, count)
    else:
        values, vectors = _lanczos_eigenpairs(root, null, solve, count)
    if not np.all(np.isfinite(values)) or (len(values) and values[0] <= 0):
        raise SolverError("the Laplace-Beltrami eigenvalues are not finite and positive")
    return Spectrum(values, vectors / root[:, None], vertex_area, labels)


def _project(basis: np.ndarray, u: np.ndarray) -> np.ndarray:
    """Remove the span of the orthonormal columns of ``basis`` from ``u``."""
    # np.dot, unlike @, multiplies by a single column (one component) through BLAS: the
    # Lanczos iteration projects about 300 times per mesh
    return u - np.dot(basis, np.dot(u, basis))


def _lanczos_eigenpairs(
    root: np.ndarray, null: np.ndarray, solve: Callable[[np.ndarray], np.ndarray], count: int
) -> tuple[np.ndarray, np.ndarray]:
    """Smallest nonzero eigenpairs in ``u`` coordinates by ARPACK on the inverse operator.

    Lanczos from one start vector can miss copies of a repeated eigenvalue (a symmetric mesh,
    equal components). So a quick, loose search for the largest eigenvalue with the
    eigenvectors found so far deflated follows; only if it finds one that belongs among the
    ``count`` smallest is an accurate search run and merged, and the check repeated. Each
    search starts from a new pseudo-random vector: the first one has no component along a
    copy that its own Krylov space missed.
    """
    inverted, vectors = _largest_inverse(root, null, solve, count, _TOLERANCE, seed=0)
    for seed in itertools.count(1):
        known = np.hstack([null, vectors])
        if len(root) - known.shape[1] < _CHECK_VECTORS + 1:
            break
        probe, _ = _largest_inverse(
            root, known, solve, 1, _CHECK_TOLERANCE, seed, vectors=_CHECK_VECTORS
        )
        if probe[0] <= inverted[-1] * (1 + _CHECK_TOLERANCE):
            break
        extra = min(count, len(root) - known.shape[1] - 1)
        more, more_vectors = _largest_inverse(root, known, solve, extra, _TOLERANCE, seed)
        order = np.argsort(-np.concatenate([inverted, more]), kind="stable")[:count]
        inverted = np.concatenate([inverted, more])[order]
        vectors = np.hstack([vectors, more_vectors])[:, order]
    with np.errstate(divide="ignore"):
        return 1.0 / inverted, vectors


def _largest_inverse(
    root: np.ndarray,
    deflated: np.ndarray,
    solve: Callable[[np.ndarray], np.ndarray],
    count: int,
    tolerance: float,
    seed: int,
    vectors: int | None = None,
) -> tuple[np.ndarray, np.ndarray]:
    """Largest eigenpairs of the inverse operator off the span of ``deflated``, descending."""
    n = len(root)

    def inverse(u: np.ndarray) -> np.ndarray:
        # -L z = M^(1/2) Q u, then Q M^(1/2) z: symmetric, independent of z's constant
        z = solve(-root * _project(deflated, u))
        return _project(deflated, root * z)

    operator = spla.LinearOperator((n, n), matvec=inverse, dtype=np.float64)
    start = _project(deflated, np.random.default_rng(seed).random(n))
    try:
        values, found = spla.eigsh(
            operator, k=count, which="LA", v0=start, tol=tolerance, ncv=vectors
        )
    except (RuntimeError, ValueError, ArithmeticError) as exc:  # ARPACK's, or a solve's
        raise SolverError(f"Laplace-Beltrami eigenvalues: {exc}") from None
    order = np.argsort(-values, kind="stable")
    return values[order], found[:, order]


def _dense_eigenpairs(
    laplacian: sp.spmatrix, root: np.ndarray, null: np.ndarray, count: int
) -> tuple[np.ndarray, np.ndarray]:
    """Smallest nonzero eigenpairs in ``u`` coordinates by a dense solve (small meshes)."""
    a = -laplacian.toarray() / np.outer(root, root)
    # shifting the null space to the top of the spectrum leaves the others in ascending order
    shift = 2 * np.abs(a).sum(axis=1).max() + 1
    values, vectors = scipy.linalg.eigh(a + shift * null @ null.T, subset_by_index=(0, count - 1))
    return values, vectors


def heat_kernel_signature(spectrum: Spectrum, times: np.ndarray) -> np.ndarray:
    """The heat kernel signature of Sun, Ovsjanikov and Guibas (2009), truncated to k terms.

    ``h_t(x) = sum_i exp(-lambda_i t) phi_i(x)^2`` over the eigenpairs, including the constant
    eigenfunction of each component (``1 / area of the component``); the sum over the spectrum
    is cut at the k eigenpairs of ``spectrum``, accurate for ``t`` well above ``1 / lambda_k``.

    Parameters
    ----------
    spectrum : Spectrum
        Eigenpairs.
    times : (T,) float64
        Diffusion times, in squared length units.

    Returns
    -------
    hks : (n, T) float64
        Heat kernel signature per vertex and time, in 1 / squared length units.
    """
    component_area = np.bincount(spectrum.labels, weights=spectrum.vertex_area)
    constant = 1.0 / component_area[spectrum.labels]
    decay = np.exp(-np.outer(spectrum.eigenvalues, times))
    return constant[:, None] + (spectrum.eigenvectors**2) @ decay
