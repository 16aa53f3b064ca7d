"""Checks on the SHREC 2007 meshes; skipped when they are not unpacked beside the project."""

import numpy as np
import pytest
import scipy.sparse as sp
from scipy.sparse.csgraph import dijkstra

from cfsig.files import elements
from cfsig.files.mesh import read_mesh
from cfsig.operators.conformal import conformal_factor


def _mean_geodesic(mesh, sources=30):
    """Mean graph distance of every vertex to a fixed random set of vertices."""
    n = len(mesh.vertices)
    edges, _ = elements.edge_face_counts(mesh.faces, n)
    w = np.linalg.norm(mesh.vertices[edges[:, 0]] - mesh.vertices[edges[:, 1]], axis=1)
    graph = sp.coo_matrix((w, (edges[:, 0], edges[:, 1])), shape=(n, n)).tocsr()
    picked = np.random.default_rng(0).choice(n, sources, replace=False)
    return dijkstra(graph, directed=False, indices=picked).mean(axis=0)


@pytest.mark.parametrize("cls", ["hand", "human"])
def test_phi_largest_on_extrusions(shrec07, cls):
    # Section 3.1: phi is positive on long extrusions (finger tips, hands and feet). The vertex
    # of largest phi must be among the 20% of vertices farthest, along the surface, from the rest.
    for path in sorted((shrec07 / cls).glob("*.off")):
        mesh = read_mesh(path)
        phi = conformal_factor(mesh).phi
        remote = _mean_geodesic(mesh)
        top = np.argmax(phi)
        assert phi[top] > 0
        assert (remote < remote[top]).mean() >= 0.8, path.name
