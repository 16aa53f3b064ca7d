"""Spikes: single vertices thrown far off the surface, as a scanner's outliers are.

A vertex thrown away from its place drags its faces along into a needle: every one of its
neighbours lies far from it, while they lie close together. One such vertex moves every channel
of a signature (its faces add area and curvature where the surface has none), so the repair
stage puts it back among its neighbours before anything else (docs/method.md, "The repair
stage").
"""

from __future__ import annotations

import numpy as np

from cfsig.files.elements import Edges

# A spike is a needle this many times longer than its base is wide: its nearest neighbour lies
# farther than SPIKE_RATIO times the radius of its neighbours about their mean. Chosen on
# SHREC 2007's copies with shot noise (docs/method.md, "The repair stage").
SPIKE_RATIO = 5.0


def flatten_spikes(vertices: np.ndarray, edges: Edges) -> tuple[np.ndarray, int]:
    """Move each vertex that stands out of the surface as a needle to the mean of its neighbours.

    Parameters
    ----------
    vertices : (n, 3) float64
        Vertex positions.
    edges : Edges
        The mesh's edges (`cfsig.files.elements.mesh_edges`).

    Returns
    -------
    vertices : (n, 3) float64
        The same array when there is no spike, else a copy with the spikes moved. A spike is a
        vertex whose edges all have two faces and whose nearest neighbour is more than
        `SPIKE_RATIO` times farther from it than the farthest neighbour is from their mean.
    count : int
        Spikes moved.
    """
    n = len(vertices)
    ends = edges.ends
    start, end = np.concatenate([ends[:, 0], ends[:, 1]]), np.concatenate([ends[:, 1], ends[:, 0]])
    counts = np.bincount(start, minlength=n)
    inside = counts > 0
    inside[ends[np.diff(edges.starts) != 2].ravel()] = False
    # Offsets from each vertex, not positions: their sums lose no digits to where the mesh lies.
    offsets = vertices[end] - vertices[start]
    lengths = np.linalg.norm(offsets, axis=1)
    degree = np.maximum(counts, 1)
    sums = np.stack([np.bincount(start, offsets[:, k], n) for k in range(3)], axis=1)
    centre = sums / degree[:, None]  # the neighbours' mean, from each vertex
    # The root mean square of the neighbours' distances from their mean is at most the largest:
    # the vertices with no neighbour within the ratio times it, found by sums alone, hold every
    # spike; the largest distance is then taken over their edges only.
    square = np.bincount(start, lengths * lengths, n) / degree
    rms = np.sqrt(np.maximum(square - np.einsum("ij,ij->i", centre, centre), 0))
    near = np.bincount(start, lengths <= SPIKE_RATIO * rms[start], n)
    candidate = inside & (near == 0)
    on = candidate[start]
    radius = np.zeros(n)
    np.maximum.at(radius, start[on], np.linalg.norm(offsets[on] - centre[start[on]], axis=1))
    nearest = np.full(n, np.inf)
    np.minimum.at(nearest, start[on], lengths[on])
    spikes = candidate & (nearest > SPIKE_RATIO * radius)
    count = int(np.count_nonzero(spikes))
    if not count:
        return vertices, 0
    moved = vertices.copy()
    moved[spikes] += centre[spikes]
    return moved, count
