"""The descriptor ``rigid``, for collections of rigid objects (furniture, vehicles, tools): the
extrinsic shape that the light field descriptor ``lf`` and the spherical harmonic descriptor
``sh`` see, together with the channels of the default descriptor ``intrinsic``.

The vector holds, computed on the repaired mesh by those descriptors' own functions:

- the heat and curvature channels of the ``intrinsic`` vector
  (`cfsig.descriptors.intrinsic.intrinsic_vector`), each multiplied by its weight in `WEIGHTS`
  over its median in `MEDIANS` (the spectrum's weight came out 0: its entries are left out);
- the ``sh`` vector (`cfsig.descriptors.sh.sh_vector`), multiplied likewise;
- the light field features of ``lf`` (`cfsig.descriptors.lf.light_field_features`) in its
  first `FIELDS` light fields rather than all 10, for the cost (docs/method.md), as they are:
  whole numbers in [0, 255].

The distance of two meshes (`rigid_distances`) is the L1 distance of the first two parts plus
the light field distance of the third (`cfsig.descriptors.lf.lf_distances`) times its weight
over its median: a weighted sum of the four channels' distances, each divided by its median
distance over the pairs of the Princeton Shape Benchmark's training models, so that a weight
tells how much its channel counts. The weights are those of the largest first tier on that
collection (docs/method.md). `rigid_bounds` replaces the light field distance by its lower
bound (`cfsig.descriptors.lf.lf_bounds`), so that searches keep their candidates by it.
"""

from __future__ import annotations

from functools import lru_cache

import numpy as np

from cfsig.descriptors import intrinsic, lf, sh
from cfsig.descriptors.base import Computed, Descriptor, Distance, L1Kernel
from cfsig.files.mesh import Mesh
from cfsig.operators.conformal import ConformalFactor
from cfsig.params import Layout, Params

CHANNELS = ("heat", "curvature", "sh", "lf")
# Each channel's median distance over the pairs of PSB-train's models: the L1 distance of its
# part of the ``intrinsic`` or ``sh`` vector, or ``lf``'s own distance (docs/method.md).
MEDIANS = {"heat": 3.1748, "curvature": 2.0402, "sh": 57.1113, "lf": 4991.0}
# Each channel's weight, chosen by the first tier on PSB-train (docs/method.md).
WEIGHTS = {"heat": 0.125, "curvature": 0.177, "sh": 0.841, "lf": 1.0}
FIELDS = 3  # light fields drawn (docs/method.md)
_HEAT = intrinsic.QUANTILES * len(intrinsic.TIMES)  # entries of the heat channel
_KEPT = intrinsic.LENGTH - intrinsic.EIGENPAIRS  # the heat and curvature entries of intrinsic
HEAD = _KEPT + sh.LENGTH  # the entries compared by L1; the light field features follow
LENGTH = HEAD + FIELDS * lf.VIEWS * lf.FEATURES
# The bound's margin below the distance: the L1 part of the two is summed in float32 by kernels
# that may group the terms differently, and searches round the distance to float32.
_BOUND_MARGIN = 1e-5


def scale(channel: str) -> float:
    """The factor of a channel's distance in the descriptor's distance.

    Parameters
    ----------
    channel : str
        One of `CHANNELS`.

    Returns
    -------
    factor : float
        Its weight over its median distance.
    """
    return WEIGHTS[channel] / MEDIANS[channel]


@lru_cache(maxsize=1)
def head_factors() -> np.ndarray:
    """The factor of each entry of the ``intrinsic`` vector's heat and curvature and of the
    ``sh`` vector in the rigid vector; cached.

    Returns
    -------
    factors : (HEAD,) float64
        Read-only: `scale` of the channel each entry belongs to.
    """
    sizes = {"heat": _HEAT, "curvature": _KEPT - _HEAT, "sh": sh.LENGTH}
    factors = np.concatenate([np.full(size, scale(name)) for name, size in sizes.items()])
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
        ``seed`` (``sh``'s surface samples).
    cf : ConformalFactor or None
        Its conformal factor, when the caller solved it (`intrinsic.intrinsic_vector`).
    solver : {"auto", "cholmod", "eigen", "scipy"}
        Sparse solver backend.

    Returns
    -------
    computed : Computed
        ``vector``: (LENGTH,) float64, the weighed heat and curvature of ``intrinsic`` and
        ``sh`` vector, then the light field features; no cells; the operators ``intrinsic``
        built on the mesh itself, if any.

    Raises
    ------
    SolverError
        As `intrinsic.intrinsic_vector`.
    """
    inner = intrinsic.intrinsic_vector(mesh, params, cf, solver)
    outer = sh.sh_vector(mesh, params, None, solver).vector
    views = lf.light_field_features(mesh, FIELDS)
    head = np.concatenate([inner.vector[intrinsic.EIGENPAIRS :], outer]) * head_factors()
    return Computed(np.concatenate([head, views]), None, inner.operators)


def _parts(
    queries: np.ndarray, rows: np.ndarray, l1: L1Kernel
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The L1 distances of the heads (q, m) float64, and the light field features of both,
    C-contiguous."""
    head = np.empty((len(queries), len(rows)), np.float32)
    l1(np.ascontiguousarray(queries[:, :HEAD]), np.ascontiguousarray(rows[:, :HEAD]), head)
    tails = (np.ascontiguousarray(queries[:, HEAD:]), np.ascontiguousarray(rows[:, HEAD:]))
    return head.astype(np.float64), *tails


def rigid_distances(queries: np.ndarray, rows: np.ndarray, l1: L1Kernel) -> np.ndarray:
    """The ``rigid`` distance between the signatures of some meshes and others.

    Parameters
    ----------
    queries : (q, LENGTH) float32, C-contiguous
        Signatures (`rigid_vector`).
    rows : (m, LENGTH) float32, C-contiguous
        Signatures to compare with.
    l1 : callable
        ``l1(a, b, out)`` fills ``out[i, j]`` with the L1 distance of rows ``a[i]`` and
        ``b[j]`` (`cfsig.search.l1`).

    Returns
    -------
    distances : (q, m) float64
        The L1 distance of the weighed ``intrinsic`` and ``sh`` parts plus the light field
        distance (`lf.lf_distances`) of the light field features times ``scale("lf")``.
    """
    head, mine, theirs = _parts(queries, rows, l1)
    return head + scale("lf") * lf.lf_distances(mine, theirs, l1)


def rigid_bounds(queries: np.ndarray, rows: np.ndarray, l1: L1Kernel) -> np.ndarray:
    """A lower bound of `rigid_distances`, with the light field distance's bound
    (`lf.lf_bounds`) in its place.

    Parameters
    ----------
    queries, rows, l1
        As `rigid_distances` takes them.

    Returns
    -------
    bounds : (q, m) float64
        At most ``rigid_distances(queries, rows, l1)`` rounded to float32, entry by entry: the
        sum is lowered by a relative 1e-5 to absorb the rounding of both.
    """
    head, mine, theirs = _parts(queries, rows, l1)
    return (head + scale("lf") * lf.lf_bounds(mine, theirs, l1)) * (1 - _BOUND_MARGIN)


DESCRIPTOR = Descriptor(
    name="rigid",
    needs_phi=False,
    layout=lambda params: Layout(LENGTH),
    compute=rigid_vector,
    distance=Distance(exact=rigid_distances, bound=rigid_bounds),
)
