"""The panoramic channel of ``rigid`` (cfsig.descriptors.panorama): pose, cylindrical projections,
folded spectra and the distance over the axes' orders."""

import numpy as np
import pytest

from cfsig.descriptors import panorama, sh
from cfsig.search.l1 import l1_numpy
from tests.helpers import SHAPES, random_rotation


def _features(vertices, faces):
    return panorama.panorama_features(*sh.surface_samples(vertices, faces, 0))


def _distance(a, b):
    return float(panorama.panorama_distances(np.float32([a]), np.float32([b]), l1_numpy)[0, 0])


@pytest.fixture(scope="module")
def features():
    return {name: _features(*make()) for name, make in SHAPES.items()}


@pytest.mark.parametrize("name", sorted(SHAPES))
def test_a_turned_mirrored_moved_and_scaled_copy_has_the_same_features(features, name):
    """The same samples, turned, mirrored, moved and scaled, give the same features to within
    rounding: the principal axes undo the turn, and the folded spectra the axes' signs and the
    mirror."""
    v, f = SHAPES[name]()
    for seed in range(3):
        mirrored = v @ (random_rotation(seed) * [-1.0, 1.0, 1.0]).T * 7.5 + [3.0, -2.0, 1.0]
        copy = _features(mirrored, f)  # the same samples, their normals reversed
        np.testing.assert_allclose(copy, features[name], rtol=0, atol=1e-9)
        assert _distance(copy, features[name]) < 1e-5 * _distance(features[name], 0 * copy)


def test_the_frames_and_the_axes_order_are_left_to_the_distance(features):
    """Features whose frames and axes are exchanged, as close second moments exchange them, are
    at distance 0, and the distance is the smallest sum over the pairs of frames and the orders
    of the axes of the paired axes' L1 distances."""
    rows = np.float32([features[name] for name in sorted(SHAPES)])
    shape = (len(rows), panorama.FRAMES, panorama.AXES, panorama.BLOCK)
    blocks = rows.reshape(shape)
    swapped = np.ascontiguousarray(blocks[:, ::-1][:, :, [2, 0, 1]].reshape(len(rows), -1))
    across = panorama.panorama_distances(rows, swapped, l1_numpy)
    assert np.all(np.diag(across) == 0)
    a, b = blocks[0].astype(float), blocks[1].astype(float)
    expected = min(
        sum(np.abs(a[i, k] - b[j, order[k]]).sum() for k in range(panorama.AXES))
        for i in range(panorama.FRAMES)
        for j in range(panorama.FRAMES)
        for order in panorama.axis_orders()
    )
    assert across[0, 1] == pytest.approx(expected, rel=1e-5)
    assert across[0, 1] > 0


def test_panoramas_of_a_cylinder():
    """Samples on a cylinder of radius 1 about the first axis: its distance panorama is
    1 / RADIUS wherever the cylinder is, and the normals point along the rays there."""
    rng = np.random.default_rng(0)
    angle, height = rng.uniform(0, 2 * np.pi, 200_000), rng.uniform(-1, 1, 200_000)
    points = np.stack([height, np.cos(angle), np.sin(angle)], axis=1)
    normals = points * [0.0, 1.0, 1.0]
    images = panorama.panoramas(points, normals)
    assert images.shape == (panorama.AXES, panorama.MAPS, panorama.ANGLES, panorama.HEIGHTS)
    rows = slice(panorama.HEIGHTS // 2 - 4, panorama.HEIGHTS // 2 + 4)  # heights within 1
    np.testing.assert_allclose(images[0, 0, :, rows], 1 / panorama.RADIUS, rtol=1e-3)
    np.testing.assert_allclose(images[0, 1, :, rows], 1.0, rtol=1e-3)
    assert np.all(images[0, :, :, :2] == 0)  # no surface beyond its ends
    assert np.all(images <= 1) and np.all(images >= 0)


def _turned_and_reversed(image):
    """The copies of a panorama that the axes' signs and mirrors make of it."""
    return (
        np.roll(image, panorama.ANGLES // 2, axis=0),  # a half turn about the axis
        image[::-1],  # the azimuth reversed
        image[:, ::-1],  # the axis reversed
        np.roll(image[::-1, ::-1], panorama.ANGLES // 2, axis=0),
    )


def test_folded_spectra_ignore_half_turns_reversals_and_mirrors_not_other_turns():
    """The absolute parts keep the phase about the image's centre: the half turns and reversals
    that the axes' signs make leave them as they are, a turn by a few cells does not."""
    rng = np.random.default_rng(1)
    image = rng.random((panorama.ANGLES, panorama.HEIGHTS))
    spectra = panorama.folded_spectra(image)
    assert spectra.shape == (panorama.PARTS, panorama.ANGULAR + 1, 2 * panorama.AXIAL + 1)
    for other in _turned_and_reversed(image):
        np.testing.assert_allclose(panorama.folded_spectra(other), spectra, atol=1e-12)
    assert np.abs(panorama.folded_spectra(np.roll(image, 5, axis=0)) - spectra).max() > 1e-4
    assert spectra.sum() == pytest.approx(1.0) and np.all(spectra >= 0)


def test_a_centred_image_has_no_imaginary_part():
    """An image symmetric about its centre has a real transform about it."""
    rng = np.random.default_rng(2)
    half = rng.random((panorama.ANGLES, panorama.HEIGHTS))
    image = half + half[::-1, ::-1]
    spectra = panorama.folded_spectra(image)
    assert np.abs(spectra[1]).max() < 1e-12 and spectra[0].sum() == pytest.approx(1.0)


def test_haar_subbands_keep_the_energy_and_find_the_finest_detail():
    """The transform is orthonormal: its subbands hold the image's energy. An image alternating
    along the azimuth only is all in the finest detail along it."""
    rng = np.random.default_rng(3)
    image = rng.random((panorama.ANGLES, panorama.HEIGHTS))
    bands = panorama.haar_subbands(image)
    assert len(bands) == panorama.SUBBANDS
    assert bands[-1].shape == (
        panorama.ANGLES >> panorama.LEVELS,
        panorama.HEIGHTS >> panorama.LEVELS,
    )
    assert sum(float((b**2).sum()) for b in bands) == pytest.approx(float((image**2).sum()))
    stripes = np.repeat((np.arange(panorama.ANGLES) % 2)[:, None], panorama.HEIGHTS, axis=1)
    moments = panorama.wavelet_moments(stripes.astype(float))
    np.testing.assert_allclose(moments[1], [1.0, 0.0, 0.0], atol=1e-12)  # along the azimuth
    others = np.delete(np.arange(panorama.SUBBANDS - 1), 1)
    np.testing.assert_allclose(moments[others, :2], 0.0, atol=1e-12)
    assert moments[-1, 0] == pytest.approx(0.5 * 2**panorama.LEVELS)  # the mean, 2x a level


def test_wavelet_features_ignore_half_turns_reversals_and_mirrors():
    """The moments of the absolute coefficients: the half turns and reversals only permute the
    coefficients and change their signs. A constant subband has no skewness."""
    rng = np.random.default_rng(4)
    image = rng.random((panorama.ANGLES, panorama.HEIGHTS)) ** 3
    features = panorama.wavelet_features(image)
    assert features.shape == (panorama.SUBBANDS, panorama.MOMENTS)
    for other in _turned_and_reversed(image):
        np.testing.assert_allclose(panorama.wavelet_features(other), features, atol=1e-12)
    flat = panorama.wavelet_features(np.full((panorama.ANGLES, panorama.HEIGHTS), 0.5))
    details = panorama.WAVELET_WEIGHT * np.log([panorama.FLOOR, panorama.FLOOR, 1.0])
    np.testing.assert_allclose(flat[:-1], np.broadcast_to(details, flat[:-1].shape))
