"""The repair stage's last resort: the surface of any triangle input, rebuilt on a fine grid.

`cfsig.repair.stage.repair_mesh` takes this route when local repairs cannot make the input one
closed manifold (docs/method.md, section "The repair stage"). The proxy is the zero level set
of the distance to the input signed by its generalized winding number (libigl's fast winding
number, robust to holes, soups and flipped parts), less half a cell near open parts so that a
sheet becomes a thin slab, extracted by marching cubes on the grid cells near the surface only.
The cell size follows the shape's thinnest parts, so that legs, wheels and handles keep their
volume; every part of the result that encloses volume is kept. It runs in a child process
under a time and memory limit (`cfsig.isolate`).
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np

from cfsig.errors import MeshError
from cfsig.files.elements import (
    components,
    edge_graph,
    edge_lengths,
    face_areas,
    mesh_edges,
    open_parts,
    signed_volumes,
)
from cfsig.files.mesh import Mesh, clean_mesh
from cfsig.isolate import Limits, run_limited
from cfsig.repair.local import orient_parts
from cfsig.repair.simplify import decimate

# The cell size: the thickness of the thinnest parts (this percentile of the surface's area)
# over this many cells, between these numbers of cells along the bounding box's longest side.
THICKNESS_PERCENTILE = 5.0
CELLS_ACROSS = 3.0
MIN_CELLS, MAX_CELLS = 64, 384
# At most about this many cells carry the surface (coarser cells beyond): time and memory.
MAX_SURFACE_CELLS = 10_000
# The iso-surface lies this many cells outside open parts (a sheet becomes a slab), on the
# surface of closed ones.
SHEET_OFFSET = 0.5
# Marching cubes gives about 2.5 faces per surface cell; a proxy with more than this many (a
# bulky shape at `MIN_CELLS`) is simplified to it. Simplifying further splits thin parts.
PROXY_FACES = 40_000
# Points whose inward balls measure the thickness.
THICKNESS_SAMPLES = 300
# Cells along each side of the coarse grid that counts the parts' bounding boxes.
BOX_CELLS = 32


def proxy_mesh(mesh: Mesh, limits: Limits) -> Mesh:
    """The proxy route: the surface rebuilt on a grid, in a child process.

    Parameters
    ----------
    mesh : Mesh
        A checked mesh.
    limits : Limits
        Time and memory allowed to the remesh.

    Returns
    -------
    mesh : Mesh
        The proxy, checked, with ``route="proxy"``: every closed part of the rebuilt surface
        (parts of the input further apart than about a cell stay apart).

    Raises
    ------
    MeshError
        The proxy came out empty; `StageLimitError` past the limits.
    """
    vertices, faces = run_limited(
        proxy_surface, (mesh.vertices, mesh.faces), limits, "the proxy remesh"
    )
    if len(faces) == 0:
        raise MeshError("the proxy surface is empty (a flat or degenerate model)")
    proxy = clean_mesh(vertices, faces)
    n_parts, _ = components(edge_graph(proxy.faces, len(proxy.vertices)))
    note = f"replaced by a proxy of its surface ({len(proxy.faces)} faces"
    note += ")" if n_parts == 1 else f", {n_parts} parts)"
    return replace(proxy, repairs=(*mesh.repairs, note), route="proxy")


def proxy_surface(vertices: np.ndarray, faces: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The closed surface around a triangle soup, its thin parts kept.

    Parameters
    ----------
    vertices : (n, 3) float64
        Vertex positions.
    faces : (m, 3) int64
        Triangles, in any orientation.

    Returns
    -------
    vertices : (p, 3) float64
        The surface's vertices.
    faces : (q, 3) int64
        Its triangles: the parts of the iso-surface that enclose volume (inner walls of
        cavities dropped), simplified by quadric edge collapses beyond `PROXY_FACES`.
    """
    import igl

    oriented = orient_parts(vertices, faces)
    cell = cell_size(vertices, oriented)
    origin = vertices.min(axis=0) - 2 * cell
    cells = surface_cells(vertices, oriented, origin, cell)
    # libigl numbers corners in yxz order and places them so: swapped in, swapped back out.
    depth = int(np.ceil(np.log2(cells.max() + 2)))
    _, corners, points = igl.unique_sparse_voxel_corners(
        origin, cell * 2.0**depth, depth, cells[:, [1, 0, 2]]
    )
    distance = signed_distance(points, vertices, oriented, 4 * cell, SHEET_OFFSET * cell)
    surface, triangles, _ = igl.marching_cubes(distance, points, corners, 0.0)
    surface, triangles = close_rims(surface, triangles)
    surface, triangles = enclosing_parts(surface, triangles)
    return decimate(surface, triangles, PROXY_FACES)


def signed_distance(
    points: np.ndarray, vertices: np.ndarray, faces: np.ndarray, bound: float, sheet: float
) -> np.ndarray:
    """The distance to a triangle soup, negative inside it, near its surface, less ``sheet``
    near its open parts.

    Inside means a generalized winding number above one half. A point whose nearest face is
    on a closed part and that lies in no other part's bounding box takes the sign of that
    part's angle-weighted pseudonormal, which is then exact; the others get theirs from the
    fast winding number (`_winding_signs`).

    Parameters
    ----------
    points : (p, 3) float64
        Query points on a lattice of spacing ``bound / 4``, each within ``bound`` of the
        surface.
    vertices : (n, 3) float64
        Vertex positions.
    faces : (m, 3) int64
        Triangles facing out (`orient_parts`).
    bound : float
        Distances beyond are not needed (libigl stops searching there).
    sheet : float
        Subtracted where the nearest face is on an open part, so that the zero level set
        wraps an open sheet at that distance.

    Returns
    -------
    distance : (p,) float64
        Signed distance, clamped to ``bound`` in magnitude, in length units.
    """
    import igl

    signed, nearest = igl.signed_distance(
        points, vertices, faces, igl.SIGNED_DISTANCE_TYPE_PSEUDONORMAL, -bound, bound
    )[:2]
    far = np.isnan(signed)
    n_parts, labels = components(edge_graph(faces, len(vertices)))
    part = labels[faces[:, 0]]
    edges = mesh_edges(faces, len(vertices))
    open_part = open_parts(edges, labels, n_parts)
    mine = part[np.maximum(nearest, 0)]
    exact = ~far & ~open_part[mine]
    if n_parts > 1:
        covering, own = _boxes_covering(points, vertices, labels, n_parts, mine)
        exact &= (covering == 0) | ((covering == 1) & own)
    distance = np.where(far, bound, np.abs(signed))
    sign = np.where(signed < 0, -1.0, 1.0)
    if not exact.all():
        sign = _winding_signs(points, distance, sign, ~exact, vertices, faces, bound / 4)
    return sign * distance - sheet * (~far & open_part[mine])


def _winding_signs(
    points: np.ndarray,
    distance: np.ndarray,
    sign: np.ndarray,
    unknown: np.ndarray,
    vertices: np.ndarray,
    faces: np.ndarray,
    cell: float,
) -> np.ndarray:
    """The sign of the winding number at lattice points, evaluated at about an eighth of them.

    The fast winding number is evaluated at the points of even lattice coordinates; a point
    whose distance plus a neighbour's exceeds their separation has no surface between them,
    and takes that neighbour's sign (a winding number of one half in open space, across a hole,
    may so move by a cell). Points left without such a neighbour are evaluated too.

    Parameters
    ----------
    points : (p, 3) float64
        Points on a lattice of spacing ``cell``.
    distance : (p,) float64
        Their distance to the surface, or less.
    sign : (p,) float64
        Their sign (-1 inside, 1 outside) where known.
    unknown : (p,) bool
        Where it is not.
    vertices : (n, 3) float64
        Vertex positions.
    faces : (m, 3) int64
        Triangles facing out.
    cell : float
        The lattice's spacing.

    Returns
    -------
    sign : (p,) float64
        Every point's sign.
    """
    import igl

    def evaluate(which: np.ndarray) -> None:
        if not which.any():
            return
        winding = igl.fast_winding_number(vertices, faces, points[which])
        sign[which] = np.where(winding > 0.5, -1.0, 1.0)

    sign = sign.copy()
    lattice = np.rint((points - points.min(axis=0)) / cell).astype(np.int64)
    shape = tuple(int(n) for n in lattice.max(axis=0) + 1)
    keys = np.ravel_multi_index(lattice.T, shape)
    order = np.argsort(keys)
    ordered = keys[order]
    even = unknown & np.all(lattice % 2 == 0, axis=1)
    evaluate(even)
    known = ~unknown | even
    steps = np.stack(np.meshgrid(*[np.arange(-1, 2)] * 3, indexing="ij"), -1).reshape(-1, 3)
    steps = steps[np.argsort(np.abs(steps).sum(axis=1), kind="stable")[1:]]  # nearest first
    for step in steps:
        todo = np.flatnonzero(~known)
        if len(todo) == 0:
            break
        target = lattice[todo] + step
        inside = np.all((target >= 0) & (target < shape), axis=1)
        todo, target = todo[inside], target[inside]
        wanted = np.ravel_multi_index(target.T, shape)
        at = np.minimum(np.searchsorted(ordered, wanted), len(ordered) - 1)
        neighbour = order[at]
        clear = distance[todo] + distance[neighbour] > np.linalg.norm(step) * cell
        ok = (ordered[at] == wanted) & known[neighbour] & clear
        sign[todo[ok]] = sign[neighbour[ok]]
        known[todo[ok]] = True
    if not known.all():
        evaluate(~known)
    return sign


def _boxes_covering(
    points: np.ndarray, vertices: np.ndarray, labels: np.ndarray, n_parts: int, mine: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """How many parts' bounding boxes may hold each point, and whether its own part's does.

    Counted on a coarse grid of `BOX_CELLS` cells along each side, each box grown to whole
    cells, so that a count is never too low.

    Parameters
    ----------
    points : (p, 3) float64
        Query points.
    vertices : (n, 3) float64
        Vertex positions.
    labels : (n,) int
        The part of each vertex, from 0 to ``n_parts - 1``.
    n_parts : int
        Number of parts.
    mine : (p,) int
        The part of each point's nearest face.

    Returns
    -------
    covering : (p,) int64
        Number of grown boxes holding each point.
    own : (p,) bool
        Whether the grown box of its own part does.
    """
    low, high = vertices.min(axis=0), vertices.max(axis=0)
    size = np.maximum(high - low, 1e-300) / BOX_CELLS
    first = np.full((n_parts, 3), BOX_CELLS - 1, dtype=np.int64)
    last = np.zeros((n_parts, 3), dtype=np.int64)
    where = np.clip(np.floor((vertices - low) / size).astype(np.int64), 0, BOX_CELLS - 1)
    np.minimum.at(first, labels, where)
    np.maximum.at(last, labels, where + 1)
    # Each box adds one to its cells: +-1 at its 8 corners of a difference array, summed up.
    count = np.zeros((BOX_CELLS + 1,) * 3, dtype=np.int64)
    for corner in np.ndindex(2, 2, 2):
        ends = np.where(np.array(corner)[:, None], last.T, first.T)
        np.add.at(count, tuple(ends), (-1) ** sum(corner))
    count = count.cumsum(0).cumsum(1).cumsum(2)
    cell = np.clip(np.floor((points - low) / size).astype(np.int64), 0, BOX_CELLS - 1)
    own = np.all((cell >= first[mine]) & (cell < last[mine]), axis=1)
    return count[tuple(cell.T)], own


def cell_size(vertices: np.ndarray, faces: np.ndarray) -> float:
    """The grid's cell: `CELLS_ACROSS` cells across the thinnest parts, within the bounds.

    Parameters
    ----------
    vertices : (n, 3) float64
        Vertex positions.
    faces : (m, 3) int64
        Triangles facing out (`orient_parts`).

    Returns
    -------
    cell : float
        Side of a cubic cell in length units: at least 1/`MAX_CELLS` and at most
        1/`MIN_CELLS` of the bounding box's longest side, and coarse enough that about
        `MAX_SURFACE_CELLS` cells hold the surface.
    """
    longest = float(np.ptp(vertices, axis=0).max())
    thin = np.percentile(thickness(vertices, faces), THICKNESS_PERCENTILE) / CELLS_ACROSS
    cell = float(np.clip(thin, longest / MAX_CELLS, longest / MIN_CELLS))
    area = float(face_areas(edge_lengths(vertices, faces)).sum())
    return max(cell, np.sqrt(area / MAX_SURFACE_CELLS))


def thickness(vertices: np.ndarray, faces: np.ndarray, seed: int = 0) -> np.ndarray:
    """The local thickness at points spread over the surface by area: shrinking balls.

    At each point, balls of growing radius are placed against the surface on its inner side;
    the thickness is the diameter of the largest that no other part of the surface enters
    (within a fifth of its radius).

    Parameters
    ----------
    vertices : (n, 3) float64
        Vertex positions.
    faces : (m, 3) int64
        Triangles facing out (`orient_parts`).
    seed : int
        Seed of the points' placement.

    Returns
    -------
    thickness : (THICKNESS_SAMPLES,) float
        In length units, from 1/512 to 1/8 of the longest side of the bounding box; 0 where
        even the smallest ball does not fit (an open sheet).
    """
    import igl

    a, b, c = (vertices[faces[:, k]] for k in range(3))
    normals = np.cross(b - a, c - a)
    doubled = np.linalg.norm(normals, axis=1)
    rng = np.random.default_rng(seed)
    face = rng.choice(len(faces), size=THICKNESS_SAMPLES, p=doubled / doubled.sum())
    r = np.sqrt(rng.random(THICKNESS_SAMPLES))[:, None]
    s = rng.random(THICKNESS_SAMPLES)[:, None]
    points = (1 - r) * a[face] + r * (1 - s) * b[face] + r * s * c[face]
    inward = -normals[face] / doubled[face, None]
    radii = float(np.ptp(vertices, axis=0).max()) * np.geomspace(1 / 1024, 1 / 16, 13)
    centres = points[:, None] + radii[None, :, None] * inward[:, None]
    squared = igl.point_mesh_squared_distance(centres.reshape(-1, 3), vertices, faces)[0]
    fits = np.sqrt(squared).reshape(len(points), -1) >= 0.8 * radii
    largest = np.cumprod(fits, axis=1).sum(axis=1)  # how many radii fit, smallest first
    return np.where(largest > 0, 2 * radii[np.maximum(largest - 1, 0)], 0.0)


def surface_cells(
    vertices: np.ndarray, faces: np.ndarray, origin: np.ndarray, cell: float
) -> np.ndarray:
    """The grid cells the surface passes through, and their neighbours.

    Parameters
    ----------
    vertices : (n, 3) float64
        Vertex positions.
    faces : (m, 3) int64
        Triangles.
    origin : (3,) float64
        The grid's lowest corner, at least two cells below every vertex.
    cell : float
        Side of a cell.

    Returns
    -------
    cells : (k, 3) int64
        Each cell's lowest corner, in cells from ``origin``: the cells that hold a point of the
        surface, grown by one cell in each of the 26 directions, so that the iso-surface,
        within a cell of the input, lies in them.
    """
    points = surface_points(vertices, faces, cell / 2)
    index = np.floor((points - origin) / cell).astype(np.int64)
    shape = tuple(int(n) for n in index.max(axis=0) + 3)
    occupied = np.unique(np.ravel_multi_index(index.T, shape))
    near = np.stack(np.unravel_index(occupied, shape), axis=1)
    steps = np.stack(np.meshgrid(*[np.arange(-1, 2)] * 3, indexing="ij"), -1).reshape(-1, 3)
    grown = (near[:, None] + steps[None]).reshape(-1, 3)
    return np.stack(np.unravel_index(np.unique(np.ravel_multi_index(grown.T, shape)), shape), 1)


def surface_points(vertices: np.ndarray, faces: np.ndarray, spacing: float) -> np.ndarray:
    """Points on every triangle, on a lattice no coarser than ``spacing`` along its sides.

    Parameters
    ----------
    vertices : (n, 3) float64
        Vertex positions.
    faces : (m, 3) int64
        Triangles.
    spacing : float
        Largest distance between lattice neighbours, in length units.

    Returns
    -------
    points : (p, 3) float64
        The vertices and, on each triangle longer than ``spacing``, its lattice points.
    """
    a, b, c = (vertices[faces[:, k]] for k in range(3))
    longest = np.linalg.norm(np.stack([b - a, c - b, a - c]), axis=2).max(axis=0)
    steps = np.maximum(1, np.ceil(longest / spacing)).astype(np.int64)
    points = [vertices]
    for n in np.unique(steps[steps > 1]):
        i, j = np.nonzero(np.add.outer(np.arange(n + 1), np.arange(n + 1)) <= n)
        mine = steps == n
        u, w = (i / n)[None, :, None], (j / n)[None, :, None]
        base = a[mine][:, None]
        lattice = base + u * (b[mine] - a[mine])[:, None] + w * (c[mine] - a[mine])[:, None]
        points.append(lattice.reshape(-1, 3))
    return np.vstack(points)


def close_rims(vertices: np.ndarray, faces: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Close the rims that marching cubes leaves where the level set leaves the cells computed.

    Across a hole in the input the winding number's level set spans open space, beyond the
    cells near the surface; the rim of its part within them is closed by a fan from its
    centroid, oriented as the faces around it.

    Parameters
    ----------
    vertices : (n, 3) float64
        Vertex positions.
    faces : (m, 3) int64
        Consistently oriented, manifold triangles (marching cubes).

    Returns
    -------
    vertices : (n + k, 3) float64
        With the centroid of each of the k rims.
    faces : (m', 3) int64
        With the fans.
    """
    import igl

    if len(faces) == 0:
        return vertices, faces
    rims = [np.asarray(rim, dtype=np.int64) for rim in igl.boundary_loop_all(faces)]
    rims = [rim for rim in rims if len(rim) >= 3]
    if not rims:
        return vertices, faces
    centres = np.array([vertices[rim].mean(axis=0) for rim in rims])
    fans = [
        np.column_stack([np.full(len(rim), len(vertices) + k), rim, np.roll(rim, -1)])
        for k, rim in enumerate(rims)
    ]
    closed = np.vstack([faces, *fans])
    # bfs_orient keeps each part's first face, a marching cubes face, and turns the fans to it.
    return np.vstack([vertices, centres]), igl.bfs_orient(closed)[0]


def enclosing_parts(vertices: np.ndarray, faces: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The parts of a marching-cubes surface that enclose volume (inner walls dropped).

    Parameters
    ----------
    vertices : (n, 3) float64
        Vertex positions.
    faces : (m, 3) int64
        Closed, consistently oriented triangles facing out of the volume.

    Returns
    -------
    vertices : (n, 3) float64
        Unchanged.
    faces : (m', 3) int64
        The faces of the parts of positive volume: the wall of a cavity faces into it and
        encloses negative volume.
    """
    if len(faces) == 0:
        return vertices, faces
    n_parts, labels = components(edge_graph(faces, len(vertices)))
    part = labels[faces[:, 0]]
    volume = np.bincount(part, signed_volumes(vertices, faces), n_parts)
    return vertices, faces[volume[part] > 0]
