"""Simplified copies of a mesh, by quadric edge collapses (fast-simplification).

The low Laplace-Beltrami spectrum barely moves when a mesh is simplified to a few thousand
faces, while its cost falls with the number of vertices; `cfsig.descriptors.intrinsic` computes
its channels on such a copy (docs/method.md, "How it is computed"). The repair stage's proxy
(`cfsig.repair.proxy`) is simplified the same way beyond 40,000 faces.

The collapses are chaotic: a perturbation of the coordinates' last bits (1e-12 of the size)
moves the copy, and so `intrinsic`'s vector, by as much as the distance between two meshes
of a class, and their error threshold is absolute. So they run on the mesh in its own frame
(`canonical_frame`), its coordinates rounded to a grid there: a moved, turned or scaled copy
of a mesh, or the same mesh listed in another order, is simplified from the same numbers, and
the copy comes back moved, turned and scaled alike.
"""

from __future__ import annotations

import numpy as np

from cfsig.errors import MeshError
from cfsig.files.elements import edge_lengths, face_areas, vertex_areas
from cfsig.files.mesh import Mesh, clean_mesh

# The grid the coordinates are rounded to in the mesh's own frame, where the square root of
# the area is 1: 2**-12, about a thousandth of a sphere's radius, coarse enough that the
# rounding of a moved copy (float32 files) rarely straddles a grid line (docs/method.md).
GRID = 2.0**-12


def decimate(vertices: np.ndarray, faces: np.ndarray, count: int) -> tuple[np.ndarray, np.ndarray]:
    """Collapse edges of a triangle mesh by increasing quadric error until ``count`` faces.

    Parameters
    ----------
    vertices : (n, 3) float64
        Vertex positions.
    faces : (m, 3) int
        Triangles.
    count : int
        Number of faces wanted; a mesh with at most that many is returned as it is.

    Returns
    -------
    vertices : (p, 3) float64
        Positions of the simplified mesh's vertices.
    faces : (q, 3) int64
        Its triangles, about ``min(m, count)`` of them.
    """
    if len(faces) <= count:
        return np.asarray(vertices, dtype=np.float64), np.asarray(faces, dtype=np.int64)
    import fast_simplification

    vertices, faces = np.asarray(vertices, dtype=np.float64), np.asarray(faces, dtype=np.int64)
    centre, scale, axes = canonical_frame(vertices, faces)
    own = np.round((vertices - centre) @ axes / (scale * GRID)) * GRID
    own, faces = canonical_numbering(own, faces)
    own, faces = fast_simplification.simplify(own, faces.astype(np.int32), target_count=count)
    vertices = np.asarray(own, dtype=np.float64) * scale @ axes.T + centre
    return vertices, np.asarray(faces, dtype=np.int64)


def canonical_frame(
    vertices: np.ndarray, faces: np.ndarray
) -> tuple[np.ndarray, float, np.ndarray]:
    """A frame of the surface that moves, turns and scales with it.

    Parameters
    ----------
    vertices : (n, 3) float64
        Vertex positions.
    faces : (m, 3) int
        Triangles.

    Returns
    -------
    centre : (3,) float64
        The surface's centroid (of its area, lumped at the vertices).
    scale : float
        The square root of its area (1 for a surface without area).
    axes : (3, 3) float64
        Orthonormal columns: the principal axes of the surface's second moments about the
        centre, largest first, each pointing where the surface's third moment along it is
        positive. A surface with two equal moments (a body of revolution) or none along an axis
        (a mirror image of itself) leaves them to round-off. The three are rounded to 30 bits.
    """
    areas = face_areas(edge_lengths(vertices, faces))
    # Each face's area shared among its corners: the surface's moments, lumped at the vertices.
    weights = vertex_areas(areas, faces, len(vertices))
    total = float(weights.sum())
    if not total > 0:
        return np.zeros(3), 1.0, np.eye(3)
    centre = weights @ vertices / total
    points = vertices - centre
    axes = np.linalg.eigh((points.T * weights) @ points)[1][:, ::-1]
    along = points @ axes
    axes *= np.where(weights @ (along * along * along) < 0, -1.0, 1.0)
    # Sums in another order round otherwise: to 30 bits, the same surface listed in another
    # order gets the same frame bit for bit, and so the same copy.
    mantissa, exponent = np.frexp(np.sqrt(total))
    scale = float(np.ldexp(np.round(mantissa * 2.0**30), exponent - 30))
    centre = np.round(centre / scale * 2.0**30) * scale / 2.0**30
    return centre, scale, np.round(axes * 2.0**30) / 2.0**30


def canonical_numbering(vertices: np.ndarray, faces: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The same triangles, numbered by position rather than as a file happened to list them.

    Parameters
    ----------
    vertices : (n, 3) float64
        Vertex positions.
    faces : (m, 3) int
        Triangles.

    Returns
    -------
    vertices : (n, 3) float64
        The vertices sorted by x, then y, then z (coincident ones in their given order).
    faces : (m, 3) int64
        The triangles over the new numbering, each starting at its smallest index (so keeping
        its orientation), sorted.
    """
    order = np.lexsort(vertices.T[::-1])
    rank = np.empty(len(order), dtype=np.int64)
    rank[order] = np.arange(len(order))
    renumbered = rank[faces]
    first = np.argmin(renumbered, axis=1)[:, None]
    renumbered = np.take_along_axis(renumbered, (first + np.arange(3)) % 3, axis=1)
    return vertices[order], renumbered[np.lexsort(renumbered.T[::-1])]


def simplified_mesh(mesh: Mesh, count: int) -> Mesh | None:
    """A checked copy of a mesh simplified to about ``count`` faces.

    Parameters
    ----------
    mesh : Mesh
        A checked mesh.
    count : int
        Number of faces wanted.

    Returns
    -------
    copy : Mesh or None
        The simplified copy, checked by `cfsig.files.mesh.clean_mesh`; None when the mesh has at
        most ``count`` faces (nothing to simplify) or the simplification leaves no usable
        triangle.
    """
    if len(mesh.faces) <= count:
        return None
    try:
        return clean_mesh(*decimate(mesh.vertices, mesh.faces, count))
    except MeshError:
        return None
