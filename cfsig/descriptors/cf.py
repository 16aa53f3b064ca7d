"""The paper's descriptor ``cf``: a histogram of the conformal factor phi sampled uniformly over
the surface (paper section 2.3), compared by L1."""

from __future__ import annotations

import numpy as np

from cfsig.descriptors.base import Computed, Descriptor
from cfsig.files.mesh import Mesh
from cfsig.operators.conformal import ConformalFactor
from cfsig.params import Layout, Params


def sample_phi(
    faces: np.ndarray, areas: np.ndarray, phi: np.ndarray, count: int, seed: int
) -> np.ndarray:
    """Sample phi at points drawn uniformly over the surface (paper section 2.3).

    Each sample falls in a face with probability proportional to its area, at a uniform point
    inside it; phi there is the barycentric interpolation of its corners' values. The face draws
    are made as ``count`` sorted uniform numbers against the cumulative areas, which gives each
    face its number of samples in one pass (the same distribution as drawing the samples one by
    one, without a random-access search per sample).

    Parameters
    ----------
    faces : (m, 3) int64
        Triangles.
    areas : (m,) float64
        Face areas.
    phi : (n,) or (n, d) float64
        Values at the vertices: phi, or any d values per vertex.
    count : int
        Number of samples.
    seed : int
        Seed of NumPy's PCG64 generator: the same inputs give the same samples bit for bit.

    Returns
    -------
    samples : (count,) or (count, d) float64
        Interpolated values, grouped by face in face order.
    """
    rng = np.random.default_rng(seed)
    cumulative = np.cumsum(areas)
    draws = rng.random(count)
    draws.sort()
    draws *= cumulative[-1]
    ends = np.searchsorted(draws, cumulative, side="right")
    ends[-1] = count  # a draw rounded up to the total area still belongs to the last face
    face = np.repeat(np.arange(len(faces)), np.diff(ends, prepend=0))
    corner = phi[faces]
    per_sample = (count,) + (1,) * (phi.ndim - 1)  # broadcast over the columns of phi
    # phi = c0 + r1 ((c1 - c0) + r2 (c2 - c1)) with r1 = sqrt(u1), r2 = u2 (uniform points)
    r1 = np.sqrt(rng.random(count)).reshape(per_sample)
    samples = rng.random(count).reshape(per_sample) * (corner[:, 2] - corner[:, 1])[face]
    samples += (corner[:, 1] - corner[:, 0])[face]
    samples *= r1
    samples += corner[:, 0][face]
    return samples


def histogram(values: np.ndarray, params: Params) -> np.ndarray:
    """Histogram with uniform bins, out-of-range values counted in the end bins.

    Parameters
    ----------
    values : (k,) float64
        Samples.
    params : Params
        Gives the number of bins and the outer edges (`Params.edges`).

    Returns
    -------
    hist : (bins,) float64
        Fractions of the samples per bin, summing to 1.
    """
    low, high = params.edges
    position = values - low
    position *= params.bins / (high - low)
    np.clip(position, 0, params.bins - 1, out=position)
    index = position.astype(np.intp)  # truncation is the floor once clipped to >= 0
    return np.bincount(index, minlength=params.bins) / len(values)


def cf_vector(mesh: Mesh, params: Params, cf: ConformalFactor | None, solver: str) -> Computed:
    """The histogram of phi of a mesh (paper section 2.3).

    Parameters
    ----------
    mesh : Mesh
        The repaired mesh.
    params : Params
        Gives the bins, their edges, the samples per face, the seed and ``normalize``.
    cf : ConformalFactor
        Its conformal factor (`cfsig.operators.conformal.conformal_factor`).
    solver : str
        Unused: the conformal factor is solved already.

    Returns
    -------
    computed : Computed
        ``vector``: (params.bins,) float64, the histogram of phi at ``samples_per_face * m``
        surface samples plus the vertices, summing to 1; the conformal factor's operators.

    Raises
    ------
    ValueError
        ``cf`` is None.
    """
    if cf is None:
        raise ValueError("the cf descriptor is a histogram of phi: give its conformal factor")
    phi = cf.phi
    if params.normalize:
        span = np.ptp(phi)
        phi = (phi - phi.min()) / span if span > 0 else np.zeros_like(phi)
    faces = mesh.faces
    ops = cf.operators
    samples = sample_phi(
        faces, ops.face_areas, phi, params.samples_per_face * len(faces), params.seed
    )
    return Computed(histogram(np.concatenate([samples, phi]), params), None, ops)


DESCRIPTOR = Descriptor(
    name="cf", needs_phi=True, layout=lambda params: Layout(params.bins), compute=cf_vector
)
