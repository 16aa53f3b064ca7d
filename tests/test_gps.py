"""The global point signature ``gps`` (cfsig.descriptors.gps) of Rustamov 2007."""

import numpy as np
import pytest

from cfsig import descriptors
from cfsig.descriptors import gps
from cfsig.descriptors.cf import sample_phi
from cfsig.descriptors.intrinsic import spectrum_of
from cfsig.descriptors.signature import compute_signature
from cfsig.files.demo import capsule, limbed_body, torus
from cfsig.files.mesh import clean_mesh
from cfsig.operators.conformal import operators
from cfsig.params import Params
from tests.helpers import icosphere, random_rotation

GPS = Params(descriptor="gps")
MESHES = {
    "capsule": lambda: capsule(length=1.5),
    "bent capsule": lambda: capsule(length=1.5, bend=1.2),
    "ellipsoid": lambda: (icosphere(3)[0] * [1.0, 0.8, 0.6], icosphere(3)[1]),
    "torus": lambda: torus(n_major=48, n_minor=16),
    "limbs3": lambda: limbed_body(3, pose=0),
    "limbs3 posed": lambda: limbed_body(3, pose=2),
    "limbs5": lambda: limbed_body(5, pose=0),
}


def _vector(v, f):
    return gps.gps_vector(clean_mesh(v, f), GPS, None, "auto").vector


def _l1(a, b):
    return float(np.abs(a - b).sum())


@pytest.fixture(scope="module")
def vectors():
    return {name: _vector(*make()) for name, make in MESHES.items()}


def _nearest_other(vectors, name, *also):
    """The distance from a shape to the nearest shape of another kind."""
    return min(_l1(vectors[name], w) for n, w in vectors.items() if n not in (name, *also))


def test_distributions_sum_to_one(vectors):
    for vector in vectors.values():
        assert vector.shape == (gps.LENGTH,) and np.isfinite(vector).all()
        assert vector.sum() == pytest.approx(1.0) and vector.min() >= 0


def test_rigid_motion_and_scale(vectors):
    """The ellipsoid (1,280 faces, solved as it is) moves by round-off only; the capsule (solved
    on a simplified copy, whose collapses follow the coordinates' last bits) by under 10% of
    its distance to any other shape."""
    for name, tolerance in (("ellipsoid", 1e-4), ("capsule", 0.1)):
        v, f = MESHES[name]()
        moved = (v @ random_rotation(3).T) * 37.0 + [5.0, -2.0, 1.0]
        bound = tolerance * _nearest_other(vectors, name, "bent capsule")
        assert _l1(_vector(moved, f), vectors[name]) < bound


@pytest.mark.parametrize(
    ("name", "bent"), [("capsule", "bent capsule"), ("limbs3", "limbs3 posed")]
)
def test_bending_keeps_the_signature(vectors, name, bent):
    """A shape bent without stretching is nearer to itself than any other shape is."""
    assert _l1(vectors[name], vectors[bent]) < 0.5 * _nearest_other(vectors, name, bent)


def test_distributions_ignore_sign_flips_and_rotations():
    """Eigenvectors are known up to sign (and up to a rotation within a repeated eigenvalue's
    space): the G2 distributions of an embedding so transformed are the same."""
    mesh = clean_mesh(*MESHES["ellipsoid"]())
    ops = operators(mesh)
    embedded = gps.embedding(spectrum_of(ops, None, "auto", gps.EIGENPAIRS))
    flip = np.where(np.arange(embedded.shape[1]) % 3 == 0, -1.0, 1.0)
    turn = np.eye(embedded.shape[1])
    turn[:2, :2] = [[0.6, -0.8], [0.8, 0.6]]
    found = [
        gps.g2_distributions(sample_phi(mesh.faces, ops.face_areas, e, gps.SAMPLES, 0))
        for e in (embedded, embedded * flip, embedded @ turn)
    ]
    pairs = gps.SAMPLES * (gps.SAMPLES - 1) / 2
    for other in found[1:]:
        assert _l1(found[0], other) <= 4 / pairs  # a pair or two at a bin edge, at most


def test_embedding_is_scaled_eigenfunctions():
    """On a sphere, GPS(p) = phi / sqrt(lambda) for l = 1 has norm sqrt(3 / (8 pi)) everywhere
    (phi_1..3 = sqrt(3 / 4 pi) x, y, z on the unit sphere, lambda = 2)."""
    v, f = icosphere(4)
    embedded = gps.embedding(spectrum_of(operators(clean_mesh(v, f)), None, "auto", gps.EIGENPAIRS))
    assert embedded.shape == (len(v), gps.EIGENPAIRS)
    norms = np.linalg.norm(embedded[:, :3], axis=1)
    np.testing.assert_allclose(norms, np.sqrt(3 / (8 * np.pi)), rtol=0.02)


def test_determinism_and_seed(vectors):
    v, f = MESHES["torus"]()
    assert np.array_equal(_vector(v, f), vectors["torus"])
    other = gps.gps_vector(clean_mesh(v, f), Params(descriptor="gps", seed=1), None, "auto")
    assert not np.array_equal(other.vector, vectors["torus"])


def test_registry_and_signature():
    descriptor = descriptors.get("gps")
    assert descriptor.name == "gps" and not descriptor.needs_phi
    assert "gps" in descriptors.NAMES and descriptors.layout(GPS).length == gps.LENGTH
    sig = compute_signature(clean_mesh(*MESHES["ellipsoid"]()), GPS)
    assert sig.vector.shape == (gps.LENGTH,) and sig.phi is None
