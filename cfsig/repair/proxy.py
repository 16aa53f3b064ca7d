"""The repair stage's last resort: the outer surface of any triangle input, rebuilt on a grid.

`cfsig.repair.stage.repair_mesh` takes this route when local repairs cannot make the input one
closed manifold (docs/method.md, section "The repair stage"). The remesh runs in a child
process under a time and memory limit (`cfsig.isolate`).
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np

from cfsig.errors import MeshError
from cfsig.files.elements import components, edge_graph, edge_lengths, face_areas
from cfsig.files.mesh import Mesh, clean_mesh
from cfsig.isolate import Limits, run_limited
from cfsig.repair.simplify import decimate

# The proxy's grid: cells along the bounding box's longest side, and the offset of its
# iso-surface outside the input, in cells.
PROXY_CELLS = 64
PROXY_OFFSET = 2.0
# Marching cubes gives more faces the larger the surface; the proxy is simplified to this many.
PROXY_FACES = 8000


def proxy_mesh(mesh: Mesh, limits: Limits) -> Mesh:
    """The proxy route: the outer surface rebuilt on a grid, in a child process.

    Parameters
    ----------
    mesh : Mesh
        A checked mesh.
    limits : Limits
        Time and memory allowed to the remesh.

    Returns
    -------
    mesh : Mesh
        The proxy's largest part by area, checked, with ``route="proxy"``: parts further apart
        than the offset stay apart on the grid, and each would get its own unrelated
        distribution of phi (the paper's drawback this stage exists for).

    Raises
    ------
    MeshError
        The proxy came out empty; `StageLimitError` past the limits.
    """
    vertices, faces = run_limited(
        offset_surface, (mesh.vertices, mesh.faces), limits, "the proxy remesh"
    )
    if len(faces) == 0:
        raise MeshError("the proxy surface is empty (a flat or degenerate model)")
    proxy = clean_mesh(vertices, faces)
    n_parts, labels = components(edge_graph(proxy.faces, len(proxy.vertices)))
    note = f"replaced by a proxy of its outer surface ({len(proxy.faces)} faces)"
    if n_parts > 1:
        face_part = labels[proxy.faces[:, 0]]
        area = face_areas(edge_lengths(proxy.vertices, proxy.faces))
        largest = np.argmax(np.bincount(face_part, area, n_parts))
        proxy = clean_mesh(proxy.vertices, proxy.faces[face_part == largest], weld=False)
        note = f"replaced by a proxy of its outer surface, its largest of {n_parts} parts "
        note += f"({len(proxy.faces)} faces)"
    return replace(proxy, repairs=(*mesh.repairs, note), route="proxy")


def offset_surface(vertices: np.ndarray, faces: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The iso-surface just outside a triangle soup, on a grid of `PROXY_CELLS` cells.

    Simplified by quadric edge collapses (fast-simplification) to `PROXY_FACES` faces.

    Parameters
    ----------
    vertices : (n, 3) float64
        Vertex positions.
    faces : (m, 3) int64
        Triangles, in any orientation.

    Returns
    -------
    vertices : (p, 3) float64
        The iso-surface's vertices.
    faces : (q, 3) int64
        Its triangles (marching cubes: closed and manifold).
    """
    import igl

    cell = float(np.ptp(vertices, axis=0).max()) / PROXY_CELLS
    oriented, _ = igl.bfs_orient(faces)
    result = igl.offset_surface(
        vertices, oriented, PROXY_OFFSET * cell, PROXY_CELLS,
        igl.SIGNED_DISTANCE_TYPE_FAST_WINDING_NUMBER,
    )  # fmt: skip
    return decimate(result[0], result[1], PROXY_FACES)
