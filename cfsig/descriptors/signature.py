"""The signature of a mesh: repaired, measured by its descriptor (`cfsig.descriptors`), with the
facts reported about it."""

from __future__ import annotations

import hashlib
import os
import time
from dataclasses import dataclass, replace

import numpy as np

from cfsig import descriptors
from cfsig.descriptors.base import Cells
from cfsig.errors import MeshError, SolverError
from cfsig.files.mesh import Mesh, parse_mesh, read_bytes
from cfsig.isolate import Limits
from cfsig.operators.conformal import (
    conformal_factor,
    mesh_components,
)
from cfsig.params import Params
from cfsig.repair.stage import repair_mesh


@dataclass(frozen=True)
class Signature:
    """A mesh's signature and the facts reported about it.

    Attributes
    ----------
    vector : (layout.length,) float64
        The descriptor's vector (`cfsig.descriptors`): its L1 distance to another compares the
        two shapes.
    phi : (n,) float64 or None
        Conformal factor per vertex; None when it was not solved (the descriptor does not need
        it and it was not asked for).
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
        (`cfsig.descriptors.cells.packed_cells`), when `Params.partial_cells`; None otherwise.
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
    descriptor = descriptors.get(params.descriptor)
    mesh = repair_mesh(mesh, params.repair, limits)
    needs_phi = phi or descriptor.needs_phi
    cf = conformal_factor(mesh, params.mollify, solver) if needs_phi else None
    vector, cells, ops = descriptor.compute(mesh, params, cf, solver)
    if ops is None and cf is not None:
        ops = cf.operators
    repairs = mesh.repairs
    if ops is not None and ops.mollified > 0:
        repairs += (f"mollified degenerate triangles (edges +{ops.mollified:.3g})",)
    return mesh, Signature(
        vector,
        None if cf is None else cf.phi,
        len(mesh.vertices),
        len(mesh.faces),
        mesh_components(mesh)[0] if ops is None else ops.n_components,
        float("nan") if cf is None else cf.curvature_error,
        repairs,
        mesh.route,
        time.perf_counter() - start,
        cells=cells,
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
