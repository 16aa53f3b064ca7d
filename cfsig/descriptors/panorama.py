"""The panoramic channel of ``rigid``: cylindrical projections of the pose-normalised surface, after
PANORAMA (Papadakis, Pratikakis, Theoharis and Perantonis, "PANORAMA: A 3D Shape Descriptor
Based on Panoramic Views for Unsupervised 3D Object Retrieval", IJCV 2010).

The steps, and where cfsig departs from the paper (docs/method.md):

- Pose: the surface samples of ``sh`` (`cfsig.descriptors.sh.surface_samples`: uniform over the
  area, centred on the area's centroid), at most `POINTS` of them, scaled to a mean distance of
  1 from the centroid, in two frames as the paper does (`principal_axes`): the principal axes
  of the area (its CPCA) and those of the normals (its NPCA). The axes' signs, and their order
  when second moments are close, are left to the features and the distance below.
- Panoramas: for each axis, a cylinder about it through the centroid, of radius `RADIUS` mean
  distances and height twice that, cut into `ANGLES` x `HEIGHTS` cells of azimuth and height
  (`panoramas`). Each cell holds the outermost sample in it, as a ray cast from the axis outward
  meets the surface last: its distance from the axis over the radius (the paper's SDM, clipped
  to 1) and the absolute cosine between its normal and the ray (NDM). The paper casts rays;
  samples are cheaper and leave a cell without surface at 0, as a ray that meets none.
- Features (`folded_spectra`): the magnitudes of each image's 2-D discrete Fourier transform at
  azimuthal frequencies 0 to `ANGULAR` and height frequencies -`AXIAL` to `AXIAL`, over their
  sum. A turn about the axis shifts the image along the azimuth, which the magnitudes ignore;
  reversing the axis reverses both coordinates, which a real image's magnitudes ignore too. A
  mirror reverses one, exchanging the frequencies (k, l) and (k, -l): each such pair is kept as
  its larger and smaller magnitude, so mirrored copies agree as well. The paper's wavelet
  features are not computed.
- Distance (`panorama_distances`): the smallest, over the 2 x 2 pairs of frames and the 6
  orders of the axes, of the L1 distances of the paired axes' features: the axes' order is
  unstable when second moments are close, as the light field's views are for the
  dodecahedron's rotations, and either frame can be the one that finds a shape's pose.

The features are ``FRAMES x AXES x MAPS x (ANGULAR + 1) x (2 AXIAL + 1)`` values, frame by frame,
axis by axis.
"""

from __future__ import annotations

from functools import lru_cache
from itertools import permutations, product

import numpy as np

from cfsig.descriptors.base import L1Kernel

FRAMES = 2  # the principal axes of the area, then of the normals
AXES = 3
MAPS = 2  # the distance (SDM) and orientation (NDM) panoramas
ANGLES = 128  # cells around each cylinder
HEIGHTS = 64  # cells along it
RADIUS = 3.0  # of each cylinder, in mean distances of the surface from its centroid
POINTS = 1 << 16  # surface samples projected, at most
ANGULAR = 16  # azimuthal frequencies 0..ANGULAR
AXIAL = 12  # height frequencies -AXIAL..AXIAL
BLOCK = MAPS * (ANGULAR + 1) * (2 * AXIAL + 1)  # features per axis
LENGTH = FRAMES * AXES * BLOCK


def principal_axes(points: np.ndarray) -> np.ndarray:
    """The principal axes of points (or vectors) about the origin.

    Parameters
    ----------
    points : (k, 3) float64
        Points, centred, or unit normals.

    Returns
    -------
    axes : (3, 3) float64
        Orthonormal columns, by decreasing second moment.
    """
    _, vectors = np.linalg.eigh(points.T @ points)
    return vectors[:, ::-1]


def panoramas(points: np.ndarray, normals: np.ndarray) -> np.ndarray:
    """The distance and orientation panoramas of points about the three coordinate axes.

    Parameters
    ----------
    points : (k, 3) float64
        Surface samples, in units of their mean distance from the origin.
    normals : (k, 3) float64
        Their unit normals (zero where undefined).

    Returns
    -------
    images : (AXES, MAPS, ANGLES, HEIGHTS) float64
        For axis a, cell (u, v) of azimuth ``[2 pi u / ANGLES - pi, ...)`` about the axis (from
        the next axis towards the one after) and height ``[(v / HEIGHTS - 1/2) 2 RADIUS, ...)``
        (samples beyond fall in the end cells): map 0 the largest distance of a sample in the
        cell from the axis over `RADIUS`, at most 1; map 1 the absolute cosine between that
        sample's normal and the direction from the axis to it. Zero in a cell without sample.
    """
    images = np.zeros((AXES, MAPS, ANGLES * HEIGHTS))
    for axis in range(AXES):
        along, x, y = (points[:, (axis + k) % AXES] for k in range(3))
        radius = np.hypot(x, y)
        turn = np.floor((np.arctan2(y, x) + np.pi) * (ANGLES / (2 * np.pi))).astype(np.int64)
        level = np.floor((along / (2 * RADIUS) + 0.5) * HEIGHTS).astype(np.int64)
        cell = (turn % ANGLES) * HEIGHTS + np.clip(level, 0, HEIGHTS - 1)
        farthest = images[axis, 0]
        np.maximum.at(farthest, cell, radius)
        outer = radius >= farthest[cell]
        normal_x, normal_y = normals[outer, (axis + 1) % AXES], normals[outer, (axis + 2) % AXES]
        cosine = np.abs(normal_x * x[outer] + normal_y * y[outer])
        np.divide(cosine, radius[outer], out=cosine, where=radius[outer] > 0)
        images[axis, 1, cell[outer]] = np.minimum(cosine, 1)  # 1 but for rounding
        np.minimum(farthest / RADIUS, 1, out=farthest)
    return images.reshape(AXES, MAPS, ANGLES, HEIGHTS)


def folded_spectra(images: np.ndarray) -> np.ndarray:
    """The magnitudes of images' 2-D Fourier transforms at low frequencies, mirrors folded.

    Parameters
    ----------
    images : (..., ANGLES, HEIGHTS) float64
        Panoramas, azimuth first.

    Returns
    -------
    spectra : (..., ANGULAR + 1, 2 AXIAL + 1) float64
        For azimuthal frequency k: ``|F(k, 0)|``, then ``max(|F(k, l)|, |F(k, -l)|)`` for l = 1
        to `AXIAL`, then the ``min`` of the same pairs; each image's over their sum (zero for
        an empty image).
    """
    magnitudes = np.abs(np.fft.fft2(images)[..., : ANGULAR + 1, :])
    up = magnitudes[..., 1 : AXIAL + 1]
    down = magnitudes[..., -1 : -AXIAL - 1 : -1]
    spectra = np.concatenate(
        [magnitudes[..., :1], np.maximum(up, down), np.minimum(up, down)], axis=-1
    )
    total = spectra.sum(axis=(-2, -1), keepdims=True)
    return np.divide(spectra, total, out=np.zeros_like(spectra), where=total > 0)


def panorama_features(points: np.ndarray, normals: np.ndarray) -> np.ndarray:
    """The panoramic features of a surface's samples.

    Parameters
    ----------
    points : (k, 3) float64
        Samples uniform over the surface's area, centred on its centroid, at any scale
        (`cfsig.descriptors.sh.surface_samples`); every ``ceil(k / POINTS)``-th is used.
    normals : (k, 3) float64
        Their unit normals.

    Returns
    -------
    features : (LENGTH,) float64
        `folded_spectra` of the `panoramas` of the samples, scaled to a mean distance of 1
        from the centroid, in the frame of the `principal_axes` of the samples, then in that
        of their normals'; frame by frame, axis by axis by decreasing second moment, the
        distance map before the orientation map.
    """
    step = -(-len(points) // POINTS)
    points, normals = points[::step], normals[::step]
    points = points / max(float(np.linalg.norm(points, axis=1).mean()), np.finfo(float).tiny)
    features = [
        folded_spectra(panoramas(points @ axes, normals @ axes))
        for axes in (principal_axes(points), principal_axes(normals))
    ]
    return np.concatenate(features, axis=None)


@lru_cache(maxsize=1)
def axis_orders() -> np.ndarray:
    """The orders of the axes a distance tries, the identity first; cached.

    Returns
    -------
    orders : (6, AXES) int64
        Read-only: order r pairs a query's axis a with a row's axis ``orders[r, a]``.
    """
    orders = np.array(list(permutations(range(AXES))))
    orders.flags.writeable = False
    return orders


def panorama_distances(queries: np.ndarray, rows: np.ndarray, l1: L1Kernel) -> np.ndarray:
    """The panoramic distance between the features of some surfaces and others.

    Parameters
    ----------
    queries : (q, LENGTH) float32, C-contiguous
        Features (`panorama_features`).
    rows : (m, LENGTH) float32, C-contiguous
        Features to compare with.
    l1 : L1Kernel
        The L1 distances of rows (`cfsig.descriptors.base.L1Kernel`).

    Returns
    -------
    distances : (q, m) float64
        The smallest, over a frame of the query's and one of the row's and over the
        `axis_orders`, of the sum over the query's axes of the L1 distance of its features to
        those of the row's axis paired with it.
    """
    blocks = [
        [np.ascontiguousarray(some[:, k * BLOCK : (k + 1) * BLOCK]) for k in range(FRAMES * AXES)]
        for some in (queries, rows)
    ]
    orders = axis_orders()
    best = np.full((len(queries), len(rows)), np.inf)
    pairs = np.empty((AXES, AXES, len(queries), len(rows)), np.float32)
    for mine, theirs in product(range(FRAMES), repeat=2):
        for a, b in product(range(AXES), repeat=2):
            l1(blocks[0][mine * AXES + a], blocks[1][theirs * AXES + b], pairs[a, b])
        sums = pairs[np.arange(AXES), orders].astype(np.float64).sum(axis=1)  # (orders, q, m)
        np.minimum(best, sums.min(axis=0), out=best)
    return best
