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
import math
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np
import scipy.linalg
import scipy.sparse as sp

from cfsig.errors import SolverError

_TOLERANCE = 1e-8
_CHECK_TOLERANCE = 1e-3  # the quick search for a missed copy of a repeated eigenvalue
_BREAKDOWN = 1e-10  # a step this small against the largest diagonal entry: an invariant space
# The Lanczos iteration's cap, steps per eigenpair and more: about three times the most seen
# on the shared collections (docs/method.md, "How it is computed")
_STEPS_PER_PAIR, _STEPS_MORE = 10, 200
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
        A solve of the Lanczos iteration gave non-finite values, or the eigenvalues are not
        finite and positive.
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
    """Smallest nonzero eigenpairs in ``u`` coordinates by Lanczos iteration on the inverse
    operator.

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
        if len(root) == known.shape[1]:
            break
        probe, _ = _largest_inverse(root, known, solve, 1, _CHECK_TOLERANCE, seed)
        if probe[0] <= inverted[-1] * (1 + _CHECK_TOLERANCE):
            break
        if seed > count:  # each round finds a missed copy: more rounds mean a broken operator
            raise SolverError("the search for repeated eigenvalues did not settle")
        extra = min(count, len(root) - known.shape[1])
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
) -> tuple[np.ndarray, np.ndarray]:
    """Largest eigenpairs of the inverse operator off the span of ``deflated``, descending."""
    rng = np.random.default_rng(seed)

    def inverse(u: np.ndarray) -> np.ndarray:
        # -L z = M^(1/2) Q u, then Q M^(1/2) z: symmetric, independent of z's constant
        z = solve(-root * _project(deflated, u))
        return _project(deflated, root * z)

    def fresh() -> np.ndarray:
        return _project(deflated, rng.random(len(root)))

    return lanczos(inverse, fresh, len(root) - deflated.shape[1], count, tolerance)


def lanczos(
    apply: Callable[[np.ndarray], np.ndarray],
    fresh: Callable[[], np.ndarray],
    dimension: int,
    count: int,
    tolerance: float,
) -> tuple[np.ndarray, np.ndarray]:
    """The largest eigenpairs of a symmetric operator by Lanczos iteration with full
    reorthogonalisation.

    The Krylov basis grows one vector per application of the operator and is kept orthonormal
    against all its vectors, without restarts: for a few dozen eigenpairs of a mesh's inverse
    Laplacian this costs about as many applications as ARPACK's implicitly restarted
    iteration, without ARPACK's own work between them (docs/method.md, "How it is computed").
    The Ritz pairs of the tridiagonal projection are checked when their residuals, falling
    geometrically, are predicted to have converged.

    One Krylov space holds one copy of each repeated eigenvalue. A space that becomes invariant
    is continued from a new start vector orthogonal to it, which finds the copies it could not
    hold; a copy missed by a space that converged first is the caller's to look for
    (`laplace_spectrum` does).

    Parameters
    ----------
    apply : callable
        ``apply(u)`` returns the operator times ``u``, a (n,) float64 vector of the operator's
        space; the operator is symmetric on that space.
    fresh : callable
        ``fresh()`` returns a new pseudo-random (n,) float64 vector of that space: the start,
        and a restart when the Krylov space becomes invariant.
    dimension : int
        Dimension of the space, at least ``count``.
    count : int
        Number of eigenpairs, at least 1.
    tolerance : float
        Relative residual at which a Ritz pair has converged:
        ``|apply(x) - theta x| <= tolerance * |theta|``, as ARPACK's ``tol``.

    Returns
    -------
    values : (count,) float64
        Largest eigenvalues, descending.
    vectors : (n, count) float64
        Orthonormal eigenvectors.

    Raises
    ------
    SolverError
        The operator gave a non-finite vector or a zero or non-finite Ritz value, or the Ritz
        pairs did not converge within
        ``_STEPS_PER_PAIR * count + _STEPS_MORE`` steps (which bounds the basis's memory).
    """
    cap = min(dimension, _STEPS_PER_PAIR * count + _STEPS_MORE)
    start = fresh()
    basis = np.empty((min(cap, 3 * count + 20), len(start)))  # rows: contiguous vectors
    alpha, beta = np.empty(cap), np.zeros(cap)
    basis[0] = start / math.sqrt(np.dot(start, start))
    check, last, largest = min(cap, count + max(10, count // 2)), None, 0.0
    j = 0
    while True:  # the check at the cap returns or raises
        v = basis[j]
        w = apply(v)
        alpha[j] = a = np.dot(v, w)
        largest = max(largest, abs(a))
        w -= a * v
        if j:
            w -= beta[j - 1] * basis[j - 1]
        w -= np.dot(np.dot(basis[: j + 1], w), basis[: j + 1])
        beta[j] = b = math.sqrt(np.dot(w, w))
        if not math.isfinite(b):
            raise SolverError("the Lanczos iteration's solve returned a non-finite vector")
        steps = j + 1
        invariant = b <= _BREAKDOWN * largest
        if steps == check or invariant:
            theta, s = scipy.linalg.eigh_tridiagonal(alpha[:steps], beta[: steps - 1])
            theta, s = theta[::-1][:count], s[:, ::-1][:, :count]
            with np.errstate(divide="ignore", invalid="ignore"):
                ratio = (b * np.abs(s[-1]) / (tolerance * np.abs(theta))).max()
            if not np.isfinite(ratio):  # a zero or non-finite Ritz value: a singular operator
                raise SolverError("the Lanczos iteration met a zero or non-finite eigenvalue")
            if steps == dimension or (len(theta) == count and ratio <= 1 and not invariant):
                return theta, np.dot(basis[:steps].T, s)
            if steps == cap:
                raise SolverError(f"the Lanczos iteration did not converge in {cap} steps")
            check = min(cap, steps + _next_check(last, steps, ratio))
            last = steps, ratio
        if steps == len(basis):
            basis = np.vstack([basis, np.empty((min(cap, 2 * steps) - steps, len(v)))])
        if invariant:  # start a new Krylov space orthogonal to this one
            w = fresh()
            for _ in range(2):
                w -= np.dot(np.dot(basis[:steps], w), basis[:steps])
            beta[j], b = 0.0, math.sqrt(np.dot(w, w))
        np.multiply(w, 1.0 / b, out=basis[steps])
        j = steps


def _next_check(last: tuple[int, float] | None, steps: int, ratio: float) -> int:
    """Steps until the residual ratio is predicted to reach 1, from its geometric fall since
    the last check; 10 after the first check."""
    if last is None or not 0 < ratio < last[1]:
        return 10
    rate = np.log(last[1] / ratio) / (steps - last[0])
    return int(np.clip(np.ceil(np.log(ratio) / rate), 2, 30))


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
