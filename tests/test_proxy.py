"""The repair stage's proxy (`cfsig.repair.proxy`) on generated meshes: it keeps the shape."""

import igl
import numpy as np
import trimesh

from cfsig.files.elements import components, edge_graph, mesh_edges
from cfsig.files.mesh import Mesh, clean_mesh
from cfsig.isolate import Limits
from cfsig.repair import proxy as proxy_module
from cfsig.repair.proxy import proxy_mesh
from tests.helpers import icosphere


def _soup(*parts: trimesh.Trimesh) -> Mesh:
    """One mesh of separate parts, each with its own vertices (they may cross each other)."""
    joined = trimesh.util.concatenate(parts)
    return clean_mesh(np.asarray(joined.vertices), np.asarray(joined.faces))


def _closed(mesh: Mesh) -> bool:
    return bool(np.all(np.diff(mesh_edges(mesh.faces, len(mesh.vertices)).starts) == 2))


def _inside(mesh: Mesh, points: np.ndarray) -> np.ndarray:
    """Whether each point is inside the closed mesh (generalized winding number above 1/2)."""
    return np.abs(igl.winding_number(mesh.vertices, mesh.faces, points)) > 0.5


def _chair():
    """A desk chair as web models make it: a seat, a back that is one open sheet, a column,
    five thin legs crossing the column and five small wheels, each a separate closed part.
    Returns the soup and a point inside each leg and each wheel."""
    seat = trimesh.creation.box((1.0, 0.08, 1.0))
    seat.apply_translation((0, 0.9, 0))
    back = trimesh.Trimesh(
        [[-0.5, 0.95, -0.5], [0.5, 0.95, -0.5], [0.5, 1.8, -0.5], [-0.5, 1.8, -0.5]],
        [[0, 1, 2], [0, 2, 3]],
    )
    column = trimesh.creation.cylinder(radius=0.04, height=0.8, sections=24)
    column.apply_transform(trimesh.transformations.rotation_matrix(np.pi / 2, (1, 0, 0)))
    column.apply_translation((0, 0.5, 0))
    parts, inner = [seat, back, column], []
    for k in range(5):
        angle = 2 * np.pi * k / 5
        direction = np.array([np.cos(angle), 0.0, np.sin(angle)])
        leg = trimesh.creation.box((0.6, 0.035, 0.035))
        leg.apply_transform(trimesh.transformations.rotation_matrix(-angle, (0, 1, 0)))
        leg.apply_translation(0.3 * direction + (0, 0.12, 0))
        wheel = trimesh.creation.icosphere(subdivisions=2, radius=0.05)
        wheel.apply_translation(0.58 * direction + (0, 0.05, 0))
        parts += [leg, wheel]
        inner += [0.3 * direction + (0, 0.12, 0), 0.58 * direction + (0, 0.05, 0)]
    return _soup(*parts), np.array(inner)


def test_the_proxy_of_a_chair_keeps_every_leg_and_wheel():
    chair, inner = _chair()
    proxy = proxy_mesh(chair, Limits())
    assert proxy.route == "proxy" and _closed(proxy)
    assert len(proxy.faces) <= proxy_module.PROXY_FACES
    assert _inside(proxy, inner).all()  # every leg and every wheel has its volume
    # The back is an open sheet: the proxy keeps it as a thin slab, not dropped.
    assert _inside(proxy, np.array([[0.0, 1.4, -0.5]])).all()
    # Legs are apart: the space between two of them, at their height, stays outside.
    between = 0.3 * np.array([np.cos(np.pi / 5), 0, np.sin(np.pi / 5)]) + (0, 0.12, 0)
    assert not _inside(proxy, between[None]).any()


def test_parts_apart_are_all_kept():
    big, small = trimesh.creation.icosphere(3, 1.0), trimesh.creation.icosphere(3, 0.3)
    small.apply_translation((3.0, 0, 0))
    proxy = proxy_mesh(_soup(big, small), Limits())
    count, _ = components(edge_graph(proxy.faces, len(proxy.vertices)))
    assert count == 2 and _closed(proxy)
    assert _inside(proxy, np.array([[0.0, 0, 0], [3.0, 0, 0]])).all()


def test_the_proxy_of_a_sphere_is_not_fattened():
    v, f = icosphere(4)
    proxy = proxy_mesh(clean_mesh(v, f), Limits())
    radius = np.linalg.norm(proxy.vertices, axis=1)
    # Within 1% of the unit radius: the old proxy's offset of two of 64 cells added 6%.
    assert abs(radius.mean() - 1) < 0.01 and radius.max() < 1.02


def test_a_hidden_inner_part_leaves_no_cavity():
    proxy = proxy_mesh(clean_mesh(*_stack_spheres(*icosphere(3))), Limits())
    count, _ = components(edge_graph(proxy.faces, len(proxy.vertices)))
    assert count == 1 and _inside(proxy, np.zeros((1, 3))).all()


def _stack_spheres(v, f):
    """A unit sphere with a smaller one inside it, facing inward (a cavity's orientation)."""
    return np.vstack([v, 0.3 * v]), np.vstack([f, f[:, ::-1] + len(v)])


def test_a_holed_shell_is_closed_over_its_hole():
    v, f = icosphere(3)
    cap = (v[f][:, :, 2] > 0.7).all(axis=1)  # a hole of a fifth of the radius, not a sheet
    proxy = proxy_mesh(clean_mesh(v, f[~cap]), Limits())
    count, _ = components(edge_graph(proxy.faces, len(proxy.vertices)))
    assert count == 1 and _closed(proxy)
    assert _inside(proxy, np.array([[0.0, 0, 0], [0, 0, 0.6]])).all()  # filled, hole spanned
