import igl
import numpy as np
import pytest
import scipy.sparse as sp

from cfsig.files import elements
from cfsig.operators import geometry
from tests.helpers import disk, icosphere, open_cylinder, torus


def _curvature(v, f):
    lengths = elements.edge_lengths(v, f)
    boundary = geometry.boundary_vertices(f, geometry.cotan_laplacian(lengths, f, len(v)))
    return geometry.angle_defect(geometry.corner_angles(lengths), f, boundary)


@pytest.mark.parametrize(
    ("mesh", "chi"),
    [(icosphere(2), 2), (torus(), 0), (disk(), 1), (open_cylinder(), 0)],
    ids=["sphere", "torus", "disk", "cylinder"],
)
def test_gauss_bonnet(mesh, chi):
    v, f = mesh
    assert _curvature(v, f).sum() == pytest.approx(2 * np.pi * chi, abs=1e-9)


def test_boundary_curvature_is_pi_minus_angles():
    v, f = disk()
    k = _curvature(v, f)
    lap = geometry.cotan_laplacian(elements.edge_lengths(v, f), f, len(v))
    boundary = geometry.boundary_vertices(f, lap)
    assert boundary.sum() == 32
    assert np.array_equal(np.flatnonzero(boundary), np.arange(len(v) - 32, len(v)))  # the rim
    # A flat disk: interior vertices have zero curvature, the rim carries all of 2 pi.
    assert np.allclose(k[~boundary], 0, atol=1e-12)
    assert k[boundary].sum() == pytest.approx(2 * np.pi)


def test_matches_libigl_on_closed_mesh():
    v, f = torus()
    lengths = elements.edge_lengths(v, f)
    ours = geometry.cotan_laplacian(lengths, f, len(v))
    assert abs(ours - igl.cotmatrix(v, f)).max() < 1e-12
    assert np.allclose(_curvature(v, f), igl.gaussian_curvature(v, f), atol=1e-12)


def test_laplacian_constants_in_null_space_and_symmetric(sphere):
    v, f = sphere
    lap = geometry.cotan_laplacian(elements.edge_lengths(v, f), f, len(v))
    assert np.abs(lap @ np.ones(len(v))).max() < 1e-12
    assert abs(lap - lap.T).max() < 1e-14
    x = np.random.default_rng(0).standard_normal(len(v))
    assert x @ (lap @ x) < 0  # negative semidefinite, as libigl's cotmatrix


def test_curvature_change_under_metric_scaling_is_minus_laplacian(sphere):
    # Scaling edge ij by exp(eps (u_i + u_j) / 2) changes the angle defects by -eps L u to
    # first order: the linearisation behind eq. (1) and the curvature error of section 3.4.
    v, f = sphere
    lengths = elements.edge_lengths(v, f)
    u = np.random.default_rng(1).standard_normal(len(v))
    eps = 1e-6
    edge_u = u[f][:, [1, 2, 0]] + u[f][:, [2, 0, 1]]
    boundary = np.zeros(len(v), bool)
    k0 = geometry.angle_defect(geometry.corner_angles(lengths), f, boundary)
    k1 = geometry.angle_defect(
        geometry.corner_angles(lengths * np.exp(eps * edge_u / 2)), f, boundary
    )
    lap = geometry.cotan_laplacian(lengths, f, len(v))
    assert np.allclose((k1 - k0) / eps, -(lap @ u), atol=1e-5)


def test_areas_match_cross_product(sphere):
    v, f = sphere
    expected = 0.5 * np.linalg.norm(
        np.cross(v[f[:, 1]] - v[f[:, 0]], v[f[:, 2]] - v[f[:, 0]]), axis=1
    )
    assert np.allclose(elements.face_areas(elements.edge_lengths(v, f)), expected)
    va = elements.vertex_areas(expected, f, len(v))
    assert va.sum() == pytest.approx(expected.sum())


def test_mollify_leaves_good_meshes_alone_and_fixes_degenerate(sphere):
    v, f = sphere
    lengths = elements.edge_lengths(v, f)
    same, delta = geometry.mollify(lengths, 1e-5)
    assert delta == 0 and same is lengths
    flat = np.array([[1.0, 1.0, 2.0], [1.0, 2.0, 3.0]])  # zero-area triangles
    fixed, delta = geometry.mollify(flat, 1e-5)
    assert delta > 0
    assert (elements.face_areas(fixed) > 0).all()
    assert np.isfinite(geometry.corner_angles(fixed)).all()


def test_components_and_target_curvature():
    v1, f1 = icosphere(1)
    v2, f2 = torus(nu=12, nv=6)
    v = np.vstack([v1, v2 + 5])
    f = np.vstack([f1, f2 + len(v1)])
    count, labels = elements.components(elements.edge_graph(f, len(v)))
    assert count == 2
    k = _curvature(v, f)
    lengths = elements.edge_lengths(v, f)
    va = elements.vertex_areas(elements.face_areas(lengths), f, len(v))
    target = geometry.target_curvature(k, va, labels)
    for c in range(2):
        assert target[labels == c].sum() == pytest.approx(k[labels == c].sum(), abs=1e-9)
    # uniform: proportional to vertex area within a component
    ratio = target[labels == 0] / va[labels == 0]
    assert np.allclose(ratio, ratio[0])


def test_non_manifold_edges_are_counted():
    f = np.array([[0, 1, 2], [1, 0, 3], [0, 1, 4]])
    graph = elements.edge_graph(f, 5)
    assert graph[0, 1] == graph[1, 0] == 3
    assert graph[0, 2] == graph[1, 2] == 1
    assert graph.nnz == 2 * 7


def test_laplacian_pattern_is_adjacency_plus_diagonal():
    # boundary_vertices counts neighbours on the pattern: every edge must be stored, even with
    # a weight of zero (here the squares' diagonals, opposite two right angles, nearly so).
    v, f = open_cylinder()
    lap = geometry.cotan_laplacian(elements.edge_lengths(v, f), f, len(v))
    pattern = (elements.edge_graph(f, len(v)) + sp.identity(len(v))).tocsc()
    assert np.array_equal(lap.indptr, pattern.indptr)
    assert np.array_equal(lap.indices, pattern.indices)


def test_mesh_edges_groups_the_half_edges_of_each_edge():
    f = np.array([[0, 1, 2], [1, 0, 3], [0, 1, 4], [2, 1, 3]])  # edge 01 in three faces
    edges = elements.mesh_edges(f, 5)
    assert edges.ends.tolist() == [[0, 1], [0, 2], [0, 3], [0, 4], [1, 2], [1, 3], [1, 4], [2, 3]]
    assert np.diff(edges.starts).tolist() == [3, 1, 1, 1, 2, 2, 1, 1]
    start, end = f.ravel(), f[:, [1, 2, 0]].ravel()  # half-edge 3f + j: corner j to j + 1
    edge_of = np.repeat(np.arange(len(edges.ends)), np.diff(edges.starts))
    half = edges.order
    assert np.array_equal(np.minimum(start, end)[half], edges.ends[edge_of, 0])
    assert np.array_equal(np.maximum(start, end)[half], edges.ends[edge_of, 1])
    assert np.array_equal(np.sort(half), np.arange(f.size))
    none = elements.mesh_edges(np.empty((0, 3), dtype=np.int64), 3)
    assert none.ends.shape == (0, 2) and none.starts.tolist() == [0]


def _reference_laplacian(lengths, f, n):
    """The cotangent Laplacian summed by SciPy from one triplet per half-edge and corner."""
    angles = geometry.corner_angles(lengths)
    rows, cols, data = [], [], []
    for k, (i, j) in enumerate(((1, 2), (2, 0), (0, 1))):  # the edge opposite corner k
        w = 0.5 / np.tan(angles[:, k])
        rows += [f[:, i], f[:, j], f[:, i], f[:, j]]
        cols += [f[:, j], f[:, i], f[:, i], f[:, j]]
        data += [w, w, -w, -w]
    matrix = sp.coo_matrix((np.concatenate(data), (np.concatenate(rows), np.concatenate(cols))))
    return matrix.tocsc()


@pytest.mark.parametrize(
    "mesh",
    [torus(), disk(), open_cylinder(), "fin"],
    ids=["torus", "disk", "cylinder", "fin"],
)
def test_laplacian_equals_a_plain_sparse_assembly(mesh):
    if mesh == "fin":  # three faces on one edge, given straight to the assembly
        v = np.array([[0, 0, 0], [1, 0, 0], [0.5, 1, 0], [0.5, -1, 0.2], [0.5, 0.1, 1.0]])
        f = np.array([[0, 1, 2], [1, 0, 3], [0, 1, 4]])
    else:
        v, f = mesh
    lengths = elements.edge_lengths(v, f)
    ours = geometry.cotan_laplacian(lengths, f, len(v))
    reference = _reference_laplacian(lengths, f, len(v))
    assert ours.has_sorted_indices
    assert np.array_equal(ours.indptr, reference.indptr)
    assert np.array_equal(ours.indices, reference.indices)
    assert np.allclose(ours.data, reference.data, rtol=1e-12, atol=1e-12)
    given = geometry.cotan_laplacian(lengths, f, len(v), edges=elements.mesh_edges(f, len(v)))
    assert np.array_equal(given.data, ours.data)
