"""The default descriptor ``intrinsic``: the spectrum, heat kernel signatures and curvature at
scales, all invariant to rigid motion and scale and (nearly) to isometric bending.

Three channels, each computed on a copy of the mesh simplified to `COARSE` faces (the mesh
itself when it has no more, or the copy cannot be solved); docs/method.md says why each is
there and how its constants were chosen:

- ``spectrum``: ``log(lambda_i * area)`` of the `EIGENPAIRS` smallest nonzero eigenvalues of the
  Laplace-Beltrami operator (ShapeDNA, Reuter et al. 2006, on a logarithmic scale), compared by
  their mean absolute difference.
- ``heat``: for each diffusion time ``t = tau * area`` of `TIMES`, the distribution of
  ``log(area * h_t(x))`` over the surface, h the heat kernel signature, as `QUANTILES`
  area-weighted quantiles: the 1-Wasserstein distance per time.
- ``curvature``: the angle defect smoothed by heat diffusion at the `SCALES`
  (`cfsig.operators.curvature`), as joint histograms of adjacent scales near their diagonal
  (`curvature_histograms`): L1 distance per histogram. It is also what partial queries compare
  (`cfsig.descriptors.parts`), so an index stores its columns on their own (the group
  ``"curvature"``), and with `Params.partial_cells` the fine cells of all the scales jointly
  (`cfsig.descriptors.cells`).

Each channel's distance is divided by a constant, the median of that distance over the pairs
of SHREC 2007 and FAUST (the spectrum's and heat's summed over their entries, the curvature's
averaged over its histograms), so that the channels weigh alike. Every entry of the vector is
premultiplied by its divisor's inverse: the descriptor's distance is the plain L1 distance of
the vectors, and the index and search treat every descriptor alike.

The vector holds no conformal factor: in the study that weighed the channels (at commit
35f8114, ``benchmarks/descriptors.py study``), phi's best weight was 0.
"""

from __future__ import annotations

from collections.abc import Callable

import numpy as np

from cfsig.descriptors.base import Cells, Computed, Descriptor
from cfsig.descriptors.cells import SLOTS, curvature_bins, packed_cells
from cfsig.errors import SolverError
from cfsig.files.mesh import Mesh
from cfsig.operators.conformal import ConformalFactor, Operators, laplacian_solver, operators
from cfsig.operators.curvature import smoothed_curvature
from cfsig.operators.spectrum import Spectrum, heat_kernel_signature, laplace_spectrum
from cfsig.params import Layout, Params
from cfsig.repair.simplify import simplified_mesh

QUANTILES = 64
EIGENPAIRS = 45
COARSE = 4000  # faces of the simplified copy every channel is computed on
TIMES = tuple(0.0025 * 2.0**j for j in range(8))  # heat diffusion times over the area
SCALES = tuple(0.00025 * 4.0**j for j in range(4))  # curvature diffusion times over the area
# Bins per axis of the joint curvature histograms, odd so that zero curvature (flat parts) lies
# mid-bin rather than on an edge where round-off would decide its side, and the bins kept
# either side of their diagonal.
BINS, BAND = 17, 2
# Bins and band of the fine cells of all four scales jointly (`cfsig.descriptors.cells`).
FINE_BINS, FINE_BAND = 33, 4
# Each channel's divisor: its median distance per entry (docs/method.md).
SPECTRUM_DIVISOR = 5.602376 / EIGENPAIRS
HEAT_DIVISOR = 63.188313 / QUANTILES
CURVATURE_DIVISOR = 0.023645
CURVATURE_SHAPE = (len(SCALES) - 1, BINS * (2 * BAND + 1))  # histograms, bins in each
LENGTH = EIGENPAIRS + QUANTILES * len(TIMES) + CURVATURE_SHAPE[0] * CURVATURE_SHAPE[1]


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
    """The joint histograms of curvature at adjacent scales, the ``curvature`` channel.

    Each vertex falls in its bin of `cfsig.descriptors.cells.curvature_bins` at each scale. Each
    pair of adjacent scales gets one joint histogram: where a vertex's curvature lies at one
    scale and at the next, the second scale's bin taken relative to the first's and clipped to
    within `BAND` bins of it, where nearly all the mass lies.

    Parameters
    ----------
    values : (n, len(SCALES)) float64
        `cfsig.operators.curvature.smoothed_curvature` at the scales, dimensionless.
    weights : (n,) float64
        Non-negative vertex weights (areas) with a positive sum.

    Returns
    -------
    histograms : CURVATURE_SHAPE float64
        Each the fractions of the weight in its bins, the first scale's bin major.
    """
    index = curvature_bins(values, BINS)
    width = CURVATURE_SHAPE[1]
    first, second = index[:, :-1], index[:, 1:]
    index = first * (2 * BAND + 1) + np.clip(second - first, -BAND, BAND) + BAND
    fractions = weights / weights.sum()
    counts = [np.bincount(b, weights=fractions, minlength=width) for b in index.T]
    return np.array(counts).reshape(index.shape[1], width)


def weigh_curvature(histograms: np.ndarray) -> np.ndarray:
    """The curvature channel's part of the descriptor vector.

    Parameters
    ----------
    histograms : CURVATURE_SHAPE float64
        `curvature_histograms`.

    Returns
    -------
    entries : (CURVATURE_SHAPE[0] * CURVATURE_SHAPE[1],) float64
        Each histogram entry divided by its width times `CURVATURE_DIVISOR`.
    """
    return (histograms / (histograms.shape[1] * CURVATURE_DIVISOR)).ravel()


def channels(ops: Operators, spectrum: Spectrum, cells: bool) -> dict[str, np.ndarray]:
    """The unweighted channels of a surface.

    Parameters
    ----------
    ops : Operators
        The operators of the surface (the simplified copy, or the mesh itself).
    spectrum : Spectrum
        Its `EIGENPAIRS` lowest eigenpairs (`spectrum_of`).
    cells : bool
        Also compute the fine curvature cells.

    Returns
    -------
    channels : dict
        ``"spectrum"``: (EIGENPAIRS,) ``log(lambda_i * area)``; a surface with fewer nonzero
        eigenvalues repeats its largest. ``"heat"``: (len(TIMES), QUANTILES) quantiles of
        ``log(area * h_t)``. ``"curvature"``: `curvature_histograms`. With ``cells``,
        ``"cells"`` and ``"cell_units"``: `cfsig.descriptors.cells.packed_cells`.

    Raises
    ------
    SolverError
        A curvature diffusion failed.
    """
    weights = ops.vertex_area / ops.vertex_area.sum()
    area = spectrum.area
    scaled = np.log(spectrum.eigenvalues * area)
    scaled = np.concatenate([scaled, np.full(EIGENPAIRS - len(scaled), scaled[-1])])
    hks = heat_kernel_signature(spectrum, np.asarray(TIMES) * area)
    heat_weights = spectrum.vertex_area / area
    heat = np.array([weighted_quantiles(np.log(area * h), heat_weights, QUANTILES) for h in hks.T])
    curvature = smoothed_curvature(ops, SCALES)
    found = {
        "spectrum": scaled,
        "heat": heat,
        "curvature": curvature_histograms(curvature, weights),
    }
    if cells:
        found["cells"], found["cell_units"] = packed_cells(
            curvature, ops.vertex_area, FINE_BINS, FINE_BAND
        )
    return found


def weigh(found: dict[str, np.ndarray]) -> np.ndarray:
    """The descriptor vector of a surface's channels: L1 between two of them is their distance.

    Parameters
    ----------
    found : dict
        What `channels` returns.

    Returns
    -------
    vector : (LENGTH,) float64
        The log spectrum, then the heat quantiles time by time, then the curvature histograms,
        each entry divided by its channel's length and divisor.
    """
    return np.concatenate(
        [
            found["spectrum"] / (EIGENPAIRS * SPECTRUM_DIVISOR),
            (found["heat"] / (QUANTILES * np.full(len(TIMES), HEAT_DIVISOR)[:, None])).ravel(),
            weigh_curvature(found["curvature"]),
        ]
    )


def spectrum_of(
    ops: Operators,
    solve: Callable[[np.ndarray], np.ndarray] | None,
    solver: str,
    count: int = EIGENPAIRS,
) -> Spectrum:
    """The ``count`` smallest nonzero eigenpairs of a surface.

    Parameters
    ----------
    ops : Operators
        The surface's operators.
    solve : callable or None
        Its factorised Laplacian when it is known (`ConformalFactor.solve`); None factorises it.
    solver : {"auto", "cholmod", "eigen", "scipy"}
        Sparse solver backend of the factorisation made here.
    count : int
        Eigenpairs wanted [`EIGENPAIRS`].

    Returns
    -------
    spectrum : Spectrum

    Raises
    ------
    SolverError
        The factorisation or the eigenvalue iteration failed.
    """
    if solve is None:
        solve = laplacian_solver(ops.laplacian, ops.labels, solver)
    return laplace_spectrum(ops.laplacian, ops.vertex_area, ops.labels, solve, count)


def _on_copy(mesh: Mesh, cells: bool, solver: str) -> tuple[np.ndarray, Cells | None] | None:
    """The vector and cells from the mesh's simplified copy; None when the mesh has no more
    faces than the copy would, or the copy cannot be solved."""
    coarse = simplified_mesh(mesh, COARSE)
    if coarse is None:
        return None
    copy = operators(coarse)
    try:
        spectrum = spectrum_of(copy, None, solver)
    except SolverError:
        return None
    return _vector(channels(copy, spectrum, cells))


def _vector(found: dict[str, np.ndarray]) -> tuple[np.ndarray, Cells | None]:
    """The weighed vector of some channels and their fine cells, if they were computed."""
    cells = (found["cells"], found["cell_units"]) if "cells" in found else None
    return weigh(found), cells


def intrinsic_vector(
    mesh: Mesh, params: Params, cf: ConformalFactor | None, solver: str
) -> Computed:
    """The ``intrinsic`` descriptor of a mesh, and its fine cells when the parameters keep them.

    Parameters
    ----------
    mesh : Mesh
        The repaired mesh.
    params : Params
        Gives ``mollify`` (for the mesh's own operators) and ``partial_cells``.
    cf : ConformalFactor or None
        Its conformal factor, when the caller solved it: its operators and factorisation serve
        a mesh that is its own copy.
    solver : {"auto", "cholmod", "eigen", "scipy"}
        Sparse solver backend of the factorisations made here.

    Returns
    -------
    computed : Computed
        ``vector`` (LENGTH,) float64 (`weigh`); ``cells`` when ``params.partial_cells``;
        ``operators`` when the mesh's own were used.

    Raises
    ------
    SolverError
        A factorisation, the eigenvalue iteration or a curvature diffusion failed.
    """
    found = _on_copy(mesh, params.partial_cells, solver)
    if found is not None:
        return Computed(*found, None)
    ops = operators(mesh, params.mollify) if cf is None else cf.operators
    spectrum = spectrum_of(ops, None if cf is None else cf.solve, solver)
    return Computed(*_vector(channels(ops, spectrum, params.partial_cells)), ops)


def intrinsic_layout(params: Params) -> Layout:
    """The vector, its curvature columns as a group, and the fine cells if kept."""
    curvature = ("curvature", LENGTH - CURVATURE_SHAPE[0] * CURVATURE_SHAPE[1], LENGTH)
    return Layout(LENGTH, (curvature,), SLOTS if params.partial_cells else 0)


DESCRIPTOR = Descriptor(
    name="intrinsic", needs_phi=False, layout=intrinsic_layout, compute=intrinsic_vector
)
