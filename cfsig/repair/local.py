"""Local repairs that hold for any amount of damage: the steps of the ``repaired`` route that
work on the whole mesh at once rather than part by part (`cfsig.repair.stage`).

- `weld_copies`: the mesh as it was before reading split its non-manifold vertices, so that
  a fin's edge is one edge of three faces again.
- `drop_dangling`: fins and dangling open sheets on edges of three or more faces go; of the
  closed sheets meeting on an edge an odd number of times, the smallest goes until the
  surface closes.
- `drop_hidden`: open parts lying inside the closed ones (inner walls, hidden interiors) go.
- `split_t_junctions`: the two sides of a seam meshed independently are stitched by splitting
  each boundary edge at the other side's vertices lying on it.
- `orient_parts`: every part oriented consistently and outward.
- `closed_parts`: closed parts inside another are dropped (generalized winding number), parts
  crossing another are joined by an exact union (manifold3d), and parts apart stay parts.
"""

from __future__ import annotations

import numpy as np
import scipy.sparse as sp
from scipy.sparse.csgraph import connected_components

from cfsig.files.elements import (
    Edges,
    edge_lengths,
    face_areas,
    mesh_edges,
    open_parts,
    signed_volumes,
)
from cfsig.isolate import Limits, run_limited

# Rounds of `drop_dangling`: each drops what the one before uncovered.
MAX_ROUNDS = 32
# A closed part is inside another when at least this share of its probe vertices is.
ENCLOSED_SHARE = 0.9
# Vertices of a part probed against the others' winding numbers.
PROBES = 64


def weld_copies(vertices: np.ndarray, faces: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Merge vertices at exactly the same position: the copies `clean_mesh` made of each
    non-manifold vertex, since reading already merged every other coincident pair.

    Parameters
    ----------
    vertices : (n, 3) float64
        Vertex positions.
    faces : (m, 3) int64
        Triangles.

    Returns
    -------
    vertices : (n, 3) float64
        Unchanged; the copies are left unreferenced, for `clean_mesh` to remove, so that the
        vertices keep their order.
    faces : (m, 3) int64
        The triangles on the first vertex at each position.
    """
    unique, first, inverse = np.unique(
        vertices + 0.0, axis=0, return_index=True, return_inverse=True
    )
    if len(unique) == len(vertices):
        return vertices, faces
    return vertices, first[inverse.reshape(-1)][faces]


def drop_dangling(
    vertices: np.ndarray, faces: np.ndarray, fraction: float
) -> tuple[np.ndarray, int, int]:
    """Resolve the edges of three or more faces by keeping the sheets that close the surface.

    A sheet is a maximal set of faces joined through edges of exactly two faces. Round after
    round: open sheets (with an edge of one face) that touch an edge of three or more faces and
    hold less than ``fraction`` of the area go (fins, dangling faces); when none is left, of the
    sheets bounded only by edges of an odd number of faces (three or more), the smallest goes
    (an inner wall between two closed parts). Dropping a fin makes its edge one of two faces
    again, which joins the sheets on either side in the next round.

    Parameters
    ----------
    vertices : (n, 3) float64
        Vertex positions.
    faces : (m, 3) int64
        Triangles, duplicates dropped.
    fraction : float
        Area fraction below which an open sheet on an edge of three or more faces is dropped.

    Returns
    -------
    faces : (m', 3) int64
        The faces kept (unreferenced vertices are left for `clean_mesh`).
    dangling : int
        Number of dangling sheets dropped.
    walls : int
        Number of inner walls dropped.
    """
    area = face_areas(edge_lengths(vertices, faces))
    dangling = walls = 0
    for _ in range(MAX_ROUNDS):
        edges = mesh_edges(faces, len(vertices))
        counts = np.diff(edges.starts)
        if not np.any(counts > 2):
            break
        face_counts = np.empty(3 * len(faces), dtype=np.int64)
        face_counts[edges.order] = np.repeat(counts, counts)
        per_face = face_counts.reshape(-1, 3)
        n_sheets, sheet = _sheets(edges, counts, len(faces))
        sheet_area = np.bincount(sheet, area, n_sheets)
        is_open = np.bincount(sheet, (per_face == 1).any(axis=1), n_sheets) > 0
        touches = np.bincount(sheet, (per_face > 2).any(axis=1), n_sheets) > 0
        drop = is_open & touches & (sheet_area < fraction * sheet_area.sum())
        if drop.any():
            dangling += int(drop.sum())
        else:
            border = (per_face != 2).any(axis=1)
            even = np.bincount(sheet, ((per_face > 2) & (per_face % 2 == 0)).any(axis=1), n_sheets)
            wall = (np.bincount(sheet, border, n_sheets) > 0) & ~is_open & (even == 0)
            if wall.sum() < 2:
                break
            drop = np.zeros(n_sheets, dtype=bool)
            drop[np.flatnonzero(wall)[np.argmin(sheet_area[wall])]] = True
            walls += 1
        keep = ~drop[sheet]
        faces, area = faces[keep], area[keep]
    return faces, dangling, walls


def _sheets(edges: Edges, counts: np.ndarray, n_faces: int) -> tuple[int, np.ndarray]:
    """Faces joined through edges of exactly two faces: the number of sheets, each face's."""
    pair = edges.starts[:-1][counts == 2]
    a, b = edges.order[pair] // 3, edges.order[pair + 1] // 3
    graph = sp.coo_matrix((np.ones(len(a)), (a, b)), shape=(n_faces, n_faces))
    count, labels = connected_components(graph, directed=False)
    return int(count), labels


def drop_hidden(
    vertices: np.ndarray, faces: np.ndarray, labels: np.ndarray, edges: Edges
) -> tuple[np.ndarray, int]:
    """Drop the open parts that lie inside the closed ones: inner walls, hidden interiors.

    An open part is hidden when at least `ENCLOSED_SHARE` of its faces have their centroid
    inside the closed parts, by the generalized winding number of all of them together (libigl's
    fast winding number). Dropped before stitching, such a part cannot be zipped to another.

    Parameters
    ----------
    vertices : (n, 3) float64
        Vertex positions.
    faces : (m, 3) int64
        Triangles with at most two faces per edge.
    labels : (n,) int
        Part of each vertex.
    edges : Edges
        The faces' edges (`cfsig.files.elements.mesh_edges`).

    Returns
    -------
    faces : (m', 3) int64
        The faces kept.
    dropped : int
        Number of open parts dropped.
    """
    n_parts = int(labels.max()) + 1
    face_part = labels[faces[:, 0]]
    open_face = open_parts(edges, labels, n_parts)[face_part]
    if open_face.all() or not open_face.any():
        return faces, 0
    import igl

    centroids = vertices[faces[open_face]].mean(axis=1)
    winding = igl.fast_winding_number(vertices, faces[~open_face], centroids)
    part = face_part[open_face]
    share = np.bincount(part, np.abs(winding) > 0.5, n_parts) / np.maximum(
        np.bincount(part, minlength=n_parts), 1
    )
    hidden = share >= ENCLOSED_SHARE
    if not hidden.any():
        return faces, 0
    return faces[~hidden[face_part]], int(hidden.sum())


def split_t_junctions(
    vertices: np.ndarray, faces: np.ndarray, edges: Edges | None, tolerance: float
) -> tuple[np.ndarray, int]:
    """Split boundary edges at the boundary vertices lying on them (T-junctions).

    Where the two sides of a seam were meshed independently, a vertex of one side lies inside
    an edge of the other, and the seam stays open however close its sides are. Each boundary
    edge gets the boundary vertices within ``tolerance`` of its inside (each vertex on its
    nearest such edge) whose two neighbours along their own boundary lie along the seam too:
    at the edge's ends, within ``tolerance`` of another boundary vertex, or inside another
    boundary edge. Its face is split into a fan through them, in order along the edge, so
    that the seam's two sides share their vertices. Two boundaries that only cross each other
    are left to stitching: splitting there would join their parts at a point and keep them
    from being stitched.

    Parameters
    ----------
    vertices : (n, 3) float64
        Vertex positions.
    faces : (m, 3) int64
        Triangles with at most two faces per edge (`clean_mesh`).
    edges : geometry.Edges or None
        The faces' `cfsig.files.elements.mesh_edges` when already known.
    tolerance : float
        Largest distance of a vertex to an edge it splits, in length units.

    Returns
    -------
    faces : (m', 3) int64
        With each split face replaced by its fan.
    split : int
        Number of vertices inserted into edges.
    """
    if edges is None:
        edges = mesh_edges(faces, len(vertices))
    counts = np.diff(edges.starts)
    half = edges.order[edges.starts[:-1][counts == 1]]
    if len(half) < 2:
        return faces, 0
    from scipy.spatial import cKDTree  # here: a tenth of a second, for open meshes only

    face, corner = half // 3, half % 3
    a, b = faces[face, corner], faces[face, (corner + 1) % 3]
    start, direction = vertices[a], vertices[b] - vertices[a]
    length = np.linalg.norm(direction, axis=1)
    points = np.unique(np.r_[a, b])
    tree = cKDTree(vertices[points])
    # Each edge's own ball, not one as wide as the longest edge: a model with one long boundary
    # edge (a ground plane) would otherwise pair every vertex with every edge.
    near = tree.query_ball_point((start + vertices[b]) / 2, length / 2 + tolerance)
    sizes = np.fromiter(map(len, near), dtype=np.int64, count=len(near))
    edge = np.repeat(np.arange(len(half)), sizes)
    point = points[np.fromiter((i for row in near for i in row), np.int64, int(sizes.sum()))]
    along = np.einsum("ij,ij->i", vertices[point] - start[edge], direction[edge])
    t = along / np.maximum(length[edge] ** 2, np.finfo(float).tiny)
    gap = np.linalg.norm(start[edge] + t[:, None] * direction[edge] - vertices[point], axis=1)
    margin = tolerance / np.maximum(length[edge], np.finfo(float).tiny)
    on = (gap <= tolerance) & (t > margin) & (t < 1 - margin)
    on &= (point != a[edge]) & (point != b[edge])
    point, edge, t, gap = point[on], edge[on], t[on], gap[on]
    # Along a seam, the vertex's two neighbours on its boundary lie on the edge's side too: at
    # the edge's ends, at another boundary vertex or inside another boundary edge. Where two
    # boundaries merely cross, they lie off it.
    seam = np.zeros(len(vertices), dtype=bool)
    seam[point] = True
    seam[points[tree.query_pairs(tolerance, output_type="ndarray")]] = True
    following, preceding = np.full(len(vertices), -1), np.full(len(vertices), -1)
    following[a], preceding[b] = b, a
    along = np.ones(len(point), dtype=bool)
    for neighbour in (following[point], preceding[point]):
        along &= seam[neighbour] | (neighbour == a[edge]) | (neighbour == b[edge])
    point, edge, t, gap = point[along], edge[along], t[along], gap[along]
    if len(point) == 0:
        return faces, 0
    nearest = np.lexsort((gap, point))
    first = np.r_[True, point[nearest][1:] != point[nearest][:-1]]
    point, edge, t = point[nearest][first], edge[nearest][first], t[nearest][first]
    # One edge per face: a face with two split edges gets its second in the next call.
    _, one = np.unique(face[edge], return_index=True)
    chosen = np.isin(edge, edge[one])
    point, edge, t = point[chosen], edge[chosen], t[chosen]
    order = np.lexsort((t, edge))
    point, edge = point[order], edge[order]
    fans = []
    for e in np.unique(edge):
        inside = point[edge == e]
        chain = np.r_[a[e], inside, b[e]]
        apex = faces[face[e], (corner[e] + 2) % 3]
        fans.append(np.column_stack([chain[:-1], chain[1:], np.full(len(chain) - 1, apex)]))
    keep = np.ones(len(faces), dtype=bool)
    keep[face[np.unique(edge)]] = False
    return np.vstack([faces[keep], *fans]), len(point)


def orient_parts(vertices: np.ndarray, faces: np.ndarray) -> np.ndarray:
    """Orient every part consistently in itself, and outward: its signed volume positive.

    Parameters
    ----------
    vertices : (n, 3) float64
        Vertex positions.
    faces : (m, 3) int64
        Triangles.

    Returns
    -------
    faces : (m, 3) int64
        The same triangles, some reversed, so that the winding numbers of parts add up.
    """
    import igl

    oriented, part = igl.bfs_orient(faces)
    oriented, part = np.asarray(oriented, dtype=np.int64), np.asarray(part).ravel()
    inward = np.bincount(part, signed_volumes(vertices, oriented)) < 0
    flip = inward[part]
    oriented[flip] = oriented[flip][:, ::-1]
    return oriented


def closed_parts(
    vertices: np.ndarray, faces: np.ndarray, labels: np.ndarray, limits: Limits
) -> tuple[np.ndarray, np.ndarray, int, int, int]:
    """Drop the closed parts inside another, join the parts that cross each other.

    A part's probe vertices (up to `PROBES`) are tested against the generalized winding number
    (libigl's fast winding number) of every other part whose bounding box meets its own: when
    at least `ENCLOSED_SHARE` of them are inside, the part is hidden inner geometry and is
    dropped; when some are, the two cross. Parts that cross are joined by manifold3d's exact
    union, in a child process under ``limits``; parts apart stay as they are, each a part of
    the object (buttons, wheels), and so do crossing parts whose union manifold3d refuses.

    Parameters
    ----------
    vertices : (n, 3) float64
        Vertex positions.
    faces : (m, 3) int64
        Closed triangles, every part oriented outward (`orient_parts`).
    labels : (n,) int
        Part of each vertex.
    limits : Limits
        Time and memory allowed to the union.

    Returns
    -------
    vertices : (n', 3) float64
        With the unions' vertices appended.
    faces : (m', 3) int64
        The faces kept and the unions'.
    enclosed : int
        Number of parts dropped.
    joined : int
        Number of parts joined into others.
    refused : int
        Number of crossing parts left apart, their union refused.

    Raises
    ------
    StageLimitError
        The union crashed or exceeded its limits.
    """
    import igl

    n_parts = int(labels.max()) + 1
    if n_parts < 2:
        return vertices, faces, 0, 0, 0
    face_part = labels[faces[:, 0]]
    low = np.full((n_parts, 3), np.inf)
    high = np.full((n_parts, 3), -np.inf)
    np.minimum.at(low, labels, vertices)
    np.maximum.at(high, labels, vertices)
    meet = np.all(low[:, None] <= high[None], axis=2) & np.all(low[None] <= high[:, None], axis=2)
    np.fill_diagonal(meet, False)
    area = np.bincount(face_part, face_areas(edge_lengths(vertices, faces)), n_parts)
    rng = np.random.default_rng(0)
    probes = np.concatenate(
        [rng.permutation(np.flatnonzero(labels == part))[:PROBES] for part in range(n_parts)]
    )
    probe_part = labels[probes]
    per_part = np.bincount(probe_part, minlength=n_parts)
    # share[p, q]: the share of p's probes inside q, by q's fast winding number (one tree per q).
    share = np.zeros((n_parts, n_parts))
    for other in np.flatnonzero(meet.any(axis=0)):
        tested = meet[probe_part, other]
        winding = igl.fast_winding_number(
            vertices, faces[face_part == other], vertices[probes[tested]]
        )
        inside = np.bincount(probe_part[tested], np.abs(winding) > 0.5, n_parts)
        share[:, other] = inside / per_part
    enclosed = np.zeros(n_parts, dtype=bool)
    for part in np.argsort(area, kind="stable"):  # the smallest first: the likeliest inside
        enclosed[part] = np.any(share[part, ~enclosed] >= ENCLOSED_SHARE)
    crossing = [(p, q) for p, q in zip(*np.nonzero((share > 0) | (share.T > 0)), strict=True)]
    kept = ~enclosed
    pairs = [(p, q) for p, q in crossing if kept[p] and kept[q]]
    if not pairs:
        return vertices, faces[kept[face_part]], int(enclosed.sum()), 0, 0
    p, q = np.array(pairs).T
    graph = sp.coo_matrix((np.ones(len(p)), (p, q)), shape=(n_parts, n_parts))
    _, group = connected_components(graph, directed=False)
    sizes = np.bincount(group[kept], minlength=n_parts)
    joined_groups = [g for g in np.unique(group[kept]) if sizes[g] > 1]
    pieces = [(faces[face_part == part]) for part in range(n_parts)]
    union_parts = [
        [(vertices, pieces[part]) for part in np.flatnonzero(kept & (group == g))]
        for g in joined_groups
    ]
    import manifold3d  # noqa: F401  (imported before the fork, once per process)

    unions = run_limited(_unions, (union_parts,), limits, "the union of crossing parts")
    done = [g for g, union in zip(joined_groups, unions, strict=True) if union is not None]
    joined = kept & np.isin(group, done)
    new_vertices, new_faces, count = [vertices], [faces[(kept & ~joined)[face_part]]], len(vertices)
    for union_vertices, union_faces in filter(None, unions):
        new_vertices.append(union_vertices)
        new_faces.append(union_faces + count)
        count += len(union_vertices)
    n_joined = int(joined.sum()) - len(done)
    refused = int(np.sum(kept & np.isin(group, joined_groups) & ~joined))
    return (np.vstack(new_vertices), np.vstack(new_faces), int(enclosed.sum()), n_joined, refused)


def _unions(
    groups: list[list[tuple[np.ndarray, np.ndarray]]],
) -> list[tuple[np.ndarray, np.ndarray] | None]:
    """manifold3d's exact union of each group of closed, outward-oriented parts; None for a
    group that manifold3d refuses (a part it does not take as a manifold, such as one that
    cannot be oriented) or whose union comes out empty."""
    import manifold3d

    results: list[tuple[np.ndarray, np.ndarray] | None] = []
    for group in groups:
        solids = []
        for vertices, faces in group:
            used, inverse = np.unique(faces, return_inverse=True)
            mesh = manifold3d.Mesh64(
                np.ascontiguousarray(vertices[used]),
                np.ascontiguousarray(inverse.reshape(-1, 3), dtype=np.uint64),
            )
            solids.append(manifold3d.Manifold(mesh))
        if any(solid.status() != manifold3d.Error.NoError for solid in solids):
            results.append(None)
            continue
        union = manifold3d.Manifold.batch_boolean(solids, manifold3d.OpType.Add).to_mesh64()
        if len(union.tri_verts) == 0:
            results.append(None)
            continue
        results.append(
            (np.asarray(union.vert_properties[:, :3], dtype=np.float64),
             np.asarray(union.tri_verts, dtype=np.int64))
        )  # fmt: skip
    return results
