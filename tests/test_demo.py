"""Tests for the synthetic demo collection in :mod:`cfsig.files.demo`."""

import numpy as np
import pytest
from scipy.sparse import coo_matrix
from scipy.sparse.csgraph import connected_components

from cfsig.files import demo

GENERATORS = {
    "capsule": lambda: demo.capsule(),
    "capsule-bent": lambda: demo.capsule(radius=0.45, length=1.4, bend=0.9, bend_azimuth=1.0),
    "torus": lambda: demo.torus(),
    "torus-wave": lambda: demo.torus(r=0.3, wave=0.15),
    **{
        f"limbs{k}-{s}": (lambda k=k, s=s: demo.limbed_body(k, s))
        for k in range(1, 6)
        for s in (0, 1)
    },
    "limbs3-straight": lambda: demo.limbed_body(3, np.zeros((3, 3))),
}


def _directed_edges(F):
    return np.vstack([F[:, [0, 1]], F[:, [1, 2]], F[:, [2, 0]]])


def _min_angle_deg(V, F):
    T = V[F]
    angles = []
    for i in range(3):
        a, b = T[:, (i + 1) % 3] - T[:, i], T[:, (i + 2) % 3] - T[:, i]
        cos = np.einsum("ij,ij->i", a, b) / np.linalg.norm(a, axis=1) / np.linalg.norm(b, axis=1)
        angles.append(np.degrees(np.arccos(np.clip(cos, -1, 1))))
    return np.min(angles)


def _areas(V, F):
    T = V[F]
    return 0.5 * np.linalg.norm(np.cross(T[:, 1] - T[:, 0], T[:, 2] - T[:, 0]), axis=1)


def _signed_volume(V, F):
    T = V[F]
    return np.einsum("ij,ij->i", T[:, 0], np.cross(T[:, 1], T[:, 2])).sum() / 6


@pytest.fixture(scope="module", params=list(GENERATORS))
def mesh(request):
    V, F = GENERATORS[request.param]()
    return request.param, V, F


def test_types_and_sizes(mesh):
    _, V, F = mesh
    assert V.dtype == np.float64 and V.ndim == 2 and V.shape[1] == 3
    assert F.dtype == np.int64 and F.ndim == 2 and F.shape[1] == 3
    assert 1000 <= len(V) <= 4000
    assert np.isfinite(V).all()


def test_closed_oriented_manifold(mesh):
    _, V, F = mesh
    directed = _directed_edges(F)
    _, directed_counts = np.unique(directed, axis=0, return_counts=True)
    assert (directed_counts == 1).all(), "each directed edge must occur once (consistent winding)"
    _, counts = np.unique(np.sort(directed, axis=1), axis=0, return_counts=True)
    assert (counts == 2).all(), "each edge must be shared by exactly two faces (closed)"
    assert len(np.unique(np.sort(F, axis=1), axis=0)) == len(F), "duplicate faces"
    assert (F[:, 0] != F[:, 1]).all() and (F[:, 1] != F[:, 2]).all() and (F[:, 2] != F[:, 0]).all()


def test_vertices_referenced_unique_and_connected(mesh):
    _, V, F = mesh
    assert np.array_equal(np.unique(F), np.arange(len(V))), "unreferenced vertices"
    assert len(np.unique(V, axis=0)) == len(V), "duplicate vertices"
    E = _directed_edges(F)
    adjacency = coo_matrix((np.ones(len(E)), (E[:, 0], E[:, 1])), shape=(len(V), len(V)))
    assert connected_components(adjacency, directed=False)[0] == 1


def test_euler_characteristic(mesh):
    name, V, F = mesh
    n_edges = len(np.unique(np.sort(_directed_edges(F), axis=1), axis=0))
    assert len(V) - n_edges + len(F) == (0 if name.startswith("torus") else 2)


def test_outward_orientation_and_triangle_quality(mesh):
    _, V, F = mesh
    assert _signed_volume(V, F) > 0
    assert _areas(V, F).min() > 1e-6
    assert _min_angle_deg(V, F) > 5.0


@pytest.mark.parametrize("n_limbs", [1, 2, 3, 5])
def test_limbed_poses_are_near_isometric(n_limbs):
    V0, F0 = demo.limbed_body(n_limbs, 0)
    V1, F1 = demo.limbed_body(n_limbs, 1)
    assert V0.shape == V1.shape and np.array_equal(F0, F1)
    assert np.abs(V0 - V1).max() > 0.1, "poses should move the limbs"
    a0, a1 = _areas(V0, F0).sum(), _areas(V1, F1).sum()
    assert abs(a0 - a1) / a0 < 0.05


def test_limbed_body_explicit_pose_and_validation():
    straight = demo.limbed_body(2, np.zeros((2, 3)))[0]
    bent = demo.limbed_body(2, [[0.0, 0.5, -0.5], [1.0, 0.0, 0.8]])[0]
    assert straight.shape == bent.shape and not np.allclose(straight, bent)
    np.testing.assert_array_equal(demo.limbed_body(2, 7)[0], demo.limbed_body(2, 7)[0])
    with pytest.raises(ValueError):
        demo.limbed_body(6)


def test_write_off_roundtrip(tmp_path):
    V, F = demo.torus(n_major=8, n_minor=5)
    path = tmp_path / "t.off"
    demo.write_off(path, V, F)
    lines = path.read_text().splitlines()
    assert lines[0] == "OFF" and lines[1] == f"{len(V)} {len(F)} 0"
    np.testing.assert_allclose(np.loadtxt(lines[2 : 2 + len(V)]), V, rtol=1e-8, atol=1e-9)
    faces = np.loadtxt(lines[2 + len(V) :], dtype=np.int64)
    assert (faces[:, 0] == 3).all() and np.array_equal(faces[:, 1:], F)


def test_make_demo_collection_layout_and_determinism(tmp_path):
    paths = demo.make_demo_collection(tmp_path / "a", per_class=2, seed=3)
    again = demo.make_demo_collection(tmp_path / "b", per_class=2, seed=3)
    other = demo.make_demo_collection(tmp_path / "c", per_class=2, seed=4)
    assert len(paths) == 2 * len(demo.CLASSES)
    expected = [tmp_path / "a" / c / f"{c}-{i}.off" for c in demo.CLASSES for i in range(2)]
    assert paths == expected
    assert all(p.read_bytes() == q.read_bytes() for p, q in zip(paths, again, strict=True))
    assert any(p.read_bytes() != q.read_bytes() for p, q in zip(paths, other, strict=True))
    for first, second in zip(paths[::2], paths[1::2], strict=True):  # poses within a class
        assert first.read_bytes() != second.read_bytes()
    for path in paths:
        header = path.read_text().splitlines()[:2]
        n_vertices, n_faces, _ = map(int, header[1].split())
        assert header[0] == "OFF" and 1000 <= n_vertices <= 4000 and n_faces > n_vertices
