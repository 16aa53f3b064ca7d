"""The ``amrg`` descriptor: the Reeb graphs of shapes whose graph is known, its invariances, its
matching and its lower bound."""

from __future__ import annotations

import numpy as np
import pytest
from click.testing import CliRunner

from cfsig.cli import main
from cfsig.descriptors import amrg
from cfsig.errors import MeshError
from cfsig.files.demo import capsule, limbed_body
from cfsig.files.mesh import clean_mesh
from cfsig.params import Params
from tests.helpers import (
    assert_command_line_round_trip,
    assert_search_equals_full_scan,
    icosphere,
    random_rotation,
    torus,
    two_classes,
    write_off,
)


def graph(vertices: np.ndarray, faces: np.ndarray) -> list[amrg.Level]:
    """The Reeb graph of a generated surface."""
    return amrg.reeb_graph(clean_mesh(vertices, faces))


def cycles(level: amrg.Level) -> int:
    """Independent cycles of a resolution's graph: edges - nodes + connected components."""
    nodes = len(level.intervals)
    parent = list(range(nodes))

    def root(i: int) -> int:
        while parent[i] != i:
            i = parent[i]
        return i

    for i, j in level.edges:
        parent[root(i)] = root(j)
    return len(level.edges) - nodes + len({root(i) for i in range(nodes)})


def degrees(level: amrg.Level) -> np.ndarray:
    """Each node's number of neighbours."""
    return np.bincount(level.edges.ravel(), minlength=len(level.intervals))


def distance(a: np.ndarray, b: np.ndarray) -> float:
    """The ``amrg`` distance of two stored vectors."""
    pair = np.array([a, b], np.float32)
    return float(amrg.amrg_distances(pair[:1], pair[1:], None)[0, 0])


@pytest.fixture(scope="module")
def bodies() -> dict[str, np.ndarray]:
    """The stored vectors of a three-limbed body at rest, moved, in two other poses, and of a
    body with five limbs."""
    rest = limbed_body(3, 0)
    moved = (rest[0] @ random_rotation(3).T * 2.5 + [1.0, -2.0, 0.5], rest[1])
    shapes = {
        "rest": rest,
        "moved": moved,
        "pose 1": limbed_body(3, 1),
        "pose 2": limbed_body(3, 2),
        "five limbs": limbed_body(5, 0),
    }
    return {name: amrg.pack(graph(*shape)) for name, shape in shapes.items()}


def test_a_sphere_and_an_ellipsoid_give_a_path_at_every_resolution():
    vertices, faces = icosphere(3)
    for shape in (vertices, vertices * [2.0, 1.0, 0.7]):
        levels = graph(shape, faces)
        assert len(levels) == amrg.RESOLUTIONS
        for level in levels:
            assert cycles(level) == 0 and degrees(level).max(initial=0) <= 2
            assert len(level.edges) == len(level.intervals) - 1  # connected
        # the ellipsoid's ends are apart: two nodes in its top interval, one in its lowest
        if shape is not vertices:
            top = levels[-1].intervals == levels[-1].intervals.max()
            assert top.sum() == 2 and (levels[-1].intervals == 0).sum() == 1


def test_a_torus_gives_one_cycle():
    levels = graph(*torus())
    assert cycles(levels[-1]) == 1
    assert (degrees(levels[-1]) == 2).all()
    assert all(cycles(level) <= 1 for level in levels)


def test_a_body_with_three_limbs_gives_three_branches():
    levels = graph(*limbed_body(3, 0))
    for level in levels[2:]:
        assert cycles(level) == 0 and len(level.edges) == len(level.intervals) - 1
        tips = level.intervals == level.intervals.max()
        assert tips.sum() == 3 and (degrees(level)[tips] == 1).all()


def test_parents_hold_their_childrens_intervals():
    levels = graph(*limbed_body(3, 0))
    for coarse, fine in zip(levels, levels[1:], strict=False):
        assert (coarse.intervals[fine.parents] == fine.intervals // 2).all()
        area = np.bincount(fine.parents, fine.attributes[:, 0], len(coarse.intervals))
        np.testing.assert_allclose(area, coarse.attributes[:, 0], atol=1e-12)


def test_rigid_motion_and_scale_change_little(bodies):
    """Only the farthest-point sampling of the bases moves: its ties on a symmetric body break
    by rounding."""
    moved = distance(bodies["rest"], bodies["moved"])
    assert moved < 0.01
    assert moved < distance(bodies["rest"], bodies["pose 2"]) / 10


def test_an_isometric_bend_stays_nearer_than_another_shape(bodies):
    other = distance(bodies["rest"], bodies["five limbs"])
    for pose in ("pose 1", "pose 2"):
        assert distance(bodies["rest"], bodies[pose]) < other / 2


def test_a_graph_matched_with_itself_scores_best(bodies):
    names = list(bodies)
    vectors = np.array([bodies[name] for name in names], np.float32)
    distances = amrg.amrg_distances(vectors, vectors, None)
    assert (np.diag(distances) == 0).all()
    assert (distances >= np.diag(distances)[:, None] - 1e-9).all()
    # the matching is symmetric, and the bound never exceeds it
    np.testing.assert_allclose(distances, distances.T, atol=1e-9)
    assert (amrg.amrg_bounds(vectors, vectors, None) <= distances).all()


def test_the_bound_holds_between_unlike_graphs():
    """Bodies of one to five limbs in two poses, a torus, an ellipsoid and a bent capsule:
    bound <= distance, pair by pair, and the bound is not nothing."""
    sphere = icosphere(3)
    shapes = [limbed_body(n, pose) for n in (1, 2, 3, 4, 5) for pose in (0, 1)]
    shapes += [torus(), (sphere[0] * [2.0, 1.0, 0.7], sphere[1]), capsule(bend=1.0)]
    vectors = np.array([amrg.pack(graph(*shape)) for shape in shapes], np.float32)
    bounds = amrg.amrg_bounds(vectors, vectors, None)
    distances = amrg.amrg_distances(vectors, vectors, None)
    assert (bounds <= distances).all()
    assert bounds[distances > 0].mean() > 0.2 * distances[distances > 0].mean()


# A tetrahedron pressed flat: a closed surface of four proper triangles and no volume.
FLAT = (
    np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0], [0.3, 0.3, 0]], float),
    np.array([[0, 2, 1], [0, 1, 3], [0, 3, 2], [1, 2, 3]]),
)


def test_a_flat_closed_surface_is_refused_in_one_line():
    with pytest.raises(MeshError, match="^its Reeb graph cannot be built: [^\n]*$"):
        graph(*FLAT)


def test_a_batch_skips_a_mesh_without_a_graph_and_goes_on(tmp_path):
    two_classes(tmp_path / "data")
    write_off(tmp_path / "data/round/flat.off", *FLAT)
    args = ["index", str(tmp_path / "data"), "-o", str(tmp_path / "index"), "--descriptor", "amrg"]
    out = CliRunner().invoke(main, args)
    assert "4 meshes added or updated, 4 in the index" in out.output
    assert "round/flat.off: its Reeb graph cannot be built: the surface has no" in out.output


def test_search_equals_a_full_scan(tmp_path):
    """Graphs of eight shapes, each indexed several times (ties), in two segments with a row
    superseded: the bounded search returns the full scan's rows and distances."""
    shapes = [limbed_body(n, pose) for n in (1, 2, 3, 4, 5) for pose in (0, 1)][:8]
    base = np.array([amrg.pack(graph(*shape)) for shape in shapes], np.float32)
    rows = [base[(3 * i) % len(base)].copy() for i in range(30)]
    assert_search_equals_full_scan(tmp_path / "index", Params(descriptor="amrg"), rows, base)


def test_the_command_line_indexes_queries_evaluates_and_checks(tmp_path):
    assert_command_line_round_trip(tmp_path, "amrg")
