"""The descriptor ``rigid``, for collections of rigid objects (furniture, vehicles, tools): the
extrinsic shape that panoramic projections and the light field descriptor ``lf`` see, together
with the channels of the default descriptor ``intrinsic``.

The vector holds, computed on the repaired mesh:

- the heat and curvature channels of the ``intrinsic`` vector
  (`cfsig.descriptors.intrinsic.intrinsic_vector`), each divided by its median in `MEDIANS`
  (the spectrum's best weight was 0: its entries are left out);
- the panoramic features (`cfsig.descriptors.panorama.panorama_features`) of the surface
  samples that ``sh`` draws (`cfsig.descriptors.sh.surface_samples`);
- the light field features of ``lf`` (`cfsig.descriptors.lf.light_field_features`) in its
  first `FIELDS` light fields rather than all 10, for the cost, as they are: whole numbers in
  [0, 255].

The distance of two meshes (`rigid_distances`) is ``sum_c WEIGHTS[c] * (d_c / m_c) ** POWER``
over the four channels (`channel_distances`): d_c the channel's distance (the L1 distance of
its entries, `cfsig.descriptors.panorama.panorama_distances` for the panorama, the light
field distance `cfsig.descriptors.lf.lf_distances` for ``lf``), m_c its median distance over
the pairs of the Princeton Shape Benchmark's training models. The power, below 1, keeps one
channel's large disagreement from outweighing the others' agreement. Power and weights are
those of the largest first tier on that collection (docs/method.md). `rigid_bounds` puts the
light field distance's lower bound (`cfsig.descriptors.lf.lf_bounds`) in its place, so that
searches keep their candidates by it.
"""

from __future__ import annotations

from functools import lru_cache

import numpy as np

from cfsig.descriptors import intrinsic, lf, panorama, sh
from cfsig.descriptors.base import Computed, Descriptor, Distance, L1Kernel
from cfsig.files.mesh import Mesh
from cfsig.operators.conformal import ConformalFactor
from cfsig.params import Layout, Params

CHANNELS = ("heat", "curvature", "panorama", "lf")
# Each channel's median distance over the pairs of PSB-train's models: the L1 distance of its
# part of the ``intrinsic`` vector, or the panorama's and ``lf``'s own distance (docs/method.md).
MEDIANS = {"heat": 3.2228, "curvature": 2.0333, "panorama": 8.5568, "lf": 5030.0}
# Each channel's weight, and the power of the normalised distances, chosen by the first tier
# on PSB-train (docs/method.md).
WEIGHTS = {"heat": 0.074, "curvature": 0.354, "panorama": 2.378, "lf": 0.595}
POWER = 0.3
FIELDS = 3  # light fields drawn (docs/method.md)
_HEAT = intrinsic.QUANTILES * len(intrinsic.TIMES)  # entries of the heat channel
HEAD = intrinsic.LENGTH - intrinsic.EIGENPAIRS  # the heat and curvature entries of intrinsic
PANORAMA = slice(HEAD, HEAD + panorama.LENGTH)  # the panoramic features
LIGHTS = slice(PANORAMA.stop, PANORAMA.stop + FIELDS * lf.VIEWS * lf.FEATURES)  # lf's features
LENGTH = LIGHTS.stop
# The columns of the channels compared by L1.
COLUMNS = {"heat": (0, _HEAT), "curvature": (_HEAT, HEAD)}
# The bound's margin below the distance: a channel's L1 distance is summed in float32 by kernels
# that may group the terms differently, and searches round the distance to float32.
_BOUND_MARGIN = 1e-5


@lru_cache(maxsize=1)
def head_factors() -> np.ndarray:
    """The factor of each entry of the ``intrinsic`` vector's heat and curvature in the rigid
    vector: the inverse of its channel's median; cached.

    Returns
    -------
    factors : (HEAD,) float64
        Read-only.
    """
    factors = np.concatenate(
        [np.full(stop - start, 1 / MEDIANS[name]) for name, (start, stop) in COLUMNS.items()]
    )
    factors.flags.writeable = False
    return factors


def rigid_vector(mesh: Mesh, params: Params, cf: ConformalFactor | None, solver: str) -> Computed:
    """The ``rigid`` descriptor of a mesh.

    Parameters
    ----------
    mesh : Mesh
        The repaired mesh.
    params : Params
        Gives ``mollify`` (``intrinsic``'s operators on a mesh that is its own copy) and
        ``seed`` (the surface samples of the panoramas).
    cf : ConformalFactor or None
        Its conformal factor, when the caller solved it (`intrinsic.intrinsic_vector`).
    solver : {"auto", "cholmod", "eigen", "scipy"}
        Sparse solver backend.

    Returns
    -------
    computed : Computed
        ``vector``: (LENGTH,) float64, the heat and curvature of ``intrinsic`` times
        `head_factors`, the panoramic features, then the light field features; no cells; the
        operators ``intrinsic`` built on the mesh itself, if any.

    Raises
    ------
    SolverError
        As `intrinsic.intrinsic_vector`.
    """
    inner = intrinsic.intrinsic_vector(mesh, params, cf, solver)
    around = panorama.panorama_features(*sh.surface_samples(mesh.vertices, mesh.faces, params.seed))
    views = lf.light_field_features(mesh, FIELDS)
    head = inner.vector[intrinsic.EIGENPAIRS :] * head_factors()
    return Computed(np.concatenate([head, around, views]), None, inner.operators)


def channel_distances(
    queries: np.ndarray, rows: np.ndarray, l1: L1Kernel, bound: bool = False
) -> dict[str, np.ndarray]:
    """Each channel's distance between the signatures of some meshes and others, over its
    median.

    Parameters
    ----------
    queries, rows : (q, LENGTH) and (m, LENGTH) float32, C-contiguous
        Signatures (`rigid_vector`) to compare.
    l1 : L1Kernel
        The L1 distances of rows (`cfsig.descriptors.base.L1Kernel`).
    bound : bool
        Put the light field distance's lower bound (`lf.lf_bounds`) in its place.

    Returns
    -------
    distances : dict of str to (q, m) float64
        For each of `CHANNELS`, ``d_c / MEDIANS[c]``: d_c the L1 distance of its columns
        (already divided by its median), `panorama.panorama_distances` of the panoramic
        features, or `lf.lf_distances` of the light field features.
    """
    out = {}
    for name, (start, stop) in COLUMNS.items():
        part = np.empty((len(queries), len(rows)), np.float32)
        l1(*_columns(queries, rows, slice(start, stop)), part)
        out[name] = part.astype(np.float64)
    around = panorama.panorama_distances(*_columns(queries, rows, PANORAMA), l1)
    out["panorama"] = around / MEDIANS["panorama"]
    light = (lf.lf_bounds if bound else lf.lf_distances)(*_columns(queries, rows, LIGHTS), l1)
    out["lf"] = light / MEDIANS["lf"]
    return out


def _columns(
    queries: np.ndarray, rows: np.ndarray, columns: slice
) -> tuple[np.ndarray, np.ndarray]:
    """Some columns of two sets of signatures, C-contiguous."""
    return np.ascontiguousarray(queries[:, columns]), np.ascontiguousarray(rows[:, columns])


def weighed(distances: dict[str, np.ndarray]) -> np.ndarray:
    """``sum_c WEIGHTS[c] * distances[c] ** POWER``.

    Parameters
    ----------
    distances : dict of str to (q, m) float64
        Each channel's normalised distance (`channel_distances`).

    Returns
    -------
    distances : (q, m) float64
    """
    total = np.zeros_like(distances["lf"])
    for name, weight in WEIGHTS.items():
        total += weight * distances[name] ** POWER
    return total


def rigid_distances(queries: np.ndarray, rows: np.ndarray, l1: L1Kernel) -> np.ndarray:
    """The ``rigid`` distance between the signatures of some meshes and others.

    Parameters
    ----------
    queries, rows, l1
        As `channel_distances` takes them.

    Returns
    -------
    distances : (q, m) float64
        `weighed` `channel_distances`.
    """
    return weighed(channel_distances(queries, rows, l1))


def rigid_bounds(queries: np.ndarray, rows: np.ndarray, l1: L1Kernel) -> np.ndarray:
    """A lower bound of `rigid_distances`, with the light field distance's bound
    (`lf.lf_bounds`) in its place (the power is increasing).

    Parameters
    ----------
    queries, rows, l1
        As `channel_distances` takes them.

    Returns
    -------
    bounds : (q, m) float64
        At most ``rigid_distances(queries, rows, l1)`` rounded to float32, entry by entry: the
        sum is lowered by a relative 1e-5 to absorb the rounding of both.
    """
    return weighed(channel_distances(queries, rows, l1, bound=True)) * (1 - _BOUND_MARGIN)


DESCRIPTOR = Descriptor(
    name="rigid",
    needs_phi=False,
    layout=lambda params: Layout(LENGTH),
    compute=rigid_vector,
    distance=Distance(exact=rigid_distances, bound=rigid_bounds),
)
