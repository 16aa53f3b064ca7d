"""Reading and repairing triangle meshes: OFF, OBJ, PLY, STL, glTF, 3MF and COLLADA files to
checked numpy arrays."""

from __future__ import annotations

import importlib.util
import io
import logging
import os
import warnings
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import scipy.sparse as sp
from scipy.sparse.csgraph import connected_components

from cfsig.errors import MeshError, MissingDependencyError
from cfsig.files.elements import Edges, face_normals, mesh_edges, paired_half_edges
from cfsig.files.folders import MESH_SUFFIXES

# The Laplacian and the curvature take products of up to four lengths, which end float64 near
# 1e+-77: larger coordinates overflow, a smaller span underflows. The bounds keep a wide margin;
# tests/test_bad_input.py checks every descriptor and partial queries just inside them.
MAX_COORDINATE = 1e50
# Formats of scenes, whose parts are placed by their nodes' transforms, and how close (relative
# to the bounding box's diagonal) two of their vertices are taken as one: float32's rounding of
# a coordinate, about 6e-8 of it, times a few for the transform.
SCENE_SUFFIXES = (".glb", ".gltf", ".3mf", ".dae")
WELD_TOLERANCE = 1e-6
MIN_SPAN = 1e-50


@dataclass(frozen=True)
class Mesh:
    """A checked triangle mesh.

    Attributes
    ----------
    vertices : (n, 3) float64
        Finite vertex positions, every one referenced by a face.
    faces : (m, 3) int64
        Triangles with three distinct in-range indices, no face repeated.
    repairs : tuple of str
        What was repaired on reading, in words (empty for a clean mesh).
    edges : geometry.Edges or None
        The faces' `cfsig.files.elements.mesh_edges`, kept from the non-manifold check of
        `clean_mesh` so
        that the Laplacian need not sort the half-edges again; None when not known.
    route : str
        Which route of `cfsig.repair.stage.repair_mesh` the mesh took: ``"clean"`` (one closed
        manifold, as read), ``"repaired"``, ``"proxy"`` or ``"unrepaired"``.
    parts : (n,) int or None
        Connected component of each vertex, numbered as `cfsig.files.elements.components` numbers
        them,
        kept from the repair stage's check so that the solve need not find them again; None
        when not known.
    """

    vertices: np.ndarray
    faces: np.ndarray
    repairs: tuple[str, ...] = ()
    edges: Edges | None = None
    route: str = "clean"
    parts: np.ndarray | None = None


def read_mesh(path: str | os.PathLike) -> Mesh:
    """Read a mesh file and check and repair it with `clean_mesh`.

    OFF is parsed here, the others through trimesh. Polygons are split into triangle fans. A
    scene (glTF, GLB, 3MF, COLLADA) is read as one mesh in world coordinates: every node's
    geometry with its transform applied.

    Parameters
    ----------
    path : str or path-like
        A file of one of the `cfsig.files.folders.MESH_SUFFIXES`.

    Returns
    -------
    mesh : Mesh

    Raises
    ------
    MeshError
        The file is missing, unreadable, of an unknown type, malformed, or holds no usable
        triangle; the message names the file and the reason.
    MissingDependencyError
        The format needs an optional package that is not installed (3MF: networkx and lxml;
        COLLADA: pycollada; Draco-compressed glTF: DracoPy); the message names the file and
        the extra.
    """
    return parse_mesh(read_bytes(path), path)


def read_bytes(path: str | os.PathLike) -> bytes:
    """Read a mesh file's bytes, checking its extension first.

    Parameters
    ----------
    path : str or path-like
        A file of one of the `cfsig.files.folders.MESH_SUFFIXES`.

    Returns
    -------
    data : bytes

    Raises
    ------
    MeshError
        Unknown extension, or the file cannot be read.
    """
    path = Path(path)
    suffix = path.suffix.lower()
    if suffix not in MESH_SUFFIXES:
        raise MeshError(f"{path}: unknown mesh type {suffix or '(no extension)'!r}")
    try:
        return path.read_bytes()
    except OSError as exc:
        raise MeshError(f"{path}: cannot read: {exc.strerror or exc}") from None


def parse_mesh(data: bytes, path: str | os.PathLike) -> Mesh:
    """Parse a mesh file's bytes and check and repair it with `clean_mesh`.

    Parameters
    ----------
    data : bytes
        The file's contents.
    path : str or path-like
        The file's name: its extension selects the format and messages name it.

    Returns
    -------
    mesh : Mesh

    Raises
    ------
    MeshError
        Malformed contents or no usable triangle; the message names the file and the reason.
    MissingDependencyError
        The format needs an optional package that is not installed (`read_mesh`).
    """
    suffix = Path(path).suffix.lower()
    if not data.strip():
        raise MeshError(f"{path}: empty file")
    try:
        vertices, faces = _parse_off(data) if suffix == ".off" else _parse_trimesh(data, path)
    except (MeshError, MissingDependencyError) as exc:
        raise type(exc)(f"{path}: {exc}") from None
    try:
        return clean_mesh(vertices, faces)
    except MeshError as exc:
        raise MeshError(f"{path}: {exc}") from None


def clean_mesh(vertices: np.ndarray, faces: np.ndarray, weld: bool = True) -> Mesh:
    """Check a triangle mesh and repair what can be repaired soundly.

    Repairs: exactly coincident vertices are merged (STL files store triangle soups), faces that
    repeat a vertex and repeated faces are dropped, unreferenced vertices are removed, and
    non-manifold vertices are split into one copy per sheet (`split_nonmanifold`).

    Parameters
    ----------
    vertices : (n, 3) array_like of float
        Vertex positions.
    faces : (m, 3) array_like of int
        Triangles.
    weld : bool
        Merge coincident vertices; off for a mesh already cleaned once, whose split vertices
        coincide with the vertex they copy.

    Returns
    -------
    mesh : Mesh

    Raises
    ------
    MeshError
        Non-finite coordinates, beyond `MAX_COORDINATE` or spanning less than `MIN_SPAN`, face
        indices out of range, no triangle left, or none with an area.
    """
    vertices = np.asarray(vertices, dtype=np.float64)
    faces = np.asarray(faces)
    if vertices.ndim != 2 or vertices.shape[1] != 3:
        raise MeshError(f"vertices must have shape (n, 3), not {vertices.shape}")
    if faces.ndim != 2 or faces.shape[1] != 3 or len(faces) == 0:
        raise MeshError("no triangles")
    if not np.all(np.isfinite(vertices)):
        bad = int(np.count_nonzero(~np.isfinite(vertices).all(axis=1)))
        raise MeshError(f"{bad} vertices have NaN or infinite coordinates")
    if np.abs(vertices).max() > MAX_COORDINATE:
        raise MeshError(
            f"coordinates up to {np.abs(vertices).max():.3g}: beyond {MAX_COORDINATE:g}, areas "
            "and curvatures overflow"
        )
    span = float(np.ptp(vertices, axis=0).max())
    if 0 < span < MIN_SPAN:
        raise MeshError(
            f"coordinates span {span:.3g}: below {MIN_SPAN:g}, areas and curvatures underflow"
        )
    if not np.issubdtype(faces.dtype, np.integer):
        raise MeshError("face indices are not integers")
    faces = faces.astype(np.int64)
    if faces.min() < 0 or faces.max() >= len(vertices):
        raise MeshError(
            f"face index out of range: indices span [{faces.min()}, {faces.max()}] "
            f"but there are {len(vertices)} vertices"
        )
    repairs: list[str] = []
    # + 0.0 turns -0.0 into 0.0, which compares equal
    if weld and _has_duplicate_rows(vertices + 0.0):
        unique, inverse = np.unique(vertices, axis=0, return_inverse=True)
        repairs.append(f"merged {len(vertices) - len(unique)} coincident vertices")
        vertices, faces = unique, inverse.reshape(-1)[faces]
    repeated = (faces[:, 0] == faces[:, 1]) | (faces[:, 1] == faces[:, 2])
    repeated |= faces[:, 2] == faces[:, 0]
    if repeated.any():
        repairs.append(f"dropped {int(repeated.sum())} faces that repeat a vertex")
        faces = faces[~repeated]
    keys = _face_keys(faces, len(vertices))
    if _has_duplicate_rows(keys):
        _, first = np.unique(keys, axis=0, return_index=True)
        repairs.append(f"dropped {len(faces) - len(first)} duplicate faces")
        faces = faces[np.sort(first)]
    if len(faces) == 0:
        raise MeshError("no triangles left after dropping degenerate faces")
    if not face_normals(vertices, faces).any():
        raise MeshError("the triangles have no area: every one is degenerate")
    used = np.zeros(len(vertices), dtype=bool)
    used[faces.ravel()] = True
    if not used.all():
        repairs.append(f"removed {int((~used).sum())} unreferenced vertices")
        remap = np.cumsum(used) - 1
        vertices, faces = vertices[used], remap[faces]
    edges: Edges | None = mesh_edges(faces, len(vertices))
    split_faces, copies = split_nonmanifold(faces, len(vertices), edges)
    if len(copies):
        repairs.append(f"split {len(np.unique(copies))} non-manifold vertices into separate sheets")
        vertices, faces, edges = np.vstack([vertices, vertices[copies]]), split_faces, None
    return Mesh(vertices, faces, tuple(repairs), edges)


def split_nonmanifold(
    faces: np.ndarray, n_vertices: int, edges: Edges | None = None
) -> tuple[np.ndarray, np.ndarray]:
    """Give each sheet of faces around a vertex its own copy of that vertex.

    The faces around a vertex form fans: maximal sequences of faces joined through edges that
    belong to exactly two faces. A manifold vertex has one fan. A vertex where two parts touch,
    or on an edge shared by three or more faces (a fin), has several; each fan after the first
    gets a new vertex. The result has at most two faces per edge and one fan per vertex, so the
    paper's angle defect and Laplacian apply; parts that touched only at vertices become
    separate components. Fans do not depend on the orientation of the faces.

    Parameters
    ----------
    faces : (m, 3) int64
        Triangles over ``n_vertices`` vertices, all referenced.
    n_vertices : int
        Number of vertices n.
    edges : geometry.Edges, optional
        The faces' `cfsig.files.elements.mesh_edges`, when already known.

    Returns
    -------
    faces : (m, 3) int64
        Triangles over ``n + k`` vertices (unchanged when ``k == 0``).
    copies : (k,) int64
        For each new vertex ``n + i``, the vertex it copies.
    """
    fan = _fans(faces, edges if edges is not None else mesh_edges(faces, n_vertices))
    roots = fan == np.arange(fan.size)
    if np.count_nonzero(roots) == n_vertices:
        return faces, np.empty(0, dtype=np.int64)
    n_fans = np.count_nonzero(roots)
    fan = np.cumsum(roots)[fan] - 1
    fan_vertex = np.empty(n_fans, dtype=np.int64)
    fan_vertex[fan] = faces.ravel()
    order = np.lexsort((np.arange(n_fans), fan_vertex))
    first = np.ones(n_fans, dtype=bool)
    first[1:] = fan_vertex[order][1:] != fan_vertex[order][:-1]
    extra = order[~first]
    new_id = fan_vertex.copy()
    new_id[extra] = n_vertices + np.arange(len(extra))
    return new_id[fan].reshape(faces.shape), fan_vertex[extra]


def _fans(faces: np.ndarray, edges: Edges) -> np.ndarray:
    """The smallest corner of the fan of every corner ``3f + j``."""
    vertex = faces.ravel()
    step = np.tile(np.array([1, 1, -2]), len(faces))  # from a corner to the next in its face
    a, b = paired_half_edges(edges)  # edges of two faces join fans; others break
    closed = len(a) == len(edges.ends)  # every edge has two faces
    if np.any(vertex[a] == vertex[b]):  # two faces run along an edge the same way
        return _fans_by_components(vertex, step, a, b)
    return _fans_by_jumping(vertex, step, a, b, closed)


def _fans_by_jumping(
    vertex: np.ndarray, step: np.ndarray, a: np.ndarray, b: np.ndarray, closed: bool
) -> np.ndarray:
    """`_fans` by pointer jumping around each vertex; needs consistently oriented pairs a, b."""
    corner = np.arange(vertex.size)
    twin = corner.copy()  # half-edge 3f + j runs from corner 3f + j to the next
    twin[a], twin[b] = b, a
    # Around a vertex, step to the face across the edge leaving the corner and across the edge
    # ending at it; on a closed mesh every fan is a cycle and the first direction suffices.
    hops = [_corner_at(twin, vertex, vertex, step)]
    if not closed:
        hops.append(_corner_at(twin[corner - np.roll(step, 1)], vertex, vertex, step))
    # After r rounds each label is the minimum over 2^r consecutive corners of its fan (in both
    # directions when open), so r with 2^r >= the most corners at a vertex covers every fan.
    rounds = (int(np.bincount(vertex).max()) - 1).bit_length()
    label = corner
    for r in range(rounds):
        new = label
        for hop in hops:
            new = np.minimum(new, label[hop])
        label = new
        if r + 1 < rounds:
            hops = [hop[hop] for hop in hops]
    return label


def _fans_by_components(
    vertex: np.ndarray, step: np.ndarray, a: np.ndarray, b: np.ndarray
) -> np.ndarray:
    """`_fans` as connected components of corners joined across the edges of two faces a, b."""
    ends = np.r_[a, a + step[a]]  # the corners of a's face at the edge's two vertices
    across = _corner_at(np.r_[b, b], vertex[ends], vertex, step)
    graph = sp.coo_matrix((np.ones(len(ends)), (ends, across)), shape=(vertex.size,) * 2)
    _, label = connected_components(graph, directed=False)
    _, smallest = np.unique(label, return_index=True)
    return smallest[label]


def _corner_at(
    half: np.ndarray, at: np.ndarray, vertex: np.ndarray, step: np.ndarray
) -> np.ndarray:
    """The corner at vertex ``at`` of the face of each half-edge ``half``, either way round."""
    return np.where(vertex[half] == at, half, half + step[half])


def _has_duplicate_rows(rows: np.ndarray) -> bool:
    """Whether two rows of a 2-D array are bitwise equal (a hash of each row, then a sort)."""
    bits = np.ascontiguousarray(rows).view(np.uint64)
    hashes = bits[:, 0].copy()
    for column in bits.T[1:]:
        hashes = hashes * np.uint64(0x9E3779B97F4A7C15) ^ column
    hashes.sort()
    if not np.any(hashes[1:] == hashes[:-1]):
        return False
    return len(np.unique(rows, axis=0)) < len(rows)  # equal hashes: check the rows themselves


def _face_keys(faces: np.ndarray, n_vertices: int) -> np.ndarray:
    """A row per face that is the same for every order of its vertices.

    One integer per face when the indices fit in 21 bits each, else the sorted faces.
    """
    if n_vertices >= 1 << 21:
        return np.sort(faces, axis=1)
    a, b, c = faces.T
    low, high = np.minimum(np.minimum(a, b), c), np.maximum(np.maximum(a, b), c)
    return ((low << 42) | ((a + b + c - low - high) << 21) | high)[:, None]


def _parse_off(data: bytes) -> tuple[np.ndarray, np.ndarray]:
    """Parse OFF bytes (also COFF, NOFF and the like) into vertices and triangulated faces."""
    if b"#" in data:
        data = b"\n".join(line.split(b"#", 1)[0] for line in data.splitlines())
    plain = _parse_plain_off(data)
    if plain is not None:
        return plain
    tokens = data.split()
    if not tokens or not tokens[0].upper().endswith(b"OFF"):
        raise MeshError("not an OFF file (no OFF header)")
    try:
        n_v, n_f = int(tokens[1]), int(tokens[2])
    except (IndexError, ValueError):
        raise MeshError("malformed OFF header: expected vertex and face counts") from None
    if n_v < 3 or n_f < 1:
        raise MeshError(f"OFF header declares {n_v} vertices and {n_f} faces")
    body = tokens[4:]
    if len(body) < 3 * n_v + 4 * n_f:  # checked before allocating: a lying header costs nothing
        raise MeshError(
            f"truncated OFF: the header declares {n_v} vertices and {n_f} faces "
            f"but the file holds only {len(body)} numbers"
        )
    try:
        values = np.array(body[: 3 * n_v + 4 * n_f], dtype=np.float64)
    except ValueError:
        values = None
    if values is not None and tokens[0].upper() == b"OFF":
        tris = values[3 * n_v :].reshape(-1, 4)
        if np.all(tris[:, 0] == 3):
            return values[: 3 * n_v].reshape(-1, 3), _as_indices(tris[:, 1:])
    return _parse_off_lines(data, n_v, n_f)


def _parse_plain_off(data: bytes) -> tuple[np.ndarray, np.ndarray] | None:
    """Parse the common OFF layout fast, or return None to let the general parser decide.

    The layout: "OFF" alone on the first line, the counts on the second, one vertex of three
    coordinates per line, then only triangles. The vertex block ends at the n_v-th line break
    after the counts: NumPy's C readers parse it as rows of floats (`numpy.loadtxt`, a sixth
    faster than `numpy.fromstring` and bit-identical, benchmarks/parsers.py) and the rest as
    integers, with no Python object per number.
    """
    lines = np.flatnonzero(np.frombuffer(data, dtype=np.uint8) == ord("\n"))
    if len(lines) < 2 or data[: lines[0]].strip().upper() != b"OFF":
        return None
    counts = data[lines[0] + 1 : lines[1]].split()
    try:
        n_v, n_f = int(counts[0]), int(counts[1])
    except (IndexError, ValueError):
        return None
    if len(counts) != 3 or n_v < 3 or n_f < 1 or len(lines) < n_v + 2:
        return None
    start, split = lines[1] + 1, lines[n_v + 1] + 1
    with warnings.catch_warnings():  # a block that does not parse goes to the general parser
        warnings.simplefilter("ignore")
        try:
            vertices = np.loadtxt(io.BytesIO(data[start:split]), comments=None, ndmin=2)
            faces = np.fromstring(data[split:], dtype=np.int64, sep=" ")
        except ValueError:
            return None
    if vertices.shape != (n_v, 3) or len(faces) != 4 * n_f:
        return None
    faces = faces.reshape(-1, 4)
    if not np.all(faces[:, 0] == 3):
        return None
    return vertices, faces[:, 1:]


def _parse_off_lines(data: bytes, n_v: int, n_f: int) -> tuple[np.ndarray, np.ndarray]:
    """Line-by-line OFF parse for polygons, colours and per-vertex extras."""
    lines = [line.split() for line in data.splitlines()]
    lines = [line for line in lines if line]
    start = 1 if len(lines[0]) > 1 else 2  # counts on the header line, or on the next
    if len(lines) < start + n_v + n_f:
        raise MeshError(f"truncated OFF: expected {n_v} vertex and {n_f} face lines")
    try:
        vertices = np.array([line[:3] for line in lines[start : start + n_v]], dtype=np.float64)
        polygons = [
            [int(i) for i in line[1 : 1 + int(line[0])]]
            for line in lines[start + n_v : start + n_v + n_f]
        ]
    except ValueError as exc:
        raise MeshError(f"malformed OFF: {exc}") from None
    return vertices, triangulate(polygons)


def triangulate(polygons: list[list[int]]) -> np.ndarray:
    """Split polygons into triangle fans.

    Parameters
    ----------
    polygons : list of list of int
        Vertex indices of each polygon; polygons with fewer than 3 vertices are dropped.

    Returns
    -------
    faces : (m, 3) int64
        Triangles ``(p[0], p[i], p[i + 1])``; exact for convex polygons.
    """
    tris = [(p[0], p[i], p[i + 1]) for p in polygons for i in range(1, len(p) - 1)]
    return np.array(tris, dtype=np.int64).reshape(-1, 3)


def _as_indices(values: np.ndarray) -> np.ndarray:
    """Float array to int64 indices, rejecting non-integral values."""
    indices = values.astype(np.int64)
    if not np.array_equal(indices, values):
        raise MeshError("face indices are not integers")
    return indices


def weld_close(vertices: np.ndarray, faces: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Merge the vertices that coincide up to the rounding of a scene's float32 coordinates.

    A scene stores each part in its own frame, in float32, and places it by its node's
    transform: the two sides of a seam between parts then meet only to within that rounding.

    Parameters
    ----------
    vertices : (n, 3) float64
        Positions in world coordinates.
    faces : (m, 3) int
        Triangles.

    Returns
    -------
    vertices : (k, 3) float64
        One of each group of vertices closer than `WELD_TOLERANCE` times the bounding box's
        diagonal, chained: the first of the group.
    faces : (m, 3) int64
        The triangles on them.
    """
    from scipy.spatial import cKDTree  # a fifth of a second to import: only for scenes

    tolerance = WELD_TOLERANCE * float(np.linalg.norm(np.ptp(vertices, axis=0)))
    pairs = cKDTree(vertices).query_pairs(tolerance, output_type="ndarray")
    if not len(pairs):
        return vertices, faces
    n = len(vertices)
    graph = sp.coo_matrix((np.ones(len(pairs)), (pairs[:, 0], pairs[:, 1])), shape=(n, n))
    _, labels = connected_components(graph, directed=False)
    first = np.full(labels.max() + 1, n)
    np.minimum.at(first, labels, np.arange(n))
    return vertices[first], labels[faces].astype(np.int64)


def _parse_trimesh(data: bytes, path: str | os.PathLike) -> tuple[np.ndarray, np.ndarray]:
    """Parse the formats other than OFF with trimesh, without its own processing; a scene's
    nodes are concatenated in world coordinates (``force="mesh"``), a glTF file's buffers found
    beside it."""
    suffix = Path(path).suffix.lower()
    try:
        import trimesh
        import trimesh.resolvers
    except ImportError:
        raise MissingDependencyError("reading this format needs trimesh") from None
    if suffix == ".3mf":
        _require("3MF", ("networkx", "lxml"), "3mf")
    elif suffix == ".dae":
        _require("COLLADA", ("collada",), "collada")
    elif suffix in (".glb", ".gltf") and b"KHR_draco_mesh_compression" in data:
        _require("Draco-compressed glTF", ("DracoPy",), "draco")
    resolver = trimesh.resolvers.FilePathResolver(str(path)) if suffix == ".gltf" else None
    # trimesh logs what then fails as the MeshError below; with no handler of its own, Python
    # would print the record on standard error.
    silent = logging.NullHandler()
    logging.getLogger("trimesh").addHandler(silent)
    try:
        loaded = trimesh.load(
            io.BytesIO(data), file_type=suffix[1:], process=False, force="mesh", resolver=resolver
        )
        assert isinstance(loaded, trimesh.Trimesh)  # force="mesh" makes one
        vertices, faces = np.asarray(loaded.vertices, np.float64), np.asarray(loaded.faces)
        if suffix in SCENE_SUFFIXES and len(vertices):
            return weld_close(vertices, faces)
        return vertices, faces
    except Exception as exc:  # trimesh raises many types on malformed files
        raise MeshError(f"malformed {suffix[1:].upper()}: {exc}") from None
    finally:
        logging.getLogger("trimesh").removeHandler(silent)


def _require(what: str, modules: tuple[str, ...], extra: str) -> None:
    """Raise `MissingDependencyError`, naming the extra to install, unless every module is."""
    if any(importlib.util.find_spec(module) is None for module in modules):
        raise MissingDependencyError(
            f"reading {what} needs the extra: pip install 'cfsig[{extra}]'"
        )
