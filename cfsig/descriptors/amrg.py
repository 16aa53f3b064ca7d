"""The descriptor ``amrg``: the augmented multiresolution Reeb graph of Tung and Schmitt ("The
augmented multiresolution Reeb graph approach for content-based retrieval of 3D shapes",
International Journal of Shape Modeling 11(1), 2005), which extends the multiresolution Reeb
graph (MRG) of Hilaga et al. (SIGGRAPH 2001) by geometric attributes of its nodes.

The steps, and the choices made where the papers leave them open (docs/method.md):

- The function: ``mu(v) = sum_b area_b g(v, b)``, Hilaga's integral of geodesic distance over
  the surface, on a copy of the mesh simplified to `COARSE` faces (the mesh itself when it has
  no more). The `BASES` base vertices b are chosen by farthest-point sampling, each carrying the
  area of the vertices nearest to it; g is the shortest path along the edges (Dijkstra, as
  Hilaga et al. compute it), the surface's parts joined first by their shortest gaps
  (`bridges`), as Hilaga et al. join close vertices. ``mu_n = (mu - min mu) / max mu``,
  Hilaga's normalisation, lies in [0, 1) and is invariant to rigid motion, scale and (nearly)
  to isometric bending.
- The graph at resolution r = 0 .. `RESOLUTIONS` - 1: [0, 1] cut into ``2**r`` intervals of
  equal width; each face falls in the interval of its corners' mean ``mu_n``; a node is a
  connected component (across shared edges) of the faces of one interval, two nodes are
  adjacent when they share an edge, and the parent of a node is the node of resolution r - 1
  that holds its faces.
- Per node (`ATTRIBUTES`), Hilaga's ``area`` (its share of the surface) and ``length`` (the
  span of ``mu_n`` it covers, as a share of the sum of its resolution's spans), then Tung and
  Schmitt's geometric attributes: ``volume`` (its share of the cones from the mesh's centroid
  to the faces, by absolute volume), ``extent`` (the mean length of
  its cords over the square root of the surface's area; a cord runs from the node's centroid to
  a face's), and three histograms of `BINS` bins weighted by face area: the Koenderink shape
  index, the cord lengths over their mean, and the absolute cosine of the cords with the node's
  principal axis.
- Storage: at each resolution the `CAPS` largest nodes by area, each as `FIELDS` numbers
  (interval, parent's slot or -1, the attributes), slots of no node all -1 but a zero area;
  before them, per resolution and interval, the sums of the kept nodes' area and length (the
  profiles the lower bound compares).

Matching (`amrg_distances`), resolution by resolution from the coarsest: a pair of nodes may be
matched when they lie in the same interval and their parents were matched to each other
(Hilaga's topological consistency; at r = 0, any pair of the one interval); among such pairs,
the one of greatest similarity is matched, then the next among those whose nodes are both
unmatched, and so on. The similarity of two nodes is

    sim(m, n) = LAMBDA (W min(a_m, a_n) + (1 - W) min(l_m, l_n))
                + (1 - LAMBDA) min(a_m, a_n) (1 - d(m, n))

with d the mean of the geometric attributes' differences (scalars: ``|x - y| / (x + y)``,
histograms: half their L1 distance), each in [0, 1]. The similarity of two graphs at a
resolution is the sum over its matched pairs, at most the similarity of either graph with
itself (`self_similarities`, 1 when no node was dropped); divided by the larger of those two,
it is 1 for a graph and itself, exactly. Their distance is 1 minus its mean over the
resolutions. `amrg_bounds` bounds it from below by the profiles: a matching pairs nodes of
one interval, one to one, so their summed minima of area (or length) cannot exceed the smaller
total of that interval.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import scipy.sparse as sp
from scipy.sparse.csgraph import connected_components, dijkstra
from scipy.spatial import cKDTree

from cfsig.descriptors.base import Computed, Descriptor, Distance, L1Kernel
from cfsig.errors import MeshError
from cfsig.files.elements import (
    edge_lengths,
    face_areas,
    mesh_edges,
    paired_half_edges,
    signed_volumes,
    vertex_areas,
    vertex_normals,
)
from cfsig.files.mesh import Mesh
from cfsig.operators.conformal import ConformalFactor, operators
from cfsig.params import Layout, Params
from cfsig.repair.simplify import simplified_mesh

COARSE = 6000  # faces of the simplified copy the graph is built on
BASES = 128  # base vertices of the integral of geodesic distance
RESOLUTIONS = 5  # r = 0 .. 4: 1, 2, 4, 8 and 16 intervals of mu_n
CAPS = (4, 8, 16, 32, 48)  # nodes kept per resolution, the largest by area
BINS = 9  # bins of each histogram attribute, odd: a cylinder's shape index, 1/2, lies mid-bin
LAMBDA = 0.25  # weight of Hilaga's topological similarity against the geometric one
W = 0.5  # Hilaga's weight of area against length
SCALARS = ("volume", "extent")
HISTOGRAMS = ("shape index", "cord length", "cord direction")
ATTRIBUTES = ("area", "length", *SCALARS, *(f"{h} {i}" for h in HISTOGRAMS for i in range(BINS)))
FIELDS = 2 + len(ATTRIBUTES)  # interval, parent slot, then the attributes
PROFILE = 2 * (2**RESOLUTIONS - 1)  # per resolution and interval: area and length sums
LENGTH = PROFILE + sum(CAPS) * FIELDS
CORD_REACH = 2.0  # the cord length histogram spans [0, CORD_REACH) times the node's mean
# The bound's margin below the distance: the profiles and the nodes are rounded to float32
# apart, and searches round the exact distance to float32.
_BOUND_MARGIN = 1e-5


@dataclass(frozen=True)
class Level:
    """The Reeb graph of ``mu_n`` at one resolution.

    Attributes
    ----------
    intervals : (k,) int64
        Interval of each node, 0 to ``2**r - 1``.
    parents : (k,) int64
        The node of the coarser resolution that holds each node's faces; -1 at r = 0.
    edges : (e, 2) int64
        Pairs of adjacent nodes, ``i < j``, each once.
    attributes : (k, len(ATTRIBUTES)) float64
        Each node's `ATTRIBUTES`, dimensionless.
    """

    intervals: np.ndarray
    parents: np.ndarray
    edges: np.ndarray
    attributes: np.ndarray


def integral_geodesic(
    vertices: np.ndarray,
    faces: np.ndarray,
    areas: np.ndarray,
    edges: np.ndarray,
    bases: int = BASES,
) -> np.ndarray:
    """Hilaga's normalised integral of geodesic distance at each vertex.

    Parameters
    ----------
    vertices : (n, 3) float64
        Vertex positions.
    faces : (m, 3) int64
        Triangles, every vertex referenced.
    areas : (m,) float64
        Their areas.
    edges : (e, 2) int64
        Their edges' ends (`cfsig.files.elements.Edges.ends`).
    bases : int
        Base vertices, chosen by farthest-point sampling along the edges.

    Returns
    -------
    mu : (n,) float64
        ``(mu - min mu) / max mu`` in [0, 1), mu the sum over the bases of their area times
        their shortest-path distance (within the vertex's own connected part).

    Raises
    ------
    MeshError
        The surface has no extent along its edges, so mu is zero everywhere.
    """
    n = len(vertices)
    edges = np.concatenate([edges, bridges(vertices, edges)])
    length = np.linalg.norm(vertices[edges[:, 0]] - vertices[edges[:, 1]], axis=1)
    graph = sp.coo_matrix((length, (edges[:, 0], edges[:, 1])), shape=(n, n)).tocsr()
    area = vertex_areas(areas, faces, n)
    rows = np.empty((min(bases, n), n))
    nearest = np.full(n, np.inf)
    base = int(np.argmax(dijkstra(graph, directed=False, indices=0)))  # an end of the surface
    for i in range(len(rows)):
        rows[i] = dijkstra(graph, directed=False, indices=base)
        nearest = np.minimum(nearest, rows[i])
        base = int(np.argmax(nearest))  # unreached parts (inf) come first
    reached = np.isfinite(rows)
    owner = np.argmin(np.where(reached, rows, np.inf), axis=0)
    weight = np.bincount(owner, area, len(rows))
    mu = (np.where(reached, rows, 0.0) * weight[:, None]).sum(axis=0)
    top = mu.max()
    if not top > 0 or not np.isfinite(top):
        raise MeshError("its Reeb graph cannot be built: no geodesic distance along its edges")
    return (mu - mu.min()) / top


def bridges(vertices: np.ndarray, edges: np.ndarray) -> np.ndarray:
    """Edges that join the connected parts of a surface into one, each between the closest
    vertices of a part and the rest (Boruvka's rounds: every part but the largest links to its
    nearest other part, until one is left).

    Parameters
    ----------
    vertices : (n, 3) float64
        Vertex positions.
    edges : (e, 2) int64
        The surface's edges.

    Returns
    -------
    bridges : (b, 2) int64
        The added edges; none for a connected surface.
    """
    n = len(vertices)
    added = np.zeros((0, 2), np.int64)
    while True:
        both = np.concatenate([edges, added])
        graph = sp.coo_matrix((np.ones(len(both)), (both[:, 0], both[:, 1])), shape=(n, n))
        count, labels = connected_components(graph, directed=False)
        if count == 1:
            return added
        largest = np.argmax(np.bincount(labels))
        links = []
        for part in range(count):
            if part == largest:
                continue
            inside, outside = np.flatnonzero(labels == part), np.flatnonzero(labels != part)
            gap, nearest = cKDTree(vertices[outside]).query(vertices[inside])
            closest = int(np.argmin(gap))
            links.append((inside[closest], outside[nearest[closest]]))
        added = np.concatenate([added, np.array(links, np.int64)])


def reeb_graph(mesh: Mesh) -> list[Level]:
    """The augmented multiresolution Reeb graph of a mesh, on its simplified copy.

    Parameters
    ----------
    mesh : Mesh
        The repaired mesh.

    Returns
    -------
    levels : list of Level
        One per resolution, coarsest first (`RESOLUTIONS`).

    Raises
    ------
    MeshError
        Its graph cannot be built: the surface has no area, volume or extent to measure by.
    """
    surface = simplified_mesh(mesh, COARSE) or mesh
    vertices, faces = surface.vertices, surface.faces
    edges = surface.edges or mesh_edges(faces, len(vertices))
    face_area = face_areas(edge_lengths(vertices, faces))
    mu = integral_geodesic(vertices, faces, face_area, edges.ends)
    total = face_area.sum()
    centre = vertices[faces].mean(axis=1)
    centroid = (centre * face_area[:, None]).sum(axis=0) / total
    cones = np.abs(signed_volumes(vertices - centroid, faces))
    if not total > 0 or not cones.sum() > 0:
        raise MeshError("its Reeb graph cannot be built: the surface has no area or volume")
    face = _FaceData(
        mu=mu[faces],
        area=face_area / total,
        volume=cones / cones.sum(),
        centre=centre,
        shape_index=_shape_index(surface)[faces].mean(axis=1),
        scale=np.sqrt(total),
    )
    a, b = paired_half_edges(edges)
    pairs = np.stack([a // 3, b // 3], axis=1)
    levels: list[Level] = []
    labels = np.zeros(len(faces), np.int64)
    for r in range(RESOLUTIONS):
        parent_labels = labels
        level, labels = _level(face, pairs, 2**r)
        if r:
            first = np.unique(labels, return_index=True)[1]
            level = Level(level.intervals, parent_labels[first], level.edges, level.attributes)
        levels.append(level)
    return levels


@dataclass(frozen=True)
class _FaceData:
    """What the nodes are measured by, per face: corners' mu_n (m, 3), area, volume (shares),
    centre (m, 3), shape index; and the surface's square root of area."""

    mu: np.ndarray
    area: np.ndarray
    volume: np.ndarray
    centre: np.ndarray
    shape_index: np.ndarray
    scale: float


def _level(face: _FaceData, pairs: np.ndarray, count: int) -> tuple[Level, np.ndarray]:
    """The graph of one resolution of ``count`` intervals (parents unset), and each face's node."""
    m = len(face.area)
    interval = np.minimum((face.mu.mean(axis=1) * count).astype(np.int64), count - 1)
    same = pairs[interval[pairs[:, 0]] == interval[pairs[:, 1]]]
    graph = sp.coo_matrix((np.ones(len(same)), (same[:, 0], same[:, 1])), shape=(m, m))
    k, node = connected_components(graph, directed=False)
    node = node.astype(np.int64)
    apart = pairs[node[pairs[:, 0]] != node[pairs[:, 1]]]
    ends = np.sort(node[apart], axis=1)
    edges = np.unique(ends, axis=0) if len(ends) else np.zeros((0, 2), np.int64)
    intervals = np.zeros(k, np.int64)
    intervals[node] = interval
    area = np.bincount(node, face.area, k)
    # the span of mu_n over the node's corners, clipped to its interval
    low, high = interval[:, None] / count, (interval[:, None] + 1) / count
    clipped = np.clip(face.mu, low, high)
    top, bottom = np.full(k, -np.inf), np.full(k, np.inf)
    np.maximum.at(top, node, clipped.max(axis=1))
    np.minimum.at(bottom, node, clipped.min(axis=1))
    span = top - bottom
    length = span / span.sum() if span.sum() > 0 else area
    weights = face.area / np.maximum(area[node], np.finfo(float).tiny)
    centre = _sums(node, face.centre * weights[:, None], k)
    cords = face.centre - centre[node]
    cord = np.linalg.norm(cords, axis=1)
    mean_cord = np.bincount(node, cord * weights, k)
    spread = _sums(node, (cords[:, :, None] * cords[:, None, :] * weights[:, None, None]), k)
    axis = np.linalg.eigh(spread)[1][:, :, -1]  # (k, 3): each node's principal axis
    cosine = np.abs(np.einsum("ij,ij->i", cords, axis[node])) / np.where(cord > 0, cord, 1)
    relative = cord / np.where(mean_cord[node] > 0, mean_cord[node], 1)
    histograms = [
        _histogram(node, (face.shape_index + 1) / 2, weights, k),
        _histogram(node, relative / CORD_REACH, weights, k),
        _histogram(node, cosine, weights, k),
    ]
    attributes = np.column_stack(
        [
            area,
            length,
            np.bincount(node, face.volume, k),
            mean_cord / face.scale,
            *histograms,
        ]
    )
    return Level(intervals, np.full(k, -1, np.int64), edges, attributes), node


def _sums(node: np.ndarray, values: np.ndarray, k: int) -> np.ndarray:
    """Per node the sum of ``values`` (m, ...) over its faces: (k, ...)."""
    out = np.zeros((k, *values.shape[1:]))
    np.add.at(out, node, values)
    return out


def _histogram(node: np.ndarray, unit: np.ndarray, weights: np.ndarray, k: int) -> np.ndarray:
    """Per node the histogram of ``unit`` (values in [0, 1], beyond to the end bins) in `BINS`
    bins, weighted by ``weights`` that sum to 1 over each node's faces: (k, BINS)."""
    bins = np.clip((unit * BINS).astype(np.int64), 0, BINS - 1)
    counts = np.bincount(node * BINS + bins, weights, k * BINS)
    return counts.reshape(k, BINS)


def _shape_index(surface: Mesh) -> np.ndarray:
    """Koenderink's shape index at each vertex, in [-1, 1] (+1: a cap, -1: a cup), from the
    mean curvature of the cotangent Laplacian and the angle defect."""
    ops = operators(surface)
    area = np.maximum(ops.vertex_area, np.finfo(float).tiny)
    normals = vertex_normals(surface.vertices, surface.faces)
    mean = -np.einsum("ij,ij->i", ops.laplacian @ surface.vertices, normals) / (2 * area)
    gauss = ops.curvature / area
    gap = 2 * np.sqrt(np.maximum(mean**2 - gauss, 0))  # k1 - k2
    return np.arctan2(2 * mean, gap) * (2 / np.pi)


def pack(levels: list[Level]) -> np.ndarray:
    """The stored vector of a graph.

    Parameters
    ----------
    levels : list of Level
        `reeb_graph`.

    Returns
    -------
    vector : (LENGTH,) float64
        The profiles, then per resolution `CAPS` slots of `FIELDS` (module docstring).
    """
    profiles, slots = [], []
    kept = np.zeros(0, np.int64)
    for r, level in enumerate(levels):
        count = 2**r
        order = np.argsort(-level.attributes[:, 0], kind="stable")[: CAPS[r]]
        slot = np.full(len(level.intervals), -1, np.int64)
        slot[order] = np.arange(len(order))
        parents = level.parents[order]
        parents = np.where(parents >= 0, kept[np.maximum(parents, 0)], -1) if r else parents
        kept = slot
        block = np.full((CAPS[r], FIELDS), -1.0)
        block[:, 2:] = 0
        block[: len(order), 0] = level.intervals[order]
        block[: len(order), 1] = parents
        block[: len(order), 2:] = level.attributes[order]
        slots.append(block.ravel())
        for column in (0, 1):  # area, length
            values = level.attributes[order, column]
            profiles.append(np.bincount(level.intervals[order], values, count))
    return np.concatenate(profiles + slots)


def _unpack(vectors: np.ndarray) -> list[np.ndarray]:
    """The node slots of each resolution: (v, CAPS[r], FIELDS) views, float32."""
    blocks, start = [], PROFILE
    for cap in CAPS:
        blocks.append(vectors[:, start : start + cap * FIELDS].reshape(len(vectors), cap, FIELDS))
        start += cap * FIELDS
    return blocks


def amrg_vector(mesh: Mesh, params: Params, cf: ConformalFactor | None, solver: str) -> Computed:
    """The ``amrg`` descriptor of a mesh.

    Parameters
    ----------
    mesh : Mesh
        The repaired mesh.
    params : Params
        Unused: the graph has no parameters of its own.
    cf : ConformalFactor or None
        Unused.
    solver : str
        Unused: no linear system is solved.

    Returns
    -------
    computed : Computed
        ``vector``: (LENGTH,) float64, `pack` of `reeb_graph`; no cells, no operators.

    Raises
    ------
    MeshError
        Its graph cannot be built (`reeb_graph`).
    """
    return Computed(pack(reeb_graph(mesh)), None, None)


def node_similarities(query: np.ndarray, rows: np.ndarray) -> np.ndarray:
    """``sim(m, n)`` of pairs of nodes (module docstring).

    Parameters
    ----------
    query, rows : (p, FIELDS) float32
        The two nodes of each pair, as stored.

    Returns
    -------
    sim : (p,) float64
        In [0, min(a_m, a_n)]: with ``a_m = a_n``, ``a_m`` exactly when the nodes agree.
    """
    query, rows = query.astype(np.float64), rows.astype(np.float64)
    area = np.minimum(query[:, 2], rows[:, 2])
    length = np.minimum(query[:, 3], rows[:, 3])
    q, s = query[:, 4 : 4 + len(SCALARS)], rows[:, 4 : 4 + len(SCALARS)]
    scalars = (np.abs(q - s) / np.maximum(q + s, 1e-12)).sum(axis=1)
    histograms = np.abs(query[:, 4 + len(SCALARS) :] - rows[:, 4 + len(SCALARS) :]).sum(axis=1)
    apart = (scalars + histograms / 2) / (len(SCALARS) + len(HISTOGRAMS))
    return LAMBDA * (W * area + (1 - W) * length) + (1 - LAMBDA) * area * (1 - apart)


def graph_similarities(query: np.ndarray, rows: np.ndarray) -> np.ndarray:
    """The matched similarity of a query graph with each row's, per resolution.

    Parameters
    ----------
    query : (LENGTH,) float32
        A stored vector (`pack`).
    rows : (v, LENGTH) float32
        Stored vectors.

    Returns
    -------
    similarities : (v, RESOLUTIONS) float64
        At each resolution, the sum of ``sim`` over the pairs matched (module docstring), in
        [0, 1].
    """
    count = len(rows)
    every = np.arange(count)
    found = np.zeros((count, RESOLUTIONS))
    partner = np.zeros((count, 0), np.int64)
    for r, (mine, theirs) in enumerate(zip(_unpack(query[None]), _unpack(rows), strict=True)):
        nodes = np.flatnonzero(mine[0, :, 0] >= 0)
        own = mine[0, nodes]
        allowed = (own[None, :, None, 0] == theirs[:, None, :, 0]) & (theirs[:, None, :, 0] >= 0)
        if r:
            parents = own[:, 1].astype(np.int64)
            matched = np.where(parents >= 0, partner[:, np.maximum(parents, 0)], -1)
            allowed &= (matched >= 0)[:, :, None] & (matched[:, :, None] == theirs[:, None, :, 1])
        which, i, j = np.nonzero(allowed)
        scores = np.full(allowed.shape, -np.inf)
        scores[which, i, j] = node_similarities(own[i], theirs[which, j])
        partner = np.full((count, mine.shape[1]), -1, np.int64)
        width = scores.shape[2]
        flat = scores.reshape(count, -1)
        live = every
        for _ in range(min(len(nodes), width)):
            best = flat[live].argmax(axis=1)
            value = flat[live, best]
            keep = np.isfinite(value)
            live, best, value = live[keep], best[keep], value[keep]
            if not len(live):
                break
            i, j = best // width, best % width
            found[live, r] += value
            partner[live, nodes[i]] = j
            scores[live, i, :] = -np.inf
            scores[live, :, j] = -np.inf
    return found


def self_similarities(vectors: np.ndarray) -> np.ndarray:
    """The matched similarity of each graph with itself, per resolution.

    Parameters
    ----------
    vectors : (v, LENGTH) float32
        Stored vectors.

    Returns
    -------
    similarities : (v, RESOLUTIONS) float64
        The sum of its nodes' ``sim(m, m)``, added in the order the matching adds them (from
        the largest), so that a graph's `graph_similarities` with itself equals it exactly.
    """
    found = np.zeros((len(vectors), RESOLUTIONS))
    for r, block in enumerate(_unpack(vectors)):
        nodes = block.reshape(-1, FIELDS)
        sims = node_similarities(nodes, nodes).reshape(block.shape[:2])
        found[:, r] = np.cumsum(-np.sort(-sims, axis=1), axis=1)[:, -1]
    return found


def amrg_distances(queries: np.ndarray, rows: np.ndarray, l1: L1Kernel) -> np.ndarray:
    """The ``amrg`` distance: 1 minus the mean over the resolutions of the graphs' similarity,
    each divided by the larger of the two graphs' similarity with itself.

    Parameters
    ----------
    queries : (q, LENGTH) float32
        Stored vectors (`pack`).
    rows : (m, LENGTH) float32
        Stored vectors.
    l1 : callable
        Unused: the matching compares nodes, not vectors.

    Returns
    -------
    distances : (q, m) float64
        In [0, 1]; 0 for a graph and itself.
    """
    own, theirs = self_similarities(queries), self_similarities(rows)
    out = np.empty((len(queries), len(rows)))
    for i, query in enumerate(queries):
        scale = np.maximum(np.maximum(own[i], theirs), np.finfo(float).tiny)
        out[i] = 1 - (graph_similarities(query, rows) / scale).mean(axis=1)
    return out


def amrg_bounds(queries: np.ndarray, rows: np.ndarray, l1: L1Kernel) -> np.ndarray:
    """A lower bound of `amrg_distances` from the interval profiles alone.

    Parameters
    ----------
    queries : (q, LENGTH) float32
        Stored vectors.
    rows : (m, LENGTH) float32
        Stored vectors.
    l1 : callable
        Unused.

    Returns
    -------
    bounds : (q, m) float64
        1 minus the mean over resolutions of the largest similarity any one-to-one matching
        within intervals can reach, per interval the smaller total area (times ``LAMBDA W +
        1 - LAMBDA``) and the smaller total length (times ``LAMBDA (1 - W)``), over the larger
        of the two graphs' similarity with itself (the same sums of their own), less a margin
        for rounding.
    """
    weights = np.concatenate(
        [np.repeat([LAMBDA * W + 1 - LAMBDA, LAMBDA * (1 - W)], 2**r) for r in range(RESOLUTIONS)]
    )
    resolution = np.repeat(np.arange(RESOLUTIONS), 2 ** (np.arange(RESOLUTIONS) + 1))
    head = rows[:, :PROFILE].astype(np.float64)
    theirs = _per_resolution(head * weights, resolution)
    out = np.empty((len(queries), len(rows)))
    for i, query in enumerate(queries):
        profile = query[:PROFILE].astype(np.float64)
        reach = _per_resolution(np.minimum(profile, head) * weights, resolution)
        own = _per_resolution((profile * weights)[None], resolution)
        scale = np.maximum(np.maximum(own, theirs), np.finfo(float).tiny)
        out[i] = (reach / scale).mean(axis=1)
    return 1 - out - _BOUND_MARGIN


def _per_resolution(values: np.ndarray, resolution: np.ndarray) -> np.ndarray:
    """Sums of profile columns (v, PROFILE) per resolution: (v, RESOLUTIONS)."""
    out = np.zeros((len(values), RESOLUTIONS))
    np.add.at(out.T, resolution, values.T)
    return out


DESCRIPTOR = Descriptor(
    name="amrg",
    needs_phi=False,
    layout=lambda params: Layout(LENGTH),
    compute=amrg_vector,
    distance=Distance(exact=amrg_distances, bound=amrg_bounds),
)
