import igl
import numpy as np
import pytest

from cfsig.descriptors.cf import histogram, sample_phi
from cfsig.descriptors.signature import compute_signature
from cfsig.files import elements
from cfsig.files.demo import limbed_body
from cfsig.files.mesh import clean_mesh
from cfsig.params import Params
from tests.helpers import l1 as _l1
from tests.helpers import random_rotation
from tests.helpers import signature_vector as _sig


@pytest.fixture(scope="module")
def reference(body):
    """The body's signature and its distance to a different class (2 and 5 limbs)."""
    sig = _sig(*body)
    other = min(_l1(sig, _sig(*limbed_body(2, 0))), _l1(sig, _sig(*limbed_body(5, 0))))
    return sig, other


def test_histogram_sums_to_one_and_is_deterministic(body):
    a, b = _sig(*body), _sig(*body)
    assert a.shape == (200,)
    assert a.sum() == pytest.approx(1.0)
    assert np.array_equal(a, b)  # bit for bit


def test_bins_centred_on_integers():
    params = Params(descriptor="cf")
    h = histogram(np.array([-0.49, 0.0, 0.49, 0.51, -500.0, 500.0]), params)
    assert h[99] == pytest.approx(3 / 6)  # bin 99 is centred on 0: [-0.5, 0.5)
    assert h[100] == pytest.approx(1 / 6)
    assert h[0] == pytest.approx(1 / 6) and h[199] == pytest.approx(1 / 6)  # clipped ends


def test_sampling_is_uniform_by_area():
    # two triangles, the second three times larger: a quarter of the samples in the first
    faces = np.array([[0, 1, 2], [3, 4, 5]])
    phi = np.array([0.0, 0.0, 0.0, 1.0, 1.0, 1.0])
    samples = sample_phi(faces, np.array([1.0, 3.0]), phi, 40000, seed=0)
    assert (samples == 0).mean() == pytest.approx(0.25, abs=0.01)


def test_barycentric_interpolation_stays_in_range():
    faces = np.array([[0, 1, 2]])
    samples = sample_phi(faces, np.array([1.0]), np.array([0.0, 1.0, 2.0]), 10000, seed=3)
    assert samples.min() >= 0 and samples.max() <= 2
    assert samples.mean() == pytest.approx(1.0, abs=0.02)  # the centroid's value


def test_invariant_to_rigid_motion_and_scale(body, reference):
    v, f = body
    moved = 0.3 * v @ random_rotation(5).T + 7.0
    assert _l1(_sig(moved, f), reference[0]) < 1e-9


def test_subdivision_gives_close_signature(body, reference):
    sig, other = reference
    v, f = igl.upsample(*body)
    assert _l1(_sig(v, f), sig) < 0.1 * other


def test_bent_pose_gives_close_signature(reference):
    sig, other = reference
    for pose in (1, 2, 3):
        assert _l1(_sig(*limbed_body(3, pose)), sig) < 0.1 * other


def test_noise_keeps_signature_close(body, reference):
    # paper section 3.2: Gaussian noise of 20% of the mean edge length
    sig, other = reference
    v, f = body
    sigma = 0.2 * elements.edge_lengths(v, f).mean()
    noisy = v + np.random.default_rng(0).normal(scale=sigma, size=v.shape)
    assert _l1(_sig(noisy, f), sig) < 0.2 * other


def test_normalized_variant(body):
    params = Params(descriptor="cf", normalize=True)
    cf = compute_signature(clean_mesh(*body), params)
    assert cf.vector.sum() == pytest.approx(1.0)
    assert cf.vector[0] > 0 and cf.vector[-1] > 0  # min and max phi land in the end bins


def test_samples_uniform_inside_a_triangle():
    # phi = 3 (b1 + 2 b2) in barycentric coordinates: P(phi < 3) = P(b1 + 2 b2 < 1) = 1/2
    faces = np.array([[0, 1, 2]])
    samples = sample_phi(faces, np.array([1.0]), np.array([0.0, 3.0, 6.0]), 60_000, seed=1)
    assert np.mean(samples < 3.0) == pytest.approx(0.5, abs=0.01)


def test_samples_reproducible_and_seeded():
    faces = np.array([[0, 1, 2], [0, 2, 3]])
    areas, phi = np.array([1.0, 2.0]), np.array([0.0, 1, 2, 3])
    a = sample_phi(faces, areas, phi, 1000, seed=5)
    assert np.array_equal(a, sample_phi(faces, areas, phi, 1000, seed=5))
    assert not np.array_equal(a, sample_phi(faces, areas, phi, 1000, seed=6))


def test_histogram_bin_edges_and_far_values():
    params = Params(descriptor="cf", bins=4, low=0.0, high=4.0)
    hist = histogram(np.array([-10.0, 0.0, 0.99, 1.0, 2.5, 3.99, 4.0, 1e30]), params)
    assert np.array_equal(hist * 8, [3, 1, 1, 3])
