"""Non-manifold input: split into manifold sheets, with signatures close to the manifold mesh."""

import numpy as np
import pytest

from cfsig.descriptors.signature import compute_signature
from cfsig.files import elements
from cfsig.files.demo import capsule, limbed_body
from cfsig.files.mesh import clean_mesh, split_nonmanifold
from cfsig.operators.conformal import conformal_factor
from cfsig.params import Params
from tests.helpers import disk, icosphere, open_cylinder, signature_vector, torus
from tests.helpers import l1 as _l1

AS_READ = Params(
    descriptor="cf", repair="off"
)  # each part solved as read: what the split itself gives


def _sig(v, f):
    return signature_vector(v, f, AS_READ)


def test_manifold_mesh_is_untouched():
    v, f = limbed_body(2, 0)
    faces, copies = split_nonmanifold(f, len(v))
    assert faces is f and len(copies) == 0


def _touching_spheres():
    """Two icospheres touching at vertex 0 only, and the same two spheres drawn 1e-3 apart."""
    v1, f1 = icosphere(2)
    v2, f2 = icosphere(1)
    opposite = int(np.argmin(np.linalg.norm(v2 + v1[0], axis=1)))  # the small one's -v1[0]
    v2 = v2 + (v1[0] - v2[opposite])  # outside the big sphere, tangent to it at v1[0]
    keep = np.arange(len(v2)) != opposite
    glued_v = np.vstack([v1, v2[keep]])
    remap = np.zeros(len(v2), dtype=np.int64)
    remap[keep] = len(v1) + np.arange(len(v2) - 1)
    apart = np.vstack([v1, v2 + 1e-3 * v1[0]]), np.vstack([f1, f2 + len(v1)])
    return (glued_v, np.vstack([f1, remap[f2]])), apart


def _finned_sphere():
    """An icosphere with a fin face on the edge of its first face's first two corners."""
    v, f = icosphere(2)
    a, b = f[0, :2]
    tip = (v[a] + v[b]) / 2 * 1.5
    return np.vstack([v, tip]), np.vstack([f, [[a, b, len(v)]]]), (a, b)


def _flip_some(f, seed, fraction=0.3):
    """The faces with a random subset reversed (inconsistent orientation), and that subset."""
    flip = np.random.default_rng(seed).random(len(f)) < fraction
    flipped = f.copy()
    flipped[flip] = f[flip, ::-1]
    return flipped, flip


def test_two_parts_touching_at_a_vertex_are_separated():
    (glued_v, glued_f), apart = _touching_spheres()
    mesh = clean_mesh(glued_v, glued_f)
    assert not any("coincident" in r for r in mesh.repairs)  # they touch at one vertex only
    assert any("non-manifold" in r for r in mesh.repairs)
    assert len(mesh.vertices) == len(glued_v) + 1
    assert elements.components(elements.edge_graph(mesh.faces, len(mesh.vertices)))[0] == 2
    assert _l1(compute_signature(mesh, AS_READ).vector, _sig(*apart)) < 1e-12


@pytest.fixture(scope="module")
def body_signature(body):
    """The body's signature and its L1 distance to the nearer of two other shapes."""
    sig = _sig(*body)
    return sig, min(_l1(sig, _sig(*limbed_body(2, 0))), _l1(sig, _sig(*capsule())))


def test_fin_on_an_edge(body, body_signature):
    v, f = body
    sig, other = body_signature
    a, b, c = f[100]
    normal = np.cross(v[b] - v[a], v[c] - v[a])
    tip = (v[a] + v[b]) / 2 + normal / np.linalg.norm(normal) * np.linalg.norm(v[b] - v[a])
    fin_v = np.vstack([v, tip])
    fin_f = np.vstack([f, [[a, b, len(v)]]])
    _, counts = elements.edge_face_counts(fin_f, len(fin_v))
    assert counts.max() == 3  # really non-manifold
    mesh = clean_mesh(fin_v, fin_f)
    _, counts = elements.edge_face_counts(mesh.faces, len(mesh.vertices))
    assert counts.max() == 2
    fin_sig = compute_signature(mesh, Params(descriptor="cf")).vector
    assert np.isfinite(fin_sig).all()
    assert _l1(fin_sig, sig) < 0.1 * other


def test_two_bodies_touching_at_a_vertex(body):
    v, f = body
    cv, cf = capsule()
    right, left = np.argmax(v[:, 0]), np.argmin(cv[:, 0])
    touching_v = np.vstack([v, cv + (v[right] - cv[left])])
    touching_v[len(v) + left] = v[right]  # the capsule's leftmost vertex meets the body's
    apart_v = touching_v + np.r_[np.zeros(len(v)), np.full(len(cv), 1e-3)][:, None]
    faces = np.vstack([f, cf + len(v)])
    touching = clean_mesh(touching_v, faces)
    assert any("merged 1 coincident" in r for r in touching.repairs)
    assert any("non-manifold" in r for r in touching.repairs)
    apart_sig = _sig(apart_v, faces)
    assert _l1(compute_signature(touching, AS_READ).vector, apart_sig) < 1e-12


def test_clean_mesh_keeps_the_edges_of_its_check_unless_it_splits():
    v, f = icosphere(2)
    mesh = clean_mesh(v, f)
    assert np.array_equal(mesh.edges.ends, elements.mesh_edges(f, len(v)).ends)
    pinched_f = np.vstack([f, [[0, len(v), len(v) + 1]]])
    pinched = clean_mesh(np.vstack([v, [[2.0, 0, 0], [2.0, 1, 0]]]), pinched_f)  # a flap at 0
    assert pinched.edges is None


@pytest.mark.parametrize(
    "shape",
    [icosphere(3), torus(), open_cylinder(), disk()],
    ids=["sphere", "torus", "cylinder", "disk"],
)
@pytest.mark.parametrize("seed", [0, 1])
def test_inconsistent_orientation_is_not_split(shape, seed):
    v, f = shape
    flipped, flip = _flip_some(f, seed)
    _, counts = elements.edge_face_counts(flipped, len(v))
    assert flip.any() and counts.max() == 2  # manifold, orientation inconsistent
    faces, copies = split_nonmanifold(flipped, len(v))
    assert faces is flipped and len(copies) == 0
    mesh = clean_mesh(v, flipped)
    assert mesh.repairs == () and len(mesh.vertices) == len(v)
    phi = conformal_factor(mesh).phi
    np.testing.assert_allclose(phi, conformal_factor(clean_mesh(v, f)).phi, rtol=0, atol=1e-12)


def test_moebius_strip_is_not_split():
    n_around, n_across = 40, 5
    u = np.repeat(2 * np.pi * np.arange(n_around) / n_around, n_across)
    s = np.tile(np.linspace(-0.3, 0.3, n_across), n_around)
    radius = 1 + s * np.cos(u / 2)
    v = np.column_stack([radius * np.cos(u), radius * np.sin(u), s * np.sin(u / 2)])
    idx = np.arange(n_around * n_across).reshape(n_around, n_across)
    nxt = np.vstack([idx[1:], idx[0, ::-1]])  # the half twist: across the seam s becomes -s
    a, b, c, d = idx[:, :-1], nxt[:, :-1], nxt[:, 1:], idx[:, 1:]
    f = np.vstack([np.stack([a, b, c], -1).reshape(-1, 3), np.stack([a, c, d], -1).reshape(-1, 3)])
    _, copies = split_nonmanifold(f, len(v))
    assert len(copies) == 0
    mesh = clean_mesh(v, f)
    assert len(mesh.vertices) == len(v)
    _, counts = elements.edge_face_counts(mesh.faces, len(v))
    assert counts.max() == 2 and np.count_nonzero(counts == 1) == 2 * n_around  # one long loop


@pytest.mark.parametrize("seed", [0, 1, 2])
@pytest.mark.parametrize("build", ["touching", "fin"])
def test_inconsistent_orientation_keeps_the_genuine_splits(build, seed):
    if build == "touching":
        (v, f), _ = _touching_spheres()
        expected = [0]
    else:
        v, f, expected = _finned_sphere()
        assert elements.edge_face_counts(f, len(v))[1].max() == 3
    faces, copies = split_nonmanifold(f, len(v))
    assert sorted(copies) == sorted(expected)
    flipped, flip = _flip_some(f, seed)
    flipped_faces, flipped_copies = split_nonmanifold(flipped, len(v))
    assert np.array_equal(flipped_copies, copies)
    faces[flip] = faces[flip, ::-1]
    assert np.array_equal(flipped_faces, faces)
    assert clean_mesh(v, flipped).repairs == clean_mesh(v, f).repairs
