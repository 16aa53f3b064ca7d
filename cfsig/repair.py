"""The repair stage: from any triangle input to a surface the descriptor means something on.

The conformal factor is defined on a closed manifold (paper section 2); on a model made of
separate parts it is solved per part, and each part gets an unrelated distribution (the paper's
"most important drawback", section 4). `repair_mesh` runs between reading (`cfsig.mesh`, which
always welds, drops duplicates and degenerate faces and splits non-manifold vertices) and the
numerics, and chooses one of three routes (docs/method.md, "Repair"):

- ``clean``: the mesh is one closed manifold; it passes unchanged, bit for bit.
- ``repaired``: local repairs make it one: parts whose boundaries nearly meet are stitched,
  small open fragments (fins, stray triangles) and parts enclosed by another part are dropped,
  holes are closed by fans. The rest of the surface is kept exactly.
- ``proxy``: otherwise, the outer surface is rebuilt: the iso-surface, slightly outside the
  input, of its signed distance with the sign of the generalized winding number (libigl's
  ``offset_surface``), on a grid of a fixed number of cells along the longest side of the
  bounding box, so that its resolution follows the shape and not the input's tessellation. It
  runs in a child process under a time and memory limit (`cfsig.isolate`).
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np
from scipy.sparse.csgraph import connected_components
from scipy.spatial import cKDTree

from .errors import MeshError
from .geometry import edge_lengths, face_areas, mesh_edges
from .isolate import Limits, run_limited
from .mesh import Mesh, clean_mesh
from .params import REPAIR_MODES

# Boundary vertices of different parts closer than this fraction of the bounding-box diagonal
# are stitched together.
STITCH_DISTANCE = 0.01
# Open parts with less than this fraction of the total area are fragments, dropped.
FRAGMENT_AREA = 0.01
# Local repairs are tried on at most this many parts; beyond, the proxy is built directly.
MAX_PARTS = 64
# The proxy's grid: cells along the bounding box's longest side, and the offset of its
# iso-surface outside the input, in cells.
PROXY_CELLS = 64
PROXY_OFFSET = 0.5
# Marching cubes gives more faces the larger the surface; the proxy is simplified to this many.
PROXY_FACES = 8000


def repair_mesh(mesh: Mesh, mode: str = "auto", limits: Limits | None = None) -> Mesh:
    """Make a checked mesh into one closed manifold, or the closest surface there is.

    Parameters
    ----------
    mesh : Mesh
        A checked mesh, as `cfsig.mesh.clean_mesh` returns.
    mode : {"auto", "off", "proxy"}
        ``"auto"``: the first route that applies (module docstring); ``"off"``: the mesh as
        read, solved per component; ``"proxy"``: the proxy for anything but a clean mesh.
    limits : Limits, optional
        Time and memory allowed to the proxy (default `Limits()`).

    Returns
    -------
    mesh : Mesh
        With ``route`` set (``"clean"``, ``"repaired"``, ``"proxy"`` or ``"unrepaired"``)
        and what was done appended to ``repairs``.

    Raises
    ------
    MeshError
        The proxy failed, exceeded its limits (`StageLimitError`) or came out empty.
    ValueError
        Unknown mode.
    """
    if mode not in REPAIR_MODES:
        raise ValueError(f"unknown repair mode {mode!r}; choose from {', '.join(REPAIR_MODES)}")
    edges = mesh.edges if mesh.edges is not None else mesh_edges(mesh.faces, len(mesh.vertices))
    n_parts, labels = _parts(edges.ends, len(mesh.vertices))
    if n_parts == 1 and np.all(np.diff(edges.starts) == 2):
        return mesh
    if mode == "off":
        return replace(mesh, route="unrepaired")
    if mode == "auto" and n_parts <= MAX_PARTS:
        repaired = _local_repairs(mesh, labels)
        if repaired is not None:
            return repaired
    return proxy_mesh(mesh, limits or Limits())


def _local_repairs(mesh: Mesh, labels: np.ndarray) -> Mesh | None:
    """Stitch, drop fragments, fill holes, drop enclosed parts; None unless one closed part."""
    done = list(mesh.repairs)
    vertices, faces = mesh.vertices, mesh.faces
    diagonal = float(np.linalg.norm(np.ptp(vertices, axis=0)))
    boundary = _boundary_vertices(mesh_edges(faces, len(vertices)), len(vertices))
    merged = stitch(vertices, labels, boundary, STITCH_DISTANCE * diagonal)
    if merged is not None:
        vertices, count = merged
        faces = clean_mesh(vertices, faces)
        vertices, faces = faces.vertices, faces.faces
        done.append(f"stitched {count} pairs of boundary vertices between parts")
    vertices, faces, dropped = drop_fragments(vertices, faces, FRAGMENT_AREA)
    if dropped:
        done.append(f"dropped {dropped} small open fragments")
    vertices, faces, filled = fill_holes(vertices, faces)
    if filled:
        done.append(f"closed {filled} holes")
    vertices, faces, enclosed = drop_enclosed(vertices, faces)
    if enclosed:
        done.append(f"dropped {enclosed} parts enclosed by another")
    result = clean_mesh(vertices, faces)
    edges = result.edges if result.edges is not None else mesh_edges(result.faces, len(vertices))
    n_parts, _ = _parts(edges.ends, len(result.vertices))
    if n_parts != 1 or not np.all(np.diff(edges.starts) == 2):
        return None
    return replace(result, repairs=tuple(done), route="repaired")


def stitch(
    vertices: np.ndarray, labels: np.ndarray, boundary: np.ndarray, distance: float
) -> tuple[np.ndarray, int] | None:
    """Merge boundary vertices of different parts that are each other's nearest.

    Parameters
    ----------
    vertices : (n, 3) float64
        Vertex positions.
    labels : (n,) int
        Part (connected component) of each vertex.
    boundary : (n,) bool
        Vertices on a boundary edge.
    distance : float
        Largest distance between two vertices to merge, in length units.

    Returns
    -------
    result : tuple or None
        The vertices with each merged pair moved to its midpoint (they then coincide, and
        `clean_mesh` welds them) and the number of pairs; None when no pair qualifies.
    """
    candidates = np.flatnonzero(boundary)
    if len(candidates) < 2:
        return None
    points = vertices[candidates]
    k = min(8, len(candidates))
    _, near = cKDTree(points).query(points, k=k, distance_upper_bound=distance)
    other = (near < len(candidates)) & (
        labels[candidates[np.minimum(near, len(candidates) - 1)]] != labels[candidates][:, None]
    )
    has = other.any(axis=1)
    first = np.argmax(other, axis=1)
    partner = np.where(has, near[np.arange(len(candidates)), first], -1)
    mutual = has & (partner[np.maximum(partner, 0)] == np.arange(len(candidates)))
    a = np.flatnonzero(mutual & (np.arange(len(candidates)) < partner))
    if len(a) == 0:
        return None
    b = partner[a]
    moved = vertices.copy()
    middle = (points[a] + points[b]) / 2
    moved[candidates[a]] = middle
    moved[candidates[b]] = middle
    return moved, len(a)


def drop_fragments(
    vertices: np.ndarray, faces: np.ndarray, fraction: float
) -> tuple[np.ndarray, np.ndarray, int]:
    """Drop open parts whose area is below a fraction of the total.

    Parameters
    ----------
    vertices : (n, 3) float64
        Vertex positions.
    faces : (m, 3) int64
        Triangles.
    fraction : float
        Area fraction below which an open part is dropped.

    Returns
    -------
    vertices : (n, 3) float64
        Unchanged (unreferenced vertices are removed later by `clean_mesh`).
    faces : (m', 3) int64
        The faces kept.
    dropped : int
        Number of parts dropped.
    """
    edges = mesh_edges(faces, len(vertices))
    n_parts, labels = _parts(edges.ends, len(vertices))
    face_part = labels[faces[:, 0]]
    area = np.bincount(face_part, face_areas(edge_lengths(vertices, faces)), n_parts)
    open_part = np.zeros(n_parts, dtype=bool)
    open_part[labels[edges.ends[np.diff(edges.starts) == 1, 0]]] = True
    drop = open_part & (area < fraction * area.sum())
    if not drop.any() or drop.all():
        return vertices, faces, 0
    return vertices, faces[~drop[face_part]], int(drop.sum())


def fill_holes(vertices: np.ndarray, faces: np.ndarray) -> tuple[np.ndarray, np.ndarray, int]:
    """Close every boundary loop: a triangle for a loop of three, else a fan from its centroid.

    Parameters
    ----------
    vertices : (n, 3) float64
        Vertex positions.
    faces : (m, 3) int64
        Triangles with at most two faces per edge and one fan per vertex (`clean_mesh`), so
        that every boundary vertex has exactly two boundary edges.

    Returns
    -------
    vertices : (n + h, 3) float64
        With one new vertex at the centroid of each loop longer than three.
    faces : (m + k, 3) int64
        With the new triangles.
    filled : int
        Number of loops closed.
    """
    loops = boundary_loops(mesh_edges(faces, len(vertices)), len(vertices))
    new_vertices, new_faces = [vertices], [faces]
    count = len(vertices)
    for loop in loops:
        if len(loop) == 3:
            new_faces.append(loop[None, :])
            continue
        new_vertices.append(vertices[loop].mean(axis=0, keepdims=True))
        fan = np.column_stack([np.full(len(loop), count), loop, np.roll(loop, -1)])
        new_faces.append(fan)
        count += 1
    return np.vstack(new_vertices), np.vstack(new_faces), len(loops)


def boundary_loops(edges, n_vertices: int) -> list[np.ndarray]:
    """The boundary edges as closed loops of vertices.

    Parameters
    ----------
    edges : geometry.Edges
        The mesh's edges; every boundary vertex has exactly two boundary edges.
    n_vertices : int
        Number of vertices n.

    Returns
    -------
    loops : list of (k,) int64
        Each loop's vertices in order along it.
    """
    ends = edges.ends[np.diff(edges.starts) == 1]
    if len(ends) == 0:
        return []
    # Each boundary vertex's two neighbours along the boundary.
    neighbours = np.full((n_vertices, 2), -1, dtype=np.int64)
    both, other = np.r_[ends[:, 0], ends[:, 1]], np.r_[ends[:, 1], ends[:, 0]]
    order = np.argsort(both, kind="stable")
    both, other = both[order], other[order]
    first = np.r_[True, both[1:] != both[:-1]]
    neighbours[both[first], 0] = other[first]
    neighbours[both[~first], 1] = other[~first]
    loops = []
    seen = np.zeros(n_vertices, dtype=bool)
    for start in np.unique(ends):
        if seen[start]:
            continue
        loop = [int(start)]
        seen[start] = True
        previous, current = -1, int(start)
        while True:
            a, b = neighbours[current]
            following = int(b if a == previous else a)
            if following < 0 or seen[following]:
                break
            loop.append(following)
            seen[following] = True
            previous, current = current, following
        if len(loop) >= 3:
            loops.append(np.array(loop, dtype=np.int64))
    return loops


def drop_enclosed(vertices: np.ndarray, faces: np.ndarray) -> tuple[np.ndarray, np.ndarray, int]:
    """Drop closed parts that lie inside another part (hidden inner geometry).

    A part is inside when the generalized winding number of the other parts, consistently
    oriented, is above one half in magnitude at most of its vertices.

    Parameters
    ----------
    vertices : (n, 3) float64
        Vertex positions.
    faces : (m, 3) int64
        Triangles.

    Returns
    -------
    vertices : (n, 3) float64
        Unchanged.
    faces : (m', 3) int64
        The faces kept.
    dropped : int
        Number of parts dropped.
    """
    import igl

    edges = mesh_edges(faces, len(vertices))
    n_parts, labels = _parts(edges.ends, len(vertices))
    if n_parts < 2:
        return vertices, faces, 0
    oriented, _ = igl.bfs_orient(faces)
    face_part = labels[faces[:, 0]]
    rng = np.random.default_rng(0)
    enclosed = np.zeros(n_parts, dtype=bool)
    for part in range(n_parts):
        members = np.flatnonzero(labels == part)
        probes = vertices[rng.choice(members, size=min(16, len(members)), replace=False)]
        others = oriented[(face_part != part) & ~enclosed[face_part]]
        winding = np.abs(igl.winding_number(vertices, others, probes))
        enclosed[part] = np.median(winding) > 0.5
    if not enclosed.any():
        return vertices, faces, 0
    return vertices, faces[~enclosed[face_part]], int(enclosed.sum())


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
        The proxy, checked, with ``route="proxy"``.

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
    note = f"replaced by a proxy of its outer surface ({len(proxy.faces)} faces)"
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
    vertices, faces = result[0], result[1]
    if len(faces) > PROXY_FACES:
        import fast_simplification

        vertices, faces = fast_simplification.simplify(
            vertices, faces.astype(np.int32), target_count=PROXY_FACES
        )
    return np.asarray(vertices, dtype=np.float64), np.asarray(faces, dtype=np.int64)


def _parts(ends: np.ndarray, n_vertices: int) -> tuple[int, np.ndarray]:
    """Connected components of the vertex graph given by its edges."""
    import scipy.sparse as sp

    graph = sp.coo_matrix(
        (np.ones(len(ends)), (ends[:, 0], ends[:, 1])), shape=(n_vertices, n_vertices)
    )
    count, labels = connected_components(graph, directed=False)
    return int(count), labels


def _boundary_vertices(edges, n_vertices: int) -> np.ndarray:
    """Vertices on an edge of one face."""
    mask = np.zeros(n_vertices, dtype=bool)
    mask[edges.ends[np.diff(edges.starts) == 1].ravel()] = True
    return mask
