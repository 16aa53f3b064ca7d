import numpy as np
import pytest
import scipy.linalg

from cfsig.files.mesh import clean_mesh
from cfsig.operators.conformal import conformal_factor
from cfsig.operators.spectrum import heat_kernel_signature, lanczos, laplace_spectrum
from tests.helpers import icosphere, random_rotation, torus


def _spectrum(v, f, count):
    cf = conformal_factor(clean_mesh(v, f))
    return cf, laplace_spectrum(
        cf.operators.laplacian, cf.operators.vertex_area, cf.operators.labels, cf.solve, count
    )


def test_sphere_eigenvalues_are_analytic():
    # on a sphere of radius r the eigenvalues are l (l + 1) / r^2, with multiplicity 2 l + 1
    r = 2.0
    v, f = icosphere(3)
    _, s = _spectrum(r * v, f, 15)
    expected = np.repeat([2.0, 6.0, 12.0], [3, 5, 7]) / r**2
    assert np.allclose(s.eigenvalues, expected, rtol=0.02)


@pytest.mark.parametrize("count", [3, 8])
def test_repeated_eigenvalues_are_all_found(count):
    # a single Lanczos run finds only two of the three l = 1 copies here: the check must add them
    v, f = icosphere(2)
    _, s = _spectrum(v, f, count)
    assert np.allclose(s.eigenvalues, np.repeat([2.0, 5.864], [3, 5])[:count], rtol=1e-3)


def test_matches_dense_generalised_problem():
    v, f = torus(nu=24, nv=10)
    cf, s = _spectrum(v, f, 12)
    reference = scipy.linalg.eigh(
        -cf.operators.laplacian.toarray(), np.diag(cf.operators.vertex_area)
    )[0]
    assert np.allclose(s.eigenvalues, reference[1:13], rtol=1e-6)
    vectors = s.eigenvectors
    assert np.allclose(
        vectors.T @ (cf.operators.vertex_area[:, None] * vectors), np.eye(12), atol=1e-8
    )
    residual = (
        -cf.operators.laplacian @ vectors
        - cf.operators.vertex_area[:, None] * vectors * s.eigenvalues
    )
    assert np.abs(residual).max() < 1e-6 * np.abs(cf.operators.laplacian @ vectors).max()


def test_small_mesh_solved_densely_gives_all_it_has():
    v, f = icosphere(0)  # 12 vertices: 11 nonzero eigenvalues
    cf, s = _spectrum(v, f, 20)
    reference = scipy.linalg.eigh(
        -cf.operators.laplacian.toarray(), np.diag(cf.operators.vertex_area)
    )[0]
    assert len(s.eigenvalues) == 11
    assert np.allclose(s.eigenvalues, reference[1:], rtol=1e-8)


def test_components_leave_out_every_constant():
    v, f = icosphere(2)
    both = clean_mesh(np.vstack([v, v + 5]), np.vstack([f, f + len(v)]))
    cf = conformal_factor(both)
    s = laplace_spectrum(
        cf.operators.laplacian, cf.operators.vertex_area, cf.operators.labels, cf.solve, 6
    )
    _, alone = _spectrum(v, f, 3)
    # two equal spheres: each eigenvalue twice, no zero eigenvalue of the second component
    assert np.allclose(s.eigenvalues, np.repeat(alone.eigenvalues, 2), rtol=1e-6)


def test_invariant_to_rigid_motion_and_scaled_by_size():
    v, f = torus(nu=30, nv=12)
    _, base = _spectrum(v, f, 10)
    _, moved = _spectrum(3.0 * v @ random_rotation(4).T + [1.0, 2.0, -3.0], f, 10)
    assert np.allclose(moved.eigenvalues, base.eigenvalues / 9.0, rtol=1e-7)
    assert np.isclose(moved.area, 9.0 * base.area)


def test_heat_kernel_signature_of_a_sphere():
    v, f = icosphere(3)
    _, s = _spectrum(v, f, 15)  # l = 1, 2, 3 complete
    t = np.array([0.5, 2.0])
    hks = heat_kernel_signature(s, t)
    ls = np.arange(4)
    expected = ((2 * ls + 1)[:, None] * np.exp(-np.outer(ls * (ls + 1), t))).sum(0) / s.area
    assert np.allclose(hks, expected, rtol=0.01)
    assert np.all(hks.std(axis=0) < 1e-3 * hks.mean(axis=0))


@pytest.mark.parametrize("count", [1, 5])
def test_deterministic(count):
    v, f = torus(nu=30, nv=12)
    _, a = _spectrum(v, f, count)
    _, b = _spectrum(v, f, count)
    assert np.array_equal(a.eigenvalues, b.eigenvalues)
    assert np.array_equal(a.eigenvectors, b.eigenvectors)


def test_a_solve_gone_non_finite_ends_in_a_solver_error():
    # the Lanczos iteration's solves are unchecked (conformal.laplacian_solver): a factorisation
    # whose solutions turn non-finite must still end the iteration with an error, not values
    from cfsig.errors import SolverError

    cf, _ = _spectrum(*icosphere(3), 3)
    ops, calls = cf.operators, []

    def failing(rhs):
        calls.append(None)
        x = cf.solve(rhs)
        x[3] = np.nan if len(calls) > 5 else x[3]
        return x

    with pytest.raises(SolverError):
        laplace_spectrum(ops.laplacian, ops.vertex_area, ops.labels, failing, 45)


def _operator(values, seed=0):
    """A symmetric matrix with the given eigenvalues and random eigenvectors, and its fresh
    pseudo-random vectors."""
    rng = np.random.default_rng(seed)
    basis = np.linalg.qr(rng.standard_normal((len(values), len(values))))[0]
    matrix = (basis * values) @ basis.T
    return (lambda u: matrix @ u), (lambda: rng.random(len(values)))


def test_lanczos_matches_a_dense_solve():
    values = 1.0 / np.arange(1.0, 301.0)  # as the inverse Laplacian's: slowly separating
    apply, fresh = _operator(values)
    found, vectors = lanczos(apply, fresh, len(values), 20, 1e-8)
    assert np.allclose(found, values[:20], rtol=1e-12)
    assert np.allclose(vectors.T @ vectors, np.eye(20), atol=1e-10)
    residual = np.column_stack([apply(x) for x in vectors.T]) - vectors * found
    assert np.linalg.norm(residual, axis=0).max() <= 1e-8 * found.max()


def test_lanczos_restarts_when_the_krylov_space_is_invariant():
    # three distinct eigenvalues: one start vector's Krylov space is invariant after three
    # steps; the copies it cannot see are found from new start vectors orthogonal to it
    values = np.repeat([4.0, 2.0, 1.0], [3, 3, 4])
    apply, fresh = _operator(values, seed=1)
    found, vectors = lanczos(apply, fresh, len(values), 6, 1e-10)
    assert np.allclose(found, values[:6], rtol=1e-10)
    assert np.allclose(vectors.T @ vectors, np.eye(6), atol=1e-10)


def test_lanczos_returns_every_eigenpair_of_a_small_space():
    values = np.array([3.0, 2.0, 1.5, 1.0, 0.5])
    apply, fresh = _operator(values, seed=2)
    found, _ = lanczos(apply, fresh, len(values), 5, 1e-12)
    assert np.allclose(found, values, rtol=1e-10)


def test_lanczos_gives_up_at_its_cap():
    # an operator that is no fixed symmetric matrix (a solve gone wrong) never converges: the
    # iteration must end in an error after a bounded number of steps, not grow its basis to
    # the size of the space
    from cfsig.errors import SolverError

    rng = np.random.default_rng(3)
    calls = []

    def apply(u):
        calls.append(None)
        return rng.standard_normal(len(u))

    with pytest.raises(SolverError, match="did not converge"):
        lanczos(apply, lambda: rng.random(5000), 5000, 10, 1e-8)
    assert len(calls) < 1000
