"""The ``cfhks`` descriptor: phi, the low Laplace-Beltrami spectrum and heat kernel signatures.

Three channels, all invariant to rigid motion and scale and all (nearly) invariant to isometric
bending, computed from the one factorisation that the conformal factor's solve makes
(see docs/descriptors.md for what each captures and how every constant here was chosen):

- ``phi``: the distribution of the conformal factor over the surface, as ``QUANTILES``
  area-weighted quantiles; two distributions are compared by the 1-Wasserstein distance, the
  mean absolute difference of their quantile functions.
- ``spectrum``: ``log(lambda_i * area)`` of the ``EIGENPAIRS`` smallest nonzero eigenvalues
  (ShapeDNA, Reuter et al. 2006, on a logarithmic scale), compared by the mean absolute
  difference.
- ``heat``: for each diffusion time ``t = tau * area`` in ``TIMES``, the distribution of
  ``log(area * h_t(x))`` over the surface, h the heat kernel signature; 1-Wasserstein distance
  per time.

The distance between two meshes is the sum over channels of the channel's distance divided by
its ``SCALES`` entry, the median of that distance over all pairs of an unlabelled collection
(the heat channel: each time by its own median, their sum again by the median of the sum), so
that each channel weighs equally. Every entry of the vector is premultiplied by its weight, so
the descriptor's distance is the plain L1 distance of the vectors and the index and search
treat every descriptor alike.
"""

from __future__ import annotations

from typing import TypedDict

import numpy as np

from .conformal import ConformalFactor
from .spectrum import heat_kernel_signature, laplace_spectrum

QUANTILES = 64
EIGENPAIRS = 30
TIMES = (0.005, 0.01, 0.02, 0.04)  # diffusion time / surface area


# Medians of the channel distances over all pairs of SHREC 2007's 400 meshes, without their
# labels: `python benchmarks/descriptors.py scales` prints them.
class Scales(TypedDict):
    """The channel scales: one number per channel, one per diffusion time for ``heat``."""

    phi: float
    spectrum: float
    heat: tuple[float, float, float, float]
    heat_sum: float


SCALES: Scales = {
    "phi": 1.834,
    "spectrum": 0.2815,
    "heat": (0.1176, 0.1588, 0.2298, 0.2984),
    "heat_sum": 4.038,
}
LENGTH = QUANTILES + EIGENPAIRS + QUANTILES * len(TIMES)


def weighted_quantiles(values: np.ndarray, weights: np.ndarray, count: int) -> np.ndarray:
    """Quantiles of a weighted discrete distribution at the probabilities ``(i + 1/2) / count``.

    Parameters
    ----------
    values : (n,) float64
        Sample values.
    weights : (n,) float64
        Non-negative weights with a positive sum.
    count : int
        Number of quantiles.

    Returns
    -------
    quantiles : (count,) float64
        Non-decreasing; the smallest value whose cumulative weight reaches each probability.
    """
    order = np.argsort(values, kind="stable")
    cumulative = np.cumsum(weights[order])
    probabilities = (np.arange(count) + 0.5) / count * cumulative[-1]
    picked = np.minimum(np.searchsorted(cumulative, probabilities), len(values) - 1)
    return values[order][picked]


def channels(cf: ConformalFactor) -> dict[str, np.ndarray]:
    """The unweighted channels of a mesh whose conformal factor is known.

    Parameters
    ----------
    cf : ConformalFactor
        Result of `conformal.conformal_factor`, whose factorisation is reused.

    Returns
    -------
    channels : dict
        ``"phi"``: (QUANTILES,) quantiles of phi, dimensionless. ``"spectrum"``: (EIGENPAIRS,)
        ``log(lambda_i * area)``; a mesh with fewer nonzero eigenvalues repeats its largest.
        ``"heat"``: (len(TIMES), QUANTILES) quantiles of ``log(area * h_t)``.

    Raises
    ------
    SolverError
        The eigenvalue iteration failed.
    """
    spectrum = laplace_spectrum(
        cf.operators.laplacian, cf.operators.vertex_area, cf.operators.labels, cf.solve, EIGENPAIRS
    )
    area = spectrum.area
    weights = cf.operators.vertex_area / area
    scaled = np.log(spectrum.eigenvalues * area)
    scaled = np.concatenate([scaled, np.full(EIGENPAIRS - len(scaled), scaled[-1])])
    hks = heat_kernel_signature(spectrum, np.asarray(TIMES) * area)
    heat = np.array([weighted_quantiles(np.log(area * h), weights, QUANTILES) for h in hks.T])
    return {
        "phi": weighted_quantiles(cf.phi, weights, QUANTILES),
        "spectrum": scaled,
        "heat": heat,
    }


def cfhks_vector(cf: ConformalFactor) -> np.ndarray:
    """The ``cfhks`` descriptor: the channels weighted so that L1 is the descriptor's distance.

    Parameters
    ----------
    cf : ConformalFactor
        Result of `conformal.conformal_factor`.

    Returns
    -------
    vector : (LENGTH,) float64
        ``phi`` quantiles, then the log spectrum, then the heat quantiles time by time, each
        entry divided by its channel's length and scale.

    Raises
    ------
    SolverError
        The eigenvalue iteration failed.
    """
    parts = channels(cf)
    heat_scales = np.asarray(SCALES["heat"])[:, None] * SCALES["heat_sum"]
    return np.concatenate(
        [
            parts["phi"] / (QUANTILES * SCALES["phi"]),
            parts["spectrum"] / (EIGENPAIRS * SCALES["spectrum"]),
            (parts["heat"] / (QUANTILES * heat_scales)).ravel(),
        ]
    )
