"""Simplified copies of a mesh, by quadric edge collapses (fast-simplification).

The low Laplace-Beltrami spectrum barely moves when a mesh is simplified to a few thousand
faces, while its cost falls with the number of vertices; `cfsig.descriptors.intrinsic` computes
its channels on such a copy (docs/method.md, "How it is computed"). The repair stage's proxy
(`cfsig.repair.proxy`) is simplified the same way beyond 40,000 faces.
"""

from __future__ import annotations

import numpy as np

from cfsig.errors import MeshError
from cfsig.files.mesh import Mesh, clean_mesh


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

    # The collapses' order, and so the copy, depend on the numbering: the same surface read
    # from two files must give the same copy.
    vertices, faces = canonical_numbering(np.asarray(vertices, dtype=np.float64), faces)
    vertices, faces = fast_simplification.simplify(
        vertices, faces.astype(np.int32), target_count=count
    )
    return np.asarray(vertices, dtype=np.float64), np.asarray(faces, dtype=np.int64)


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
