"""The light field descriptor ``lf`` (cfsig.descriptors.lf) of Chen et al. 2003, and the search
by its own distance."""

from math import factorial

import numpy as np
import pytest

from cfsig.descriptors import lf
from cfsig.descriptors.signature import compute_signature
from cfsig.files.demo import capsule, torus
from cfsig.files.mesh import clean_mesh
from cfsig.params import Params
from cfsig.search.l1 import l1_numpy
from tests.helpers import (
    SHAPES,
    assert_command_line_round_trip,
    assert_search_equals_full_scan,
    icosphere,
    random_rotation,
)

LF = Params(descriptor="lf")


def _vector(v, f):
    return lf.lf_vector(clean_mesh(v, f), LF, None, "auto").vector


def _distance(a, b):
    return float(lf.lf_distances(np.float32([a]), np.float32([b]), l1_numpy)[0, 0])


@pytest.fixture(scope="module")
def vectors():
    return {name: _vector(*make()) for name, make in SHAPES.items()}


def test_the_dodecahedron_rotations_permute_its_views():
    vertices = lf.dodecahedron()
    rotations = lf.dodecahedron_rotations()
    assert rotations.shape == (60, 3, 3)
    for r in rotations:
        np.testing.assert_allclose(r @ r.T, np.eye(3), atol=1e-12)
        assert np.linalg.det(r) == pytest.approx(1)
        turned = vertices @ r.T
        assert np.abs(turned[:, None] - vertices[None]).sum(axis=2).min(axis=1).max() < 1e-9
    perms = lf.view_permutations()
    assert all(sorted(p) == list(range(lf.VIEWS)) for p in perms)
    assert len({tuple(p) for p in perms}) == 60  # no two rotations pair the views alike


def test_rasterise_fills_the_pixel_centres_inside():
    square = np.float32([[[2, 2], [10, 2], [10, 6]], [[2, 2], [10, 6], [2, 6]]])
    image = lf.rasterise(square, np.array([0, 0]), 1, 16)[0]
    expected = np.zeros((16, 16), bool)
    expected[2:6, 2:10] = True
    np.testing.assert_array_equal(image, expected)
    triangle = np.float32([[[1.3, 2.1], [60.2, 9.7], [20.5, 55.9]]])
    (ax, ay), (bx, by) = triangle[0, 1] - triangle[0, 0], triangle[0, 2] - triangle[0, 0]
    area = abs(ax * by - ay * bx) / 2
    filled = lf.rasterise(triangle, np.array([0]), 1, 64).sum()
    assert filled == pytest.approx(area, rel=0.03)


def _radial(n: int, m: int, rho: float) -> float:
    return sum(
        (-1) ** s
        * factorial(n - s)
        / (factorial(s) * factorial((n + m) // 2 - s) * factorial((n - m) // 2 - s))
        * rho ** (n - 2 * s)
        for s in range((n - m) // 2 + 1)
    )


def test_zernike_moments_of_a_disk():
    """A centred disk of radius a: the moments with m > 0 vanish, those with m = 0 are
    ``integral_0^a R_n0(rho) rho d rho / integral_0^a rho d rho``; the unit disk's all vanish."""
    grid, a = 256, 0.6
    centres = (np.arange(grid) + 0.5) / (grid / 2) - 1
    x, y = np.meshgrid(centres, centres)
    disks = np.stack([np.hypot(x, y) <= a, np.hypot(x - 0.2, y + 0.1) <= a])
    shifted = np.array([[0.0, 0.0], [0.2, -0.1]])  # y up in the moments' units
    found = lf.zernike_magnitudes(disks, shifted, np.ones(2))
    pairs = [(n, m) for n in range(1, lf.ORDER + 1) for m in range(n % 2, n + 1, 2)]
    expected = [
        abs(sum(_radial(n, 0, r) * r for r in np.linspace(0, a, 20001)[1:]) * a / 20000)
        / (a**2 / 2)
        if m == 0
        else 0.0
        for n, m in pairs
    ]
    np.testing.assert_allclose(found[0], expected, atol=0.01)
    assert np.abs(found[1] - found[0]).max() > 0.05  # off centre, the moments move
    unit = lf.zernike_magnitudes(
        np.hypot(x, y)[None] <= 1, np.zeros((1, 2)), np.ones(1)
    )  # the whole disk of the moments: orthogonal to every moment after (0, 0)
    assert unit.max() < 0.01


def test_fourier_descriptors_of_the_contour():
    """A centred disk's contour is at one distance: no frequency but 0. An ellipse's distance
    repeats twice a turn: frequency 2 leads, the odd ones vanish. A rotated copy, the mirror
    image, or a larger copy reaching the grid's edges as a fitted silhouette does, has the same
    descriptors."""
    grid = 128
    centres = (np.arange(grid) + 0.5) / (grid / 2) - 1
    x, y = np.meshgrid(centres, -centres)
    c, s = np.cos(0.7), np.sin(0.7)
    shapes = np.stack(
        [
            np.hypot(x, y) <= 0.8,
            (x / 0.8) ** 2 + (y / 0.4) ** 2 <= 1,
            ((c * x + s * y) / 0.8) ** 2 + ((c * y - s * x) / 0.4) ** 2 <= 1,
            ((c * x - s * y) / 0.8) ** 2 + ((c * y + s * x) / 0.4) ** 2 <= 1,
            x**2 + (y / 0.5) ** 2 <= 1,
        ]
    )
    found = lf.fourier_descriptors(lf.contour_distances(shapes, np.zeros((5, 2))))
    assert found[0].max() < 0.01
    assert np.argmax(found[1]) == 1 and found[1, 1] > 0.1
    assert found[1, ::2].max() < 0.01  # frequencies 1, 3, 5...
    np.testing.assert_allclose(found[2:], found[[1, 1, 1]], atol=0.01)


def test_features_are_whole_numbers_in_8_bits(vectors):
    for vector in vectors.values():
        assert vector.shape == (lf.LENGTH,)
        assert np.array_equal(vector, np.round(vector)) and vector.min() >= 0
        assert vector.max() <= 255


def test_identical_silhouettes_are_at_distance_zero(vectors):
    """A sphere inside the mesh changes none of its silhouettes; moving and scaling it
    changes none of their features."""
    v, f = torus(wave=0.2)
    assert len(f) < lf.FACE_LIMIT  # drawn as it is, not simplified
    inner_v, inner_f = icosphere(1)
    inside = 0.05 * inner_v + v[np.argmin(v[:, 0])] * 0.9  # within the tube
    both = (np.vstack([v, inside]), np.vstack([f, inner_f + len(v)]))
    assert _distance(vectors["torus"], _vector(*both)) == 0
    assert _distance(vectors["torus"], _vector(3.5 * v + [1.0, -2.0, 0.5], f)) == 0


@pytest.mark.parametrize("name", sorted(SHAPES))
def test_rotation_invariance(vectors, name):
    """Turned by a rotation of the dodecahedron, a mesh keeps its silhouettes (up to the pixel
    grid): its distance is far below that to any other shape; turned by any rotation, well
    below."""
    v, f = SHAPES[name]()
    others = min(_distance(vectors[name], vectors[o]) for o in SHAPES if o != name)
    turned = _vector(v @ lf.dodecahedron_rotations()[17].T, f)
    assert _distance(vectors[name], turned) < 0.15 * others
    turned = _vector(v @ random_rotation(4).T, f)
    assert _distance(vectors[name], turned) < 0.5 * others


def test_the_bound_is_below_the_distance(vectors):
    rng = np.random.default_rng(3)
    real = np.float32(list(vectors.values()))
    noisy = np.clip(real + rng.integers(-30, 30, real.shape), 0, 255).astype(np.float32)
    rows = np.vstack([real, noisy, rng.integers(0, 256, (3, lf.LENGTH)).astype(np.float32)])
    exact = lf.lf_distances(rows, rows, l1_numpy)
    bounds = lf.lf_bounds(rows, rows, l1_numpy)
    assert np.all(bounds <= exact) and np.all(np.diag(exact) == 0)
    np.testing.assert_array_equal(exact, exact.T)
    assert bounds[exact > 0].mean() > 0.3 * exact[exact > 0].mean()  # bounds that prune


def test_search_equals_a_full_scan(tmp_path, vectors):
    """Rows near a few shapes, duplicates among them (ties), in two segments with a row
    superseded: the bounded search returns the full scan's rows and distances."""
    rng = np.random.default_rng(7)
    base = np.float32(list(vectors.values()))
    rows = [np.clip(base[i % 4] + rng.integers(-40, 40, lf.LENGTH), 0, 255) for i in range(30)]
    rows[5] = rows[9] = rows[2]
    assert_search_equals_full_scan(tmp_path / "index", LF, [np.float32(r) for r in rows], base)


def test_the_command_line_indexes_queries_evaluates_and_checks(tmp_path):
    assert_command_line_round_trip(tmp_path, "lf")


def test_signature_goes_through_the_repair_stage():
    v, f = capsule()
    sig = compute_signature(clean_mesh(v, f), LF)
    assert sig.vector.shape == (lf.LENGTH,) and sig.route == "clean" and sig.phi is None


def test_fewer_light_fields_are_the_first_ones(vectors):
    """The features of the first light fields are those the full vector begins with, and their
    distance is that of the full vectors' first light fields, bounded as the full one is."""
    v, f = SHAPES["limbs3"]()
    first = lf.light_field_features(clean_mesh(v, f), 3)
    np.testing.assert_array_equal(first, vectors["limbs3"][: len(first)])
    rows = np.float32([vectors[name][: len(first)] for name in SHAPES])
    exact = lf.lf_distances(rows, rows, l1_numpy)
    full = lf.lf_distances(*(2 * [np.float32(list(vectors.values()))]), l1_numpy)
    assert np.all(lf.lf_bounds(rows, rows, l1_numpy) <= exact) and np.all(exact >= full)
