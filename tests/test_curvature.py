import numpy as np
import pytest

from cfsig.descriptors import intrinsic as cfhks
from cfsig.descriptors.cells import curvature_bins
from cfsig.files.mesh import clean_mesh
from cfsig.operators import curvature
from cfsig.operators.conformal import operators
from cfsig.operators.curvature import smoothed_curvature
from tests.helpers import disk, icosphere, random_rotation, torus

SCALES = (0.0000625, 0.001, 0.01)


def _curvature(v, f, scales=SCALES):
    ops = operators(clean_mesh(v, f))
    return ops, smoothed_curvature(ops, scales, 1e-10)


def test_sphere_is_four_pi_everywhere():
    _, values = _curvature(*icosphere(4), scales=(0.001, 0.01))
    assert np.allclose(values, 4 * np.pi, rtol=0.02)


@pytest.mark.parametrize("mesh", [icosphere(3), torus()], ids=["sphere", "torus"])
def test_diffusion_keeps_the_total_curvature(mesh):
    ops, values = _curvature(*mesh)
    area = ops.vertex_area.sum()
    totals = (ops.vertex_area[:, None] * values).sum(axis=0) / area
    assert np.allclose(totals, ops.curvature.sum(), atol=1e-8)  # Gauss-Bonnet: 4 pi, 0


def test_larger_scales_are_smoother():
    v, f = icosphere(3)
    _, values = _curvature(v * [1.0, 0.6, 0.4], f)
    spread = values.std(axis=0)
    assert spread[0] > spread[1] > spread[2] > 0


def test_invariant_to_scale_and_rigid_motion():
    v, f = icosphere(3)
    v = v * [1.0, 0.7, 0.5]
    _, values = _curvature(v, f)
    _, moved = _curvature(3.0 * v @ random_rotation(1).T + [1.0, -2.0, 0.5], f)
    assert np.allclose(values, moved, rtol=1e-7, atol=1e-9)


def test_boundary_turning_is_not_curvature():
    ops, values = _curvature(*disk())  # flat: no curvature inside, the boundary turns 2 pi
    assert ops.boundary.any() and np.allclose(values, 0.0, atol=1e-9)


def test_histograms_weigh_by_area():
    values = np.array([[0.0, 0.0], [1e6, 1e6], [-1e6, -1e6]])  # the same at both scales
    hist = cfhks.curvature_histograms(values, np.array([2.0, 1.0, 1.0]))
    width = 2 * cfhks.BAND + 1
    assert hist.shape == (1, cfhks.BINS * width)
    diagonal = hist.reshape(cfhks.BINS, width)[:, cfhks.BAND]
    assert diagonal[cfhks.BINS // 2] == 0.5  # asinh(0): the middle bin's centre
    assert diagonal[0] == diagonal[-1] == 0.25  # beyond the range: the end bins
    assert hist.sum() == 1.0


def test_joint_histograms_of_adjacent_scales():
    """Each pair of adjacent scales binned jointly, near the diagonal."""
    rng = np.random.default_rng(3)
    values = np.cumsum(rng.normal(0.0, 20.0, (500, 4)), axis=1)  # adjacent scales close
    weights = rng.uniform(0.5, 2.0, 500)
    bins, band = cfhks.BINS, cfhks.BAND
    joint = cfhks.curvature_histograms(values, weights)
    assert joint.shape == (3, bins * (2 * band + 1)) == cfhks.CURVATURE_SHAPE
    assert np.allclose(joint.sum(axis=1), 1.0) and np.all(joint >= 0)
    # summed over the second scale, each pair is the first scale's own histogram
    first = curvature_bins(values[:, :3], bins)
    marginal = [np.bincount(b, weights / weights.sum(), bins) for b in first.T]
    assert np.allclose(joint.reshape(3, bins, -1).sum(axis=2), marginal)
    # two surfaces whose per-scale histograms agree, whose curvature moves unlike across scales
    apart = np.array([[0.0, 0.0], [1e3, 1e3]])
    crossed = np.array([[0.0, 1e3], [1e3, 0.0]])
    joints = [cfhks.curvature_histograms(v, np.ones(2)) for v in (apart, crossed)]
    assert not np.array_equal(*joints)
    # beyond the band, the second scale's bin is clipped to its edge
    far = cfhks.curvature_histograms(np.array([[0.0, 1e6]]), np.ones(1))
    assert far[0, (bins // 2) * (2 * band + 1) + 2 * band] == 1.0


def test_zero_curvature_falls_in_one_bin_whatever_the_round_off():
    """Flat parts: an odd number of bins keeps them in the middle one, whatever the sign of
    their round-off."""
    bins = curvature_bins(np.array([[1e-9], [-1e-9], [0.0]]), cfhks.BINS)
    assert (bins == cfhks.BINS // 2).all()


def test_conjugate_gradients_agree_with_the_factorisation(monkeypatch):
    v, f = icosphere(3)
    ops, iterative = _curvature(v * [1.0, 0.6, 0.4], f)
    monkeypatch.setattr(curvature, "CG_ITERATIONS", 1)  # every scale falls back to a factorisation
    direct = smoothed_curvature(ops, SCALES, 1e-10)
    assert not np.array_equal(iterative, direct)
    assert np.allclose(iterative, direct, rtol=1e-8, atol=1e-8 * np.abs(direct).max())


def test_predicted_hard_scales_are_factorised_at_once(monkeypatch):
    v, f = icosphere(4)
    ops = operators(clean_mesh(v * [1.0, 0.6, 0.4], f))
    scales = tuple(1e-4 * 4.0**j for j in range(4))
    calls = []  # the iterations of each scale the conjugate gradients were tried on
    solve = curvature._conjugate_gradients

    def counted(*args):
        result = solve(*args)
        calls.append(result[1])
        return result

    monkeypatch.setattr(curvature, "_conjugate_gradients", counted)
    exact = smoothed_curvature(ops, scales, 1e-12)
    tried = len(calls)
    # a cap between the first scale's iterations and twice them: the later scales, which
    # would need more, are not tried
    monkeypatch.setattr(curvature, "CG_ITERATIONS", calls[0] * 2 - 1)
    calls.clear()
    predicted = smoothed_curvature(ops, scales, 1e-12)
    assert len(calls) == 1 < tried
    np.testing.assert_allclose(predicted, exact, rtol=0, atol=1e-9 * np.abs(exact).max())


@pytest.mark.parametrize("tolerance", [1e-3, 1e-10])
def test_conjugate_gradients_are_scipys_iteration(tolerance):
    import scipy.sparse as sp
    import scipy.sparse.linalg as spla

    v, f = icosphere(3)
    ops = operators(clean_mesh(v * [1.0, 0.6, 0.4], f))
    system = sp.diags(ops.vertex_area) + 0.01 * sp.csr_matrix(-ops.laplacian)
    rhs, guess = ops.curvature, ops.curvature / ops.vertex_area
    steps: list[None] = []
    inverse = 1.0 / system.diagonal()
    expected, info = spla.cg(
        system, rhs, x0=guess, rtol=tolerance, atol=0.0, maxiter=curvature.CG_ITERATIONS,
        M=spla.LinearOperator(system.shape, matvec=lambda r: inverse * r),
        callback=lambda _: steps.append(None),
    )  # fmt: skip
    solved, iterations = curvature._conjugate_gradients(system, rhs, guess, tolerance)
    assert info == 0 and iterations == len(steps) > 1
    assert np.array_equal(solved, expected)
    zero, _ = curvature._conjugate_gradients(system, np.zeros_like(rhs), guess, tolerance)
    assert not zero.any()  # scipy returns the zero right-hand side at once


def test_conjugate_gradients_give_up_past_the_cap(monkeypatch):
    import scipy.sparse as sp

    v, f = icosphere(3)
    ops = operators(clean_mesh(v, f))
    monkeypatch.setattr(curvature, "CG_ITERATIONS", 2)
    system = sp.csr_matrix(-ops.laplacian) + 1e-6 * sp.identity(len(v), format="csr")
    solved, iterations = curvature._conjugate_gradients(
        system, ops.curvature - ops.curvature.mean(), np.zeros(len(v)), 1e-12
    )
    assert solved is None and iterations == 2
