"""The spherical harmonic descriptor ``sh`` (cfsig.descriptors.sh) of Kazhdan et al. 2003."""

import numpy as np
import pytest
from click.testing import CliRunner
from scipy.special import sph_harm_y

from cfsig import descriptors
from cfsig.cli import main
from cfsig.descriptors import sh
from cfsig.descriptors.signature import compute_signature
from cfsig.files.demo import capsule, limbed_body, torus
from cfsig.files.mesh import clean_mesh
from cfsig.params import Params
from tests.helpers import icosphere, random_rotation, write_off

SH = Params(descriptor="sh")
MESHES = {
    "capsule": lambda: capsule(bend=0.6),
    "torus": lambda: torus(wave=0.2),
    "limbs3": lambda: limbed_body(3, pose=1),
}


def _vector(v, f):
    return sh.sh_vector(clean_mesh(v, f), SH, None, "auto").vector


@pytest.fixture(scope="module")
def vectors():
    return {name: _vector(*make()) for name, make in MESHES.items()}


def test_fejer_weights_integrate_polynomials():
    weights = sh.fejer_weights(64)
    x = np.cos(np.pi * (2 * np.arange(64) + 1) / 128)
    for power in range(64):
        exact = (1 - (-1) ** (power + 1)) / (power + 1)
        assert weights @ x**power == pytest.approx(exact, abs=1e-13)


def test_harmonic_energies_of_known_harmonics():
    """The energies of a sum of harmonics, which also pins sph_harm_y's argument order (theta
    polar, phi azimuth)."""
    d = sh.sphere_directions(sh.BANDWIDTH)
    theta, phi = np.arccos(d[..., 2]), np.mod(np.arctan2(d[..., 1], d[..., 0]), 2 * np.pi)
    f = (
        2
        + 5 * sph_harm_y(3, 2, theta, phi).real  # |Re Y_3^2| = 1 / sqrt(2)
        + 3 * sph_harm_y(16, 7, theta, phi).imag
        - 1.5 * sph_harm_y(5, 0, theta, phi).real
    )
    expected = np.zeros(sh.DEGREE + 1)
    expected[[0, 3, 5, 16]] = 2 * np.sqrt(4 * np.pi), 5 / np.sqrt(2), 1.5, 3 / np.sqrt(2)
    found = sh.harmonic_energies(np.stack([f, -2 * f]), sh.DEGREE)
    np.testing.assert_allclose(found, [expected, 2 * expected], atol=1e-12)


@pytest.mark.parametrize("name", sorted(MESHES))
def test_rotation_invariance(vectors, name):
    """A rotated shape moves by under 5% of its distance to any other shape (about 1%: the
    voxelisation is not exactly invariant)."""
    v, f = MESHES[name]()
    nearest = min(np.abs(vectors[name] - w).sum() for n, w in vectors.items() if n != name)
    moved = np.abs(_vector(v @ random_rotation(len(name)).T, f) - vectors[name]).sum()
    assert moved < 0.05 * nearest


def test_scale_and_translation_invariance(vectors):
    v, f = MESHES["limbs3"]()
    for scale, shift in ((0.01, [3.0, -1.0, 2.0]), (250.0, [-40.0, 7.0, 0.5])):
        np.testing.assert_allclose(_vector(v * scale + shift, f), vectors["limbs3"], atol=1e-9)


def test_sphere_has_only_frequency_zero():
    """A sphere about the origin: all the energy in l = 0, the other frequencies below 1% of its
    peak on every sphere, and the l = 0 profile peaking at the sphere's radius (the mean
    radius, 16 voxels). (Far from the surface, where the Gaussian is tiny, the voxelisation's
    anisotropy is larger relative to that sphere's own l = 0 energy.)"""
    v, f = icosphere(4)
    energies = _vector(3 * v, f).reshape(sh.SPHERES, sh.DEGREE + 1)
    peak = energies[:, 0].max()
    assert np.argmax(energies[:, 0]) + 1 == sh.MEAN_RADIUS
    assert energies[:, 1:].max() < 0.01 * peak
    near = energies[:, 0] > 0.8 * peak  # the spheres of radii 15..17 voxels
    assert np.all(energies[near, 1:] < 0.01 * energies[near, :1])


def test_determinism(vectors):
    again = _vector(*MESHES["capsule"]())
    assert again.dtype == np.float64 and np.array_equal(again, vectors["capsule"])


def test_registry_and_signature():
    descriptor = descriptors.get("sh")
    assert descriptor.name == "sh" and not descriptor.needs_phi
    assert "sh" in descriptors.NAMES and descriptors.layout(SH).length == sh.LENGTH == 544
    sig = compute_signature(clean_mesh(*MESHES["torus"]()), SH)
    assert sig.vector.shape == (544,) and np.isfinite(sig.vector).all() and sig.phi is None


def test_evaluate_side_by_side(tmp_path):
    v, f = icosphere(2)
    for i, stretch in enumerate((1.0, 1.2)):
        write_off(tmp_path / "shapes" / "blob" / f"{i}.off", v * [stretch, 0.6, 0.5], f)
    for i, r in enumerate((0.3, 0.35)):
        write_off(tmp_path / "shapes" / "ring" / f"{i}.off", *torus(r=r, n_major=40, n_minor=14))
    args = ["evaluate", str(tmp_path / "shapes"), "--descriptor", "cf,intrinsic,sh", "--jobs", "1"]
    result = CliRunner().invoke(main, args)
    assert result.exit_code == 0, result.output
    lines = result.stdout.splitlines()
    assert lines[0] == "4 queries"
    assert [line.split()[0] for line in lines[2:5]] == ["cf", "intrinsic", "sh"]
