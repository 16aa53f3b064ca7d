"""What a descriptor is: a name, the rows it keeps in an index, and how it computes them."""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from typing import NamedTuple

import numpy as np

from cfsig.files.mesh import Mesh
from cfsig.operators.conformal import ConformalFactor, Operators
from cfsig.params import Layout, Params

# A mesh's fine curvature cells, kept beside its vector for partial queries
# (`cfsig.descriptors.cells.packed_cells`): (slots,) uint16 cells and their (slots,) uint16 shares.
Cells = tuple[np.ndarray, np.ndarray]


# ``l1(a, b, out)`` fills ``out[i, j]`` with the L1 distance of ``a[i]`` and ``b[j]``, all float32
# and C-contiguous (`cfsig.search.l1`, which the search stage passes in).
L1Kernel = Callable[[np.ndarray, np.ndarray, np.ndarray], None]


@dataclass(frozen=True)
class Distance:
    """A descriptor's distance when it is not the L1 distance of its vectors.

    Attributes
    ----------
    exact : callable
        ``exact(queries, rows, l1) -> (q, m) float64``: the distances between signatures
        (q, length) and (m, length), float32 and C-contiguous, given an L1 kernel.
    bound : callable
        ``bound(queries, rows, l1) -> (q, m) float64``: a lower bound of ``exact``, entry by
        entry, much cheaper, by which searches keep their candidates
        (`cfsig.search.nearest.nearest_by`).
    """

    exact: Callable[[np.ndarray, np.ndarray, L1Kernel], np.ndarray]
    bound: Callable[[np.ndarray, np.ndarray, L1Kernel], np.ndarray]


class Computed(NamedTuple):
    """What a descriptor computes for one mesh.

    Attributes
    ----------
    vector : (layout.length,) float64
        The signature vector: the L1 distance of two is the descriptor's distance, unless the
        descriptor declares another (`Descriptor.distance`).
    cells : Cells or None
        Its fine curvature cells, when the parameters keep them (`Params.partial_cells`).
    operators : Operators or None
        The mesh's operators, when they were built (their components and mollification are
        reported); None when the descriptor worked on a simplified copy alone.
    """

    vector: np.ndarray
    cells: Cells | None
    operators: Operators | None


@dataclass(frozen=True)
class Descriptor:
    """One descriptor, as `cfsig.descriptors.get` returns it.

    Attributes
    ----------
    name : str
        Its name in `Params.descriptor`, the command line and an index.
    needs_phi : bool
        Whether its vector is computed from the conformal factor (paper section 2.2), which
        `compute` then receives.
    layout : callable
        ``layout(params) -> Layout``: what an index keeps per row.
    compute : callable
        ``compute(mesh, params, cf, solver) -> Computed`` for a repaired mesh; ``cf`` is its
        `ConformalFactor` when ``needs_phi`` or the caller solved it anyway, else None.
    distance : Distance or None
        How two vectors compare, when not by their L1 distance (None).
    """

    name: str
    needs_phi: bool
    layout: Callable[[Params], Layout]
    compute: Callable[[Mesh, Params, ConformalFactor | None, str], Computed]
    distance: Distance | None = None
