"""The descriptor ``lf``: the light field descriptor of Chen, Tian, Shen and Ouhyoung ("On Visual
Similarity Based 3D Model Retrieval", Eurographics 2003), the peer the conformal factor paper
found strongest.

The steps, and the choices made where the paper leaves them open (docs/method.md):

- Light fields: `LIGHT_FIELDS` = 10 per mesh. Each looks at the mesh from the 20 vertices of a
  dodecahedron about it, the first dodecahedron as `dodecahedron` places it and the others
  rotated so that the 200 directions spread over the sphere (`light_field_rotations`). Opposite
  vertices see mirrored silhouettes, which the features below do not tell apart, so each light
  field keeps `VIEWS` = 10 silhouettes, one per pair of opposite vertices.
- Silhouettes: orthographic projections of a copy simplified to `FACE_LIMIT` faces,
  rasterised on a `GRID` x `GRID` grid (a pixel is in the silhouette when its centre is in a
  projected triangle, `rasterise`). Each silhouette is centred on its centroid (the authors'
  code takes the centre of its bounding box, which moves as the view turns in its plane), and
  as in their code the unit disk of the moments is the largest distance of a silhouette point
  from its centre over the light field's 10 views, so that the views of one light field keep
  their relative sizes. Translation and scale of the mesh are normalised by these, so the mesh
  is not normalised in 3D first.
- Features per silhouette: the magnitudes of the 35 Zernike moments of orders 1 to 10
  (`zernike_magnitudes`), divided by the zeroth (the area), so each lies in [0, 1]; and 10
  Fourier descriptors of the contour, the magnitudes of frequencies 1 to 10 of the distance
  from the centre along the silhouette's longest boundary (`contour_distances`), divided by
  frequency 0. Both are quantised to 8 bits as the authors' code does: ``floor(256 x)``
  (``floor(512 x)`` for the Fourier descriptors), at most 255.
- Distance (`lf_distances`): between two silhouettes, the L1 distance of their 45 features;
  between two light fields, the smallest sum of the 10 silhouette distances over the 60
  rotations of the dodecahedron (`view_permutations`); between two meshes, the smallest over
  the 10 x 10 pairs of their light fields. `lf_bounds` is a lower bound of it, about twenty
  times cheaper, by which searches keep their candidates (`cfsig.search.nearest.nearest_by`).

The vector is the quantised features, light field by light field, view by view: ``LENGTH`` =
10 x 10 x 45 values, whole numbers in [0, 255], so that every distance is a sum of whole
numbers, exact in float32.
"""

from __future__ import annotations

from functools import lru_cache
from math import comb, factorial
from typing import NamedTuple, cast

import numpy as np
from contourpy import contour_generator

from cfsig.descriptors.base import Computed, Descriptor, Distance, L1Kernel
from cfsig.files.elements import face_normals
from cfsig.files.mesh import Mesh
from cfsig.operators.conformal import ConformalFactor
from cfsig.params import Layout, Params
from cfsig.repair.simplify import decimate

LIGHT_FIELDS = 10
VIEWS = 10  # silhouettes per light field: the dodecahedron's 20 vertices, opposite ones paired
ROTATIONS = 60  # the rotations of a dodecahedron onto itself
FACE_LIMIT = 4000  # faces of the simplified copy the silhouettes are drawn from
GRID = 128  # pixels per side of a silhouette's grid
ORDER = 10  # largest order of the Zernike moments
ZERNIKE = 35  # the moments (n, m) with 1 <= n <= ORDER, 0 <= m <= n, n - m even
FOURIER = 10  # Fourier descriptors: frequencies 1..FOURIER of the edge's distance
CONTOUR_POINTS = 128  # points of a silhouette's contour its Fourier descriptors are taken at
FEATURES = ZERNIKE + FOURIER
MONOMIALS = (ORDER + 1) * (ORDER + 2) // 2
QUANT = 256  # the authors' 8-bit quantisation: floor(QUANT * value), at most 255
FOURIER_SCALE = 2  # the Fourier descriptors are doubled before quantisation, as the authors do
IMAGES = LIGHT_FIELDS * VIEWS
LENGTH = IMAGES * FEATURES
_SPREAD_CANDIDATES = 2000  # random rotations the light fields' rotations are chosen among
_ROW_CHUNK = 64  # rows of another signature compared at a time (bounds the memory)


@lru_cache(maxsize=1)
def dodecahedron() -> np.ndarray:
    """The unit vertices of a regular dodecahedron, opposite ones paired; cached.

    Returns
    -------
    vertices : (20, 3) float64
        Read-only; vertex ``a + 10`` is opposite vertex ``a``.
    """
    g = (1 + np.sqrt(5)) / 2
    half = [(1, 1, 1), (1, 1, -1), (1, -1, 1), (-1, 1, 1)]
    half += [(0, 1 / g, g), (0, 1 / g, -g), (1 / g, g, 0), (-1 / g, g, 0), (g, 0, 1 / g)]
    half += [(g, 0, -1 / g)]
    vertices = np.array(half, dtype=np.float64)
    vertices = np.vstack([vertices, -vertices]) / np.sqrt(3)
    vertices.flags.writeable = False
    return vertices


@lru_cache(maxsize=1)
def dodecahedron_rotations() -> np.ndarray:
    """The 60 rotations that map the dodecahedron onto itself; cached.

    Returns
    -------
    rotations : (60, 3, 3) float64
        Read-only, the identity first.
    """
    g = (1 + np.sqrt(5)) / 2

    def turn(axis: np.ndarray, angle: float) -> np.ndarray:
        x, y, z = axis / np.linalg.norm(axis)
        k = np.array([[0, -z, y], [z, 0, -x], [-y, x, 0]])
        return np.eye(3) + np.sin(angle) * k + (1 - np.cos(angle)) * k @ k

    # a fifth of a turn about a face's centre and a third about a vertex generate the group
    generators = [turn(np.array([0, g, 1]), 2 * np.pi / 5), turn(np.ones(3), 2 * np.pi / 3)]
    found = [np.eye(3)]
    keys = {(np.round(found[0], 6) + 0.0).tobytes()}
    for rotation in found:  # grows while it is walked: a breadth-first closure
        for generator in generators:
            product = generator @ rotation
            key = (np.round(product, 6) + 0.0).tobytes()  # no negative zero
            if key not in keys:
                keys.add(key)
                found.append(product)
    rotations = np.array(found)
    assert len(rotations) == ROTATIONS
    rotations.flags.writeable = False
    return rotations


@lru_cache(maxsize=1)
def view_permutations() -> np.ndarray:
    """Where each rotation of the dodecahedron takes each of its 10 views; cached.

    Returns
    -------
    permutations : (60, VIEWS) int64
        Read-only: rotation r takes vertex a (or its opposite) to vertex ``permutations[r, a]``
        or its opposite.
    """
    vertices = dodecahedron()
    views = vertices[:VIEWS]
    turned = np.einsum("rij,aj->rai", dodecahedron_rotations(), views)
    closeness = np.abs(np.einsum("rai,bi->rab", turned, views))  # 1 for the same axis
    permutations = np.argmax(closeness, axis=2)
    permutations.flags.writeable = False
    return permutations


@lru_cache(maxsize=1)
def light_field_rotations() -> np.ndarray:
    """The rotations of the light fields' dodecahedra; cached.

    The first is the identity. Each next one is, among `_SPREAD_CANDIDATES` rotations drawn
    uniformly (seeded), the one whose 20 directions lie farthest (by their smallest angle)
    from the directions already taken, so that the 200 directions spread over the sphere as
    the authors' camera sets do.

    Returns
    -------
    rotations : (LIGHT_FIELDS, 3, 3) float64
        Read-only.
    """
    rng = np.random.default_rng(0)
    q = rng.normal(size=(_SPREAD_CANDIDATES, 4))
    q /= np.linalg.norm(q, axis=1, keepdims=True)
    w, x, y, z = q.T
    candidates = np.stack(
        [
            [1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)],
            [2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)],
            [2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)],
        ]
    ).transpose(2, 0, 1)
    views = dodecahedron()[:VIEWS]
    directions = np.einsum("cij,aj->cai", candidates, views)  # (candidates, VIEWS, 3)
    chosen = [np.eye(3)]
    taken = views.copy()
    for _ in range(LIGHT_FIELDS - 1):
        closeness = np.abs(np.einsum("cai,bi->cab", directions, taken)).max(axis=(1, 2))
        pick = int(np.argmin(closeness))
        chosen.append(candidates[pick])
        taken = np.vstack([taken, directions[pick]])
    rotations = np.array(chosen)
    rotations.flags.writeable = False
    return rotations


@lru_cache(maxsize=1)
def view_frames() -> np.ndarray:
    """The image plane of every view: two unit vectors orthogonal to its direction; cached.

    Returns
    -------
    frames : (LIGHT_FIELDS * VIEWS, 3, 2) float64
        Read-only; a point p of the mesh projects to ``p @ frames[v]`` in view v (light field
        ``v // VIEWS``, view ``v % VIEWS``).
    """
    directions = np.einsum("lij,aj->lai", light_field_rotations(), dodecahedron()[:VIEWS])
    directions = directions.reshape(-1, 3)
    helper = np.where(np.abs(directions[:, :1]) < 0.9, [[1.0, 0, 0]], [[0, 1.0, 0]])
    u = np.cross(directions, helper)
    u /= np.linalg.norm(u, axis=1, keepdims=True)
    w = np.cross(directions, u)
    frames = np.stack([u, w], axis=2)
    frames.flags.writeable = False
    return frames


def rasterise(corners: np.ndarray, image: np.ndarray, images: int, grid: int) -> np.ndarray:
    """Fill 2-D triangles on pixel grids.

    A pixel is filled when its centre lies in a triangle (pixel (i, j) has its centre at
    ``(j + 1/2, i + 1/2)``). Each triangle is cut at its middle corner's height into two
    halves bounded by two edges each; every row of pixel centres that a half spans is a run
    of pixels between those edges, marked at its ends and filled by a running sum.

    Parameters
    ----------
    corners : (t, 3, 2) float32
        The triangles' corners (x, y) in pixel units, within ``[0, grid]``.
    image : (t,) int64
        The image each triangle is drawn on, in ``[0, images)``.
    images : int
        Number of images.
    grid : int
        Pixels per side.

    Returns
    -------
    filled : (images, grid, grid) bool
        Row i is y in ``[i, i + 1)``.
    """
    (xa, ya), (xb, yb), (xc, yc) = (corners[:, k].T for k in range(3))
    # sort each triangle's corners by y with three compare-and-swaps
    for (x0, y0), (x1, y1) in [((xa, ya), (xb, yb)), ((xb, yb), (xc, yc)), ((xa, ya), (xb, yb))]:
        swap = y1 < y0
        for p, q in ((x0, x1), (y0, y1)):
            low = np.where(swap, q, p)
            q[...] = np.where(swap, p, q)
            p[...] = low

    def slope(x0, y0, x1, y1):  # dx / dy of an edge, 0 for a level one (it spans no row)
        height = y1 - y0
        return np.divide(x1 - x0, height, out=np.zeros_like(height), where=height > 0)

    long, upper, lower = slope(xa, ya, xc, yc), slope(xa, ya, xb, yb), slope(xb, yb, xc, yc)
    first = np.clip(np.ceil(ya - 0.5), 0, grid)  # the first row whose centre is below a
    end = np.clip(np.floor(yc - 0.5) + 1, 0, grid)
    middle = np.clip(np.ceil(yb - 0.5), first, end)
    # each half: first row, rows, the x of its two edges at the first row's centre, slopes
    both = np.empty((2, len(corners), 6), np.float32)
    for half, (start, stop, edge, x0, y0) in enumerate(
        [(first, middle, upper, xa, ya), (middle, end, lower, xb, yb)]
    ):
        centre = start + 0.5
        both[half] = np.stack(
            [start, stop - start, xa + (centre - ya) * long, x0 + (centre - y0) * edge, long, edge],
            axis=1,
        )
    halves = both.reshape(-1, 6)
    counts = halves[:, 1].astype(np.int64)
    keep = np.flatnonzero(counts > 0)
    counts = counts[keep]
    owner = np.repeat(keep, counts)
    step = (np.arange(len(owner)) - np.repeat(np.cumsum(counts) - counts, counts)).astype(
        np.float32
    )
    rows = halves[owner]
    one = rows[:, 2] + step * rows[:, 4]
    two = rows[:, 3] + step * rows[:, 5]
    left = np.clip(np.ceil(np.minimum(one, two) - 0.5), 0, grid).astype(np.int64)
    right = np.clip(np.floor(np.maximum(one, two) - 0.5) + 1, 0, grid).astype(np.int64)
    runs = left < right
    width = grid + 1
    line = image[owner[runs] % len(corners)] * grid + (rows[runs, 0] + step[runs]).astype(np.int64)
    line *= width
    size = images * grid * width
    marks = np.bincount(line + left[runs], minlength=size)
    marks -= np.bincount(line + right[runs], minlength=size)
    return np.cumsum(marks.reshape(images, grid, width)[:, :, :grid], axis=2) > 0


@lru_cache(maxsize=1)
def zernike_coefficients() -> np.ndarray:
    """The conjugated Zernike polynomials of orders 0 to `ORDER` as polynomials in x and y;
    cached.

    Returns
    -------
    coefficients : (ZERNIKE + 1, MONOMIALS) complex128
        Read-only: row k holds ``conj(V_nm)(x, y) = R_nm(rho) exp(-i m theta)`` for the k-th
        pair (n, m) in order of n, then m (the first (0, 0)), in the monomials of `monomials`.
    """
    powers = {pq: k for k, pq in enumerate(_monomial_powers())}
    rows = []
    for n in range(ORDER + 1):
        for m in range(n % 2, n + 1, 2):
            row = np.zeros(len(powers), np.complex128)
            for s in range((n - m) // 2 + 1):
                weight = (-1) ** s * factorial(n - s)
                weight /= factorial(s) * factorial((n + m) // 2 - s) * factorial((n - m) // 2 - s)
                # rho^(n - 2s) exp(-i m theta) = (x - i y)^m (x^2 + y^2)^((n - 2s - m) / 2)
                half = (n - 2 * s - m) // 2
                for a in range(m + 1):  # (x - i y)^m
                    for b in range(half + 1):  # (x^2 + y^2)^half
                        term = weight * comb(m, a) * (-1j) ** (m - a) * comb(half, b)
                        row[powers[(a + 2 * b, m - a + 2 * (half - b))]] += term
            rows.append(row)
    coefficients = np.array(rows)
    coefficients.flags.writeable = False
    return coefficients


@lru_cache(maxsize=1)
def _monomial_powers() -> list[tuple[int, int]]:
    """The powers (p, q) of the monomials ``x^p y^q`` of degree at most `ORDER`, by degree."""
    return [(p, d - p) for d in range(ORDER + 1) for p in range(d, -1, -1)]


@lru_cache(maxsize=2)
def monomials(grid: int) -> np.ndarray:
    """The monomials of degree at most `ORDER` at the pixel centres of a grid; cached.

    Parameters
    ----------
    grid : int
        Pixels per side.

    Returns
    -------
    values : (grid * grid, MONOMIALS) float64
        Read-only: ``x^p y^q`` for the powers of `_monomial_powers`, x and y in [-1, 1] about
        the grid's centre (y up, row 0 at the top).
    """
    centres = (np.arange(grid) + 0.5) / (grid / 2) - 1
    x, y = np.meshgrid(centres, -centres)
    x, y = x.ravel(), y.ravel()
    values = np.stack([x**p * y**q for p, q in _monomial_powers()], axis=1)
    values.flags.writeable = False
    return values


def zernike_magnitudes(images: np.ndarray, centres: np.ndarray, radii: np.ndarray) -> np.ndarray:
    """The magnitudes of the Zernike moments of silhouettes, relative to their area.

    The moments are taken over the disk of each silhouette's centre and radius, from its
    geometric moments about the grid's centre, moved to its own by the binomial theorem.

    Parameters
    ----------
    images : (k, grid, grid) bool
        Silhouettes.
    centres : (k, 2) float64
        The centre (x, y) of each disk, in the units of `monomials` (the grid spans [-1, 1]).
    radii : (k,) float64
        The radius of each disk in those units; every silhouette lies in its disk.

    Returns
    -------
    magnitudes : (k, ZERNIKE) float64
        ``|sum_pixels conj(V_nm)| / sum_pixels V_00`` for the moments after (0, 0), in [0, 1]
        since ``|V_nm| <= 1`` on the disk; 0 for an empty silhouette.
    """
    raw = images.reshape(len(images), -1).astype(np.float64) @ monomials(images.shape[1])
    powers = _monomial_powers()
    index = {pq: k for k, pq in enumerate(powers)}
    shifted = np.zeros_like(raw)
    cx, cy = -centres[:, 0], -centres[:, 1]
    for k, (p, q) in enumerate(powers):
        for i in range(p + 1):
            for j in range(q + 1):
                weight = comb(p, i) * comb(q, j) * cx ** (p - i) * cy ** (q - j)
                shifted[:, k] += weight * raw[:, index[(i, j)]]
        shifted[:, k] /= radii ** (p + q)
    moments = np.abs(shifted @ zernike_coefficients().T)
    area = moments[:, :1]
    return np.divide(moments[:, 1:], area, out=np.zeros((len(images), ZERNIKE)), where=area > 0)


def contour_distances(images: np.ndarray, centres: np.ndarray) -> np.ndarray:
    """The distance from the centre of each silhouette along its outer contour.

    The contour is the longest of the silhouette's boundaries (contourpy's marching squares at
    level 1/2), resampled at `CONTOUR_POINTS` points equally spaced along its length from where
    contourpy starts it: the Fourier magnitudes taken of it do not depend on that start. The
    grid is framed by a pixel of background first: a silhouette fitted to its grid reaches the
    edges, where marching squares would cut its boundary into open pieces.

    Parameters
    ----------
    images : (k, grid, grid) bool
        Silhouettes, the grid spanning [-1, 1] (y up, row 0 at the top).
    centres : (k, 2) float64
        The centre (x, y) of each, in the grid's units.

    Returns
    -------
    distances : (k, CONTOUR_POINTS) float64
        Distances from the centre, in the grid's units; zero for an empty silhouette.
    """
    grid = images.shape[1]
    axis = (np.arange(-1, grid + 1) + 0.5) / (grid / 2) - 1
    out = np.zeros((len(images), CONTOUR_POINTS))
    for i, image in enumerate(images):
        framed = np.pad(image[::-1].astype(np.float64), 1)
        generator = contour_generator(axis, axis, framed, name="serial")
        lines = cast(list[np.ndarray], generator.lines(0.5))  # the default type: separate lines
        if not lines:
            continue
        line = max(lines, key=len)
        along = np.concatenate([[0.0], np.cumsum(np.hypot(*np.diff(line, axis=0).T))])
        at = np.linspace(0, along[-1], CONTOUR_POINTS, endpoint=False)
        x, y = np.interp(at, along, line[:, 0]), np.interp(at, along, line[:, 1])
        out[i] = np.hypot(x - centres[i, 0], y - centres[i, 1])
    return out


def fourier_descriptors(distances: np.ndarray) -> np.ndarray:
    """The Fourier descriptors of the edge's distance from the centre.

    Parameters
    ----------
    distances : (k, points) float64
        As `contour_distances` returns.

    Returns
    -------
    descriptors : (k, FOURIER) float64
        ``|F_1..F_FOURIER| / |F_0|`` of the discrete Fourier transform, in [0, 1]; 0 for an
        empty silhouette.
    """
    spectrum = np.abs(np.fft.rfft(distances, axis=1))
    mean = spectrum[:, :1]
    out = np.zeros((len(distances), FOURIER))
    return np.divide(spectrum[:, 1 : FOURIER + 1], mean, out=out, where=mean > 0)


def closed_and_oriented(faces: np.ndarray) -> bool:
    """Whether triangles form oriented surfaces without boundary: each directed edge is used as
    often as its reverse (edges shared by four faces or more allowed).

    Every line that meets such a surface crosses it as often one way as the other, so it
    crosses a triangle facing either way.

    Parameters
    ----------
    faces : (m, 3) int64
        Triangles.

    Returns
    -------
    closed : bool
    """
    n = int(faces.max()) + 1 if len(faces) else 0
    tails, heads = faces.ravel(), np.roll(faces, -1, axis=1).ravel()
    return bool(np.array_equal(np.sort(tails * n + heads), np.sort(heads * n + tails)))


class Views(NamedTuple):
    """The silhouettes of a mesh in every view of its light fields, and their disks.

    Attributes
    ----------
    images : (fields * VIEWS, GRID, GRID) bool
        View v (light field ``v // VIEWS``), the grid spanning [-1, 1] about the centre of the
        projection's bounding box and fitted to it.
    centres : (fields * VIEWS, 2) float64
        Each silhouette's centroid, in the grid's units.
    radii : (fields * VIEWS,) float64
        The largest distance of a vertex from its silhouette's centroid over the views of its
        light field, in each grid's units.
    """

    images: np.ndarray
    centres: np.ndarray
    radii: np.ndarray


def silhouettes(vertices: np.ndarray, faces: np.ndarray, fields: int = LIGHT_FIELDS) -> Views:
    """The silhouettes of a mesh in every view of its first light fields.

    When the triangles form oriented surfaces without boundary (`closed_and_oriented`), each
    view draws only the triangles that face one way along it: every line of sight through such
    a surface crosses one of those, so the silhouette is the same, for half the work.

    Parameters
    ----------
    vertices : (n, 3) float64
        Vertex positions.
    faces : (m, 3) int64
        Triangles.
    fields : int
        The light fields drawn, the first of `light_field_rotations` [all `LIGHT_FIELDS`].

    Returns
    -------
    views : Views
    """
    images = fields * VIEWS
    frames = view_frames()[:images]
    projected = np.einsum("nk,vkj->vnj", vertices, frames)  # (views, n, 2)
    low, high = projected.min(axis=1), projected.max(axis=1)
    middle = (low + high) / 2
    half = np.maximum((high - low).max(axis=1) / 2, np.finfo(float).tiny)
    projected = (projected - middle[:, None, :]) / half[:, None, None]  # in [-1, 1]
    pixels = (projected * [1, -1] + 1) * (GRID / 2)  # y up: row 0 at the top
    if closed_and_oriented(faces):
        normals = face_normals(vertices, faces)
        directions = np.cross(frames[:, :, 0], frames[:, :, 1])
        view, face = np.nonzero(directions @ normals.T > 0)
    else:
        view, face = np.divmod(np.arange(images * len(faces)), len(faces))
    corners = pixels.astype(np.float32)[view[:, None], faces[face]]
    filled = rasterise(corners, view, images, GRID)
    flat = filled.reshape(images, -1)
    area = flat.sum(axis=1)
    first = monomials(GRID)[:, 1:3]  # x and y
    centres = np.divide(
        flat @ first, area[:, None], out=np.zeros((images, 2)), where=area[:, None] > 0
    )
    reach = np.sqrt(((projected - centres[:, None, :]) ** 2).sum(axis=2).max(axis=1)) * half
    radii = reach.reshape(fields, VIEWS).max(axis=1).repeat(VIEWS) / half
    return Views(filled, centres, radii)


def quantise(values: np.ndarray, scale: float = 1.0) -> np.ndarray:
    """The authors' 8-bit quantisation: ``min(floor(256 * scale * values), 255)``.

    Parameters
    ----------
    values : float ndarray
        Non-negative values.
    scale : float
        Multiplies the values first.

    Returns
    -------
    quantised : float64 ndarray
        Whole numbers in [0, 255], of the same shape.
    """
    return np.minimum(np.floor(QUANT * scale * values), QUANT - 1)


def image_features(views: Views) -> np.ndarray:
    """The quantised features of silhouettes: 35 Zernike moments, then 10 Fourier descriptors.

    Parameters
    ----------
    views : Views
        Silhouettes, as `silhouettes` makes them.

    Returns
    -------
    features : (len(views.images), FEATURES) float64
        Whole numbers in [0, 255].
    """
    zernike = quantise(zernike_magnitudes(*views))
    fourier = quantise(fourier_descriptors(contour_distances(*views[:2])), FOURIER_SCALE)
    return np.hstack([zernike, fourier])


def lf_vector(mesh: Mesh, params: Params, cf: ConformalFactor | None, solver: str) -> Computed:
    """The ``lf`` descriptor of a mesh.

    Parameters
    ----------
    mesh : Mesh
        The repaired mesh.
    params : Params
        Unused: the descriptor has no parameter.
    cf : ConformalFactor or None
        Unused.
    solver : str
        Unused.

    Returns
    -------
    computed : Computed
        ``vector``: (LENGTH,) float64, `image_features` of `silhouettes`, light field by light
        field, view by view; no cells nor operators.
    """
    return Computed(light_field_features(mesh), None, None)


def light_field_features(mesh: Mesh, fields: int = LIGHT_FIELDS) -> np.ndarray:
    """The features of a mesh's silhouettes in its first light fields.

    Parameters
    ----------
    mesh : Mesh
        The repaired mesh.
    fields : int
        Light fields, the first of `light_field_rotations` [all `LIGHT_FIELDS`].

    Returns
    -------
    features : (fields * VIEWS * FEATURES,) float64
        `image_features` of `silhouettes` of a copy simplified to `FACE_LIMIT` faces, light
        field by light field, view by view.
    """
    vertices, faces = decimate(mesh.vertices, mesh.faces, FACE_LIMIT)
    return image_features(silhouettes(vertices, faces, fields)).ravel()


@lru_cache(maxsize=1)
def _rotation_sums() -> np.ndarray:
    """(VIEWS * VIEWS, ROTATIONS) float32: column r sums the silhouette pairs (a, perm_r(a))."""
    pairs = np.zeros((VIEWS, VIEWS, ROTATIONS), np.float32)
    permutations = view_permutations()
    for r in range(ROTATIONS):
        pairs[np.arange(VIEWS), permutations[r], r] = 1
    sums = pairs.reshape(VIEWS * VIEWS, ROTATIONS)
    sums.flags.writeable = False
    return sums


def lf_distances(queries: np.ndarray, rows: np.ndarray, l1: L1Kernel) -> np.ndarray:
    """The light field distance between the signatures of some meshes and others.

    Parameters
    ----------
    queries : (q, length) float32, C-contiguous
        Signatures (`lf_vector`, or `light_field_features` of fewer light fields: ``length``
        is their number times ``VIEWS * FEATURES``).
    rows : (m, length) float32, C-contiguous
        Signatures to compare with, of as many light fields.
    l1 : callable
        ``l1(a, b, out)`` fills ``out[i, j]`` with the L1 distance of rows ``a[i]`` and
        ``b[j]`` (`cfsig.search.l1`).

    Returns
    -------
    distances : (q, m) float64
        The smallest, over the pairs of light fields (10 x 10 for `lf_vector`) and the 60
        rotations of the dodecahedron, of the sum of the L1 distances of the paired
        silhouettes' features.
    """
    out = np.empty((len(queries), len(rows)))
    sums = _rotation_sums()
    images = rows.reshape(-1, FEATURES)
    fields = queries.shape[1] // (VIEWS * FEATURES)
    per_row = fields * VIEWS
    for j, query in enumerate(queries):
        mine = query.reshape(-1, FEATURES)
        for first in range(0, len(rows), _ROW_CHUNK):
            some = images[first * per_row : (first + _ROW_CHUNK) * per_row]
            pairs = np.empty((len(mine), len(some)), np.float32)
            l1(mine, some, pairs)
            count = len(some) // per_row
            # (query field, view a, row, row field, view b) -> (row, fields, fields, a * b)
            pairs = pairs.reshape(fields, VIEWS, count, fields, VIEWS)
            pairs = pairs.transpose(2, 0, 3, 1, 4).reshape(-1, VIEWS * VIEWS)
            best = (pairs @ sums).reshape(count, -1).min(axis=1)
            out[j, first : first + count] = best
    return out


def field_summaries(signatures: np.ndarray) -> np.ndarray:
    """Each light field's features sorted over its views, feature by feature.

    For two light fields and any pairing of their views, the sum of the paired silhouettes'
    L1 distances is at least the L1 distance of their summaries: in each feature, matching the
    sorted values is the pairing of least total difference. `lf_bounds` rests on this.

    Parameters
    ----------
    signatures : (k, length) float32
        Signatures of some light fields each (`lf_distances`).

    Returns
    -------
    summaries : (k * fields, VIEWS * FEATURES) float32
        C-contiguous; row ``i * fields + l`` is light field l of signature i.
    """
    fields = signatures.reshape(-1, VIEWS, FEATURES)
    return np.ascontiguousarray(np.sort(fields, axis=1).reshape(len(fields), -1))


def lf_bounds(queries: np.ndarray, rows: np.ndarray, l1: L1Kernel) -> np.ndarray:
    """A lower bound of `lf_distances`: the smallest L1 distance of `field_summaries` over the
    pairs of light fields.

    Parameters
    ----------
    queries, rows, l1
        As `lf_distances` takes them.

    Returns
    -------
    bounds : (q, m) float64
        At most ``lf_distances(queries, rows, l1)``, entry by entry.
    """
    fields = queries.shape[1] // (VIEWS * FEATURES)
    pairs = np.empty((len(queries) * fields, len(rows) * fields), np.float32)
    l1(field_summaries(queries), field_summaries(rows), pairs)
    return pairs.reshape(len(queries), fields, len(rows), fields).min(axis=(1, 3)).astype(float)


DESCRIPTOR = Descriptor(
    name="lf",
    needs_phi=False,
    layout=lambda params: Layout(LENGTH),
    compute=lf_vector,
    distance=Distance(exact=lf_distances, bound=lf_bounds),
)
