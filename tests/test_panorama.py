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


def test_folded_spectra_ignore_shifts_reversals_and_mirrors():
    rng = np.random.default_rng(1)
    image = rng.random((panorama.ANGLES, panorama.HEIGHTS))
    spectra = panorama.folded_spectra(image)
    assert spectra.shape == (panorama.ANGULAR + 1, 2 * panorama.AXIAL + 1)
    for other in (
        np.roll(image, 5, axis=0),  # a turn about the axis
        np.roll(image[::-1, ::-1], 1, axis=0),  # the axis reversed
        np.roll(image[::-1], 1, axis=0),  # a mirror through a plane holding the axis
    ):
        np.testing.assert_allclose(panorama.folded_spectra(other), spectra, atol=1e-12)
    assert spectra.sum() == pytest.approx(1.0) and np.all(spectra >= 0)
