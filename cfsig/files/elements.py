"""The elements of a triangle mesh: its edges, their lengths, face areas, its connected parts."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import scipy.sparse as sp
from scipy.sparse.csgraph import connected_components

OPPOSITE = ((1, 2), (2, 0), (0, 1))  # edge j of a face is the edge opposite its corner j


@dataclass(frozen=True)
class Edges:
    """The undirected edges of a triangle mesh and the half-edges on each, from one sort.

    Half-edge ``3f + j`` runs from corner ``j`` of face ``f`` to its corner ``(j + 1) % 3``: it is
    the edge opposite corner ``(j + 2) % 3``.

    Attributes
    ----------
    ends : (e, 2) int64
        Each edge's vertices ``(i, j)`` with ``i < j``; the rows are sorted.
    order : (3m,) int64
        The half-edges sorted by edge.
    starts : (e + 1,) int64
        Edge ``k`` is made of the half-edges ``order[starts[k]:starts[k + 1]]``, one per face
        that contains it.
    """

    ends: np.ndarray
    order: np.ndarray
    starts: np.ndarray


def mesh_edges(faces: np.ndarray, n_vertices: int) -> Edges:
    """Find the undirected edges of a triangle mesh by sorting its half-edges.

    Parameters
    ----------
    faces : (m, 3) int64
        Triangles.
    n_vertices : int
        Number of vertices n.

    Returns
    -------
    edges : Edges
    """
    start = faces.ravel()
    end = faces[:, [1, 2, 0]].ravel()
    low, high = np.minimum(start, end), np.maximum(start, end)
    keys = low * n_vertices + high
    count = len(keys)
    if int(n_vertices) ** 2 * count < 2**63:  # the half-edge in the key's low digits: a plain sort
        packed = keys * count + np.arange(count)
        packed.sort()
        order = packed % count
    else:
        order = np.argsort(keys)
    sorted_keys = keys[order]
    starts = np.flatnonzero(np.r_[True, sorted_keys[1:] != sorted_keys[:-1], True])
    starts = starts[: count + 1]  # no faces: no edges, starts == [0]
    first = order[starts[:-1]]
    return Edges(np.stack([low[first], high[first]], axis=1), order, starts)


def paired_half_edges(edges: Edges) -> tuple[np.ndarray, np.ndarray]:
    """The two half-edges of every edge that has exactly two faces.

    Parameters
    ----------
    edges : Edges
        A mesh's edges (`mesh_edges`).

    Returns
    -------
    a, b : (k,) int64
        Half-edges ``3f + j`` on the same edge, k the number of edges of two faces. The faces
        are consistently oriented across that edge when ``faces.ravel()[a] != faces.ravel()[b]``
        (they leave it from different ends).
    """
    pair = edges.starts[:-1][np.diff(edges.starts) == 2]
    return edges.order[pair], edges.order[pair + 1]


def open_parts(edges: Edges, labels: np.ndarray, n_parts: int) -> np.ndarray:
    """Which parts have a boundary edge (an edge of one face).

    Parameters
    ----------
    edges : Edges
        A mesh's edges (`mesh_edges`).
    labels : (n,) int
        Part of each vertex.
    n_parts : int
        Number of parts.

    Returns
    -------
    open : (n_parts,) bool
        True for the parts with a boundary edge.
    """
    found = np.zeros(n_parts, dtype=bool)
    found[labels[edges.ends[np.diff(edges.starts) == 1, 0]]] = True
    return found


def edge_graph(faces: np.ndarray, n_vertices: int) -> sp.csr_matrix:
    """The mesh's edges as a symmetric sparse matrix of face counts.

    Parameters
    ----------
    faces : (m, 3) int64
        Triangles.
    n_vertices : int
        Number of vertices n.

    Returns
    -------
    graph : (n, n) scipy.sparse.csr_matrix, float64
        ``graph[i, j]`` is the number of faces that contain the edge ij: 1 on a boundary, 2 inside
        a manifold, more on a non-manifold edge; no entry where there is no edge.
    """
    ends, counts = edge_face_counts(faces, n_vertices)
    both = np.r_[counts, counts].astype(np.float64)
    ij = (np.r_[ends[:, 0], ends[:, 1]], np.r_[ends[:, 1], ends[:, 0]])
    return sp.csr_matrix((both, ij), shape=(n_vertices, n_vertices))


def edge_face_counts(faces: np.ndarray, n_vertices: int) -> tuple[np.ndarray, np.ndarray]:
    """Every undirected edge and the number of faces that contain it.

    Parameters
    ----------
    faces : (m, 3) int64
        Triangles.
    n_vertices : int
        Number of vertices n.

    Returns
    -------
    edges : (e, 2) int64
        Unique edges ``(i, j)`` with ``i < j``, sorted.
    counts : (e,) int64
        Faces per edge: 1 on a boundary, 2 inside a manifold, more on a non-manifold edge.
    """
    edges = mesh_edges(faces, n_vertices)
    return edges.ends, np.diff(edges.starts)


def components(graph: sp.spmatrix) -> tuple[int, np.ndarray]:
    """Connected components of the mesh's vertex graph.

    Parameters
    ----------
    graph : (n, n) scipy.sparse matrix
        Symmetric, with the vertex adjacency as its pattern (a diagonal does not matter): the
        `cotan_laplacian` or the `edge_graph`.

    Returns
    -------
    count : int
        Number of components.
    labels : (n,) int32
        Component of each vertex, numbered from 0.
    """
    count, labels = connected_components(graph, directed=False)
    return int(count), labels


def edge_lengths(vertices: np.ndarray, faces: np.ndarray) -> np.ndarray:
    """Length of each triangle's three edges.

    Parameters
    ----------
    vertices : (n, 3) float64
        Vertex positions.
    faces : (m, 3) int64
        Triangles as indices into ``vertices``.

    Returns
    -------
    lengths : (m, 3) float64
        ``lengths[f, j]`` is the length of the edge of face ``f`` opposite its corner ``j``,
        in the units of ``vertices``.
    """
    squared = np.zeros(faces.shape)
    for coordinate in np.ascontiguousarray(vertices.T):
        corner = coordinate[faces]
        delta = np.empty_like(corner)
        for j, (a, b) in enumerate(OPPOSITE):
            np.subtract(corner[:, b], corner[:, a], out=delta[:, j])
        delta *= delta
        squared += delta
    return np.sqrt(squared, out=squared)


def signed_volumes(vertices: np.ndarray, faces: np.ndarray) -> np.ndarray:
    """Six times the signed volume of each face's tetrahedron with the origin.

    Parameters
    ----------
    vertices : (n, 3) float64
        Vertex positions.
    faces : (m, 3) int64
        Triangles.

    Returns
    -------
    volumes : (m,) float64
        In cubed length units; summed over a closed part, six times its volume, positive when
        its faces face out.
    """
    a, b, c = (vertices[faces[:, k]] for k in range(3))
    return np.einsum("ij,ij->i", a, np.cross(b, c))


def face_areas(lengths: np.ndarray) -> np.ndarray:
    """Triangle areas by Heron's formula in its numerically stable form (Kahan).

    Parameters
    ----------
    lengths : (m, 3) float64
        Edge lengths.

    Returns
    -------
    areas : (m,) float64
        Areas in squared length units; 0 for triangles that violate the triangle inequality.
    """
    x, y, z = lengths.T
    a = np.maximum(np.maximum(x, y), z)  # a >= b >= c, as Kahan's formula needs
    b = np.maximum(np.minimum(x, y), np.minimum(np.maximum(x, y), z))
    c = np.minimum(np.minimum(x, y), z)
    prod = (a + (b + c)) * (c - (a - b)) * (c + (a - b)) * (a + (b - c))
    return 0.25 * np.sqrt(np.maximum(prod, 0.0))


def vertex_areas(areas: np.ndarray, faces: np.ndarray, n_vertices: int) -> np.ndarray:
    """A third of the area of the faces around each vertex (the barycentric vertex area).

    Parameters
    ----------
    areas : (m,) float64
        Face areas.
    faces : (m, 3) int64
        Triangles.
    n_vertices : int
        Number of vertices n.

    Returns
    -------
    vertex_area : (n,) float64
        In squared length units; sums to the total area.
    """
    return np.bincount(faces.ravel(), weights=np.repeat(areas / 3, 3), minlength=n_vertices)


def face_normals(vertices: np.ndarray, faces: np.ndarray) -> np.ndarray:
    """Each face's normal scaled by twice its area: the cross product of two of its edges.

    Parameters
    ----------
    vertices : (n, 3) float64
        Vertex positions.
    faces : (m, 3) int64
        Triangles.

    Returns
    -------
    normals : (m, 3) float64
        Along the face's orientation (its corners counter-clockwise seen from the tip); zero
        for a degenerate face.
    """
    corners = vertices[faces]
    return np.cross(corners[:, 1] - corners[:, 0], corners[:, 2] - corners[:, 0])


def vertex_normals(vertices: np.ndarray, faces: np.ndarray) -> np.ndarray:
    """Area-weighted vertex normals.

    Parameters
    ----------
    vertices : (n, 3) float64
        Vertex positions.
    faces : (m, 3) int64
        Triangles.

    Returns
    -------
    normals : (n, 3) float64
        Unit length (zero for isolated vertices), along the faces' orientation.
    """
    scaled = face_normals(vertices, faces)
    index = faces.ravel()
    normals = np.column_stack(
        [np.bincount(index, np.repeat(scaled[:, d], 3), len(vertices)) for d in range(3)]
    )
    return normals / np.maximum(np.linalg.norm(normals, axis=1, keepdims=True), 1e-300)
