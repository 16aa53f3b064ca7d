"""The signature: a histogram of phi sampled uniformly over the surface (paper section 2.3).

It is the ``cf`` descriptor; `signature_of` also makes the other descriptors of `DESCRIPTORS`
(docs/descriptors.md). Every descriptor is a vector whose L1 distance is the descriptor's
distance. The conformal factor is solved when the descriptor's vector holds it (`needs_phi`) or
when a caller asks for it.
"""

from __future__ import annotations

import hashlib
import os
import time
from dataclasses import dataclass, replace

import numpy as np

from cfsig.descriptors.cells import Cells
from cfsig.descriptors.intrinsic import cfhks_vector, copy_vector, solves_phi
from cfsig.errors import MeshError, SolverError
from cfsig.files.mesh import Mesh, parse_mesh, read_bytes
from cfsig.isolate import Limits
from cfsig.operators.conformal import (
    ConformalFactor,
    Operators,
    conformal_factor,
    mesh_components,
    operators,
)
from cfsig.params import Params
from cfsig.repair.stage import repair_mesh


@dataclass(frozen=True)
class Signature:
    """A mesh's signature and the facts reported about it.

    Attributes
    ----------
    vector : (signature_length(params),) float64
        The signature vector: for ``cf`` the histogram of phi, summing to 1; for another
        descriptor its vector (`signature_of`).
    phi : (n,) float64 or None
        Conformal factor per vertex; None when it was not solved (`needs_phi`).
    n_vertices, n_faces, n_components : int
        Size of the mesh after repairs.
    curvature_error : float
        Paper section 3.4, in units of pi; NaN when phi was not solved.
    repairs : tuple of str
        Repairs made on reading and by the repair stage, in words.
    route : str
        The repair stage's route (`cfsig.repair.stage.repair_mesh`): ``"clean"``, ``"repaired"``,
        ``"proxy"`` or ``"unrepaired"``.
    seconds : float
        Wall time from reading to histogram.
    sha256 : str
        Hash of the file's bytes ("" for an in-memory mesh).
    cells : Cells or None
        The fine curvature cells kept beside the vector for partial queries
        (`cfsig.descriptors.cells.packed_cells`), by ``cfhks`` version 10 and later; None otherwise.
    """

    vector: np.ndarray
    phi: np.ndarray | None
    n_vertices: int
    n_faces: int
    n_components: int
    curvature_error: float
    repairs: tuple[str, ...]
    route: str
    seconds: float
    sha256: str = ""
    cells: Cells | None = None

    @property
    def phi_range(self) -> tuple[float, float]:
        """The smallest and largest phi; NaN when phi was not solved."""
        if self.phi is None:
            return float("nan"), float("nan")
        return float(self.phi.min()), float(self.phi.max())


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
    phi : (n,) float64
        Values at the vertices.
    count : int
        Number of samples.
    seed : int
        Seed of NumPy's PCG64 generator: the same inputs give the same samples bit for bit.

    Returns
    -------
    samples : (count,) float64
        Interpolated phi values, grouped by face in face order.
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
    # phi = c0 + r1 ((c1 - c0) + r2 (c2 - c1)) with r1 = sqrt(u1), r2 = u2 (uniform points)
    r1 = np.sqrt(rng.random(count))
    samples = rng.random(count)
    samples *= (corner[:, 2] - corner[:, 1])[face]
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


def needs_phi(params: Params) -> bool:
    """Whether the signatures that ``params`` make hold the conformal factor.

    Parameters
    ----------
    params : Params
        Signature parameters.

    Returns
    -------
    needs : bool
        True for ``cf`` and ``cfhks`` version 1 (`cfhks.solves_phi`).
    """
    return params.descriptor == "cf" or solves_phi(params.version or 0)


def signature_of(
    mesh: Mesh,
    ops: Operators,
    params: Params,
    cf: ConformalFactor | None = None,
    solver: str = "auto",
) -> np.ndarray:
    """The signature vector of a mesh, for ``params.descriptor``.

    Parameters
    ----------
    mesh : Mesh
        The mesh.
    ops : Operators
        Its operators (`conformal.operators`).
    params : Params
        Signature parameters.
    cf : ConformalFactor or None
        Its conformal factor (`conformal_factor`), needed when `needs_phi`.
    solver : {"auto", "cholmod", "eigen", "scipy"}
        Sparse solver backend of the factorisations ``cfhks`` makes.

    Returns
    -------
    signature : (signature_length(params),) float64
        For ``cf``: the histogram of phi at ``samples_per_face * m`` surface samples plus the
        vertices, summing to 1. For ``cfhks``: `cfhks.cfhks_vector`.

    Raises
    ------
    SolverError
        ``cfhks`` only: a factorisation, the eigenvalue iteration or a diffusion failed.
    ValueError
        ``cf`` is None and `needs_phi`.
    """
    return _vector_and_cells(mesh, ops, params, cf, solver)[0]


def _vector_and_cells(
    mesh: Mesh, ops: Operators, params: Params, cf: ConformalFactor | None, solver: str
) -> tuple[np.ndarray, Cells | None]:
    """`signature_of`, and the fine cells of the ``cfhks`` versions that keep them."""
    if params.descriptor == "cfhks":
        assert params.version is not None  # resolved by Params.__post_init__
        return cfhks_vector(mesh, ops, params.version, cf, solver)
    if cf is None:
        raise ValueError("the cf descriptor is a histogram of phi: give its conformal factor")
    phi = cf.phi
    if params.normalize:
        span = np.ptp(phi)
        phi = (phi - phi.min()) / span if span > 0 else np.zeros_like(phi)
    faces = mesh.faces
    samples = sample_phi(
        faces, ops.face_areas, phi, params.samples_per_face * len(faces), params.seed
    )
    return histogram(np.concatenate([samples, phi]), params), None


def compute_signature(
    mesh: Mesh,
    params: Params,
    solver: str = "auto",
    phi: bool = False,
    limits: Limits | None = None,
) -> Signature:
    """Repair, conformal factor and signature of an in-memory mesh.

    Parameters
    ----------
    mesh : Mesh
        A checked mesh, as `read_mesh` or `clean_mesh` return; it goes through
        `cfsig.repair.stage.repair_mesh` with ``params.repair`` first.
    params : Params
        Signature parameters.
    solver : {"auto", "cholmod", "eigen", "scipy"}
        Sparse solver backend.
    phi : bool
        Solve for the conformal factor even when the descriptor does not need it.
    limits : Limits, optional
        Wall time and memory allowed to the repair stage's proxy remesh (default `Limits()`).

    Returns
    -------
    signature : Signature

    Raises
    ------
    MeshError
        The repair stage failed (`cfsig.repair.stage.repair_mesh`).
    SolverError, MissingDependencyError
        As `conformal_factor` and `signature_of`.
    """
    return _repair_and_sign(mesh, params, solver, phi, limits)[1]


def _repair_and_sign(
    mesh: Mesh, params: Params, solver: str, phi: bool, limits: Limits | None
) -> tuple[Mesh, Signature]:
    """`compute_signature`, also returning the repaired mesh that phi lives on."""
    start = time.perf_counter()
    mesh = repair_mesh(mesh, params.repair, limits)
    cf = conformal_factor(mesh, params.mollify, solver) if phi or needs_phi(params) else None
    ops, found, repairs = None, None, mesh.repairs
    if cf is None and params.descriptor == "cfhks":
        assert params.version is not None  # resolved by Params.__post_init__
        found = copy_vector(mesh, params.version, solver)  # no need for the mesh's operators
    if found is None:
        ops = operators(mesh, params.mollify) if cf is None else cf.operators
        found = _vector_and_cells(mesh, ops, params, cf, solver)
        if ops.mollified > 0:
            repairs += (f"mollified degenerate triangles (edges +{ops.mollified:.3g})",)
    return mesh, Signature(
        found[0],
        None if cf is None else cf.phi,
        len(mesh.vertices),
        len(mesh.faces),
        mesh_components(mesh)[0] if ops is None else ops.n_components,
        float("nan") if cf is None else cf.curvature_error,
        repairs,
        mesh.route,
        time.perf_counter() - start,
        cells=found[1],
    )


def signature_file(
    path: str | os.PathLike, params: Params, solver: str = "auto", limits: Limits | None = None
) -> Signature:
    """Read a mesh file and compute its signature.

    Parameters
    ----------
    path : str or path-like
        An OFF, OBJ, PLY or STL file.
    params : Params
        Signature parameters.
    solver : {"auto", "cholmod", "eigen", "scipy"}
        Sparse solver backend.
    limits : Limits, optional
        As `compute_signature`.

    Returns
    -------
    signature : Signature
        With ``sha256`` of the file's bytes and ``seconds`` including the reading.

    Raises
    ------
    MeshError
        The file cannot be read or gives no finite signature; the message names the file.
    """
    return mesh_and_signature(path, params, solver, limits=limits)[1]


def mesh_and_signature(
    path: str | os.PathLike,
    params: Params,
    solver: str = "auto",
    phi: bool = False,
    limits: Limits | None = None,
) -> tuple[Mesh, Signature]:
    """Read a mesh file and compute its signature, keeping the mesh (e.g. to draw phi on it).

    Parameters
    ----------
    path : str or path-like
        An OFF, OBJ, PLY or STL file.
    params : Params
        Signature parameters.
    solver : {"auto", "cholmod", "eigen", "scipy"}
        Sparse solver backend.
    phi : bool
        Solve for the conformal factor even when the descriptor does not need it.
    limits : Limits, optional
        As `compute_signature`.

    Returns
    -------
    mesh : Mesh
        The mesh as read and through the repair stage; ``signature.phi``, when solved, has one
        value per vertex of it.
    signature : Signature
        As `signature_file` returns.

    Raises
    ------
    MeshError
        As `signature_file`.
    """
    start = time.perf_counter()
    data = read_bytes(path)
    mesh = parse_mesh(data, path)
    try:
        mesh, sig = _repair_and_sign(mesh, params, solver, phi, limits)
    except MeshError as exc:  # its subclasses too (a stage past its limits)
        raise type(exc)(f"{path}: {exc}") from None
    except SolverError as exc:
        raise MeshError(f"{path}: {exc}") from None
    seconds = time.perf_counter() - start
    return mesh, replace(sig, seconds=seconds, sha256=hashlib.sha256(data).hexdigest())
