"""The descriptor ``gps``: the global point signature of Rustamov ("Laplace-Beltrami
eigenfunctions for deformation invariant shape representation", SGP 2007), compared as Rustamov
compares shapes, by G2 distributions: the D2 shape distribution of Osada et al. taken in the
GPS embedding, split by patches of that embedding.

The steps, and the choices made where the paper leaves them open (docs/method.md):

- The embedding: ``GPS(p) = (phi_1(p) / sqrt(lambda_1), ..., phi_d(p) / sqrt(lambda_d))`` with
  the `EIGENPAIRS` = d smallest nonzero eigenpairs of ``-L phi = lambda M phi`` (cotangent
  Laplacian, lumped mass matrix, phi M-orthonormal), computed as the ``intrinsic``
  descriptor's are, on a copy of the mesh simplified to `COARSE` faces (the mesh itself when it
  has no more or the copy cannot be solved). With phi M-orthonormal, GPS is dimensionless:
  scaling the surface leaves it unchanged, so no scale normalisation is needed.
- Invariance: each eigenfunction is known up to its sign, and eigenfunctions of one repeated
  eigenvalue up to a rotation among them; both are orthogonal maps of the embedding, which
  keep every distance between two points and every point's distance from the origin (the
  area-weighted centroid of the embedding, since each phi is orthogonal to the constants).
  The G2 distributions see nothing else.
- Samples: `SAMPLES` points uniform over the surface (seeded by `Params.seed`), their GPS
  interpolated from the vertices' (`cfsig.descriptors.cf.sample_phi`).
- Patches: `SHELLS` concentric shells about the origin of the embedding, of equal width out to
  `SHELL_REACH` times the mean distance between two samples (beyond, the last shell).
- Histograms: for each pair of shells, the histogram of the GPS distances between the pairs of
  samples, one in each shell, in `BINS` bins of equal width out to `DISTANCE_REACH` times the
  mean distance (beyond, the last bin); each counts the fraction of all the pairs, so that
  the vector sums to 1. Dividing by the mean distance is Osada's normalisation of D2.

The vector is the ``SHELLS (SHELLS + 1) / 2`` histograms, shell pairs ``(a, b)`` with a <= b in
order of a, then b; it is compared by L1, the distance of Osada's histograms.
"""

from __future__ import annotations

import numpy as np
from scipy.spatial.distance import cdist, pdist

from cfsig.descriptors.base import Computed, Descriptor
from cfsig.descriptors.cf import sample_phi
from cfsig.descriptors.intrinsic import COARSE, spectrum_of
from cfsig.errors import SolverError
from cfsig.files.mesh import Mesh
from cfsig.operators.conformal import ConformalFactor, Operators, operators
from cfsig.operators.spectrum import Spectrum
from cfsig.params import Layout, Params
from cfsig.repair.simplify import simplified_mesh

EIGENPAIRS = 10
SAMPLES = 2048
SHELLS = 8
BINS = 32
SHELL_REACH = 1.5  # the shells span [0, SHELL_REACH * mean distance)
DISTANCE_REACH = 3.0  # the bins span [0, DISTANCE_REACH * mean distance)
PAIRS = SHELLS * (SHELLS + 1) // 2
LENGTH = PAIRS * BINS


def embedding(spectrum: Spectrum) -> np.ndarray:
    """The global point signature of each vertex of a surface.

    Parameters
    ----------
    spectrum : Spectrum
        Its smallest nonzero eigenpairs (`cfsig.descriptors.intrinsic.spectrum_of`).

    Returns
    -------
    gps : (n, k) float64
        ``phi_i / sqrt(lambda_i)`` for its k eigenpairs, dimensionless.
    """
    return spectrum.eigenvectors / np.sqrt(spectrum.eigenvalues)


def g2_distributions(points: np.ndarray) -> np.ndarray:
    """The G2 distributions of points of the GPS embedding.

    Parameters
    ----------
    points : (s, k) float64
        At least two points of the embedding, not all equal.

    Returns
    -------
    histograms : (PAIRS, BINS) float64
        Row of the shell pair (a, b), a <= b: the fractions of all point pairs that have one
        point in shell a and the other in shell b, by distance (module docstring). Sums to 1.
    """
    count = len(points)
    centred = points - points.mean(axis=0)
    # the root mean square distance of two distinct points, from the second moments alone
    scale = np.sqrt(2 * count / (count - 1) * np.einsum("ij,ij->", centred, centred) / count)
    shell = np.linalg.norm(points, axis=1) * (SHELLS / (SHELL_REACH * scale))
    shell = np.minimum(shell, SHELLS - 1).astype(np.intp)
    order = np.argsort(shell, kind="stable")
    ends = np.searchsorted(shell[order], np.arange(SHELLS + 1))
    blocks = [points[order[ends[a] : ends[a + 1]]] for a in range(SHELLS)]
    histograms = np.zeros((PAIRS, BINS))
    row = 0
    for a in range(SHELLS):
        for b in range(a, SHELLS):
            distances = pdist(blocks[a]) if a == b else cdist(blocks[a], blocks[b]).ravel()
            distances *= BINS / (DISTANCE_REACH * scale)
            index = np.minimum(distances, BINS - 1).astype(np.intp)
            histograms[row] = np.bincount(index, minlength=BINS)
            row += 1
    return histograms / (count * (count - 1) / 2)


def gps_vector(mesh: Mesh, params: Params, cf: ConformalFactor | None, solver: str) -> Computed:
    """The ``gps`` descriptor of a mesh.

    Parameters
    ----------
    mesh : Mesh
        The repaired mesh.
    params : Params
        Gives the seed of the surface samples and ``mollify`` (for the mesh's own operators).
    cf : ConformalFactor or None
        Its conformal factor, when the caller solved it: its operators and factorisation serve
        a mesh that is its own copy.
    solver : {"auto", "cholmod", "eigen", "scipy"}
        Sparse solver backend of the factorisations made here.

    Returns
    -------
    computed : Computed
        ``vector``: (LENGTH,) float64, `g2_distributions` row by row; ``operators`` when the
        mesh's own were used; no cells.

    Raises
    ------
    SolverError
        A factorisation or the eigenvalue iteration failed, or the surface's GPS is one point.
    """
    coarse = simplified_mesh(mesh, COARSE)
    if coarse is not None:
        copy = operators(coarse)
        try:
            gps = embedding(spectrum_of(copy, None, solver, EIGENPAIRS))
            return _distributions(coarse, copy, gps, params.seed, None)
        except SolverError:
            pass  # the mesh itself, as the intrinsic descriptor does
    ops = operators(mesh, params.mollify) if cf is None else cf.operators
    gps = embedding(spectrum_of(ops, None if cf is None else cf.solve, solver, EIGENPAIRS))
    return _distributions(mesh, ops, gps, params.seed, ops)


def _distributions(
    surface: Mesh, ops: Operators, gps: np.ndarray, seed: int, own: Operators | None
) -> Computed:
    """The descriptor of a surface from its vertices' GPS; ``own``: the operators reported."""
    points = sample_phi(surface.faces, ops.face_areas, gps, SAMPLES, seed)
    if not np.ptp(points, axis=0).any():
        raise SolverError("the global point signature maps the surface to one point")
    return Computed(g2_distributions(points).ravel(), None, own)


DESCRIPTOR = Descriptor(
    name="gps", needs_phi=False, layout=lambda params: Layout(LENGTH), compute=gps_vector
)
