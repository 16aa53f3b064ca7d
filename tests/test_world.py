"""The query makers of benchmarks/world.py on generated meshes: the share of the area asked for,
no triangle of the whole kept, a scan that sees one side."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from scipy.sparse.csgraph import connected_components

from cfsig.files.demo import limbed_body
from cfsig.files.mesh import Mesh, clean_mesh
from tests.helpers import icosphere

BENCHMARKS = Path(__file__).resolve().parents[1] / "benchmarks"


@pytest.fixture
def world(monkeypatch):
    """The benchmark script as a module (it imports its neighbour ``common``)."""
    monkeypatch.syspath_prepend(str(BENCHMARKS))
    import world

    return world


@pytest.fixture(scope="module")
def sphere() -> Mesh:
    return clean_mesh(*icosphere(4))


@pytest.fixture(scope="module")
def body() -> Mesh:
    return clean_mesh(*limbed_body(4))


def _share(world, part: Mesh, whole: Mesh) -> float:
    area = world.face_areas
    return float(area(part.vertices, part.faces).sum() / area(whole.vertices, whole.faces).sum())


def _shared_triangles(part: Mesh, whole: Mesh) -> int:
    """Triangles of the part whose three corners are all corners of the whole."""
    corners = {tuple(np.round(v, 9)) for v in whole.vertices}
    on_whole = np.array([tuple(np.round(v, 9)) in corners for v in part.vertices])
    return int(on_whole[part.faces].all(axis=1).sum())


@pytest.mark.parametrize("share", [0.3, 0.5, 0.7])
def test_a_cut_keeps_the_share_asked_for_on_new_triangles(world, body, share):
    part = world.query_mesh(body, "cut", share, np.random.default_rng(1))
    assert _share(world, part, body) == pytest.approx(share, abs=0.03)
    assert _shared_triangles(part, body) == 0


@pytest.mark.parametrize("share", [0.1, 0.25, 0.4])
def test_holes_remove_the_share_asked_for_on_new_triangles(world, sphere, share):
    part = world.query_mesh(sphere, "holes", share, np.random.default_rng(2))
    assert _share(world, part, sphere) == pytest.approx(1 - share, abs=0.03)
    assert _shared_triangles(part, sphere) == 0
    assert np.any(np.bincount(part.faces.ravel()) < 4)  # it has a boundary: holes were cut


@pytest.fixture(scope="module")
def irregular_sphere() -> Mesh:
    """A unit sphere on the hull of 3,000 random points: triangles of every size and shape."""
    from scipy.spatial import ConvexHull

    points = np.random.default_rng(0).normal(size=(3000, 3))
    points /= np.linalg.norm(points, axis=1)[:, None]
    faces = ConvexHull(points).simplices
    normals = np.cross(
        points[faces[:, 1]] - points[faces[:, 0]], points[faces[:, 2]] - points[faces[:, 0]]
    )
    inward = (normals * points[faces].mean(axis=1)).sum(axis=1) < 0
    faces[inward] = faces[inward][:, ::-1]
    return clean_mesh(points, faces)


@pytest.mark.parametrize("share", [0.1, 0.25, 0.4])
def test_holes_are_round_on_any_triangles(world, irregular_sphere, share):
    """Each hole's rim follows a circle: the rims are no longer than five separate caps' of the
    area removed (plus the zigzag of edges), and what is left stays in one piece or two."""
    vertices, faces = world.holes(irregular_sphere, share, np.random.default_rng(1))
    part = clean_mesh(*world._used(vertices, faces))  # splits pieces that touch at a vertex
    edges = np.sort(part.faces[:, [0, 1, 1, 2, 2, 0]].reshape(-1, 2), axis=1)
    unique, uses = np.unique(edges, axis=0, return_counts=True)
    rims = part.vertices[unique[uses == 1]]
    rim_length = np.linalg.norm(rims[:, 0] - rims[:, 1], axis=1).sum()
    cap = np.arccos(1 - 2 * share / 5)  # the angle of a cap holding share / 5 of the sphere
    assert rim_length < 1.3 * 5 * 2 * np.pi * np.sin(cap)
    pieces = connected_components(world.edge_graph(part), directed=False)[0]
    assert pieces <= 2


def test_a_scan_sees_one_side_only(world, sphere):
    rng = np.random.default_rng(3)
    part = world.query_mesh(sphere, "scan", 0.0, rng)
    toward = np.random.default_rng(3).normal(size=3)  # the direction the scan drew first
    toward /= np.linalg.norm(toward)
    facing = part.vertices @ toward  # a unit sphere: the vertex is its own normal
    assert facing.min() > -0.05  # nothing of the far side
    assert 0.25 < _share(world, part, sphere) <= 0.5  # at most the near half
    assert _shared_triangles(part, sphere) == 0


def test_a_scan_is_noisy_along_the_view_only(world, sphere):
    clean = world.query_mesh(sphere, "scan", 0.0, np.random.default_rng(4))
    noisy = world.query_mesh(sphere, "scan", 0.01, np.random.default_rng(4))
    toward = np.random.default_rng(4).normal(size=3)
    toward /= np.linalg.norm(toward)
    moved = noisy.vertices - clean.vertices
    along = moved @ toward
    across = moved - np.outer(along, toward)
    assert np.std(along) == pytest.approx(0.01 * world.diagonal(sphere.vertices), rel=0.1)
    assert np.abs(across).max() < 1e-9


def test_noise_moves_every_vertex_by_the_amount_asked_for(world, sphere):
    noisy = world.query_mesh(sphere, "noise", 0.01, np.random.default_rng(5))
    moved = noisy.vertices - sphere.vertices
    assert np.std(moved) == pytest.approx(0.01 * world.diagonal(sphere.vertices), rel=0.05)
    assert np.array_equal(noisy.faces, sphere.faces)
