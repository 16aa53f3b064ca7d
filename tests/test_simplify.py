import numpy as np

from cfsig.descriptors.signature import compute_signature
from cfsig.files.elements import mesh_edges
from cfsig.files.mesh import clean_mesh
from cfsig.params import Params
from cfsig.repair.simplify import decimate, simplified_mesh
from tests.helpers import icosphere, random_rotation


def test_decimate_reaches_the_count_and_keeps_the_shape():
    v, f = icosphere(4)  # 5120 faces
    vertices, faces = decimate(v, f, 1000)
    assert 900 <= len(faces) <= 1000 and faces.dtype == np.int64
    radii = np.linalg.norm(vertices, axis=1)
    assert np.allclose(radii, 1.0, atol=0.02)  # still the unit sphere


def test_the_copy_does_not_depend_on_the_numbering():
    """The same surface listed in another order by another file: the same copy, and the same
    signature, bit for bit."""
    v, f = icosphere(4)
    rng = np.random.default_rng(0)
    v = v * (1 + 0.1 * rng.random((len(v), 1)))
    moved = rng.permutation(len(v))  # vertex i is listed at moved[i]
    listed = np.empty_like(v)
    listed[moved] = v
    faces = moved[f][rng.permutation(len(f))]
    faces = np.take_along_axis(faces, (rng.integers(0, 3, (len(f), 1)) + np.arange(3)) % 3, 1)
    for a, b in zip(decimate(v, f, 1000), decimate(listed, faces, 1000), strict=True):
        assert np.array_equal(a, b)
    one, other = (compute_signature(clean_mesh(*m), Params()) for m in ((v, f), (listed, faces)))
    assert np.array_equal(one.vector, other.vector)


def test_the_copy_turns_moves_and_scales_with_the_mesh():
    """Simplified in the mesh's own frame: a turned, scaled and moved mesh gives the same copy,
    turned, scaled and moved alike (its faces the same), mirrored too; to the 30 bits the frame
    is rounded to."""
    v, f = icosphere(4)
    rng = np.random.default_rng(0)
    v = v * [1.0, 0.7, 0.4] * (1 + 0.1 * rng.random((len(v), 1)))
    vertices, faces = decimate(v, f, 1000)
    rotation, shift = random_rotation(5), np.array([2.0, -3.0, 0.5])
    for turn in (rotation, rotation * [1.0, 1.0, -1.0]):  # a turn and a mirror image
        moved, same = decimate(2.5 * v @ turn.T + shift, f, 1000)
        assert np.array_equal(same, faces)
        np.testing.assert_allclose(moved, 2.5 * vertices @ turn.T + shift, rtol=0, atol=1e-7)


def test_decimate_leaves_a_small_mesh_alone():
    v, f = icosphere(2)
    vertices, faces = decimate(v, f, len(f))
    assert np.array_equal(vertices, v) and np.array_equal(faces, f)


def test_simplified_mesh_is_checked_and_closed():
    copy = simplified_mesh(clean_mesh(*icosphere(4)), 1000)
    assert copy is not None and len(copy.faces) <= 1000
    edges = mesh_edges(copy.faces, len(copy.vertices))
    assert len(copy.vertices) - len(edges.ends) + len(copy.faces) == 2  # still a sphere


def test_simplified_mesh_is_none_when_already_small():
    assert simplified_mesh(clean_mesh(*icosphere(3)), 1280) is None
