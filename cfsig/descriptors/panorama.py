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
- Spectra (`folded_spectra`): the absolute real and imaginary parts of each image's 2-D
  discrete Fourier transform at azimuthal frequencies 0 to `ANGULAR` and height frequencies
  -`AXIAL` to `AXIAL`, as the paper keeps them, each image's over their sum, the phase taken
  about the image's centre. The pose fixes the azimuth's origin up to the axes' signs, which
  turn an image by half a turn (multiplying frequency k by (-1)^k) or reverse its azimuth or
  height (taking G(k, l) to G(k, -l) or to its conjugate), as a mirror does: each pair (k, l),
  (k, -l) is kept as its larger and smaller absolute part, so that turned and mirrored copies
  agree.
- Wavelets (`wavelet_features`), as the paper adds them: the mean, standard deviation and
  skewness of the absolute coefficients of each subband of a `LEVELS`-level 2-D Haar transform
  of each image, periodic along the azimuth (the paper's Haar and D4 give way to Haar alone,
  whose subbands the half turn and the reversals above only permute and change the signs
  of). Their logarithms (the skewness's inverse hyperbolic sine) compare by L1 where the
  paper's Canberra distance compares their ratios, weighed against the spectra by
  `WAVELET_WEIGHT`.
- Distance (`panorama_distances`): the smallest, over the 2 x 2 pairs of frames and the 6
  orders of the axes, of the L1 distances of the paired axes' features: the axes' order is
  unstable when second moments are close, as the light field's views are for the
  dodecahedron's rotations, and either frame can be the one that finds a shape's pose.

The features are ``FRAMES x AXES x BLOCK`` values, frame by frame, axis by axis: each axis's
``MAPS x PARTS x (ANGULAR + 1) x (2 AXIAL + 1)`` spectra, then its ``MAPS x SUBBANDS x MOMENTS``
wavelet features. docs/method.md tells how the constants were chosen.
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
PARTS = 2  # the real and imaginary parts of the transform
SPECTRUM = MAPS * PARTS * (ANGULAR + 1) * (2 * AXIAL + 1)  # spectral features per axis
LEVELS = 6  # of the Haar transform: 2 ** LEVELS divides ANGLES and HEIGHTS
SUBBANDS = 3 * LEVELS + 1  # three of details a level, then the last approximation
MOMENTS = 3  # mean, standard deviation and skewness of a subband's absolute coefficients
WAVELETS = MAPS * SUBBANDS * MOMENTS  # wavelet features per axis
FLOOR = 0.3  # added to the mean and standard deviation before their logarithm
WAVELET_WEIGHT = 0.041  # of the wavelet features, against the spectra's
BLOCK = SPECTRUM + WAVELETS  # features per axis
_HALF = np.sqrt(0.5)  # the Haar filters' taps
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
    """The absolute real and imaginary parts of images' 2-D Fourier transforms at low
    frequencies, about the images' centres, mirrors folded.

    Parameters
    ----------
    images : (..., ANGLES, HEIGHTS) float64
        Panoramas, azimuth first.

    Returns
    -------
    spectra : (..., PARTS, ANGULAR + 1, 2 AXIAL + 1) float64
        Part p (real, imaginary) at azimuthal frequency k, of the transform ``G(k, l)`` with
        phases about the centre ``((ANGLES - 1) / 2, (HEIGHTS - 1) / 2)``: ``|p G(k, 0)|``,
        then ``max(|p G(k, l)|, |p G(k, -l)|)`` for l = 1 to `AXIAL`, then the ``min`` of the
        same pairs; each image's over their sum (zero for an empty image).
    """
    angles, heights = images.shape[-2:]
    azimuthal = np.arange(ANGULAR + 1)[:, None] * ((angles - 1) / angles)
    axial = np.fft.fftfreq(heights, 1 / heights)[None, :] * ((heights - 1) / heights)
    centred = np.fft.fft2(images)[..., : ANGULAR + 1, :] * np.exp(1j * np.pi * (azimuthal + axial))
    parts = np.abs(np.stack([centred.real, centred.imag], axis=-3))
    up = parts[..., 1 : AXIAL + 1]
    down = parts[..., -1 : -AXIAL - 1 : -1]
    spectra = np.concatenate([parts[..., :1], np.maximum(up, down), np.minimum(up, down)], axis=-1)
    total = spectra.sum(axis=(-3, -2, -1), keepdims=True)
    return np.divide(spectra, total, out=np.zeros_like(spectra), where=total > 0)


def haar_subbands(images: np.ndarray) -> list[np.ndarray]:
    """The subbands of images' orthonormal 2-D Haar transform, `LEVELS` levels deep.

    Parameters
    ----------
    images : (..., ANGLES, HEIGHTS) float64
        Panoramas; both sides divisible by ``2 ** LEVELS``.

    Returns
    -------
    subbands : list of SUBBANDS arrays (..., a, h) float64
        Level by level from the finest, the details along the height, along the azimuth and
        along both (a, h halved at each level), then the last approximation.
    """
    subbands = []
    low = images
    for _ in range(LEVELS):
        even, odd = low[..., ::2, :], low[..., 1::2, :]
        smooth, sharp = (even + odd) * _HALF, (even - odd) * _HALF
        subbands += [
            (smooth[..., ::2] - smooth[..., 1::2]) * _HALF,
            (sharp[..., ::2] + sharp[..., 1::2]) * _HALF,
            (sharp[..., ::2] - sharp[..., 1::2]) * _HALF,
        ]
        low = (smooth[..., ::2] + smooth[..., 1::2]) * _HALF
    return [*subbands, low]


def wavelet_moments(images: np.ndarray) -> np.ndarray:
    """The moments of the absolute coefficients of each of images' `haar_subbands`.

    Parameters
    ----------
    images : (..., ANGLES, HEIGHTS) float64
        Panoramas.

    Returns
    -------
    moments : (..., SUBBANDS, MOMENTS) float64
        Each subband's mean, standard deviation and skewness (0 where the deviation is below
        1e-9, as for a constant subband).
    """
    coefficients = [np.abs(band).reshape(*band.shape[:-2], -1) for band in haar_subbands(images)]
    out = []
    for band in coefficients:
        mean = band.mean(axis=-1)
        deviation = band - mean[..., None]
        spread = np.sqrt((deviation**2).mean(axis=-1))
        third = (deviation**3).mean(axis=-1)
        skew = np.divide(third, spread**3, out=np.zeros_like(third), where=spread > 1e-9)
        out.append(np.stack([mean, spread, skew], axis=-1))
    return np.stack(out, axis=-2)


def wavelet_features(images: np.ndarray) -> np.ndarray:
    """The wavelet features of images: their `wavelet_moments` on a logarithmic scale.

    Parameters
    ----------
    images : (..., ANGLES, HEIGHTS) float64
        Panoramas.

    Returns
    -------
    features : (..., SUBBANDS, MOMENTS) float64
        `WAVELET_WEIGHT` times ``log(FLOOR + mean)``, ``log(FLOOR + deviation)`` and
        ``arcsinh(skewness)``.
    """
    moments = wavelet_moments(images)
    logarithms = np.concatenate(
        [np.log(FLOOR + moments[..., :2]), np.arcsinh(moments[..., 2:])], axis=-1
    )
    return WAVELET_WEIGHT * logarithms


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
        The `panoramas` of the samples, scaled to a mean distance of 1 from the centroid, in the
        frame of the `principal_axes` of the samples, then in that of their normals'; frame by
        frame, axis by axis by decreasing second moment: the `folded_spectra` of the axis's
        distance map and orientation map, then their `wavelet_features`.
    """
    step = -(-len(points) // POINTS)
    points, normals = points[::step], normals[::step]
    points = points / max(float(np.linalg.norm(points, axis=1).mean()), np.finfo(float).tiny)
    features = []
    for axes in (principal_axes(points), principal_axes(normals)):
        images = panoramas(points @ axes, normals @ axes)
        spectra = folded_spectra(images).reshape(AXES, SPECTRUM)
        features.append(np.hstack([spectra, wavelet_features(images).reshape(AXES, WAVELETS)]))
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
