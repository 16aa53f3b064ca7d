"""Spikes, a scanner's outliers: `cfsig.repair.spikes` and the repair stage's use of it."""

import numpy as np

from cfsig.files.elements import edge_lengths, mesh_edges
from cfsig.files.mesh import clean_mesh
from cfsig.params import Params
from cfsig.repair.spikes import SPIKE_RATIO, flatten_spikes
from cfsig.repair.stage import repair_mesh
from tests.helpers import icosphere, l1, open_cylinder, signature_vector, torus

SPHERE = icosphere(4)


def _thrown(vertices, faces, count, reach, seed):
    """``count`` vertices, none two neighbours, each thrown ``reach`` in a random direction."""
    rng = np.random.default_rng(seed)
    edges = mesh_edges(faces, len(vertices)).ends
    chosen: list[int] = []
    for i in rng.permutation(len(vertices)):
        near = edges[(edges == i).any(axis=1)].ravel()
        if not np.isin(near, chosen).any():
            chosen.append(int(i))
        if len(chosen) == count:
            break
    away = rng.normal(size=(count, 3))
    moved = vertices.copy()
    moved[chosen] += reach * away / np.linalg.norm(away, axis=1)[:, None]
    return moved, np.array(chosen)


def test_thrown_vertices_go_back_among_their_neighbours():
    v, f = SPHERE
    edge = float(np.median(edge_lengths(v, f)))
    thrown, chosen = _thrown(v, f, 5, 1.0, seed=1)
    moved, count = flatten_spikes(thrown, mesh_edges(f, len(v)))
    assert count == 5
    # Back within half an edge of where they were, on a sphere of radius 1.
    assert np.linalg.norm(moved[chosen] - v[chosen], axis=1).max() < 0.5 * edge
    others = np.setdiff1d(np.arange(len(v)), chosen)
    assert np.array_equal(moved[others], thrown[others])


def test_surfaces_without_spikes_are_left_as_they_are():
    for v, f in (SPHERE, torus(), icosphere(1)):
        moved, count = flatten_spikes(v, mesh_edges(f, len(v)))
        assert count == 0 and moved is v


def test_a_needle_shorter_than_the_ratio_is_kept():
    # One vertex pulled out into a needle: kept while its nearest neighbour lies within the
    # ratio times its base's radius, flattened beyond.
    v, f = SPHERE
    edges = mesh_edges(f, len(v))
    tip = int(np.argmax(v[:, 2]))
    ring = v[np.unique(edges.ends[(edges.ends == tip).any(axis=1)])]
    ring = ring[~np.all(ring == v[tip], axis=1)]
    radius = float(np.linalg.norm(ring - ring.mean(axis=0), axis=1).max())
    for length, expected in ((0.8 * SPIKE_RATIO, 0), (1.2 * SPIKE_RATIO, 1)):
        needle = v.copy()
        needle[tip] = ring.mean(axis=0) + [0, 0, length * radius]
        assert flatten_spikes(needle, edges)[1] == expected


def test_a_boundary_vertex_is_never_a_spike():
    v, f = open_cylinder()
    edges = mesh_edges(f, len(v))
    boundary = edges.ends[np.diff(edges.starts) == 1].ravel()
    thrown = v.copy()
    thrown[boundary[0]] += [0, 0, 50.0]
    assert flatten_spikes(thrown, edges)[1] == 0


def test_the_repair_stage_flattens_spikes_unless_off():
    v, f = SPHERE
    thrown, _ = _thrown(v, f, 3, 1.0, seed=2)
    mesh = clean_mesh(thrown, f)
    repaired = repair_mesh(mesh)
    assert repaired.route == "repaired"
    assert any("3 spikes" in line for line in repaired.repairs)
    assert np.array_equal(repair_mesh(mesh, "off").vertices, thrown)
    assert repair_mesh(clean_mesh(*SPHERE)).route == "clean"


def test_spikes_move_a_signature_less_than_a_slight_stretch():
    # Shot noise (vertices thrown a radius) moves the intrinsic vector, once flattened, less
    # than stretching the sphere by 10% does; left in, more.
    v, f = SPHERE
    clean = signature_vector(v, f, Params())
    stretched = signature_vector(v * [1.1, 1, 1], f, Params())
    thrown, _ = _thrown(v, f, 4, 1.0, seed=3)
    flattened = signature_vector(thrown, f, Params())
    kept = signature_vector(thrown, f, Params(repair="off"))
    assert l1(flattened, clean) < l1(stretched, clean) < l1(kept, clean)
