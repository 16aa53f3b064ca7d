"""The repair stage: from any triangle input to a surface the descriptor means something on.

The conformal factor is defined on a closed manifold (paper section 2); on a model made of
separate parts it is solved per part, and each part gets an unrelated distribution (the paper's
"most important drawback", section 4). `repair_mesh` runs between reading (`cfsig.files.mesh`, which
always welds, drops duplicates and degenerate faces and splits non-manifold vertices) and the
numerics. Under every mode but ``off`` it first moves spikes, single vertices thrown off the
surface, back among their neighbours (`cfsig.repair.spikes`). It then chooses one of three
routes (docs/method.md, "The repair stage"):

- ``clean``: the mesh is one closed manifold, oriented outward, without spikes; it passes
  unchanged, bit for bit. One closed manifold with faces reversed or spikes only has them
  turned or moved (route ``repaired``).
- ``repaired``: local repairs make it closed manifold parts, for any amount of damage: fins,
  dangling sheets and inner walls on non-manifold edges are dropped, and so are open parts
  inside closed ones; T-junctions split, parts whose boundaries nearly meet stitched, small
  open fragments dropped, holes closed by ears, parts oriented, parts enclosed by another
  dropped and parts crossing another joined by their union (`cfsig.repair.local`); closed
  parts apart are kept. The rest of the surface is kept exactly.
- ``proxy``: otherwise, the surface is rebuilt on a grid whose cells follow the thinnest
  parts (`cfsig.repair.proxy`), in a child process under a time and memory limit.
"""

from __future__ import annotations

import heapq
from dataclasses import replace

import numpy as np
import scipy.sparse as sp
from scipy.sparse.csgraph import connected_components

from cfsig.errors import StageLimitError
from cfsig.files.elements import (
    Edges,
    edge_lengths,
    face_areas,
    mesh_edges,
    open_parts,
    paired_half_edges,
    signed_volumes,
)
from cfsig.files.mesh import Mesh, clean_mesh
from cfsig.isolate import Limits
from cfsig.params import REPAIR_MODES
from cfsig.repair.local import (
    closed_parts,
    drop_dangling,
    drop_hidden,
    orient_parts,
    split_t_junctions,
    weld_copies,
)
from cfsig.repair.proxy import proxy_mesh
from cfsig.repair.spikes import flatten_spikes

# Boundary vertices of different parts closer than this fraction of the bounding-box diagonal
# are stitched together.
STITCH_DISTANCE = 0.02
# A seam cut through a model: SEAM_PAIRS or more pairs of boundary vertices whose offsets agree
# to within SEAM_AGREEMENT of the stitching distance (`_seeds`), 0.1% of the diagonal.
SEAM_AGREEMENT = 0.05
SEAM_PAIRS = 3
# Two boundary edges are not zipped when their faces would lie on the same side of the merged
# edge, within about 25 degrees of each other: folded onto each other (`stitch`). A seam along
# a crease sharper than that is left open, for `fill_holes`' ears.
FOLDED = 0.9
# Rounds of stitching at most (`stitch` pairs each vertex once a round).
STITCH_ROUNDS = 3
# A part's faces within this fraction of the diagonal of a larger part's surface cover it twice.
OVERLAP_DISTANCE = 0.002
# Open parts with less than this fraction of the total area are fragments, dropped, as long
# as they hold no more than this fraction together.
FRAGMENT_AREA = 0.01
# Local repairs are tried on at most this many parts; beyond, the proxy is built directly
# (docs/method.md: the cost of local repairs beyond it).
MAX_PARTS = 1024
# A boundary vertex this close to a boundary edge (fraction of the diagonal) splits it.
T_JUNCTION = 1e-4


def repair_mesh(mesh: Mesh, mode: str = "auto", limits: Limits | None = None) -> Mesh:
    """Make a checked mesh into one closed manifold, or the closest surface there is.

    Parameters
    ----------
    mesh : Mesh
        A checked mesh, as `cfsig.files.mesh.clean_mesh` returns.
    mode : {"auto", "off", "proxy"}
        ``"auto"``: the first route that applies (module docstring); ``"off"``: the mesh as
        read, solved per component; ``"proxy"``: the proxy for anything but a clean mesh or
        one closed manifold with faces reversed, which are turned.
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
    edges, n_parts, labels, closed = _surface(mesh)
    if mode != "off":
        vertices, spikes = flatten_spikes(mesh.vertices, edges)
        if spikes:
            moved = f"moved {spikes} spikes back among their neighbours"
            mesh = replace(
                mesh,
                vertices=vertices,
                repairs=(*mesh.repairs, moved),
                edges=edges,
                route="repaired",
            )
    if n_parts == 1 and closed:
        if _oriented_outward(mesh, edges):
            return replace(mesh, parts=labels)
        if mode != "off":  # a closed mesh with reversed faces: turning them is all it needs
            done = list(mesh.repairs)
            faces = _oriented(mesh.vertices, mesh.faces, done)
            return replace(
                mesh, faces=faces, repairs=tuple(done), edges=None, route="repaired", parts=labels
            )
    if mode == "off":
        return replace(mesh, route="unrepaired")
    if mode == "auto":
        repaired = _local_repairs(mesh, limits or Limits())
        if repaired is not None:
            return repaired
    return proxy_mesh(mesh, limits or Limits())


def _local_repairs(mesh: Mesh, limits: Limits) -> Mesh | None:
    """Resolve non-manifold edges, trim overlaps, stitch, drop fragments, fill holes, orient,
    drop inner parts and join crossing ones (docs/method.md, "The repair stage").

    Returns None, for the proxy, beyond `MAX_PARTS` parts, when the open fragments hold more
    than `FRAGMENT_AREA` of the area together, when the union's child fails or when the result
    is not closed.
    """
    done = list(mesh.repairs)
    vertices, faces = weld_copies(mesh.vertices, mesh.faces)
    faces, dangling, walls = drop_dangling(vertices, faces, FRAGMENT_AREA)
    if dangling:
        done.append(f"dropped {dangling} fins and dangling sheets")
    if walls:
        done.append(f"dropped {walls} inner walls between closed sheets")
    vertices, faces, edges = _tidy(vertices, faces)
    edges, n_parts, labels = _face_graph(faces, len(vertices), edges)
    if n_parts > MAX_PARTS:
        return None
    faces, hidden = drop_hidden(vertices, faces, labels, edges)
    if hidden:
        done.append(f"dropped {hidden} open parts inside closed ones")
        vertices, faces, edges = _tidy(vertices, faces)
        edges, _, labels = _face_graph(faces, len(vertices), edges)
    diagonal = float(np.linalg.norm(np.ptp(vertices, axis=0)))
    faces, trimmed = trim_overlaps(vertices, faces, labels, edges, OVERLAP_DISTANCE * diagonal)
    if trimmed:
        done.append(f"dropped {trimmed} faces lying on another part's surface")
        vertices, faces, edges = _tidy(vertices, faces)
    for _ in range(3):  # a face with T-junctions on two or three edges is split edge by edge
        faces, split = split_t_junctions(vertices, faces, edges, T_JUNCTION * diagonal)
        if not split:
            break
        done.append(f"split boundary edges at {split} T-junctions")
        # The seam's corners were split apart as non-manifold while it was open: weld them.
        vertices, faces, edges = _tidy(*weld_copies(vertices, faces))
    # Each step gets the faces cleaned after the one before, with the edges of that cleaning.
    # A vertex is paired once a round: where three parts meet, the third waits for the next.
    # The seams cut through a model come first, so that the parts they join are one before
    # boundaries that merely pass near each other (fingers side by side) are compared.
    stitched = 0
    for cut in (True, False):
        for _ in range(STITCH_ROUNDS):
            vertices, faces, pairs = stitch(vertices, faces, edges, STITCH_DISTANCE * diagonal, cut)
            if not pairs:
                break
            vertices, faces, edges = _tidy(vertices, faces)
            stitched += pairs
    if stitched:
        done.append(f"stitched {stitched} pairs of boundary vertices between parts")
    kept = drop_fragments(vertices, faces, edges, FRAGMENT_AREA)
    if kept is None:
        return None
    vertices, faces, dropped = kept
    if dropped:
        done.append(f"dropped {dropped} small open fragments")
    vertices, faces, edges = _tidy(vertices, faces)
    vertices, faces, filled = fill_holes(vertices, faces, edges)
    if filled:
        done.append(f"closed {filled} holes")
    vertices, faces, edges = _tidy(vertices, faces)
    faces = _oriented(vertices, faces, done)
    labels = _face_graph(faces, len(vertices), edges)[2]
    try:
        vertices, faces, enclosed, joined, refused = closed_parts(vertices, faces, labels, limits)
    except StageLimitError:
        return None
    if enclosed:
        done.append(f"dropped {enclosed} parts enclosed by another")
    if joined:
        done.append(f"joined {joined} crossing parts to others by their union")
    if refused:
        done.append(f"left {refused} crossing parts apart: manifold3d refused their union")
    result = clean_mesh(vertices, faces, weld=False)
    _, n_parts, labels, closed = _surface(result)
    if not closed:
        return None
    if n_parts > 1:
        done.append(f"kept {n_parts} closed parts")
    return replace(result, repairs=tuple(done), route="repaired", parts=labels)


def _tidy(vertices: np.ndarray, faces: np.ndarray) -> tuple[np.ndarray, np.ndarray, Edges | None]:
    """`clean_mesh` without welding (faces that became degenerate or repeated go, fans split):
    vertices, faces and their edges when the cleaning kept them."""
    mesh = clean_mesh(vertices, faces, weld=False)
    return mesh.vertices, mesh.faces, mesh.edges


def trim_overlaps(
    vertices: np.ndarray, faces: np.ndarray, labels: np.ndarray, edges: Edges, distance: float
) -> tuple[np.ndarray, int]:
    """Drop the faces of a part that lie on the surface of a larger part (a surface covered twice).

    Parts are taken from the largest; a face of an open part whose three vertices all lie
    within ``distance`` of the faces kept so far is dropped. A closed part is dropped only
    whole (a copy), else kept whole (a part of the object).

    Parameters
    ----------
    vertices : (n, 3) float64
        Vertex positions.
    faces : (m, 3) int64
        Triangles.
    labels : (n,) int
        Part of each vertex.
    edges : geometry.Edges
        The faces' edges (`cfsig.files.elements.mesh_edges`).
    distance : float
        Largest distance of a face's vertices to the other surface, in length units.

    Returns
    -------
    faces : (m', 3) int64
        The faces kept.
    dropped : int
        Number of faces dropped.
    """
    import igl

    face_part = labels[faces[:, 0]]
    n_parts = int(labels.max()) + 1
    if n_parts < 2:
        return faces, 0
    area = _part_areas(vertices, faces, face_part, n_parts)
    closed = ~open_parts(edges, labels, n_parts)
    keep = np.zeros(len(faces), dtype=bool)
    order = np.argsort(-area, kind="stable")
    keep[face_part == order[0]] = True
    corners_of = vertices[faces]
    face_low, face_high = corners_of.min(axis=1), corners_of.max(axis=1)
    for part in order[1:]:
        mine = np.flatnonzero(face_part == part)
        corners = np.unique(faces[mine])
        # Only the kept faces near the part's bounding box: one small search tree per part.
        low = vertices[corners].min(axis=0) - distance
        high = vertices[corners].max(axis=0) + distance
        nearby = keep & np.all(face_low <= high, axis=1) & np.all(face_high >= low, axis=1)
        if not nearby.any():
            keep[mine] = True
            continue
        squared = igl.point_mesh_squared_distance(vertices[corners], vertices, faces[nearby])[0]
        near = np.zeros(len(vertices), dtype=bool)
        near[corners] = squared <= distance**2
        lying = near[faces[mine]].all(axis=1)
        if closed[part] and not lying.all():
            lying[:] = False  # a closed part is a part of the object, or a copy dropped whole
        keep[mine[~lying]] = True
    return faces[keep], int(len(faces) - keep.sum())


def stitch(
    vertices: np.ndarray, faces: np.ndarray, edges: Edges | None, distance: float, cut: bool
) -> tuple[np.ndarray, np.ndarray, int]:
    """Zip together the boundaries of different parts that run side by side.

    Seeds are pairs of boundary vertices of different parts within ``distance``; the parts
    they join are first moved back together (`_aligned`), then the seeds are taken shortest
    first, each vertex paired at most once. From each seed the two boundaries are walked in
    step, both ways, pairing vertex after vertex while each next pair is on two parts and within
    ``distance`` once the shift is undone (a cut seam's within `SEAM_AGREEMENT` of it), and the
    faces on the two edges walked would not fold onto each other (`FOLDED`); a seed from which
    no such step leads is not paired, nor one whose seam, with those taken before it, would join
    the parts into a surface that cannot be oriented. Each pair is merged at its midpoint.

    Parameters
    ----------
    vertices : (n, 3) float64
        Vertex positions.
    faces : (m, 3) int64
        Triangles with at most two faces per edge and one fan per vertex.
    edges : geometry.Edges or None
        The faces' `cfsig.files.elements.mesh_edges` when already known (`clean_mesh` keeps them).
    distance : float
        Largest distance between two vertices to merge, in length units.
    cut : bool
        Stitch only the seams cut through a model (`_seeds`); False stitches every two parts
        whose boundaries run side by side.

    Returns
    -------
    vertices : (n, 3) float64
        Each part that meets another moved by its translation, then each merged pair's first
        vertex moved to the midpoint.
    faces : (m, 3) int64
        With each pair's second vertex replaced by its first (unreferenced vertices and faces
        that became degenerate are left for `clean_mesh`).
    stitched : int
        Number of pairs merged.
    """
    n = len(vertices)
    edges, _, labels = _face_graph(faces, n, edges)
    loops = boundary_loops(edges, n)
    if len(loops) < 2:
        return vertices, faces, 0
    following, preceding = np.full(n, -1), np.full(n, -1)
    for loop in loops:
        following[loop], preceding[loop] = np.roll(loop, -1), np.roll(loop, 1)
    candidates = np.concatenate(loops)
    seeds, shift, support = _seeds(vertices, labels, candidates, distance, cut)
    if shift:  # a shift per two parts with seeds, none without
        vertices = _aligned(vertices, labels, shift, support)
        seeds, shift, _ = _seeds(vertices, labels, candidates, distance, cut)
    if not seeds:
        return vertices, faces, 0

    def gap(x: int, y: int) -> float:
        """The distance of x and y once y's part is moved back onto x's."""
        offset = shift.get((labels[x], labels[y]))
        return (
            np.inf if offset is None else float(np.linalg.norm(vertices[y] - offset - vertices[x]))
        )

    # A cut seam's pairs all agree with its shift: the walk stops where the seam ends, not on
    # the next seam along, where another part meets both.
    reach = SEAM_AGREEMENT * distance if cut else distance
    normals, runs = _boundary_sides(vertices, faces, edges, following)
    # The parts joined so far, each with whether it must be reversed to agree with the part it
    # is joined to (a union-find whose links carry that parity).
    joined_to = np.arange(int(labels.max()) + 1)
    reversed_to = np.zeros(len(joined_to), dtype=bool)

    def joined(part: int) -> tuple[int, bool]:
        """The first part of the parts joined with ``part``, and whether ``part`` is reversed
        against it."""
        reverse = False
        while joined_to[part] != part:
            reverse ^= bool(reversed_to[part])
            part = int(joined_to[part])
        return part, reverse

    def walked(x: int, step: np.ndarray) -> tuple[int, bool]:
        """The boundary edge a walk takes from x, by its first vertex along the loop, and
        whether the walk runs along the loop."""
        return (x, True) if step is following else (int(preceding[x]), False)

    def forward(x: int, step: np.ndarray) -> bool:
        """Whether the walk's edge from x runs as the faces of x's part, once oriented, run."""
        edge, along = walked(x, step)
        return bool(runs[edge]) == along

    def zips(x: int, step_x: np.ndarray, y: int, step_y: np.ndarray) -> bool:
        """Whether the walk from the pair (x, y) may take the next pair: within reach once the
        shift is undone, its faces not folded onto each other (`FOLDED`: a zip's faces run along
        the merged edge in opposite directions, whatever the parts' orientation)."""
        (edge_x, along_x), (edge_y, along_y) = walked(x, step_x), walked(y, step_y)
        agree = normals[edge_x] @ normals[edge_y] * (1 if along_x == along_y else -1)
        return gap(step_x[x], step_y[y]) <= reach and bool(agree <= FOLDED)

    partner = np.full(n, -1)
    for a, b in seeds:
        if partner[a] >= 0 or partner[b] >= 0:
            continue
        walks = [
            (step_a, min((following, preceding), key=lambda step: gap(step_a[a], step[b])))
            for step_a in (following, preceding)
        ]
        valid = [(step_a, step_b) for step_a, step_b in walks if zips(a, step_a, b, step_b)]
        if not valid:
            continue  # no seam runs through the pair: merged, its faces would fold or pinch
        # Zipped edges must run opposite ways: if both run forward, one part must be reversed.
        reverse = forward(a, valid[0][0]) == forward(b, valid[0][1])
        (first_a, reverse_a), (first_b, reverse_b) = joined(labels[a]), joined(labels[b])
        if first_a == first_b and reverse_a ^ reverse_b != reverse:
            continue  # joined already the other way: the surface would have one side
        if first_a != first_b:
            joined_to[first_b], reversed_to[first_b] = first_a, reverse_a ^ reverse_b ^ reverse
        partner[a], partner[b] = b, a
        for step_a, step_b in walks:
            x, y = a, b
            while partner[step_a[x]] < 0 and partner[step_b[y]] < 0 and zips(x, step_a, y, step_b):
                x, y = step_a[x], step_b[y]
                partner[x], partner[y] = y, x
    first = np.flatnonzero(np.arange(n) < partner)
    if len(first) == 0:
        return vertices, faces, 0
    second = partner[first]
    moved = vertices.copy()
    moved[first] = (vertices[first] + vertices[second]) / 2
    remap = np.arange(n)
    remap[second] = first
    return moved, remap[faces], len(first)


def _boundary_sides(
    vertices: np.ndarray, faces: np.ndarray, edges: Edges, following: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """For each boundary vertex x, the unit normal of the face on the boundary edge from x to
    ``following[x]``, its corners taken from x to ``following[x]`` whichever way the face runs
    ((n, 3), zero elsewhere and for a face without area); and whether that face, once its part
    is oriented (libigl's `bfs_orient`), runs from x to ``following[x]`` ((n,) bool)."""
    boundary = np.flatnonzero(np.diff(edges.starts) == 1)
    half = edges.order[edges.starts[boundary]]
    face, corner = half // 3, half % 3
    start, end = faces[face, corner], faces[face, (corner + 1) % 3]
    apex = faces[face, (corner + 2) % 3]
    tail = np.where(following[start] == end, start, end)
    head = np.where(following[start] == end, end, start)
    normal = np.cross(vertices[head] - vertices[tail], vertices[apex] - vertices[tail])
    length = np.linalg.norm(normal, axis=1)[:, None]
    normals = np.zeros_like(vertices)
    normals[tail] = np.divide(normal, length, out=np.zeros_like(normal), where=length > 0)
    import igl

    oriented = np.asarray(igl.bfs_orient(faces)[0])[face]
    first = np.argmax(oriented == faces[face, :1], axis=1)
    kept = oriented[np.arange(len(face)), (first + 1) % 3] == faces[face, 1]  # not reversed
    runs = np.zeros(len(vertices), dtype=bool)
    runs[tail] = (start == tail) == kept
    return normals, runs


def _seeds(
    vertices: np.ndarray, labels: np.ndarray, candidates: np.ndarray, distance: float, cut: bool
) -> tuple[list[tuple[int, int]], dict[tuple[int, int], np.ndarray], dict[tuple[int, int], int]]:
    """Candidate pairs for `stitch`, the shift between each two parts that meet, and the
    number of pairs it was measured on.

    Each boundary vertex is paired with its nearest few on other parts within ``distance``.
    With ``cut``, only seams cut through a model count: such a seam keeps its vertices in step
    when its parts are moved apart, so the offsets of its pairs agree, where two boundaries that
    merely pass near each other give offsets that vary. Two parts whose largest set of offsets
    within `SEAM_AGREEMENT` of ``distance`` of one of them holds `SEAM_PAIRS` or more have a
    cut seam: its mean offset is their shift and its pairs are the seeds. Without ``cut``, each
    two parts get the median of their pairs' offsets as their shift (seams meshed on each side
    on their own), and all their pairs are seeds. The seeds are sorted by their distance once
    the shift is undone.
    """
    from scipy.spatial import cKDTree  # here: a tenth of a second to import, for a rare repair

    points = vertices[candidates]
    k = min(8, len(candidates))
    length, near = cKDTree(points).query(points, k=k, distance_upper_bound=distance)
    rows = np.repeat(np.arange(len(candidates)), k)
    near = near.ravel()
    valid = near < len(candidates)
    a, b = candidates[rows[valid]], candidates[near[valid]]
    keep = (a < b) & (labels[a] != labels[b])
    a, b = a[keep], b[keep]
    offsets = vertices[b] - vertices[a]
    shift: dict[tuple[int, int], np.ndarray] = {}
    support: dict[tuple[int, int], int] = {}
    taken = [np.zeros(0, dtype=np.intp)]
    for (pa, pb), mine in _groups(labels[a], labels[b]).items():
        if cut:
            if len(mine) >= SEAM_PAIRS:
                mine = mine[_agreeing(offsets[mine], SEAM_AGREEMENT * distance)]
            if len(mine) < SEAM_PAIRS:
                continue
        offset = np.mean(offsets[mine], axis=0) if cut else np.median(offsets[mine], axis=0)
        shift[(pa, pb)], shift[(pb, pa)] = offset, -offset
        support[(pa, pb)] = len(mine)
        taken.append(mine)
    seeds = np.concatenate(taken)
    a, b = a[seeds], b[seeds]
    pairs = zip(labels[a].tolist(), labels[b].tolist(), strict=True)
    shifts = np.array([shift[key] for key in pairs]).reshape(-1, 3)
    residual = np.linalg.norm(vertices[b] - shifts - vertices[a], axis=1)
    order = np.argsort(residual, kind="stable")
    return list(zip(a[order].tolist(), b[order].tolist(), strict=True)), shift, support


def _groups(first: np.ndarray, second: np.ndarray) -> dict[tuple[int, int], np.ndarray]:
    """The indices of each pair of labels, ascending, in the order the set of pairs iterates."""
    if len(first) == 0:
        return {}
    keys = first.astype(np.int64) * (int(second.max()) + 1) + second
    order = np.argsort(keys, kind="stable")
    starts = np.flatnonzero(np.diff(keys[order])) + 1
    found = {(int(first[run[0]]), int(second[run[0]])): run for run in np.split(order, starts)}
    return {pair: found[pair] for pair in set(zip(first.tolist(), second.tolist(), strict=True))}


def _agreeing(offsets: np.ndarray, agreement: float) -> np.ndarray:
    """The indices of the largest set of offsets within ``agreement`` of one of them."""
    from scipy.spatial import cKDTree  # as in `_seeds`

    tree = cKDTree(offsets)
    counts = tree.query_ball_point(offsets, agreement, return_length=True)
    return np.asarray(tree.query_ball_point(offsets[np.argmax(counts)], agreement), dtype=np.intp)


def _aligned(
    vertices: np.ndarray,
    labels: np.ndarray,
    shift: dict[tuple[int, int], np.ndarray],
    support: dict[tuple[int, int], int],
) -> np.ndarray:
    """The vertices with each part that meets another moved back by a translation ``t``: the
    least-squares solution of ``t_b - t_a = shift[a, b]`` over the pairs of parts, each
    weighted by its number of pairs, the smallest such (parts moved apart together come back
    together; docs/method.md)."""
    parts = sorted({p for pair in support for p in pair})
    column = {p: i for i, p in enumerate(parts)}
    system = np.zeros((len(support), len(parts)))
    target = np.empty((len(support), 3))
    for row, ((pa, pb), count) in enumerate(support.items()):
        weight = np.sqrt(count)
        system[row, column[pb]], system[row, column[pa]] = weight, -weight
        target[row] = weight * shift[(pa, pb)]
    moves = np.zeros((int(labels.max()) + 1, 3))
    moves[parts] = np.linalg.lstsq(system, target, rcond=None)[0]
    return vertices - moves[labels]


def drop_fragments(
    vertices: np.ndarray, faces: np.ndarray, edges: Edges | None, fraction: float
) -> tuple[np.ndarray, np.ndarray, int] | None:
    """Drop open parts whose area is below a fraction of the total, unless together they hold
    more than that fraction: they are then the object's parts (slats, panels), not strays.

    Parameters
    ----------
    vertices : (n, 3) float64
        Vertex positions.
    faces : (m, 3) int64
        Triangles.
    edges : geometry.Edges or None
        The faces' `cfsig.files.elements.mesh_edges` when already known (`clean_mesh` keeps them).
    fraction : float
        Area fraction below which an open part is dropped, and that the dropped parts may
        hold together.

    Returns
    -------
    vertices : (n, 3) float64
        Unchanged (unreferenced vertices are removed later by `clean_mesh`).
    faces : (m', 3) int64
        The faces kept.
    dropped : int
        Number of parts dropped.

    None when the parts to drop hold more than ``fraction`` of the area together.
    """
    edges, n_parts, labels = _face_graph(faces, len(vertices), edges)
    face_part = labels[faces[:, 0]]
    area = _part_areas(vertices, faces, face_part, n_parts)
    open_part = open_parts(edges, labels, n_parts)
    drop = open_part & (area < fraction * area.sum())
    if not drop.any() or drop.all():
        return vertices, faces, 0
    if area[drop].sum() > fraction * area.sum():
        return None
    return vertices, faces[~drop[face_part]], int(drop.sum())


def drop_small_pieces(mesh: Mesh, fraction: float = FRAGMENT_AREA) -> Mesh:
    """A part without its pieces of less than a fraction of its area.

    A piece is a set of faces joined through their vertices (`cfsig.files.mesh.clean_mesh` has
    split the vertices at which pieces touch). A partial query measures what is left
    (`cfsig.descriptors.parts.measure_part`): a piece far smaller than the disc of the largest
    curvature scale has no curvature there but its rim's (docs/method.md, "Partial queries").

    Parameters
    ----------
    mesh : Mesh
        A checked mesh.
    fraction : float
        Pieces of less than this share of the total area are dropped (`FRAGMENT_AREA`, as the
        repair stage drops open fragments).

    Returns
    -------
    mesh : Mesh
        Checked; the mesh itself when it has no such piece, or when every piece is one.
    """
    _, n_parts, labels = _face_graph(mesh.faces, len(mesh.vertices), mesh.edges)
    face_part = labels[mesh.faces[:, 0]]
    area = _part_areas(mesh.vertices, mesh.faces, face_part, n_parts)
    keep = area >= fraction * area.sum()
    if keep.all() or not keep.any():
        return mesh
    return clean_mesh(mesh.vertices, mesh.faces[keep[face_part]], weld=False)


def fill_holes(
    vertices: np.ndarray, faces: np.ndarray, edges: Edges | None = None
) -> tuple[np.ndarray, np.ndarray, int]:
    """Close every boundary loop by clipping ears, the shortest new edge first.

    A slit between two boundaries that were not stitched closes as a zip of thin triangles; a
    fan from the loop's centroid would span a curved slit with large ones (docs/method.md).
    An ear whose new edge the mesh already has is not clipped; what no ear can close, and a
    loop of three that bounds a face already, is closed by a fan from its centroid.

    Parameters
    ----------
    vertices : (n, 3) float64
        Vertex positions.
    faces : (m, 3) int64
        Triangles with at most two faces per edge and one fan per vertex (`clean_mesh`), so
        that every boundary vertex has exactly two boundary edges.
    edges : geometry.Edges or None
        The faces' `cfsig.files.elements.mesh_edges` when already known (`clean_mesh` keeps them).

    Returns
    -------
    vertices : (n + h, 3) float64
        With a new vertex at the centroid of each of the h loops no ear could close.
    faces : (m + k, 3) int64
        With the new triangles, oriented as the loop's faces.
    filled : int
        Number of loops closed.
    """
    edges = _face_graph(faces, len(vertices), edges)[0]
    loops = boundary_loops(edges, len(vertices))
    if not loops:
        return vertices, faces, 0
    on_loop = np.zeros(len(vertices), dtype=bool)
    on_loop[np.concatenate(loops)] = True
    near = edges.ends[on_loop[edges.ends].all(axis=1)]
    taken = set(map(tuple, near.tolist()))  # (i, j), i < j
    # A loop of three may bound a face already (a part of one face): closing it by that face
    # again would leave a double, which the cleaning removes; a fan keeps it as a flat sheet,
    # as ears keep a larger open sheet.
    present = set(map(tuple, np.sort(faces[on_loop[faces].all(axis=1)], axis=1).tolist()))
    new_vertices, new_faces = [vertices], [faces]
    for loop in loops:
        triangles, rest = _clip_ears(vertices, loop.tolist(), taken)
        if len(rest) > 3 or tuple(sorted(rest)) in present:
            centre = len(vertices) + len(new_vertices) - 1
            new_vertices.append(vertices[rest].mean(axis=0, keepdims=True))
            triangles += [
                (centre, a, b) for a, b in zip(rest, np.roll(rest, -1).tolist(), strict=True)
            ]
        else:
            triangles.append((rest[0], rest[1], rest[2]))
        new_faces.append(np.array(triangles, dtype=faces.dtype).reshape(-1, 3))
    return np.vstack(new_vertices), np.vstack(new_faces), len(loops)


def _clip_ears(
    vertices: np.ndarray, loop: list[int], taken: set[tuple[int, int]]
) -> tuple[list[tuple[int, int, int]], list[int]]:
    """`fill_holes`' ears of one loop, shortest new edge first, none on an edge in ``taken``
    (to which the new edges are added); and the loop left, in order, once no ear is left."""
    count = len(loop)
    before, after = np.roll(np.arange(count), 1), np.roll(np.arange(count), -1)
    alive = np.ones(count, dtype=bool)
    points = vertices[loop]

    def key(i: int) -> float:
        return float(np.linalg.norm(points[after[i]] - points[before[i]]))

    heap = [(key(i), i) for i in range(count)]
    heapq.heapify(heap)
    triangles: list[tuple[int, int, int]] = []
    while count > 3 and heap:
        length, i = heapq.heappop(heap)
        if not alive[i] or length != key(i):
            continue  # clipped, or its neighbours changed since it was pushed
        a, b = loop[before[i]], loop[after[i]]
        edge = (min(a, b), max(a, b))
        if edge in taken:
            continue  # pushed again when a neighbour is clipped
        taken.add(edge)
        triangles.append((a, loop[i], b))
        alive[i] = False
        count -= 1
        after[before[i]], before[after[i]] = after[i], before[i]
        for j in (before[i], after[i]):
            heapq.heappush(heap, (key(j), j))
    start = int(np.flatnonzero(alive)[0])
    rest, i = [], start
    for _ in range(count):
        rest.append(loop[i])
        i = after[i]
    return triangles, rest


def boundary_loops(edges: Edges, n_vertices: int) -> list[np.ndarray]:
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


def _part_areas(
    vertices: np.ndarray, faces: np.ndarray, face_part: np.ndarray, n_parts: int
) -> np.ndarray:
    """The surface area of each part, (n_parts,) in squared length units."""
    return np.bincount(face_part, face_areas(edge_lengths(vertices, faces)), n_parts)


def _surface(mesh: Mesh) -> tuple[Edges, int, np.ndarray, bool]:
    """A mesh's edges, number of parts, the part of each vertex, and whether every edge has two
    faces."""
    edges, n_parts, labels = _face_graph(mesh.faces, len(mesh.vertices), mesh.edges)
    return edges, n_parts, labels, bool(np.all(np.diff(edges.starts) == 2))


def _oriented(vertices: np.ndarray, faces: np.ndarray, done: list[str]) -> np.ndarray:
    """`orient_parts`, noting in ``done`` how many faces it reversed."""
    oriented = orient_parts(vertices, faces)
    count = int(np.count_nonzero(np.any(oriented != faces, axis=1)))
    if count:
        done.append(f"reversed {count} faces to orient every part outward")
    return oriented


def _oriented_outward(mesh: Mesh, edges: Edges) -> bool:
    """Whether the two faces of each edge of a closed mesh run along it in opposite directions,
    and the faces enclose a positive volume."""
    a, b = paired_half_edges(edges)
    vertex = mesh.faces.ravel()
    if np.any(vertex[a] == vertex[b]):
        return False
    return bool(signed_volumes(mesh.vertices, mesh.faces).sum() > 0)


def _face_graph(
    faces: np.ndarray, n_vertices: int, edges: Edges | None
) -> tuple[Edges, int, np.ndarray]:
    """The edges (sorted now unless given), the number of parts and the part of each vertex."""
    if edges is None:
        edges = mesh_edges(faces, n_vertices)
    n_parts, labels = _parts(edges.ends, n_vertices)
    return edges, n_parts, labels


def _parts(ends: np.ndarray, n_vertices: int) -> tuple[int, np.ndarray]:
    """Connected components of the vertex graph given by its edges, sorted as `mesh_edges`
    sorts them (so that the graph's rows are laid out directly)."""
    indptr = np.zeros(n_vertices + 1, dtype=np.int64)
    np.cumsum(np.bincount(ends[:, 0], minlength=n_vertices), out=indptr[1:])
    data = np.ones(len(ends), dtype=np.int8)
    graph = sp.csr_matrix((data, ends[:, 1], indptr), shape=(n_vertices, n_vertices))
    count, labels = connected_components(graph, directed=False)
    return int(count), labels
