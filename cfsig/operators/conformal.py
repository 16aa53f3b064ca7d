"""The solve: the conformal factor phi of paper section 2.2, L phi = K^T - K^orig (eq. 1)."""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import numpy as np
import scipy.sparse as sp
import scipy.sparse.linalg as spla

from cfsig.errors import MissingDependencyError, SolverError
from cfsig.files import elements
from cfsig.files.mesh import Mesh
from cfsig.operators import geometry
from cfsig.params import SOLVERS

# The order "auto" tries the backends in: fastest first, as measured by benchmarks/solvers.py.
_PREFERENCE = ("cholmod", "eigen", "scipy")


@dataclass(frozen=True)
class Operators:
    """The discrete operators of a mesh: everything the solve for phi needs.

    Attributes
    ----------
    lengths : (m, 3) float64
        Edge lengths after mollification, opposite each corner.
    mollified : float
        Length added to every edge by the intrinsic mollification (0 if none was needed).
    boundary : (n,) bool
        Boundary vertices.
    curvature : (n,) float64
        Angle defects K^orig, radians.
    face_areas : (m,) float64
        Triangle areas.
    n_components : int
        Number of connected components.
    labels : (n,) int32
        Connected component of each vertex.
    vertex_area : (n,) float64
        Barycentric vertex areas, the lumped mass matrix.
    target : (n,) float64
        Target curvature K^T, radians.
    laplacian : (n, n) scipy.sparse.csc_matrix
        Cotangent Laplacian, negative semidefinite.
    """

    lengths: np.ndarray
    mollified: float
    boundary: np.ndarray
    curvature: np.ndarray
    face_areas: np.ndarray
    n_components: int
    labels: np.ndarray
    vertex_area: np.ndarray
    target: np.ndarray
    laplacian: sp.csc_matrix


@dataclass(frozen=True)
class ConformalFactor:
    """The conformal factor of a mesh and the operators it was solved with.

    Attributes
    ----------
    phi : (n,) float64
        Conformal factor per vertex (dimensionless, log of the length scale), zero mean on every
        connected component.
    operators : Operators
        The mesh's curvature, target curvature, Laplacian, areas and components (`operators`).
    curvature_error : float
        ``||K^T - K^R|| / |V| / pi``, paper section 3.4.
    solve : callable
        The factorised L (`laplacian_solver`: solutions up to a constant per component,
        unchecked), for further solves at the cost of one forward and back substitution each.
    """

    phi: np.ndarray
    operators: Operators
    curvature_error: float
    solve: Callable[[np.ndarray], np.ndarray]


def operators(mesh: Mesh, mollify: float = 1e-5) -> Operators:
    """Curvature, target curvature and cotangent Laplacian of a mesh (paper section 2.2).

    Parameters
    ----------
    mesh : Mesh
        A checked triangle mesh with n vertices and m faces (at most two faces per edge and one
        fan per vertex, as `clean_mesh` makes it).
    mollify : float
        Intrinsic mollification margin relative to the mean edge length (see
        `geometry.mollify`); it changes nothing on meshes without near-degenerate triangles.

    Returns
    -------
    ops : Operators
    """
    n, faces = len(mesh.vertices), mesh.faces
    lengths, delta = geometry.mollify(elements.edge_lengths(mesh.vertices, faces), mollify)
    areas = elements.face_areas(lengths)
    laplacian = geometry.cotan_laplacian(lengths, faces, n, areas, mesh.edges)
    boundary = geometry.boundary_vertices(faces, laplacian)
    curvature = geometry.angle_defect(geometry.corner_angles(lengths), faces, boundary)
    count, labels = mesh_components(mesh, laplacian)
    vertex_area = elements.vertex_areas(areas, faces, n)
    target = geometry.target_curvature(curvature, vertex_area, labels)
    return Operators(
        lengths, delta, boundary, curvature, areas, count, labels, vertex_area, target, laplacian
    )


def mesh_components(mesh: Mesh, graph: sp.spmatrix | None = None) -> tuple[int, np.ndarray]:
    """The connected components of a mesh, as the solve numbers them.

    Parameters
    ----------
    mesh : Mesh
        A checked mesh; its ``parts``, when the repair stage kept them, are the components.
    graph : (n, n) sparse, optional
        A matrix with the mesh's vertex adjacency as its pattern, e.g. its Laplacian, when one
        is at hand: the same graph as ``parts``, so the same numbering; else the edge graph is
        built.

    Returns
    -------
    count : int
        Number of components.
    labels : (n,) int
        Component of each vertex, numbered from 0.
    """
    if mesh.parts is not None:
        return int(mesh.parts.max()) + 1, mesh.parts
    if graph is None:
        graph = elements.edge_graph(mesh.faces, len(mesh.vertices))
    return elements.components(graph)


def conformal_factor(mesh: Mesh, mollify: float = 1e-5, solver: str = "auto") -> ConformalFactor:
    """Compute the discrete conformal factor of a mesh (paper section 2.2).

    Parameters
    ----------
    mesh : Mesh
        A checked triangle mesh with n vertices and m faces.
    mollify : float
        Intrinsic mollification margin, see `operators`.
    solver : {"auto", "cholmod", "eigen", "scipy"}
        Sparse solver backend, see `laplacian_solver`.

    Returns
    -------
    result : ConformalFactor

    Raises
    ------
    SolverError
        The system could not be solved to a finite solution.
    MissingDependencyError
        ``solver="cholmod"`` without a CHOLMOD binding installed.
    """
    ops = operators(mesh, mollify)
    solve = laplacian_solver(ops.laplacian, ops.labels, solver)
    phi = _zero_mean(solve, ops.labels)(ops.target - ops.curvature)
    error = curvature_error(ops.lengths, mesh.faces, ops.boundary, phi, ops.target)
    return ConformalFactor(phi, ops, error, solve)


def curvature_error(
    lengths: np.ndarray,
    faces: np.ndarray,
    boundary: np.ndarray,
    phi: np.ndarray,
    target: np.ndarray,
) -> float:
    """The curvature error of paper section 3.4.

    Scales every edge ij by ``exp(-(phi_i + phi_j) / 2)``, the metric scaling of [BGB08] whose
    linearisation is eq. (1) with our sign of L (phi > 0 on extrusions shrinks them), recomputes
    the angle defects K^R and returns ``||K^T - K^R||_2 / |V|`` in units of pi.

    Parameters
    ----------
    lengths : (m, 3) float64
        Edge lengths, opposite each corner.
    faces : (m, 3) int64
        Triangles.
    boundary : (n,) bool
        Boundary vertices.
    phi : (n,) float64
        Conformal factor.
    target : (n,) float64
        Target curvature K^T in radians.

    Returns
    -------
    error : float
        Dimensionless, in units of pi.
    """
    corner_phi = phi[faces]
    edge_phi = corner_phi[:, [1, 2, 0]] + corner_phi[:, [2, 0, 1]]
    # A face's angles do not change when all three of its lengths are scaled alike, so each
    # face's exponents are taken relative to its smallest: no length grows, none overflows
    # where phi is huge.
    edge_phi -= edge_phi.min(axis=1, keepdims=True)
    scaled = lengths * np.exp(-edge_phi / 2)
    reached = geometry.angle_defect(geometry.corner_angles(scaled), faces, boundary)
    return float(np.linalg.norm(target - reached) / len(phi) / np.pi)


def factorize_laplacian(
    laplacian: sp.spmatrix, labels: np.ndarray, solver: str = "auto"
) -> Callable[[np.ndarray], np.ndarray]:
    """Factorise a cotangent Laplacian once, for solves ``L x = rhs`` with zero mean per component.

    The solutions of `laplacian_solver`, checked, with their mean subtracted per component
    afterwards (the paper's zero-mean condition).

    Parameters
    ----------
    laplacian, labels, solver
        As `laplacian_solver`.

    Returns
    -------
    solve : callable
        ``solve(rhs)`` maps a (n,) float64 right-hand side to the (n,) float64 solution with
        zero mean on every component, raising `SolverError` for non-finite input or output.

    Raises
    ------
    SolverError, ValueError, MissingDependencyError
        As `laplacian_solver`.
    """
    return _zero_mean(laplacian_solver(laplacian, labels, solver), labels)


def _zero_mean(
    solve_pinned: Callable[[np.ndarray], np.ndarray], labels: np.ndarray
) -> Callable[[np.ndarray], np.ndarray]:
    """`factorize_laplacian`'s checked solve with zero mean per component, from
    `laplacian_solver`'s."""
    counts = np.bincount(labels)

    def solve(rhs: np.ndarray) -> np.ndarray:
        if not np.all(np.isfinite(rhs)):
            raise SolverError("the Laplacian or curvature is not finite (degenerate triangles?)")
        try:
            x = solve_pinned(rhs)
        except (RuntimeError, ValueError, ArithmeticError) as exc:
            raise SolverError(f"sparse solve failed: {exc}") from None
        if not np.all(np.isfinite(x)):
            raise SolverError("the sparse solve returned a non-finite solution")
        return x - (np.bincount(labels, weights=x) / counts)[labels]

    return solve


def laplacian_solver(
    laplacian: sp.spmatrix, labels: np.ndarray, solver: str = "auto"
) -> Callable[[np.ndarray], np.ndarray]:
    """Factorise a cotangent Laplacian once, for unchecked solves ``L x = rhs`` up to constants.

    L has one null vector per component (the constants), so one vertex per component is pinned
    to 0 and the remaining symmetric positive definite system ``-L' x' = -rhs'`` is factorised;
    ``rhs`` must sum to zero on every component, so that the pinned equation is implied by the
    others. Neither the right-hand side nor the solution is checked, and no mean is subtracted:
    the Lanczos iteration of `cfsig.operators.spectrum.laplace_spectrum`, about 150 solves,
    projects the
    constants out itself and checks its eigenvalues once (`factorize_laplacian` checks).

    Parameters
    ----------
    laplacian : (n, n) sparse float64
        Symmetric negative semidefinite Laplacian whose null space is the per-component constants.
    labels : (n,) int
        Connected component of each vertex.
    solver : {"auto", "cholmod", "eigen", "scipy"}
        ``"cholmod"``: CHOLMOD's sparse Cholesky (needs the ``cholmod`` extra); ``"eigen"``:
        Eigen's simplicial Cholesky with an AMD ordering, through libigl; ``"scipy"``: SciPy's
        SuperLU with a symmetric minimum-degree ordering; ``"auto"``: the fastest installed
        (see `available_solvers`).

    Returns
    -------
    solve : callable
        ``solve(rhs)`` maps a (n,) float64 right-hand side that sums to zero on every
        component to a (n,) float64 solution, 0 at the first vertex of each component.

    Raises
    ------
    SolverError
        Non-finite Laplacian or a failed factorisation.
    ValueError
        Unknown solver name.
    MissingDependencyError
        ``solver="cholmod"`` and no CHOLMOD binding installed.
    """
    if solver not in SOLVERS:
        raise ValueError(f"unknown solver {solver!r}; choose from {', '.join(SOLVERS)}")
    if not np.all(np.isfinite(laplacian.data)):
        raise SolverError("the Laplacian or curvature is not finite (degenerate triangles?)")
    system, keep = pinned_system(laplacian, labels)
    if not system.shape[0]:  # every component a single vertex: every vertex pinned
        return np.zeros_like
    try:
        factor = factorize(system, solver)
    except (RuntimeError, ValueError, ArithmeticError) as exc:
        raise SolverError(f"sparse solve failed: {exc}") from None
    rows = slice(1, None) if not keep[0] and keep[1:].all() else keep  # one component

    def solve(rhs: np.ndarray) -> np.ndarray:
        x = np.zeros(len(rhs))
        x[rows] = factor(-rhs[rows])
        return x

    return solve


def pinned_system(laplacian: sp.spmatrix, labels: np.ndarray) -> tuple[sp.csc_matrix, np.ndarray]:
    """The symmetric positive definite system left once one vertex per component is pinned.

    Parameters
    ----------
    laplacian : (n, n) sparse float64
        Negative semidefinite Laplacian whose null space is the per-component constants.
    labels : (n,) int
        Connected component of each vertex; the first vertex of each component is pinned.

    Returns
    -------
    system : (k, k) scipy.sparse.csc_matrix
        ``-L`` without the pinned rows and columns, k = n - number of components.
    keep : (n,) bool
        The vertices that remain.
    """
    _, pinned = np.unique(labels, return_index=True)
    keep = np.ones(len(labels), dtype=bool)
    keep[pinned] = False
    if pinned.tolist() == [0]:  # one component: a slice, which SciPy cuts in one pass
        return (-laplacian[1:, 1:]).tocsc(), keep
    return (-laplacian[keep][:, keep]).tocsc(), keep


def available_solvers() -> tuple[str, ...]:
    """Names of the solver backends usable here, in the order ``"auto"`` prefers them.

    Returns
    -------
    names : tuple of str
        A subset of ``("cholmod", "eigen", "scipy")``.
    """
    return tuple(name for name in _PREFERENCE if name != "cholmod" or _cholmod() is not None)


def factorize(matrix: sp.csc_matrix, solver: str) -> Callable[[np.ndarray], np.ndarray]:
    """Factorise a symmetric positive definite matrix with the chosen backend.

    Parameters
    ----------
    matrix : (k, k) scipy.sparse.csc_matrix
        Symmetric positive definite, e.g. from `pinned_system`.
    solver : {"auto", "cholmod", "eigen", "scipy"}
        Backend, see `laplacian_solver`.

    Returns
    -------
    solve : callable
        Maps a right-hand side (k,) float64 to the solution (k,) float64.

    Raises
    ------
    MissingDependencyError
        ``solver="cholmod"`` and no CHOLMOD binding installed.
    RuntimeError
        The matrix is not positive definite (``"cholmod"`` and ``"eigen"``).
    """
    if solver == "auto":
        solver = available_solvers()[0]
    if solver == "cholmod":
        cholesky = _cholmod()
        if cholesky is None:
            raise MissingDependencyError(
                "solver 'cholmod' needs a CHOLMOD binding: pip install 'cfsig[cholmod]'"
            )
        return cholesky(matrix).solve_A
    if solver == "eigen":
        return _eigen_cholesky(matrix)
    lu = spla.splu(matrix, permc_spec="MMD_AT_PLUS_A", options={"SymmetricMode": True})
    return lu.solve


def _eigen_cholesky(matrix: sp.csc_matrix) -> Callable[[np.ndarray], np.ndarray]:
    """Eigen's simplicial Cholesky (AMD ordering) through libigl's min_quad_with_fixed."""
    import igl

    # min_quad_with_fixed minimises z'Az/2 + z'B with no fixed values and no constraints, so
    # A z = -B; it raises RuntimeError when A is not positive definite.
    data = igl.min_quad_with_fixed_data()
    no_rows = np.empty((0, 1))
    constraints = sp.csc_matrix((0, matrix.shape[0]))
    igl.min_quad_with_fixed_precompute(matrix, np.empty(0, np.int64), constraints, True, data)
    return lambda b: igl.min_quad_with_fixed_solve(data, -b[:, None], no_rows, no_rows)[:, 0]


def _cholmod() -> Callable | None:
    """The CHOLMOD factorisation class of sksparse-minimal, or None when not installed."""
    try:
        from sksparse_minimal import SparseCholesky
    except ImportError:
        return None
    return SparseCholesky
