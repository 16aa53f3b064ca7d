"""The ``cfhks`` descriptor: phi, the spectrum, heat kernel signatures and curvature at scales.

Up to four channels, all invariant to rigid motion and scale and all (nearly) invariant to
isometric bending, computed from the one factorisation that the conformal factor's solve makes
(see docs/descriptors.md for what each captures and how every constant here was chosen):

- ``phi``: the distribution of the conformal factor over the surface, as ``QUANTILES``
  area-weighted quantiles; two distributions are compared by the 1-Wasserstein distance, the
  mean absolute difference of their quantile functions.
- ``spectrum``: ``log(lambda_i * area)`` of the ``EIGENPAIRS`` smallest nonzero eigenvalues
  (ShapeDNA, Reuter et al. 2006, on a logarithmic scale), compared by the mean absolute
  difference.
- ``heat``: for each diffusion time ``t = tau * area`` of the version's ``times``, the
  distribution of ``log(area * h_t(x))`` over the surface, h the heat kernel signature;
  1-Wasserstein distance per time.
- ``curvature``: for each scale ``s`` of the version's ``scales``, the area-weighted histogram
  of the angle defect smoothed by heat diffusion for ``s * area`` (`cfsig.curvature`), on
  ``asinh(value / 10)`` in ``CURVATURE_BINS`` bins; L1 distance per scale. It needs no
  eigenproblem, only one factorisation per scale.

The distance between two meshes is the sum over channels of the channel's distance divided by
a constant of the version (`Design`): a median of that distance over the pairs of unlabelled
collections, divided by the channel's weight. Every entry of the vector is premultiplied by
its divisor's inverse, so the descriptor's distance is the plain L1 distance of the vectors
and the index and search treat every descriptor alike.

Versions (`Params.version`; an index stores its own, and a query recomputes with it):

1. Four times (0.005 to 0.04), equal weights, medians over SHREC 2007's pairs.
2. Eight times (0.0025 to 0.32, doubling), weights 0 (phi: left out of the vector), 1
   (spectrum) and 3 (heat, its distance averaged over the times), chosen on SHREC 2007 and
   McGill together, with the medians averaged over those two collections.
3. Version 2 plus curvature at four scales (0.0000156 to 0.001, quadrupling), weighed like
   all of version 2 together, chosen on SHREC 2007 and FAUST (McGill held out).
4. Version 3 with the spectrum and the heat kernel signature computed on a copy of the mesh
   simplified to ``coarse`` faces (`cfsig.simplify`), at a fraction of the eigenproblem's cost;
   phi and the curvature stay on the full mesh, bit for bit version 3's.
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np

from .conformal import ConformalFactor, factorize_laplacian, operators
from .curvature import smoothed_curvature
from .errors import SolverError
from .mesh import Mesh
from .simplify import simplified_mesh
from .spectrum import Spectrum, heat_kernel_signature, laplace_spectrum

QUANTILES = 64
EIGENPAIRS = 30
CURVATURE_BINS = 48
CURVATURE_RANGE = 6.0  # bins span asinh(value / CURVATURE_UNIT) in [-6, 6]: +-2000 in value
CURVATURE_UNIT = 10.0  # about the sphere's 4 pi: the histogram is linear below, logarithmic above


@dataclass(frozen=True)
class Design:
    """The constants of one version of ``cfhks``.

    Attributes
    ----------
    times : tuple of float
        Diffusion times of the heat channel divided by the surface area (dimensionless).
    phi : float or None
        Divisor of the phi distance; None leaves phi out of the vector.
    spectrum : float
        Divisor of the spectrum distance.
    heat : tuple of float
        Divisor of each time's heat distance, one per time.
    scales : tuple of float
        Diffusion times of the curvature channel divided by the surface area; empty leaves the
        channel out.
    curvature : float
        Divisor of each scale's curvature distance.
    coarse : int
        Faces of the simplified copy on which the spectrum and heat are computed; 0 computes
        them on the mesh itself.
    """

    times: tuple[float, ...]
    phi: float | None
    spectrum: float
    heat: tuple[float, ...]
    scales: tuple[float, ...] = ()
    curvature: float = 1.0
    coarse: int = 0

    @property
    def length(self) -> int:
        """Length of the descriptor vector."""
        return (
            (self.phi is not None) * QUANTILES
            + EIGENPAIRS
            + QUANTILES * len(self.times)
            + CURVATURE_BINS * len(self.scales)
        )


_V1_HEAT = (0.1176, 0.1588, 0.2298, 0.2984)  # per time, then their sum's median, 4.038
_V2_TIMES = tuple(0.0025 * 2.0**j for j in range(8))
# The medians are printed by `python benchmarks/descriptors.py study` (docs/descriptors.md):
# version 1 over SHREC 2007's pairs; version 2 the mean of SHREC 2007's and McGill's, each
# divided by its channel's weight (heat 3, its time average taken by the divisor).
_V2 = Design(_V2_TIMES, None, 0.3173, (len(_V2_TIMES) * 0.2152 / 3,) * len(_V2_TIMES))
# Version 3's scales and curvature divisor, printed by `python benchmarks/descriptors.py study3`:
# the median curvature distance over SHREC 2007's and FAUST's pairs, relative to the median of
# version 2's distance there (weight 1, docs/descriptors.md).
_V3 = replace(_V2, scales=tuple(0.0000625 * 4.0**j for j in range(-1, 3)), curvature=0.015153)
# Version 4's copy: 4000 faces, about 2000 vertices on a closed surface, chosen on SHREC 2007
# and FAUST by `python benchmarks/descriptors.py coarse` (docs/descriptors.md).
DESIGNS = {
    1: Design((0.005, 0.01, 0.02, 0.04), 1.834, 0.2815, tuple(s * 4.038 for s in _V1_HEAT)),
    2: _V2,
    3: _V3,
    4: replace(_V3, coarse=4000),
}


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


def curvature_histograms(values: np.ndarray, weights: np.ndarray) -> np.ndarray:
    """Histograms of curvature at scales, the ``curvature`` channel.

    Parameters
    ----------
    values : (n, k) float64
        `cfsig.curvature.smoothed_curvature` at k scales, dimensionless.
    weights : (n,) float64
        Non-negative vertex weights (areas) with a positive sum.

    Returns
    -------
    histograms : (k, CURVATURE_BINS) float64
        Per scale, the fraction of the weight in each bin of ``asinh(value / CURVATURE_UNIT)``
        on [-CURVATURE_RANGE, CURVATURE_RANGE], values beyond counted in the end bins.
    """
    position = np.arcsinh(values / CURVATURE_UNIT) + CURVATURE_RANGE
    position *= CURVATURE_BINS / (2 * CURVATURE_RANGE)
    bins = np.clip(position, 0, CURVATURE_BINS - 1).astype(np.intp)
    fractions = weights / weights.sum()
    counts = [np.bincount(b, weights=fractions, minlength=CURVATURE_BINS) for b in bins.T]
    return np.array(counts).reshape(values.shape[1], CURVATURE_BINS)


def channels(
    cf: ConformalFactor,
    times: tuple[float, ...],
    scales: tuple[float, ...] = (),
    coarse: Mesh | None = None,
) -> dict[str, np.ndarray]:
    """The unweighted channels of a mesh whose conformal factor is known.

    Parameters
    ----------
    cf : ConformalFactor
        Result of `conformal.conformal_factor`, whose factorisation is reused.
    times : tuple of float
        Diffusion times of the heat channel divided by the surface area (`Design.times`).
    scales : tuple of float
        Scales of the curvature channel (`Design.scales`).
    coarse : Mesh or None
        A simplified copy of the mesh (`cfsig.simplify.simplified_mesh`) on which the spectrum
        and heat are computed, with its own factorisation; None, or a copy that cannot be
        solved, computes them with ``cf``'s.

    Returns
    -------
    channels : dict
        ``"phi"``: (QUANTILES,) quantiles of phi, dimensionless. ``"spectrum"``: (EIGENPAIRS,)
        ``log(lambda_i * area)``; a mesh with fewer nonzero eigenvalues repeats its largest.
        ``"heat"``: (len(times), QUANTILES) quantiles of ``log(area * h_t)``.
        ``"curvature"``: (len(scales), CURVATURE_BINS) `curvature_histograms`.

    Raises
    ------
    SolverError
        The eigenvalue iteration or a curvature diffusion failed.
    """
    ops = cf.operators
    weights = ops.vertex_area / ops.vertex_area.sum()
    spectrum = _spectrum(cf, coarse)
    area = spectrum.area
    scaled = np.log(spectrum.eigenvalues * area)
    scaled = np.concatenate([scaled, np.full(EIGENPAIRS - len(scaled), scaled[-1])])
    hks = heat_kernel_signature(spectrum, np.asarray(times) * area)
    heat_weights = spectrum.vertex_area / area
    heat = np.array([weighted_quantiles(np.log(area * h), heat_weights, QUANTILES) for h in hks.T])
    return {
        "phi": weighted_quantiles(cf.phi, weights, QUANTILES),
        "spectrum": scaled,
        "heat": heat,
        "curvature": curvature_histograms(smoothed_curvature(ops, scales), weights),
    }


def _spectrum(cf: ConformalFactor, coarse: Mesh | None) -> Spectrum:
    """The low spectrum of the copy when there is one and it can be solved, else of cf's mesh."""
    if coarse is not None:
        ops = operators(coarse)
        try:
            solve = factorize_laplacian(ops.laplacian, ops.labels)
            return laplace_spectrum(ops.laplacian, ops.vertex_area, ops.labels, solve, EIGENPAIRS)
        except SolverError:
            pass  # a copy the simplification left unsolvable: the spectrum of the mesh itself
    ops = cf.operators
    return laplace_spectrum(ops.laplacian, ops.vertex_area, ops.labels, cf.solve, EIGENPAIRS)


def weigh(parts: dict[str, np.ndarray], design: Design) -> np.ndarray:
    """The descriptor vector of a mesh's channels: L1 between two of them is their distance.

    Parameters
    ----------
    parts : dict
        What `channels` returns for ``design.times`` and ``design.scales``.
    design : Design
        The version's divisors.

    Returns
    -------
    vector : (design.length,) float64
        ``phi`` quantiles (unless ``design.phi`` is None), then the log spectrum, then the heat
        quantiles time by time, then the curvature histograms scale by scale, each entry
        divided by its channel's length and divisor.
    """
    phi = [] if design.phi is None else [parts["phi"] / (QUANTILES * design.phi)]
    return np.concatenate(
        [
            *phi,
            parts["spectrum"] / (EIGENPAIRS * design.spectrum),
            (parts["heat"] / (QUANTILES * np.asarray(design.heat)[:, None])).ravel(),
            weigh_curvature(parts["curvature"], design),
        ]
    )


def weigh_curvature(histograms: np.ndarray, design: Design) -> np.ndarray:
    """The curvature channel's part of the descriptor vector.

    Parameters
    ----------
    histograms : (len(design.scales), CURVATURE_BINS) float64
        `curvature_histograms`.
    design : Design
        The version's divisors.

    Returns
    -------
    entries : (len(design.scales) * CURVATURE_BINS,) float64
        Each histogram entry divided by ``CURVATURE_BINS * design.curvature``, scale by scale.
    """
    return (histograms / (CURVATURE_BINS * design.curvature)).ravel()


def cfhks_vector(cf: ConformalFactor, mesh: Mesh, version: int) -> np.ndarray:
    """The ``cfhks`` descriptor of a mesh whose conformal factor is known.

    Parameters
    ----------
    cf : ConformalFactor
        Result of `conformal.conformal_factor` on ``mesh``.
    mesh : Mesh
        The mesh, simplified for the spectrum when the version has a ``coarse`` copy.
    version : int
        A key of `DESIGNS`.

    Returns
    -------
    vector : (DESIGNS[version].length,) float64
        See `weigh`.

    Raises
    ------
    SolverError
        The eigenvalue iteration failed.
    """
    design = DESIGNS[version]
    coarse = simplified_mesh(mesh, design.coarse) if design.coarse else None
    return weigh(channels(cf, design.times, design.scales, coarse), design)
