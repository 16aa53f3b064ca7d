"""Partial queries: find the whole shapes that a part of a shape (a cut, a scan) comes from.

The paper names partial matching as the natural extension (section 4). The global channels of
``cfhks`` change when a shape is cut, but its curvature at small scales (`cfsig.curvature`)
changes only near the cut: a part's histograms of it are close to those of the whole it was
cut from, once both are measured at the same scale. That scale is relative to the whole's
area, which a part does not know, so the part is measured for each share ``f`` of `SHARES`:
diffusion times ``s * area / f`` and values divided by ``f``, as if its whole had the area
``area / f``. A whole's partial distance is the smallest L1 distance of its curvature channel
over those shares.

The nearest whole then stands for the part (query expansion): the others are ranked by their
whole-shape distance to it, so a part finds the relatives of its whole as a whole would.
Only ``cfhks`` version 3 and later store the curvature channel (docs/method.md).
"""

from __future__ import annotations

import os

import numpy as np

from .cfhks import DESIGNS, Design, channel_columns, curvature_histograms, weigh_curvature
from .conformal import Operators, operators
from .curvature import smoothed_curvature
from .errors import MeshError, PartialError, SolverError
from .index import IndexReader
from .mesh import Mesh, read_mesh
from .nearest import Hit, l1_distances, nearest
from .params import Params
from .simplify import simplified_mesh

SHARES = tuple(2.0 ** (-j / 2) for j in range(7))  # a part's area over its whole's: 1 to 1/8


def curvature_columns(params: Params) -> slice:
    """The columns of the curvature channel in the signatures that ``params`` make.

    Parameters
    ----------
    params : Params
        Signature parameters.

    Returns
    -------
    columns : slice
        The last ``bins * len(scales)`` columns of the version's design.

    Raises
    ------
    PartialError
        The descriptor has no curvature channel (``cf``, ``cfhks`` before version 3).
    """
    design = DESIGNS.get(params.version or 0) if params.descriptor == "cfhks" else None
    if design is None or not design.scales:
        raise PartialError(
            f"partial queries need the curvature channel of cfhks version 3 or later; this "
            f"index holds {params.descriptor} version {params.version}: rebuild it with "
            f"'cfsig index FOLDER -o NEW --descriptor cfhks'"
        )
    return channel_columns(design)["curvature"]


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
    vectors : (len(SHARES), bins * len(scales)) float64
        Comparable by L1 with the `curvature_columns` of the index's signatures.

    Raises
    ------
    PartialError
        As `curvature_columns`.
    SolverError
        A curvature diffusion failed.
    """
    curvature_columns(params)
    assert params.version is not None  # checked by curvature_columns
    design = DESIGNS[params.version]
    if not design.curvature_on_copy:
        return _share_vectors(operators(mesh, params.mollify), design, SHARES)
    # The wholes' curvature is measured on copies of `coarse` faces (`cfsig.cfhks`): a part
    # that is a share f of its whole is simplified to f times as many. The part's own operators
    # serve the shares it has too few faces to simplify for, built once if any.
    rows, whole = [], None
    for share in SHARES:
        copy = simplified_mesh(mesh, round(design.coarse * share))
        if copy is not None:
            surface = operators(copy)
        else:
            if whole is None:
                whole = operators(mesh, params.mollify)
            surface = whole
        rows.append(_share_vectors(surface, design, (share,)))
    return np.concatenate(rows)


def _share_vectors(ops: Operators, design: Design, shares: tuple[float, ...]) -> np.ndarray:
    """`partial_vectors` of a part's operators for some shares of `SHARES`."""
    fractions = np.asarray(shares)
    scales = np.asarray(design.scales)[None, :] / fractions[:, None]  # (shares, scales)
    # Quadrupling scales over shares a factor 2 apart in area meet: each distinct one once.
    distinct, where = np.unique(scales, return_inverse=True)
    values = smoothed_curvature(ops, tuple(distinct), design.tolerance, design.predict)
    values = values[:, where.reshape(scales.shape)]
    values /= fractions[:, None]
    return np.array(
        [
            weigh_curvature(
                curvature_histograms(values[:, i], ops.vertex_area, design.bins), design
            )
            for i in range(len(shares))
        ]
    )


def partial_search(
    reader: IndexReader, vectors: np.ndarray, k: int = 20
) -> tuple[list[Hit], float]:
    """The whole shapes related to a part: the nearest by its curvature, then its relatives.

    Parameters
    ----------
    reader : IndexReader
        An open index of ``cfhks`` version 3 or later.
    vectors : (len(SHARES), columns) float
        `partial_vectors` of the part, made with the index's parameters.
    k : int
        Results.

    Returns
    -------
    hits : list of Hit
        The nearest whole by partial distance first, then the indexed meshes nearest to that
        whole; each ``distance`` is the whole-shape distance to the first.
    distance : float
        The part's partial distance to the first hit.

    Raises
    ------
    PartialError
        As `curvature_columns`.
    """
    columns = curvature_columns(reader.params)
    rows, dists = nearest(reader, vectors, 1, columns)
    if rows.size == 0:
        return [], float("nan")
    best = int(np.argmin(dists[:, 0]))
    first = int(rows[best, 0])
    near, near_dists = nearest(reader, reader.signatures[np.array([first])], k)
    others = [(int(r), float(d)) for r, d in zip(near[0], near_dists[0], strict=True) if r != first]
    ranked = [(first, 0.0), *others][:k]
    entries = reader.entries(np.array([r for r, _ in ranked]))
    hits = [Hit(i + 1, d, e) for i, ((_, d), e) in enumerate(zip(ranked, entries, strict=True))]
    return hits, float(dists[best, 0])


def partial_file(path: str | os.PathLike, params: Params) -> np.ndarray:
    """Read a part from a file and make its `partial_vectors`.

    The part goes through no repair stage: its cuts and holes are what it is.

    Parameters
    ----------
    path : str or path-like
        An OFF, OBJ, PLY or STL file.
    params : Params
        The index's parameters.

    Returns
    -------
    vectors : (len(SHARES), columns) float64

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
        return partial_vectors(mesh, params)
    except SolverError as exc:
        raise MeshError(f"{path}: {exc}") from None


def partial_distances(vectors: np.ndarray, signatures: np.ndarray, params: Params) -> np.ndarray:
    """The partial distance of a part to every whole of a collection held in memory.

    Parameters
    ----------
    vectors : (len(SHARES), columns) float
        `partial_vectors` of the part.
    signatures : (N, length) float
        The wholes' signatures, made with ``params``.
    params : Params
        Their parameters.

    Returns
    -------
    distances : (N,) float64
        The smallest L1 distance of the curvature channels over the shares.
    """
    stored = np.asarray(signatures, np.float32)[:, curvature_columns(params)]
    return l1_distances(vectors, stored).min(axis=0)


def expanded_distances(vectors: np.ndarray, signatures: np.ndarray, params: Params) -> np.ndarray:
    """Distances that rank a collection held in memory as `partial_search` ranks an index.

    Parameters
    ----------
    vectors : (len(SHARES), columns) float
        `partial_vectors` of the part.
    signatures : (N, length) float
        The wholes' signatures, made with ``params``.
    params : Params
        Their parameters.

    Returns
    -------
    distances : (N,) float64
        -1 for the nearest whole by partial distance, the whole-shape distance to it for the
        others.
    """
    first = int(np.argmin(partial_distances(vectors, signatures, params)))
    distances = l1_distances(signatures[first : first + 1], signatures)[0]
    distances[first] = -1.0
    return distances
