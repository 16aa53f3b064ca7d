"""The ``cfhks`` descriptor: phi, the spectrum, heat kernel signatures and curvature at scales.

Up to four channels, all invariant to rigid motion and scale and all (nearly) invariant to
isometric bending (see docs/descriptors.md for what each captures and how every constant here
was chosen):

- ``phi``: the distribution of the conformal factor over the surface, as ``QUANTILES``
  area-weighted quantiles; two distributions are compared by the 1-Wasserstein distance, the
  mean absolute difference of their quantile functions.
- ``spectrum``: ``log(lambda_i * area)`` of the version's ``eigenpairs`` smallest nonzero
  eigenvalues (ShapeDNA, Reuter et al. 2006, on a logarithmic scale), compared by the mean
  absolute difference.
- ``heat``: for each diffusion time ``t = tau * area`` of the version's ``times``, the
  distribution of ``log(area * h_t(x))`` over the surface, h the heat kernel signature;
  1-Wasserstein distance per time.
- ``curvature``: for each scale ``s`` of the version's ``scales``, the area-weighted histogram
  of the angle defect smoothed by heat diffusion for ``s * area`` (`cfsig.operators.curvature`) on the
  mesh (from version 7: on its simplified copy), on ``asinh(value / 10)`` in the version's
  ``bins`` (from version 9: the joint histograms of adjacent scales, near their diagonal);
  L1 distance per histogram. It needs no eigenproblem, only conjugate gradients.

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
   simplified to ``coarse`` faces (`cfsig.repair.simplify`), at a fraction of the eigenproblem's cost;
   phi and the curvature stay on the full mesh, bit for bit version 3's.
5. Version 4 for less work: the curvature's conjugate gradients stopped at 1e-5, in 49 bins.
6. Version 5 with the curvature's conjugate gradients stopped at 1e-3.
7. Every channel on the simplified copy, chosen for noisy scans as well as clean models: 60
   eigenpairs (the heat from all 60) and the curvature at 0.00025 to 0.016 (quadrupling),
   scales at which vertex noise no longer moves it; divisors from SHREC 2007's and FAUST's pairs.
8. Version 7 with 45 eigenpairs, at three quarters of its eigenproblem's cost.
9. Version 8 with the curvature channel as joint histograms of adjacent scales, near their
   diagonal: what a part keeps of its whole, for partial queries (`cfsig.search.partial`).

Only version 1's vector holds phi, so only version 1 solves for it (`solves_phi`); the others
factorise the Laplacian of the mesh, or of its copy, for the spectrum alone.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, replace

import numpy as np

from cfsig.descriptors.cells import Cells, curvature_bins, packed_cells
from cfsig.errors import SolverError
from cfsig.files.mesh import Mesh
from cfsig.operators.conformal import ConformalFactor, Operators, laplacian_solver, operators
from cfsig.operators.curvature import CG_TOLERANCE, smoothed_curvature
from cfsig.operators.spectrum import Spectrum, heat_kernel_signature, laplace_spectrum
from cfsig.repair.simplify import simplified_mesh

QUANTILES = 64
EIGENPAIRS = 30


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
        Divisor of each curvature histogram's distance.
    coarse : int
        Faces of the simplified copy on which the spectrum and heat are computed; 0 computes
        them on the mesh itself.
    bins : int
        Bins of each curvature histogram, or of each axis of the joint ones.
    band : int or None
        Make the curvature channel the joint histograms of adjacent scales within this many
        bins of the diagonal (`curvature_histograms`); None: a histogram per scale.
    fine : (int, int) or None
        Bins and band of the fine cells of all the curvature scales jointly, kept beside the
        vector for partial queries (`cfsig.descriptors.cells.packed_cells`); None keeps none.
    tolerance : float
        Relative residual of the curvature's conjugate gradients.
    predict : bool
        Factorise the curvature's larger scales at once when the conjugate gradients would
        not solve them cheaply (`cfsig.operators.curvature.smoothed_curvature`).
    eigenpairs : int
        Eigenpairs of the spectrum, from which the heat kernel signature is also computed.
    curvature_on_copy : bool
        Compute the curvature channel on the simplified copy rather than on the mesh itself.
    """

    times: tuple[float, ...]
    phi: float | None
    spectrum: float
    heat: tuple[float, ...]
    scales: tuple[float, ...] = ()
    curvature: float = 1.0
    coarse: int = 0
    bins: int = 48
    tolerance: float = CG_TOLERANCE
    predict: bool = False
    eigenpairs: int = EIGENPAIRS
    curvature_on_copy: bool = False
    band: int | None = None
    fine: tuple[int, int] | None = None

    @property
    def length(self) -> int:
        """Length of the descriptor vector."""
        return list(channel_columns(self).values())[-1].stop


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
# Version 5: version 4 for less work, its channels' meaning unchanged (docs/method.md, section
# 13): the curvature's conjugate gradients stop at a relative residual of 1e-5, which moves a
# histogram by about 1e-3 of its mass, and give way to a factorisation as soon as they would
# cost more; 49 bins put zero curvature (flat parts) in the middle of a bin rather than on an
# edge, where round-off would decide its side. Its divisor by version 3's rule on version 5's
# own vectors: `python benchmarks/descriptors.py divisor --version 5`.
DESIGNS[5] = replace(DESIGNS[4], bins=49, tolerance=1e-5, predict=True, curvature=0.015128)
# Version 6: version 5 with the curvature's conjugate gradients stopped at a relative residual of
# 1e-3, the loosest power of ten at which the histograms move, on average over SHREC 2007's and
# FAUST's meshes, by at most 5% of the median distance between two meshes' histograms
# (`python benchmarks/descriptors.py tolerance`; docs/method.md, section 14). Its divisor by
# version 3's rule: `python benchmarks/descriptors.py divisor --version 6`.
DESIGNS[6] = replace(DESIGNS[5], tolerance=1e-3, curvature=0.015126)
# Version 7: every channel on the simplified copy, chosen for scans as well as models by
# `python benchmarks/descriptors.py study7` (docs/descriptors.md, "Version 7"; docs/method.md,
# section 15): 60 eigenpairs, heat weight 1, curvature at 0.00025 to 0.016 (quadrupling) with
# weight 1. Its divisors are the channels' median distances printed there (the spectrum's and
# heat's summed over their entries, the curvature's averaged over its scales), per entry as
# `weigh` divides.
_V7_SCALES = tuple(0.00025 * 4.0**j for j in range(4))
DESIGNS[7] = replace(
    DESIGNS[6],
    spectrum=6.136714 / 60,
    heat=(62.617243 / QUANTILES,) * len(_V2_TIMES),
    scales=_V7_SCALES,
    curvature=0.512178 * len(_V7_SCALES) / DESIGNS[6].bins,
    eigenpairs=60,
    curvature_on_copy=True,
)
# Version 8: version 7 with 45 eigenpairs, the cheapest candidate within 0.01 of version 7's
# objective that meets issue 14's quality bars on SHREC 2007 and FAUST, chosen among copies of
# 1000, 2000, 3000 and 4000 faces and 30, 45 and 60 eigenpairs by `python benchmarks/descriptors.py
# study8` (docs/descriptors.md, "Version 8"; docs/method.md, section 16): the same scales and
# weights, its own spectrum's and heat's medians.
DESIGNS[8] = replace(
    DESIGNS[7],
    spectrum=5.602376 / 45,
    heat=(63.188313 / QUANTILES,) * len(_V2_TIMES),
    eigenpairs=45,
)
# Version 9: version 8 with the curvature channel as the joint histograms of adjacent scales
# within `band` bins of the diagonal, on an odd number of bins per axis so that zero curvature
# lies mid-bin (version 5's reason), chosen for partial queries by `python
# benchmarks/partial_joint.py` (docs/partial.md, "Joint histograms of adjacent scales";
# docs/method.md, section 18). Its divisor by version 7's rule, the channel's median distance
# over SHREC 2007's and FAUST's pairs averaged over its histograms, per entry as `weigh`
# divides: `python benchmarks/descriptors.py divisor --version 9`.
DESIGNS[9] = replace(DESIGNS[8], bins=17, band=2, curvature=0.023645)
# Version 10: version 9's vector, and beside it the fine cells of the four curvature scales
# jointly, 33 bins and steps within 4, for partial queries: the best by version 9's rule (the
# mean NN over SHREC 2007's three kinds of parts) in `python benchmarks/partial_fine.py`
# (docs/partial.md, "Four scales jointly, on finer bins"; docs/method.md, section 19).
DESIGNS[10] = replace(DESIGNS[9], fine=(33, 4))


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


def curvature_histograms(
    values: np.ndarray, weights: np.ndarray, bins: int, band: int | None = None
) -> np.ndarray:
    """Histograms of curvature at scales, the ``curvature`` channel.

    Each vertex falls in its bin of `cfsig.descriptors.cells.curvature_bins`. Without ``band``, one
    histogram per scale; with it, one joint histogram per pair of adjacent scales: where a
    vertex's curvature lies at one scale and at the next, which the per-scale histograms
    forget, the second scale's bin taken relative to the first's and clipped to within
    ``band`` bins of it, where nearly all the mass lies (docs/partial.md, "Joint histograms of
    adjacent scales").

    Parameters
    ----------
    values : (n, k) float64
        `cfsig.operators.curvature.smoothed_curvature` at k scales, dimensionless.
    weights : (n,) float64
        Non-negative vertex weights (areas) with a positive sum.
    bins : int
        Bins per histogram, or per axis of the joint ones (`Design.bins`).
    band : int or None
        Bins either side of the diagonal kept in the joint histograms (`Design.band`); None
        gives the per-scale histograms.

    Returns
    -------
    histograms : (k, bins) or (k - 1, bins * (2 * band + 1)) float64
        Each the fractions of the weight in its bins: per scale, or with ``band`` per pair of
        adjacent scales, the first scale's bin major.
    """
    index = curvature_bins(values, bins)
    width = bins
    if band is not None:
        width = bins * (2 * band + 1)
        first, second = index[:, :-1], index[:, 1:]
        index = first * (2 * band + 1) + np.clip(second - first, -band, band) + band
    fractions = weights / weights.sum()
    counts = [np.bincount(b, weights=fractions, minlength=width) for b in index.T]
    return np.array(counts).reshape(index.shape[1], width)


def curvature_shape(design: Design) -> tuple[int, int]:
    """The shape of a version's `curvature_histograms`.

    Parameters
    ----------
    design : Design
        A version's constants.

    Returns
    -------
    shape : (int, int)
        Histograms, and bins in each: ``(len(scales), bins)``, or with a band
        ``(len(scales) - 1, bins * (2 * band + 1))``.
    """
    if design.band is None:
        return len(design.scales), design.bins
    return len(design.scales) - 1, design.bins * (2 * design.band + 1)


def channels(
    ops: Operators, spectrum: Spectrum, design: Design, phi: np.ndarray | None = None
) -> dict[str, np.ndarray]:
    """The unweighted channels of a mesh.

    Parameters
    ----------
    ops : Operators
        The operators on which the curvature channel is computed: the mesh's
        (`cfsig.operators.conformal.operators`), or its simplified copy's (`Design.curvature_on_copy`).
    spectrum : Spectrum
        Its low spectrum, or its simplified copy's (`spectrum_of`), with ``design.eigenpairs``
        pairs.
    design : Design
        Gives the heat channel's times and the curvature channel's scales, bins and tolerance.
    phi : (n,) float64 or None
        The conformal factor, for the versions whose vector holds it.

    Returns
    -------
    channels : dict
        ``"spectrum"``: (design.eigenpairs,) ``log(lambda_i * area)``; a mesh with fewer nonzero
        eigenvalues repeats its largest. ``"heat"``: (len(times), QUANTILES) quantiles of
        ``log(area * h_t)``. ``"curvature"``: `curvature_histograms` of `curvature_shape`.
        ``"phi"``: (QUANTILES,) quantiles of phi, dimensionless, when ``phi`` is given.
        ``"cells"`` and ``"cell_fractions"``: `cfsig.descriptors.cells.packed_cells` of the curvature, when
        the design keeps them (``design.fine``).

    Raises
    ------
    SolverError
        A curvature diffusion failed.
    """
    weights = ops.vertex_area / ops.vertex_area.sum()
    area = spectrum.area
    scaled = np.log(spectrum.eigenvalues * area)
    scaled = np.concatenate([scaled, np.full(design.eigenpairs - len(scaled), scaled[-1])])
    hks = heat_kernel_signature(spectrum, np.asarray(design.times) * area)
    heat_weights = spectrum.vertex_area / area
    heat = np.array([weighted_quantiles(np.log(area * h), heat_weights, QUANTILES) for h in hks.T])
    curvature = smoothed_curvature(ops, design.scales, design.tolerance, design.predict)
    parts = {
        "spectrum": scaled,
        "heat": heat,
        "curvature": curvature_histograms(curvature, weights, design.bins, design.band),
    }
    if design.fine is not None:
        parts["cells"], parts["cell_fractions"] = packed_cells(
            curvature, ops.vertex_area, *design.fine
        )
    if phi is not None:
        parts["phi"] = weighted_quantiles(phi, weights, QUANTILES)
    return parts


def spectrum_of(
    ops: Operators,
    coarse: Mesh | None = None,
    solve: Callable[[np.ndarray], np.ndarray] | None = None,
    solver: str = "auto",
    count: int = EIGENPAIRS,
) -> tuple[Spectrum, Operators]:
    """The ``count`` smallest nonzero eigenpairs of a mesh, or of its simplified copy.

    Parameters
    ----------
    ops : Operators
        The mesh's operators.
    coarse : Mesh or None
        A simplified copy (`cfsig.repair.simplify.simplified_mesh`), solved with its own
        factorisation; None, or a copy that cannot be solved, takes the mesh itself.
    solve : callable or None
        The mesh's factorised Laplacian when it is known (`ConformalFactor.solve`); None
        factorises it when it is needed.
    solver : {"auto", "cholmod", "eigen", "scipy"}
        Sparse solver backend of the factorisations made here.
    count : int
        Number of eigenpairs.

    Returns
    -------
    spectrum : Spectrum
    surface : Operators
        The operators it was computed on: the copy's, or ``ops``.

    Raises
    ------
    SolverError
        The mesh's factorisation or eigenvalue iteration failed.
    """
    if coarse is not None:
        found = _copy_spectrum(coarse, solver, count)
        if found is not None:
            return found
    if solve is None:
        solve = laplacian_solver(ops.laplacian, ops.labels, solver)
    return _eigenpairs(ops, solve, count), ops


def _copy_spectrum(coarse: Mesh, solver: str, count: int) -> tuple[Spectrum, Operators] | None:
    """The spectrum of a simplified copy, with its own factorisation, and the copy's operators;
    None when the copy cannot be solved (the simplification left it degenerate)."""
    copy = operators(coarse)
    try:
        factor = laplacian_solver(copy.laplacian, copy.labels, solver)
        return _eigenpairs(copy, factor, count), copy
    except SolverError:
        return None


def _eigenpairs(ops: Operators, solve: Callable[[np.ndarray], np.ndarray], count: int) -> Spectrum:
    """`laplace_spectrum` of a mesh's operators with ``count`` pairs."""
    return laplace_spectrum(ops.laplacian, ops.vertex_area, ops.labels, solve, count)


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
            parts["spectrum"] / (design.eigenpairs * design.spectrum),
            (parts["heat"] / (QUANTILES * np.asarray(design.heat)[:, None])).ravel(),
            weigh_curvature(parts["curvature"], design),
        ]
    )


def channel_columns(design: Design) -> dict[str, slice]:
    """Where each channel lies in the descriptor vector (`weigh`'s order).

    Parameters
    ----------
    design : Design
        A version's constants (`DESIGNS`).

    Returns
    -------
    columns : dict of str to slice
        ``"phi"`` (only when the vector holds it), ``"spectrum"``, ``"heat"`` and
        ``"curvature"`` (empty when the version has no scales), in that order, together
        covering ``0`` to ``design.length``.
    """
    sizes = {
        "phi": 0 if design.phi is None else QUANTILES,
        "spectrum": design.eigenpairs,
        "heat": QUANTILES * len(design.times),
        "curvature": int(np.prod(curvature_shape(design))),
    }
    if design.phi is None:
        del sizes["phi"]
    columns, start = {}, 0
    for name, size in sizes.items():
        columns[name] = slice(start, start + size)
        start += size
    return columns


def weigh_curvature(histograms: np.ndarray, design: Design) -> np.ndarray:
    """The curvature channel's part of the descriptor vector.

    Parameters
    ----------
    histograms : (rows, width) float64
        `curvature_histograms` of the design, of `curvature_shape`.
    design : Design
        The version's divisors.

    Returns
    -------
    entries : (rows * width,) float64
        Each histogram entry divided by ``width * design.curvature``, histogram by histogram.
    """
    return (histograms / (histograms.shape[1] * design.curvature)).ravel()


def cfhks_vector(
    mesh: Mesh,
    ops: Operators,
    version: int,
    cf: ConformalFactor | None = None,
    solver: str = "auto",
) -> tuple[np.ndarray, Cells | None]:
    """The ``cfhks`` descriptor of a mesh, and its fine cells when the version keeps them.

    Parameters
    ----------
    mesh : Mesh
        The mesh, simplified for the spectrum (and, from version 7, every channel: `copy_vector`)
        when the version has a ``coarse`` copy.
    ops : Operators
        Its operators (`cfsig.operators.conformal.operators`), for the channels not on the copy.
    version : int
        A key of `DESIGNS`.
    cf : ConformalFactor or None
        Its conformal factor (`conformal.conformal_factor`), needed when the version's vector
        holds phi (`solves_phi`); its factorisation is reused for the spectrum.
    solver : {"auto", "cholmod", "eigen", "scipy"}
        Sparse solver backend of the factorisations made here.

    Returns
    -------
    vector : (DESIGNS[version].length,) float64
        See `weigh`.
    cells : Cells or None
        `cfsig.descriptors.cells.packed_cells` of its curvature, for the versions with ``fine`` cells.

    Raises
    ------
    SolverError
        A factorisation, the eigenvalue iteration or a curvature diffusion failed.
    ValueError
        The version needs phi and ``cf`` is None.
    """
    design = DESIGNS[version]
    if solves_phi(version) and cf is None:
        raise ValueError(f"cfhks version {version} holds phi: give its conformal factor")
    found = copy_vector(mesh, version, solver)
    if found is not None:
        return found
    # Versions 4 to 6 take the spectrum from the copy; a version with every channel on the copy
    # gets here only without a usable copy, and takes the mesh itself.
    coarse = None
    if design.coarse and not design.curvature_on_copy:
        coarse = simplified_mesh(mesh, design.coarse)
    solve = None if cf is None else cf.solve
    spectrum, _ = spectrum_of(ops, coarse, solve, solver, design.eigenpairs)
    phi = cf.phi if cf is not None and solves_phi(version) else None  # else weigh drops it
    return _descriptor(channels(ops, spectrum, design, phi), design)


def copy_vector(
    mesh: Mesh, version: int, solver: str = "auto"
) -> tuple[np.ndarray, Cells | None] | None:
    """The ``cfhks`` descriptor of a mesh from its simplified copy alone, for the versions whose
    channels are all on the copy: the mesh's own operators are not needed.

    Parameters
    ----------
    mesh : Mesh
        The mesh.
    version : int
        A key of `DESIGNS`.
    solver : {"auto", "cholmod", "eigen", "scipy"}
        Sparse solver backend of the copy's factorisation.

    Returns
    -------
    vector, cells : or None
        As `cfhks_vector` returns; None when the version computes a channel on the mesh itself,
        the mesh has no more faces than the copy would, or the copy cannot be solved: then
        `cfhks_vector` with the mesh's operators gives them.

    Raises
    ------
    SolverError
        The eigenvalue iteration or a curvature diffusion of the copy failed.
    """
    design = DESIGNS[version]
    if not (design.coarse and design.curvature_on_copy):
        return None
    coarse = simplified_mesh(mesh, design.coarse)
    found = None if coarse is None else _copy_spectrum(coarse, solver, design.eigenpairs)
    if found is None:
        return None
    spectrum, surface = found
    return _descriptor(channels(surface, spectrum, design), design)


def _descriptor(parts: dict[str, np.ndarray], design: Design) -> tuple[np.ndarray, Cells | None]:
    """The vector of some channels (`weigh`) and their fine cells, if the design keeps them."""
    cells = (parts["cells"], parts["cell_fractions"]) if design.fine is not None else None
    return weigh(parts, design), cells


def solves_phi(version: int) -> bool:
    """Whether a version's vector holds phi, so that computing it needs the conformal solve.

    Parameters
    ----------
    version : int
        A key of `DESIGNS`.

    Returns
    -------
    solves : bool
        True for version 1 only: from version 2 on, phi's weight is 0 (docs/descriptors.md).
    """
    return DESIGNS[version].phi is not None
