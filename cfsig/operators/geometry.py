"""Curvature and the Laplacian: the discrete operators of paper section 2.2.

Everything here is intrinsic: it is computed from the edge lengths of each triangle, so the same
functions serve the original mesh, a mollified mesh and the conformally scaled metric of the
curvature error (paper section 3.4). Edge ``j`` of a face is the edge opposite its corner ``j``.
"""

from __future__ import annotations

import numpy as np
import scipy.sparse as sp

from cfsig.files.elements import Edges, face_areas, mesh_edges

_OPPOSITE = ((1, 2), (2, 0), (0, 1))


def mollify(lengths: np.ndarray, factor: float) -> tuple[np.ndarray, float]:
    """Intrinsic mollification of Sharp and Crane (2020, section 4.5).

    Adds the smallest constant to every edge length such that each triangle satisfies the triangle
    inequality with a margin of ``factor`` times the mean edge length, so that zero-area and needle
    triangles get finite angles and cotangents. Meshes that need nothing are returned unchanged.

    Parameters
    ----------
    lengths : (m, 3) float64
        Edge lengths as returned by `edge_lengths`.
    factor : float
        Margin relative to the mean edge length; 0 returns ``lengths`` unchanged.

    Returns
    -------
    lengths : (m, 3) float64
        The mollified edge lengths.
    delta : float
        The constant added to every length (0 when none was needed), in length units.
    """
    if factor <= 0 or len(lengths) == 0:
        return lengths, 0.0
    eps = factor * float(lengths.mean())
    slack = _row_sums(lengths) - 2 * lengths
    delta = max(0.0, float((eps - slack).max()))
    return (lengths + delta, delta) if delta > 0 else (lengths, 0.0)


def corner_angles(lengths: np.ndarray) -> np.ndarray:
    """Interior angle at each corner, by the law of cosines.

    Parameters
    ----------
    lengths : (m, 3) float64
        Edge lengths, ``lengths[f, j]`` opposite corner ``j``.

    Returns
    -------
    angles : (m, 3) float64
        Angles in radians, in [0, pi]; a metric that violates the triangle inequality gives
        clipped angles of 0 or pi rather than NaN.
    """
    a, b, c = lengths.T
    a2, b2, c2 = a * a, b * b, c * c
    with np.errstate(divide="ignore", invalid="ignore", over="ignore"):
        cos = np.stack(
            [
                (b2 + c2 - a2) / (2 * b * c),
                (c2 + a2 - b2) / (2 * c * a),
                (a2 + b2 - c2) / (2 * a * b),
            ],
            axis=1,
        )
    cos[np.isnan(cos)] = 1.0
    np.clip(cos, -1.0, 1.0, out=cos)
    return np.arccos(cos, out=cos)


def cotan_laplacian(
    lengths: np.ndarray,
    faces: np.ndarray,
    n_vertices: int,
    areas: np.ndarray | None = None,
    edges: Edges | None = None,
) -> sp.csc_matrix:
    """The cotangent Laplacian (paper eq. 1, [HPW06]) of an intrinsic metric.

    Parameters
    ----------
    lengths : (m, 3) float64
        Edge lengths of the non-degenerate triangles ``faces``.
    faces : (m, 3) int64
        Triangles.
    n_vertices : int
        Number of vertices n.
    areas : (m,) float64, optional
        The faces' areas, `face_areas` of ``lengths``, when already known.
    edges : Edges, optional
        The faces' `mesh_edges`, when already known.

    Returns
    -------
    L : (n, n) scipy.sparse.csc_matrix, float64
        Symmetric, negative semidefinite, ``L[i, j] = (cot a + cot b) / 2`` for an edge ij and
        rows summing to zero; the same sign convention as libigl's ``cotmatrix``. Dimensionless.
        An entry is stored for every edge, even of weight 0, and for every diagonal element, so
        the pattern is the vertex adjacency plus the diagonal; row indices are sorted.
    """
    if areas is None:
        areas = face_areas(lengths)
    if edges is None:
        edges = mesh_edges(faces, n_vertices)
    a2 = lengths * lengths
    half_cot = _row_sums(a2) - 2 * a2  # cot = (b^2 + c^2 - a^2) / (4 area), halved
    half_cot /= (8 * areas)[:, None]
    # Half-edge 3f + j is opposite corner (j + 2) % 3; an edge's weight sums its half-edges'.
    per_half_edge = half_cot[:, [2, 0, 1]].ravel()[edges.order]
    if len(per_half_edge) == 2 * len(edges.ends) and np.all(np.diff(edges.starts) == 2):
        weight = per_half_edge[0::2] + per_half_edge[1::2]  # closed: two faces on every edge
    else:
        weight = np.add.reduceat(per_half_edge, edges.starts[:-1])
    low, high = edges.ends[:, 0], edges.ends[:, 1]
    diag = -(np.bincount(low, weight, n_vertices) + np.bincount(high, weight, n_vertices))
    return _symmetric_csc(edges.ends, weight, diag, n_vertices)


def _symmetric_csc(ends: np.ndarray, weight: np.ndarray, diag: np.ndarray, n: int) -> sp.csc_matrix:
    """The symmetric (n, n) CSC matrix of sorted edges' weights and a diagonal, laid out."""
    low, high = ends[:, 0], ends[:, 1]
    below = np.bincount(low, minlength=n)  # entries under the diagonal, per column
    above = np.bincount(high, minlength=n)
    indptr = np.zeros(n + 1, dtype=np.int64)
    np.cumsum(below + above + 1, out=indptr[1:])
    # Column j holds its entries above the diagonal, the diagonal, then those below. The edges,
    # sorted by (low, high), are already the part below; the part above is its transpose,
    # reordered by SciPy's linear counting sort.
    upper = sp.csr_matrix((weight, high, np.r_[0, np.cumsum(below)]), shape=(n, n)).tocsc()
    every, rank = np.arange(n), np.arange(len(low))
    start_above = upper.indptr[:-1]
    start_below = indptr[:-1] - start_above - every
    diagonal = indptr[:-1] + above
    nnz = int(indptr[-1])
    index_type = np.int32 if nnz < 2**31 else np.int64
    indices, data = np.empty(nnz, dtype=index_type), np.empty(nnz)
    where_above = rank + np.repeat(indptr[:-1] - start_above, above)
    where_below = rank + np.repeat(diagonal + 1 - start_below, below)
    indices[where_above], data[where_above] = upper.indices, upper.data
    indices[where_below], data[where_below] = high, weight
    indices[diagonal], data[diagonal] = every, diag
    return sp.csc_matrix((data, indices, indptr.astype(index_type)), shape=(n, n))


def boundary_vertices(faces: np.ndarray, laplacian: sp.spmatrix) -> np.ndarray:
    """Mark the vertices that lie on a boundary edge (an edge of one face only).

    On a mesh with at most two faces per edge and one fan of faces per vertex (what `clean_mesh`
    guarantees), a vertex is inside when its fan closes, with as many neighbours as faces, and
    on the boundary when its fan is open, with one neighbour more than faces.

    Parameters
    ----------
    faces : (m, 3) int64
        Triangles.
    laplacian : (n, n) scipy.sparse.csc_matrix or csr_matrix
        The mesh's `cotan_laplacian`, whose pattern holds each edge and the diagonal.

    Returns
    -------
    boundary : (n,) bool
    """
    n = laplacian.shape[0]
    neighbours = np.diff(laplacian.indptr) - 1
    return np.bincount(faces.ravel(), minlength=n) < neighbours


def angle_defect(angles: np.ndarray, faces: np.ndarray, boundary: np.ndarray) -> np.ndarray:
    """Discrete Gaussian curvature as the angle defect (paper section 2.2, [MDSB02]).

    Parameters
    ----------
    angles : (m, 3) float64
        Corner angles in radians.
    faces : (m, 3) int64
        Triangles.
    boundary : (n,) bool
        Boundary vertices, which get pi - sum of angles instead of 2 pi - sum.

    Returns
    -------
    K : (n,) float64
        Curvature in radians per vertex; sums to 2 pi chi (Gauss-Bonnet).
    """
    total = np.bincount(faces.ravel(), weights=angles.ravel(), minlength=len(boundary))
    return np.where(boundary, np.pi, 2 * np.pi) - total


def target_curvature(
    curvature: np.ndarray, vertex_area: np.ndarray, labels: np.ndarray
) -> np.ndarray:
    """The uniform target curvature K^T of paper section 2.2, per connected component.

    Each vertex gets its component's total curvature times its share of the component's area,
    so that K^T - K sums to zero on every component, as the singular system needs.

    Parameters
    ----------
    curvature : (n,) float64
        Angle defects K^orig in radians.
    vertex_area : (n,) float64
        Barycentric vertex areas.
    labels : (n,) int
        Component of each vertex.

    Returns
    -------
    K_target : (n,) float64
        Target curvature in radians per vertex.
    """
    total_k = np.bincount(labels, weights=curvature)
    total_a = np.bincount(labels, weights=vertex_area)
    return total_k[labels] * vertex_area / total_a[labels]


def _row_sums(values: np.ndarray) -> np.ndarray:
    """Sums of the three columns as an (m, 1) column, added left to right like ``sum(axis=1)``."""
    return (values[:, 0] + values[:, 1] + values[:, 2])[:, None]
