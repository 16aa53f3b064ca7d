"""A part of a shape (a cut, a scan) measured for partial queries (paper section 4).

The global channels of the ``intrinsic`` descriptor change when a shape is cut, but its
curvature at small scales (`cfsig.operators.curvature`) changes only near the cut: a part's
histograms of it are close to those of the whole it was cut from, once both are measured at the
same scale. That scale is relative to the whole's area, which a part does not know, so the part
is measured for each share ``f`` of `SHARES`: diffusion times ``s * area / f`` and values divided
by ``f``, as if its whole had the area ``area / f``. An index built with `Params.partial_cells`
keeps beside each whole's vector its fine curvature cells (`cfsig.descriptors.cells`): a part is
then measured at the 13 `FINE_SHARES` as cells instead.

A part that holds most of its whole is better told by its whole-shape signature once its holes
are closed: so a part is also measured as a whole, through the repair stage like any file
(`closed_vector`). Both are measured on the part's pieces of at least 1% of its area
(`cfsig.repair.stage.drop_small_pieces`): a scan's stray islands and the slivers a ragged hole
leaves hold no curvature at the part's scales but their rims'. `cfsig.search.partial` ranks the
wholes by what is measured here.
"""

from __future__ import annotations

import os
from dataclasses import dataclass

import numpy as np

from cfsig.descriptors import intrinsic
from cfsig.descriptors.cells import cell_histogram
from cfsig.descriptors.signature import compute_signature
from cfsig.errors import MeshError, PartialError, SolverError
from cfsig.files.elements import face_normals
from cfsig.files.mesh import Mesh, read_mesh
from cfsig.operators.conformal import Operators, operators
from cfsig.operators.curvature import smoothed_curvature
from cfsig.params import Params
from cfsig.repair.simplify import simplified_mesh
from cfsig.repair.stage import drop_small_pieces

SHARES = tuple(2.0 ** (-j / 2) for j in range(7))  # a part's area over its whole's: 1 to 1/8
# The shares at which a part's fine cells are measured (`Part.cells`): a fine histogram moves by
# whole cells when the share is off by a factor sqrt(2), so twice as many, a factor 2^(1/4)
# apart, of which `SHARES` are every other one (studied at commit 35f8114, docs/partial.md).
FINE_SHARES = tuple(2.0 ** (-j / 4) for j in range(13))


@dataclass(frozen=True)
class Part:
    """A part measured with an index's parameters, as a partial query compares it.

    Attributes
    ----------
    vectors : (len(SHARES), columns) float64 or None
        `partial_vectors`: the curvature channel at each share, for an index without fine
        cells; None for one with them.
    cells : tuple of (cells, fractions), or None
        For an index with fine cells (`Params.partial_cells`), the part's
        `cfsig.descriptors.cells.cell_histogram` of all its scales at each share of `FINE_SHARES`:
        cells
        (c,) int64 ascending, fractions (c,) float64 summing to 1; None for the others.
    closed : (intrinsic.LENGTH,) float64 or None
        `closed_vector`: the part's whole-shape signature with its holes closed; None when the
        repair stage or the solver could not make one.
    one_sided : float
        `one_sidedness`, in [0, 1]: 1 for a part every face of which faces one way, as a
        single view does.
    """

    vectors: np.ndarray | None = None
    cells: tuple[tuple[np.ndarray, np.ndarray], ...] | None = None
    closed: np.ndarray | None = None
    one_sided: float = 0.0


def measure_part(mesh: Mesh, params: Params) -> Part:
    """Measure a part as a partial query against an index of ``params`` compares it.

    Parameters
    ----------
    mesh : Mesh
        The part; its boundary may be open.
    params : Params
        The index's parameters.

    Returns
    -------
    part : Part
        Its fine cells at `FINE_SHARES` when ``params`` keep fine cells, else its
        `partial_vectors`; and its `closed_vector`: all of its pieces of at least 1% of its
        area (`cfsig.repair.stage.drop_small_pieces`).

    Raises
    ------
    PartialError
        As `curvature_columns`.
    SolverError
        A curvature diffusion failed.
    """
    curvature_columns(params)
    mesh = drop_small_pieces(mesh)
    closed, one_sided = closed_vector(mesh, params), one_sidedness(mesh)
    if not params.partial_cells:
        return Part(partial_vectors(mesh, params), None, closed, one_sided)
    measured = share_curvatures(mesh, params, FINE_SHARES)
    fine = (intrinsic.FINE_BINS, intrinsic.FINE_BAND)
    cells = tuple(cell_histogram(v, a, *fine) for v, a in measured)
    return Part(None, cells, closed, one_sided)


def one_sidedness(mesh: Mesh) -> float:
    """How nearly a part is a single view of a surface: its faces all turned one way.

    With ``a`` the share of the area whose faces turn toward the area-weighted mean normal,
    ``2 a - 1``: 1 when every face does, as in a depth sensor's single view (every face it
    sees faces it); near 0 for a closed surface or a part that wraps around its object.

    Parameters
    ----------
    mesh : Mesh
        The part.

    Returns
    -------
    one_sided : float
        In [0, 1].
    """
    normals = face_normals(mesh.vertices, mesh.faces)
    areas = np.linalg.norm(normals, axis=1)
    mean = normals.sum(axis=0)
    if not (areas.sum() > 0 and np.linalg.norm(mean) > 0):
        return 0.0
    facing = areas[normals @ mean > 0].sum() / areas.sum()
    return float(np.clip(2 * facing - 1, 0.0, 1.0))


def closed_vector(mesh: Mesh, params: Params) -> np.ndarray | None:
    """The whole-shape signature of a part whose holes the repair stage closes.

    It is what ``cfsig compute`` gives for the part's file: the repair stage closes its cuts
    and holes (`cfsig.repair.stage.repair_mesh`) and the ``intrinsic`` vector is computed on
    that closed surface.

    Parameters
    ----------
    mesh : Mesh
        The part; its boundary may be open.
    params : Params
        The index's parameters.

    Returns
    -------
    vector : (intrinsic.LENGTH,) float64 or None
        None when the repair stage or the solver fails on the part: it is then ranked by its
        curvature alone.
    """
    try:
        return compute_signature(mesh, params).vector
    except (MeshError, SolverError):
        return None


def curvature_columns(params: Params) -> slice:
    """The columns of the curvature channel in the signatures that ``params`` make.

    Parameters
    ----------
    params : Params
        Signature parameters.

    Returns
    -------
    columns : slice
        The curvature group of the intrinsic descriptor's layout.

    Raises
    ------
    PartialError
        The descriptor is not ``intrinsic``, the only one with a curvature channel.
    """
    if params.descriptor != "intrinsic":
        raise PartialError(
            f"partial queries need the curvature channel of the intrinsic descriptor; this "
            f"index holds {params.descriptor}: build one with 'cfsig index FOLDER -o NEW'"
        )
    columns = intrinsic.intrinsic_layout(params).group("curvature")
    assert columns is not None  # the intrinsic layout has it
    return columns


def partial_vectors(mesh: Mesh, params: Params) -> np.ndarray:
    """The curvature channel of a part for each share of `SHARES`, weighed as in the index.

    Parameters
    ----------
    mesh : Mesh
        The part; its boundary may be open.
    params : Params
        The index's parameters.

    Returns
    -------
    vectors : (len(SHARES), columns) float64
        Comparable by L1 with the `curvature_columns` of the index's signatures.

    Raises
    ------
    PartialError
        As `curvature_columns`.
    SolverError
        A curvature diffusion failed.
    """
    curvatures = share_curvatures(mesh, params)
    return np.array(
        [
            intrinsic.weigh_curvature(intrinsic.curvature_histograms(values, areas))
            for values, areas in curvatures
        ]
    )


def share_curvatures(
    mesh: Mesh, params: Params, shares: tuple[float, ...] = SHARES
) -> list[tuple[np.ndarray, np.ndarray]]:
    """The curvature at scales of a part, measured as if it were each share of its whole.

    For a share ``f``, at the diffusion times ``s * area / f`` of the design's scales ``s``, the
    values divided by ``f`` (the module's docstring); `partial_vectors` holds their histograms.

    Parameters
    ----------
    mesh : Mesh
        The part; its boundary may be open.
    params : Params
        The index's parameters.
    shares : tuple of float
        The shares, in (0, 1].

    Returns
    -------
    curvatures : list of (values, areas), one per share
        ``values`` (n, len(scales)) float64, dimensionless, at the vertices of the surface it was
        measured on (the part, or its simplified copy of ``f * coarse`` faces); ``areas`` (n,)
        float64, their vertex areas.

    Raises
    ------
    PartialError
        As `curvature_columns`.
    SolverError
        A curvature diffusion failed.
    """
    curvature_columns(params)
    # The wholes' curvature is measured on copies of `coarse` faces
    # (`cfsig.descriptors.intrinsic`): a part
    # that is a share f of its whole is simplified to f times as many. The part's own operators
    # serve the shares it has too few faces to simplify for, built once if any.
    curvatures, whole = [], None
    for share in shares:
        copy = simplified_mesh(mesh, round(intrinsic.COARSE * share))
        if copy is not None:
            surface = operators(copy)
        else:
            if whole is None:
                whole = operators(mesh, params.mollify)
            surface = whole
        curvatures.append(_share_values(surface, share))
    return curvatures


def _share_values(ops: Operators, share: float) -> tuple[np.ndarray, np.ndarray]:
    """`share_curvatures` of a part's operators for one share."""
    scales = tuple(s / share for s in intrinsic.SCALES)
    return smoothed_curvature(ops, scales) / share, ops.vertex_area


def partial_file(path: str | os.PathLike, params: Params) -> Part:
    """Read a part from a file and measure it (`measure_part`).

    The part goes through no repair stage: its cuts and holes are what it is, and only its
    smallest pieces are dropped (`measure_part`).

    Parameters
    ----------
    path : str or path-like
        An OFF, OBJ, PLY or STL file.
    params : Params
        The index's parameters.

    Returns
    -------
    part : Part

    Raises
    ------
    MeshError
        The file cannot be read or solved; the message names the file.
    PartialError
        As `curvature_columns`.
    """
    curvature_columns(params)
    mesh = read_mesh(path)
    try:
        return measure_part(mesh, params)
    except SolverError as exc:
        raise MeshError(f"{path}: {exc}") from None
