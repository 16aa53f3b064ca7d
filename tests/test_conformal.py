import numpy as np
import pytest

from cfsig.errors import SolverError
from cfsig.files import elements
from cfsig.files.mesh import clean_mesh
from cfsig.operators import geometry
from cfsig.operators.conformal import (
    available_solvers,
    conformal_factor,
    factorize_laplacian,
    laplacian_solver,
    pinned_system,
)
from tests.helpers import icosphere, random_rotation, torus


def _bumpy(seed=0):
    v, f = icosphere(3)
    # an ellipsoid with a long extrusion along +x: phi must be largest at its tip
    v = v * [1.0, 0.6, 0.5]
    v[:, 0] += 1.5 * np.clip(v[:, 0], 0, None) ** 4
    return v, f


def test_phi_solves_equation_with_zero_mean():
    v, f = _bumpy()
    cf = conformal_factor(clean_mesh(v, f))
    lap = geometry.cotan_laplacian(elements.edge_lengths(v, f), f, len(v))
    assert np.allclose(lap @ cf.phi, cf.operators.target - cf.operators.curvature, atol=1e-9)
    assert abs(cf.phi.mean()) < 1e-12


def test_phi_positive_on_extrusion():
    v, f = _bumpy()
    cf = conformal_factor(clean_mesh(v, f))
    assert np.argmax(cf.phi) == np.argmax(v[:, 0])
    assert cf.phi[np.argmax(v[:, 0])] > 0


def test_invariant_to_rigid_motion_and_scale():
    v, f = _bumpy()
    base = conformal_factor(clean_mesh(v, f)).phi
    moved = 3.7 * v @ random_rotation(2).T + [10.0, -4.0, 2.0]
    assert np.allclose(conformal_factor(clean_mesh(moved, f)).phi, base, atol=1e-8)


@pytest.mark.parametrize("solver", available_solvers())
def test_solvers_agree(solver):
    v, f = _bumpy()
    mesh = clean_mesh(v, f)
    a = conformal_factor(mesh, solver="scipy").phi
    b = conformal_factor(mesh, solver=solver).phi
    assert np.allclose(a, b, atol=1e-9)


def test_auto_is_the_first_available():
    assert available_solvers()[-1] == "scipy" and "eigen" in available_solvers()
    v, f = _bumpy()
    mesh = clean_mesh(v, f)
    auto = conformal_factor(mesh, solver="auto").phi
    assert np.array_equal(auto, conformal_factor(mesh, solver=available_solvers()[0]).phi)


def test_eigen_refuses_a_singular_system():
    # Two spheres labelled as one component: one pinned vertex leaves the other sphere floating.
    v, f = icosphere(2)
    v2, f2 = np.vstack([v, v + 3]), np.vstack([f, f + len(v)])
    lap = geometry.cotan_laplacian(elements.edge_lengths(v2, f2), f2, len(v2))
    rhs = np.random.default_rng(0).standard_normal(len(v2))
    rhs[: len(v)] -= rhs[: len(v)].mean()
    rhs[len(v) :] -= rhs[len(v) :].mean()
    with pytest.raises(SolverError):
        factorize_laplacian(lap, np.zeros(len(v2), int), "eigen")(rhs)


def test_per_component_zero_mean():
    v1, f1 = _bumpy()
    v2, f2 = torus(nu=24, nv=8)
    mesh = clean_mesh(np.vstack([v1, v2 + 9]), np.vstack([f1, f2 + len(v1)]))
    cf = conformal_factor(mesh)
    assert cf.operators.n_components == 2
    assert abs(cf.phi[: len(v1)].mean()) < 1e-12
    assert abs(cf.phi[len(v1) :].mean()) < 1e-12
    # each component is solved as if alone
    alone = conformal_factor(clean_mesh(v1, f1)).phi
    assert np.allclose(cf.phi[: len(v1)], alone, atol=1e-9)


def test_curvature_error_small_on_smooth_mesh(sphere):
    v, f = sphere
    cf = conformal_factor(clean_mesh(v * [1, 0.8, 0.6], f))
    assert 0 <= cf.curvature_error < 1e-3
    assert np.isfinite(cf.curvature_error)


def test_non_finite_system_raises():
    lap = geometry.cotan_laplacian(np.ones((1, 3)), np.array([[0, 1, 2]]), 3)
    with pytest.raises(SolverError):
        factorize_laplacian(lap, np.zeros(3, int))(np.array([np.nan, 0, 0]))


def test_unknown_solver():
    v, f = icosphere(1)
    with pytest.raises(ValueError, match="unknown solver"):
        conformal_factor(clean_mesh(v, f), solver="magic")


@pytest.mark.parametrize("parts", [1, 2])
def test_pinned_system_drops_the_first_vertex_of_each_component(parts):
    v, f = torus(nu=12, nv=6)
    f = np.vstack([f + k * len(v) for k in range(parts)])
    lap = geometry.cotan_laplacian(
        elements.edge_lengths(np.vstack([v] * parts), f), f, parts * len(v)
    )
    labels = np.repeat(np.arange(parts), len(v))
    system, keep = pinned_system(lap, labels)
    assert np.flatnonzero(~keep).tolist() == [k * len(v) for k in range(parts)]
    expected = -lap.toarray()[np.ix_(keep, keep)]
    assert system.format == "csc" and system.has_sorted_indices
    assert np.array_equal(system.toarray(), expected)


@pytest.mark.parametrize("parts", [1, 2])
def test_laplacian_solver_solves_up_to_a_constant_per_component(parts):
    v, f = icosphere(2)
    v, f = (
        np.vstack([v + 3 * k for k in range(parts)]),
        np.vstack([f + k * 162 for k in range(parts)]),
    )
    lap = geometry.cotan_laplacian(elements.edge_lengths(v, f), f, len(v))
    labels = np.repeat(np.arange(parts), 162)
    rhs = np.random.default_rng(1).standard_normal(len(v))
    rhs -= (np.bincount(labels, weights=rhs) / 162)[labels]
    x = laplacian_solver(lap, labels)(rhs)
    assert np.allclose(lap @ x, rhs, atol=1e-9)
    assert np.all(x[162 * np.arange(parts)] == 0)  # the pinned vertices
    centred = factorize_laplacian(lap, labels)(rhs)
    assert np.allclose(x - (np.bincount(labels, weights=x) / 162)[labels], centred, atol=1e-12)
