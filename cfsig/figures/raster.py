"""The rasteriser: meshes drawn lit and shaded, coloured by a value per vertex or plain clay.

A small z-buffer in numpy: orthographic view, per-pixel interpolation of the value and of the
vertex normals, Lambert shading, 2x2 supersampling. It returns RGBA arrays; `cfsig.figures.plots`
lays
them out in pictures. Same input, same pixels: nothing depends on the time, the display or the
random state.
"""

from __future__ import annotations

from types import ModuleType

import numpy as np

from cfsig.errors import MissingDependencyError
from cfsig.files.elements import components, edge_graph, face_normals, vertex_normals
from cfsig.files.mesh import Mesh

CMAP = "turbo"
LIGHT = np.array([-0.4, 0.5, 1.0]) / np.linalg.norm([-0.4, 0.5, 1.0])
_AMBIENT, _DIFFUSE = 0.3, 0.7
_CLAY = np.array([0.78, 0.76, 0.72])
_SUPERSAMPLE = 2
_MAX_CANDIDATES = 1 << 20  # pixel candidates per rasteriser pass, bounds the memory
_SIZE = 480  # pixels of a `shade_mesh` image by default


def require_matplotlib() -> ModuleType:
    """Import matplotlib (for its colour maps and figures), or explain how to install it.

    Returns
    -------
    matplotlib : module

    Raises
    ------
    MissingDependencyError
        matplotlib is not installed.
    """
    try:
        import matplotlib
    except ImportError:
        raise MissingDependencyError(
            "pictures need matplotlib: pip install 'cfsig[plots]'"
        ) from None
    return matplotlib


def colormap(name: str):
    """A matplotlib colour map by name.

    Parameters
    ----------
    name : str
        E.g. ``"turbo"``.

    Returns
    -------
    cmap : matplotlib.colors.Colormap
        Maps values in [0, 1] to RGBA rows.

    Raises
    ------
    MissingDependencyError
        matplotlib is not installed.
    """
    return require_matplotlib().colormaps[name]


def unit_interval(values: np.ndarray) -> np.ndarray:
    """Scale values linearly to [0, 1], as the paper does for its colour coding.

    Parameters
    ----------
    values : (n,) float
        E.g. phi per vertex.

    Returns
    -------
    scaled : (n,) float64
        0 at the smallest value, 1 at the largest; all 0.5 when the values are constant.
    """
    values = np.asarray(values, dtype=np.float64)
    span = np.ptp(values)
    return (values - values.min()) / span if span > 0 else np.full_like(values, 0.5)


def default_view(vertices: np.ndarray) -> np.ndarray:
    """A view that shows a shape well: along its thinnest principal axis, slightly tilted.

    The longest principal axis of the vertices points up the screen, the camera looks along
    the shortest one, then turns 20 degrees about the vertical and looks 15 degrees down.
    Each axis's sign makes its largest coordinate positive, so a model built upright along
    +y stays upright; the frame is right-handed, so nothing is mirrored.

    Parameters
    ----------
    vertices : (n, 3) float
        Vertex positions.

    Returns
    -------
    view : (3, 3) float64
        Rotation whose rows are the screen's right, up and towards-the-viewer directions in
        model coordinates.
    """
    centred = vertices - vertices.mean(axis=0)
    _, axes = np.linalg.eigh(centred.T @ centred)  # columns by ascending variance
    up, toward = _signed(axes[:, 2]), _signed(axes[:, 0])
    frame = np.array([np.cross(up, toward), up, toward])
    return _rotation(0, np.radians(15)) @ _rotation(1, np.radians(20)) @ frame


def screen_coordinates(
    vertices: np.ndarray, view: np.ndarray, size: tuple[int, int], margin: float = 0.06
) -> np.ndarray:
    """Where vertices land in an image: orthographic projection fitted to the image.

    Parameters
    ----------
    vertices : (n, 3) float
        Vertex positions.
    view : (3, 3) float
        Rotation as `default_view` returns.
    size : (int, int)
        Image width and height in pixels.
    margin : float
        Empty border on each side, as a fraction of the smaller image side.

    Returns
    -------
    points : (n, 3) float64
        Column (x, from the left edge), row (y, from the top edge), both in pixels with pixel
        ``(i, j)`` covering ``[j, j+1) x [i, i+1)``; and depth towards the viewer in pixels.
    """
    rotated = np.asarray(vertices, dtype=np.float64) @ np.asarray(view).T
    low, high = rotated.min(axis=0), rotated.max(axis=0)
    width, height = size
    extent = max(high[0] - low[0], high[1] - low[1]) or 1.0
    scale = (1 - 2 * margin) * min(width, height) / extent
    centre = (low + high) / 2
    return np.column_stack(
        [
            width / 2 + (rotated[:, 0] - centre[0]) * scale,
            height / 2 - (rotated[:, 1] - centre[1]) * scale,
            (rotated[:, 2] - centre[2]) * scale,
        ]
    )


def shade_mesh(
    mesh: Mesh,
    values: np.ndarray | None = None,
    view: np.ndarray | None = None,
    size: tuple[int, int] = (_SIZE, _SIZE),
    cmap: str = CMAP,
) -> np.ndarray:
    """Render a mesh, lit and shaded, coloured by a value per vertex or plain clay.

    Parameters
    ----------
    mesh : Mesh
        The mesh.
    values : (n,) float, optional
        Per-vertex values already in [0, 1] (see `unit_interval`), interpolated across faces
        and mapped through ``cmap``; None draws a uniform clay colour.
    view : (3, 3) float, optional
        Rotation as `default_view` returns (the default).
    size : (int, int)
        Width and height in pixels.
    cmap : str
        A matplotlib colour map.

    Returns
    -------
    image : (height, width, 4) float32
        RGBA in [0, 1], alpha 0 outside the mesh and fractional on anti-aliased edges
        (straight, not premultiplied, colour).

    Raises
    ------
    MissingDependencyError
        ``values`` is given and matplotlib is not installed.
    """
    view = default_view(mesh.vertices) if view is None else np.asarray(view, dtype=np.float64)
    width, height = (s * _SUPERSAMPLE for s in size)
    points = screen_coordinates(mesh.vertices, view, (width, height))
    faces = _visible_faces(mesh, view[2])
    face, bary = rasterize(points, faces, width, height)
    covered = face >= 0
    corners, bary = faces[face[covered]], bary[covered]
    normals = np.einsum(
        "kj,kjd->kd", bary, (vertex_normals(mesh.vertices, mesh.faces) @ view.T)[corners]
    )
    normals /= np.maximum(np.linalg.norm(normals, axis=1, keepdims=True), 1e-300)
    normals *= np.where(normals[:, 2:] < 0, -1.0, 1.0)  # light both sides of open surfaces
    light = _AMBIENT + _DIFFUSE * np.clip(normals @ LIGHT, 0, 1)
    if values is None:
        color = np.broadcast_to(_CLAY, (len(light), 3))
    else:
        value = np.einsum("kj,kj->k", bary, np.asarray(values, dtype=np.float64)[corners])
        color = colormap(cmap)(np.clip(value, 0, 1))[:, :3]
    rgba = np.zeros((height * width, 4))
    rgba[covered, :3] = color * light[:, None]
    rgba[covered, 3] = 1.0
    blocks = rgba.reshape(size[1], _SUPERSAMPLE, size[0], _SUPERSAMPLE, 4).mean(axis=(1, 3))
    alpha = blocks[..., 3:]
    blocks[..., :3] /= np.where(alpha > 0, alpha, 1.0)
    return blocks.astype(np.float32)


def _signed(axis: np.ndarray) -> np.ndarray:
    """The axis with the sign that makes its largest-magnitude coordinate positive."""
    return axis if axis[np.argmax(np.abs(axis))] > 0 else -axis


def _rotation(axis: int, angle: float) -> np.ndarray:
    """Rotation by ``angle`` radians about coordinate axis 0 (x) or 1 (y)."""
    c, s = np.cos(angle), np.sin(angle)
    if axis == 0:
        return np.array([[1, 0, 0], [0, c, -s], [0, s, c]])
    return np.array([[c, 0, s], [0, 1, 0], [-s, 0, c]])


def _visible_faces(mesh: Mesh, toward: np.ndarray) -> np.ndarray:
    """The faces that can be seen: those facing the viewer on a closed, oriented surface."""
    faces, n = mesh.faces, len(mesh.vertices)
    edges = faces[:, [0, 1, 1, 2, 2, 0]].reshape(-1, 2)
    keys = np.sort(edges[:, 0] * n + edges[:, 1])
    # Each directed edge once and its reverse once: every edge joins two faces oriented alike.
    if (keys[1:] == keys[:-1]).any() or not np.array_equal(
        keys, np.sort(edges[:, 1] * n + edges[:, 0])
    ):
        return faces  # open, non-manifold or inconsistently oriented: the z-buffer sorts it out
    corner = mesh.vertices[faces]
    normals = face_normals(mesh.vertices, faces)
    _, labels = components(edge_graph(faces, n))
    component = labels[faces[:, 0]]
    volume = np.bincount(component, np.einsum("ij,ij->i", corner[:, 0], normals))
    outward = np.where(volume[component] < 0, -1.0, 1.0)
    return faces[outward * (normals @ toward) > 0]


def rasterize(
    points: np.ndarray, faces: np.ndarray, width: int, height: int
) -> tuple[np.ndarray, np.ndarray]:
    """Z-buffer: the face nearest the viewer at each pixel centre, and where on it.

    Parameters
    ----------
    points : (n, 3) float64
        Vertices in screen coordinates (`screen_coordinates`): column, row, depth towards the
        viewer, in pixels.
    faces : (m, 3) int
        Triangles.
    width, height : int
        Image size in pixels.

    Returns
    -------
    face : (height * width,) int64
        The nearest face at each pixel centre, row-major; -1 where none covers it.
    barycentric : (height * width, 3) float64
        The pixel centre's barycentric coordinates on that face (zeros where none).
    """
    face_buf = np.full(width * height, -1, dtype=np.int64)
    depth_buf = np.full(width * height, -np.inf)
    bary_buf = np.zeros((width * height, 3))
    a, b, c = (points[faces[:, k]] for k in range(3))
    det = (b[:, 0] - a[:, 0]) * (c[:, 1] - a[:, 1]) - (b[:, 1] - a[:, 1]) * (c[:, 0] - a[:, 0])
    corners = np.stack([a, b, c])
    low = np.ceil(corners[..., :2].min(axis=0) - 0.5).astype(np.int64)
    high = np.floor(corners[..., :2].max(axis=0) - 0.5).astype(np.int64)
    low, high = np.maximum(low, 0), np.minimum(high, [width - 1, height - 1])
    span = np.maximum(high - low + 1, 0)
    counts = np.where(np.abs(det) > 1e-12, span[:, 0] * span[:, 1], 0)
    ends = np.cumsum(counts)
    start = 0
    while start < len(faces):
        base = ends[start - 1] if start else 0
        stop = max(int(np.searchsorted(ends, base + _MAX_CANDIDATES, side="right")), start + 1)
        ids = np.arange(start, stop)
        n = counts[ids]
        f = np.repeat(ids, n)
        local = np.arange(n.sum()) - np.repeat(np.cumsum(n) - n, n)
        px = low[f, 0] + local % np.maximum(span[f, 0], 1)
        py = low[f, 1] + local // np.maximum(span[f, 0], 1)
        x, y = px + 0.5 - a[f, 0], py + 0.5 - a[f, 1]
        b1 = (x * (c[f, 1] - a[f, 1]) - y * (c[f, 0] - a[f, 0])) / det[f]
        b2 = ((b[f, 0] - a[f, 0]) * y - (b[f, 1] - a[f, 1]) * x) / det[f]
        bary = np.column_stack([1 - b1 - b2, b1, b2])
        inside = (bary >= -1e-9).all(axis=1)
        f, bary, pixel = f[inside], bary[inside], (py * width + px)[inside]
        depth = np.einsum("kj,jk->k", bary, corners[:, f, 2])
        order = np.lexsort((depth, pixel))
        last = np.append(pixel[order][1:] != pixel[order][:-1], True)
        win = order[last]
        nearer = depth[win] > depth_buf[pixel[win]]
        win, target = win[nearer], pixel[win][nearer]
        face_buf[target], depth_buf[target], bary_buf[target] = f[win], depth[win], bary[win]
        start = stop
    return face_buf, bary_buf
