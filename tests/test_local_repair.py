"""Local repairs for heavy damage (`cfsig.repair.local`), each on small generated meshes."""

import igl
import numpy as np

from cfsig.descriptors.signature import compute_signature
from cfsig.files.elements import mesh_edges
from cfsig.files.mesh import clean_mesh
from cfsig.params import Params
from cfsig.repair.local import drop_dangling, drop_hidden, orient_parts, split_t_junctions
from cfsig.repair.stage import repair_mesh
from tests.helpers import disk, icosphere, random_rotation
from tests.helpers import l1 as _l1

SPHERE = icosphere(3)


def _stack(*parts):
    """One mesh of several (vertices, faces) parts, each with its own vertices."""
    offsets = np.cumsum([0] + [len(v) for v, _ in parts[:-1]])
    faces = [f + o for (_, f), o in zip(parts, offsets, strict=True)]
    return np.vstack([v for v, _ in parts]), np.vstack(faces)


def _box(low, high):
    """A closed, outward-oriented box, each side two triangles."""
    v, f = _unit_box()
    return np.asarray(low) + v * (np.asarray(high) - np.asarray(low)), f


def _unit_box():
    v = np.array([[x, y, z] for x in (0, 1) for y in (0, 1) for z in (0, 1)], dtype=float)
    f = np.array(
        [[0, 1, 3], [0, 3, 2], [4, 6, 7], [4, 7, 5], [0, 4, 5], [0, 5, 1]]
        + [[2, 3, 7], [2, 7, 6], [0, 2, 6], [0, 6, 4], [1, 5, 7], [1, 7, 3]]
    )
    return v, f


def _closed_parts(mesh):
    """The number of parts, and whether every edge has two faces."""
    edges = mesh_edges(mesh.faces, len(mesh.vertices))
    count = igl.vertex_components(mesh.faces).max() + 1
    return int(count), bool(np.all(np.diff(edges.starts) == 2))


def _volume(vertices, faces):
    corners = vertices[faces]
    return float(np.einsum("ij,ij->", corners[:, 0], np.cross(corners[:, 1], corners[:, 2]))) / 6


def _inside(mesh, points):
    """Whether each point is inside the mesh, by its winding number."""
    return np.abs(igl.winding_number(mesh.vertices, mesh.faces, np.asarray(points, float))) > 0.5


def _fins(vertices, faces, every):
    """A fin (a third triangle, its tip just off the surface) on every ``every``-th edge."""
    edges = mesh_edges(faces, len(vertices)).ends[::every]
    a, b = edges.T
    tips = (vertices[a] + vertices[b]) / 2 * 1.05
    fins = np.column_stack([a, b, len(vertices) + np.arange(len(edges))])
    return np.vstack([vertices, tips]), np.vstack([faces, fins])


def test_fins_on_a_fifth_of_the_edges_are_dropped():
    v, f = SPHERE
    fv, ff = _fins(v, f, 5)
    mesh = clean_mesh(fv, ff)
    repaired = repair_mesh(mesh)
    assert repaired.route == "repaired"
    assert _closed_parts(repaired) == (1, True) and len(repaired.faces) == len(f)
    params = Params(descriptor="cf")
    clean = compute_signature(clean_mesh(v, f), params)
    assert _l1(compute_signature(mesh, params).vector, clean.vector) < 1e-9


def test_fins_duplicates_and_flips_at_once():
    v, f = SPHERE
    rng = np.random.default_rng(0)
    flipped = f.copy()
    flip = rng.random(len(f)) < 0.3
    flipped[flip] = flipped[flip, ::-1]
    fv, ff = _fins(v, flipped, 7)
    ff = np.vstack([ff, f[rng.choice(len(f), 40, replace=False), ::-1]])
    repaired = repair_mesh(clean_mesh(fv, ff))
    assert repaired.route == "repaired" and _closed_parts(repaired) == (1, True)
    assert len(repaired.faces) == len(f)


def test_a_dangling_strip_goes_and_its_edge_closes():
    v, f = SPHERE
    a, b = f[0, :2]
    far = (v[a] + v[b]) / 2 * 1.1
    strip_v = np.vstack([v, far, far * 1.1])
    n = len(v)
    strip = np.array([[a, b, n], [b, n + 1, n]])  # two faces: one on the edge, one beyond
    faces, dangling, walls = drop_dangling(strip_v, np.vstack([f, strip]), 0.01)
    assert dangling == 1 and walls == 0 and len(faces) == len(f)


def test_an_inner_wall_between_two_boxes_goes():
    # Two unit cubes side by side, with the square between them kept: its four edges have
    # three faces each, and only the outer sheets close the surface.
    left, right = _box([0, 0, 0], [1, 1, 1]), _box([1, 0, 0], [2, 1, 1])
    wall = left[1][[2, 3]]  # the side x = 1 of the left cube
    outer_left = np.delete(left[1], [2, 3], axis=0)
    outer_right = np.delete(right[1], [0, 1], axis=0)  # its side x = 1 is the right one's x = 0
    mesh = clean_mesh(*_stack((left[0], np.vstack([outer_left, wall])), (right[0], outer_right)))
    repaired = repair_mesh(mesh)
    assert repaired.route == "repaired" and any("inner walls" in r for r in repaired.repairs)
    assert _closed_parts(repaired) == (1, True) and len(repaired.faces) == 20
    assert abs(abs(_volume(repaired.vertices, repaired.faces)) - 2.0) < 1e-12


def test_orientation_is_made_consistent_and_outward():
    v, f = SPHERE
    rng = np.random.default_rng(1)
    mixed = f.copy()
    flip = rng.random(len(f)) < 0.4
    mixed[flip] = mixed[flip, ::-1]
    second = (0.3 * v + [3.0, 0, 0], f[:, ::-1])  # a whole part inward
    vertices, faces = _stack((v, mixed), second)
    oriented = orient_parts(vertices, faces)
    assert {frozenset(face) for face in oriented} == {frozenset(face) for face in faces}
    first = oriented[: len(f)]
    assert _volume(vertices, first) > 0 and _volume(vertices, oriented[len(f) :]) > 0
    # Consistent: every edge run once each way.
    half = np.sort(np.column_stack([first.ravel(), first[:, [1, 2, 0]].ravel()]), axis=1)
    directed = first.ravel() < first[:, [1, 2, 0]].ravel()
    _, which = np.unique(half, axis=0, return_inverse=True)
    assert np.all(np.bincount(which.ravel(), directed) == 1)


def _t_junction_halves():
    """The sphere cut into two halves meshed independently: the upper half's faces along the
    cut are split at their cut edge's midpoint, a vertex inside the lower half's edge."""
    v, f = SPHERE
    upper = v[f].mean(axis=1)[:, 2] > 0
    lower_faces, upper_faces = f[~upper], f[upper]
    lower_edges = mesh_edges(lower_faces, len(v))
    seam = lower_edges.ends[np.diff(lower_edges.starts) == 1]
    on_seam = {tuple(e) for e in seam}
    vertices, faces = [v], []
    for face in upper_faces:
        for j in range(3):
            a, b, c = face[j], face[(j + 1) % 3], face[(j + 2) % 3]
            if (min(a, b), max(a, b)) in on_seam:
                m = len(v) + len(vertices) - 1
                vertices.append(((v[a] + v[b]) / 2)[None])
                faces += [[a, m, c], [m, b, c]]
                break
        else:
            faces.append(face)
    upper_mesh = (np.vstack(vertices), np.array(faces))
    return (v, lower_faces), upper_mesh, len(seam)


def test_t_junctions_are_stitched_by_splitting_edges():
    lower, upper, n_seam = _t_junction_halves()
    vertices, faces = _stack(lower, upper)
    mesh = clean_mesh(vertices, faces)  # welds the seam's shared corners
    split, count = split_t_junctions(mesh.vertices, mesh.faces, None, 1e-9)
    assert count == n_seam and len(split) == len(mesh.faces) + n_seam
    repaired = repair_mesh(mesh)
    assert repaired.route == "repaired" and any("T-junctions" in r for r in repaired.repairs)
    assert _closed_parts(repaired) == (1, True)
    assert not any("holes" in r for r in repaired.repairs)  # closed by the splits alone


def _chair():
    """A seat, four legs crossing into it, and a wheel near the foot of each leg."""
    seat = _box([0, 0, 1.0], [2, 2, 1.3])
    legs = [_box([x, y, 0.2], [x + 0.2, y + 0.2, 1.1]) for x in (0.1, 1.7) for y in (0.1, 1.7)]
    wheel_v, wheel_f = icosphere(2)
    wheels = [
        (0.1 * wheel_v + [x + 0.1, y + 0.1, 0.08], wheel_f) for x in (0.1, 1.7) for y in (0.1, 1.7)
    ]
    return seat, legs, wheels


def test_a_model_of_several_closed_parts_keeps_every_part():
    seat, legs, wheels = _chair()
    mesh = clean_mesh(*_stack(seat, *legs, *wheels))
    repaired = repair_mesh(mesh)
    assert repaired.route == "repaired"
    # The legs are joined to the seat; the wheels, apart from them, stay parts.
    assert _closed_parts(repaired) == (5, True)
    centres = [v.mean(axis=0) for v, _ in (seat, *legs, *wheels)]
    assert np.all(_inside(repaired, centres))
    union = 2 * 2 * 0.3 + 4 * 0.2 * 0.2 * 0.8
    wheel_volumes = sum(_volume(*wheel) for wheel in wheels)
    assert abs(_volume(repaired.vertices, repaired.faces) - union - wheel_volumes) < 1e-9
    sig = compute_signature(mesh, Params())
    assert sig.route == "repaired" and sig.n_components == 5 and np.isfinite(sig.vector).all()


def test_crossing_parts_are_joined_by_their_union():
    v, f = SPHERE
    mesh = clean_mesh(*_stack((v, f), (v + [1.2, 0, 0], f[:, ::-1])))
    repaired = repair_mesh(mesh)
    assert repaired.route == "repaired" and any("union" in r for r in repaired.repairs)
    assert _closed_parts(repaired) == (1, True)
    assert np.all(_inside(repaired, [[-0.5, 0, 0], [0.6, 0, 0], [1.7, 0, 0]]))
    assert not np.any(_inside(repaired, [[0.6, 0.95, 0], [-1.1, 0, 0]]))


def test_a_small_closed_part_beside_the_body_is_kept():
    v, f = SPHERE
    button = (0.05 * icosphere(2)[0] + [1.2, 0, 0], icosphere(2)[1])
    mesh = clean_mesh(*_stack((v, f), button))
    repaired = repair_mesh(mesh)
    assert repaired.route == "repaired" and _closed_parts(repaired) == (2, True)
    assert np.array_equal(repaired.vertices[: len(v)], v) or len(repaired.vertices) == len(v) + len(
        button[0]
    )
    params = Params(descriptor="cf")
    alone = compute_signature(clean_mesh(v, f), params).vector
    both = compute_signature(mesh, params)
    assert both.n_components == 2 and _l1(both.vector, alone) < 0.2


def test_inner_parts_anywhere_inside_are_dropped():
    v, f = SPHERE
    small = icosphere(1)
    inner = [(0.1 * small[0] + c, small[1]) for c in ([0.8, 0, 0], [0, -0.7, 0.2], [0, 0, 0])]
    mesh = clean_mesh(*_stack((v, f), *inner))
    repaired = repair_mesh(mesh)
    assert repaired.route == "repaired" and any(
        "dropped 3 parts enclosed" in r for r in repaired.repairs
    )
    assert np.array_equal(repaired.vertices, v) and np.array_equal(repaired.faces, f)


def _walls(radius, count):
    """``count`` flat disks of ``radius`` through the origin, each turned its own way."""
    v, f = disk(24, 6)
    return [((radius / 6) * v @ random_rotation(seed).T, f) for seed in range(count)]


def test_inner_walls_crossing_each_other_inside_a_body_are_dropped():
    v, f = SPHERE
    mesh = clean_mesh(*_stack((v, f), *_walls(0.6, 3)))
    repaired = repair_mesh(mesh)
    assert repaired.route == "repaired"
    assert any("dropped 3 open parts inside closed ones" in r for r in repaired.repairs)
    assert _position_faces(repaired) == _position_faces(clean_mesh(v, f))


def test_an_open_part_through_the_surface_is_not_hidden():
    v, f = SPHERE
    mesh = clean_mesh(*_stack((v, f), *_walls(1.5, 1)))
    edges = mesh_edges(mesh.faces, len(mesh.vertices))
    labels = igl.vertex_components(mesh.faces)
    faces, dropped = drop_hidden(mesh.vertices, mesh.faces, labels, edges)
    assert dropped == 0 and np.array_equal(faces, mesh.faces)


def _projective_plane(points):
    """A closed surface that cannot be oriented: the icosahedron with antipodal vertices and
    faces identified (6 vertices, 10 triangles), its vertices at ``points``."""
    v, f = icosphere(0)
    antipode = np.argmin(np.linalg.norm(v[:, None] + v[None], axis=2), axis=1)
    _, vertex = np.unique(np.minimum(np.arange(len(v)), antipode), return_inverse=True)
    _, first = np.unique(np.sort(vertex[f], axis=1), axis=0, return_index=True)
    return np.asarray(points, dtype=float), vertex[f][first]


def test_crossing_parts_whose_union_is_refused_stay_apart():
    v, f = SPHERE
    points = np.random.default_rng(1).normal(size=(6, 3)) * 0.5 + [0.9, 0, 0]
    crossing = _projective_plane(points)
    mesh = clean_mesh(*_stack((v, f), crossing))
    assert _closed_parts(mesh) == (2, True)
    repaired = repair_mesh(mesh)
    assert repaired.route == "repaired" and any("refused" in r for r in repaired.repairs)
    assert len(repaired.faces) == len(f) + len(crossing[1])
    assert _position_faces(repaired) == _position_faces(mesh)


def _position_faces(mesh):
    """The faces as sets of vertex positions, independent of numbering and orientation."""
    return {frozenset(map(tuple, mesh.vertices[face])) for face in mesh.faces}


def test_a_boundary_crossing_an_edge_is_no_t_junction():
    # A triangle whose boundary edge runs from (0, 0, 0) to (1, 0, 0), and a second sheet with
    # a boundary vertex at that edge's midpoint.
    base = np.array([[0, 0, 0], [1, 0, 0], [0.5, 1, 0]], dtype=float)
    along = np.array([[0.2, 0, 0], [0.5, 0, 0], [0.8, 0, 0], [0.5, -0.5, 0]])
    across = np.array([[0.5, 0, 0], [0.5, -0.5, 0.5], [0.8, -0.3, -0.6]])
    for sheet, faces, expected in (
        (along, [[0, 1, 3], [1, 2, 3]], 1),  # its boundary runs along the edge: a seam
        (across, [[0, 1, 2]], 0),  # its boundary crosses the edge there
    ):
        vertices, triangles = _stack((base, np.array([[0, 1, 2]])), (sheet, np.array(faces)))
        split, count = split_t_junctions(vertices, triangles, None, 1e-9)
        assert count == expected
        assert len(split) == len(triangles) + expected
