"""Partial queries: find the whole shapes that a part of a shape (a cut, a scan) comes from.

The paper names partial matching as the natural extension (section 4). The global channels of
``cfhks`` change when a shape is cut, but its curvature at small scales (`cfsig.curvature`)
changes only near the cut: a part's histograms of it are close to those of the whole it was
cut from, once both are measured at the same scale. That scale is relative to the whole's
area, which a part does not know, so the part is measured for each share ``f`` of `SHARES`:
diffusion times ``s * area / f`` and values divided by ``f``, as if its whole had the area
``area / f``. A whole's partial distance, over those shares, is the smallest sum of two terms
(`partial_scores`): the share of the part's histograms that the whole's cannot hold (a part is
a subset of its whole's surface), and their L1 distance.

The nearest whole then stands for the part (query expansion): the others are ranked by their
whole-shape distance to it, so a part finds the relatives of its whole as a whole would.
Only ``cfhks`` version 3 and later store the curvature channel (docs/method.md).
"""

from __future__ import annotations

import os
from functools import partial

import numpy as np

from .cfhks import DESIGNS, Design, curvature_histograms, weigh_curvature
from .conformal import Operators, operators
from .curvature import smoothed_curvature
from .errors import MeshError, PartialError, SolverError
from .index import IndexReader
from .mesh import Mesh, read_mesh
from .nearest import Hit, l1_distances, nearest
from .params import Params, curvature_slice
from .simplify import simplified_mesh

SHARES = tuple(2.0 ** (-j / 2) for j in range(7))  # a part's area over its whole's: 1 to 1/8
# The L1 distance's weight beside the unexplained share in `partial_scores`: chosen on SHREC 2007
# alone, the best mean NN of its three kinds of parts (docs/partial.md, "The partial distance's
# weight").
HISTOGRAM_WEIGHT = 1.0


def curvature_columns(params: Params) -> slice:
    """The columns of the curvature channel in the signatures that ``params`` make.

    Parameters
    ----------
    params : Params
        Signature parameters.

    Returns
    -------
    columns : slice
        The last columns, of the size of the version's `cfsig.cfhks.curvature_shape`.

    Raises
    ------
    PartialError
        The descriptor has no curvature channel (``cf``, ``cfhks`` before version 3).
    """
    columns = curvature_slice(params)
    if columns is None:
        raise PartialError(
            f"partial queries need the curvature channel of cfhks version 3 or later; this "
            f"index holds {params.descriptor} version {params.version}: rebuild it with "
            f"'cfsig index FOLDER -o NEW --descriptor cfhks'"
        )
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
    assert params.version is not None  # checked by share_curvatures
    design = DESIGNS[params.version]
    return np.array(
        [
            weigh_curvature(curvature_histograms(values, areas, design.bins, design.band), design)
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
    assert params.version is not None  # checked by curvature_columns
    design = DESIGNS[params.version]
    if not design.curvature_on_copy:
        return _share_values(operators(mesh, params.mollify), design, shares)
    # The wholes' curvature is measured on copies of `coarse` faces (`cfsig.cfhks`): a part
    # that is a share f of its whole is simplified to f times as many. The part's own operators
    # serve the shares it has too few faces to simplify for, built once if any.
    curvatures, whole = [], None
    for share in shares:
        copy = simplified_mesh(mesh, round(design.coarse * share))
        if copy is not None:
            surface = operators(copy)
        else:
            if whole is None:
                whole = operators(mesh, params.mollify)
            surface = whole
        curvatures += _share_values(surface, design, (share,))
    return curvatures


def _share_values(
    ops: Operators, design: Design, shares: tuple[float, ...]
) -> list[tuple[np.ndarray, np.ndarray]]:
    """`share_curvatures` of a part's operators for some shares."""
    fractions = np.asarray(shares)
    scales = np.asarray(design.scales)[None, :] / fractions[:, None]  # (shares, scales)
    # Quadrupling scales over shares a factor 2 apart in area meet: each distinct one once.
    distinct, where = np.unique(scales, return_inverse=True)
    values = smoothed_curvature(ops, tuple(distinct), design.tolerance, design.predict)
    values = values[:, where.reshape(scales.shape)]
    values /= fractions[:, None]
    return [(values[:, i], ops.vertex_area) for i in range(len(shares))]


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
    score = partial(partial_scores, mass=float(vectors[0].sum()))
    rows, dists = nearest(reader, share_queries(vectors), 1, columns, score)
    if rows.size == 0:
        return [], float("nan")
    first = int(rows[0, 0])
    near, near_dists = nearest(reader, reader.signatures[np.array([first])], k)
    others = [(int(r), float(d)) for r, d in zip(near[0], near_dists[0], strict=True) if r != first]
    ranked = [(first, 0.0), *others][:k]
    entries = reader.entries(np.array([r for r, _ in ranked]))
    hits = [Hit(i + 1, d, e) for i, ((_, d), e) in enumerate(zip(ranked, entries, strict=True))]
    return hits, float(dists[0, 0])


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
        `partial_scores` of the wholes.
    """
    stored = np.asarray(signatures, np.float32)[:, curvature_columns(params)]
    distances = l1_distances(share_queries(vectors), stored)
    return partial_scores(distances, float(vectors[0].sum()))


def share_queries(vectors: np.ndarray) -> np.ndarray:
    """The rows whose L1 distances to the wholes `partial_scores` takes.

    Parameters
    ----------
    vectors : (len(SHARES), columns) float
        `partial_vectors` of a part.

    Returns
    -------
    queries : (2 * len(SHARES), columns) float64
        Each share's vector times the share, then the vectors as they are.
    """
    return np.concatenate([np.asarray(SHARES)[:, None] * vectors, vectors])


def partial_scores(
    distances: np.ndarray, mass: float, weight: float = HISTOGRAM_WEIGHT
) -> np.ndarray:
    """The partial distance of each whole: unexplained share plus L1 distance, at the best share.

    For a part ``p`` measured as the share ``f`` of a whole ``w`` (histograms of equal mass
    ``m``), the part's histograms scaled by ``f`` lie under its whole's, bin for bin, as its
    surface lies within the whole's. The unexplained share ``sum(max(f p - w, 0)) / (f m)``, in
    [0, 1], measures how far they do not; alone it would favour the smallest shares, which
    explain least, so ``weight`` times the L1 distance ``sum|p - w| / m``, in [0, 2],
    is added. Since ``sum|f p - w| = 2 sum(max(f p - w, 0)) + (1 - f) m``, both terms come
    from L1 distances, which the blockwise search computes.

    Parameters
    ----------
    distances : (2 * len(SHARES), N) float
        L1 distances of the part's `share_queries` to the curvature columns of N wholes.
    mass : float
        The sum of one of the part's `partial_vectors`, which equals a whole's.
    weight : float
        The L1 distance's weight (`HISTOGRAM_WEIGHT`).

    Returns
    -------
    scores : (N,) float, of ``distances``'s type
        The smallest sum over the shares, dimensionless, in [0, 3].
    """
    shares = np.asarray(SHARES, distances.dtype)[:, None]
    scaled, plain = distances[: len(SHARES)], distances[len(SHARES) :]
    unexplained = np.maximum(scaled - (1 - shares) * mass, 0) / (2 * shares * mass)
    return (unexplained + weight * plain / mass).min(axis=0)


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
