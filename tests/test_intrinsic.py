"""The default descriptor ``intrinsic`` (cfsig.descriptors.intrinsic) and the descriptor
registry."""

import json
from pathlib import Path

import numpy as np
import pytest
from click.testing import CliRunner

from cfsig import descriptors
from cfsig.cli import main
from cfsig.descriptors import intrinsic
from cfsig.descriptors.signature import compute_signature
from cfsig.errors import SolverError
from cfsig.files.demo import capsule, limbed_body, torus
from cfsig.files.mesh import clean_mesh
from cfsig.index.store import IndexReader, check_index
from cfsig.operators.conformal import conformal_factor, operators
from cfsig.params import Params
from tests.helpers import disk, icosphere, open_cylinder, random_rotation, read_plain, write_off

DEFAULT = Params()
GOLDEN = Path(__file__).parent / "golden" / "vectors.npz"
# The meshes of the golden vectors: generated, the same on every machine.
GOLDEN_MESHES = {
    "limbs3": lambda: limbed_body(3, pose=1),
    "capsule": lambda: capsule(bend=0.6),
    "torus": lambda: torus(wave=0.2),
}


def _bumpy(stretch=1.5, levels=3):
    v, f = icosphere(levels)
    v = v * [1.0, 0.6, 0.5]
    v[:, 0] += stretch * np.clip(v[:, 0], 0, None) ** 4
    return v, f


def _vector(v, f, params=DEFAULT):
    return compute_signature(clean_mesh(v, f), params).vector


@pytest.mark.parametrize("name", sorted(GOLDEN_MESHES))
def test_golden_vectors(name):
    """Both descriptors, and the fine cells, as they were released: bit for bit, but for the
    default's vector, whose Lanczos sums round differently with other processors and BLAS
    builds (by at most 1e-12, measured on another machine): within 1e-10, far below what any
    change of the method moves."""
    golden = np.load(GOLDEN)
    mesh = clean_mesh(*GOLDEN_MESHES[name]())
    assert np.array_equal(
        _vector(mesh.vertices, mesh.faces, Params(descriptor="cf")), golden[f"{name}_cf"]
    )
    sig = compute_signature(mesh, Params(partial_cells=True))
    np.testing.assert_allclose(sig.vector, golden[f"{name}_default"], rtol=0, atol=1e-10)
    assert sig.cells is not None
    assert np.array_equal(sig.cells[0], golden[f"{name}_cells"])
    assert np.array_equal(sig.cells[1], golden[f"{name}_cell_units"])
    assert np.array_equal(compute_signature(mesh, DEFAULT).vector, sig.vector)


def test_weighted_quantiles():
    q = intrinsic.weighted_quantiles(np.array([3.0, 1.0, 2.0]), np.array([1.0, 1.0, 2.0]), 4)
    assert np.array_equal(q, [1.0, 2.0, 2.0, 3.0])


def test_channels_and_their_columns():
    mesh = clean_mesh(*_bumpy())
    ops = operators(mesh)
    found = intrinsic.channels(ops, intrinsic.spectrum_of(ops, None, "auto"), cells=False)
    assert found["spectrum"].shape == (intrinsic.EIGENPAIRS,)
    assert found["heat"].shape == (len(intrinsic.TIMES), intrinsic.QUANTILES)
    assert found["curvature"].shape == intrinsic.CURVATURE_SHAPE
    assert np.allclose(found["curvature"].sum(axis=1), 1.0)
    assert np.all(np.diff(found["spectrum"]) >= 0) and np.all(np.diff(found["heat"]) >= 0)
    vector = intrinsic.weigh(found)
    assert vector.shape == (intrinsic.LENGTH,) == (descriptors.layout(DEFAULT).length,)
    assert np.array_equal(vector, compute_signature(mesh, DEFAULT).vector)
    columns = descriptors.layout(DEFAULT).group("curvature")
    assert np.array_equal(vector[columns], intrinsic.weigh_curvature(found["curvature"]))


def test_layout_declares_the_curvature_group_and_the_cells():
    plain, cells = descriptors.layout(DEFAULT), descriptors.layout(Params(partial_cells=True))
    assert plain.cells == 0 and cells.cells == 1024
    assert plain.groups == cells.groups and plain.group("curvature").stop == intrinsic.LENGTH
    assert plain.group("spectrum") is None
    assert descriptors.layout(Params(descriptor="cf", bins=30)).length == 30


def test_invariant_to_rigid_motion_and_scale():
    v, f = _bumpy()
    base = _vector(v, f)
    moved = _vector(0.2 * v @ random_rotation(7).T + [5.0, 1.0, -2.0], f)
    assert np.abs(moved - base).sum() < 1e-6 * np.abs(base).sum()


def test_a_simplified_mesh_is_invariant_to_rigid_motion_scale_and_numbering():
    """A mesh beyond `COARSE` faces, turned, scaled, moved and listed in another order: its
    copy is simplified from the same numbers (`cfsig.repair.simplify`), so the vector is the
    same to round-off (numbered by position in the mesh's own pose, the copies moved it by
    0.2 to 0.6, a fifth of the distance to the other bump)."""
    v, f = _bumpy(levels=5)  # 20,480 faces
    assert len(f) > intrinsic.COARSE
    base = _vector(v, f)
    rng = np.random.default_rng(1)
    order = rng.permutation(len(v))  # vertex i is listed at order[i]
    for rotation, scale, shift in ((random_rotation(7), 0.2, [5.0, 1.0, -2.0]),
                                   (random_rotation(8), 3.0, [0.0, -40.0, 0.5])):  # fmt: skip
        moved = np.empty_like(v)
        moved[order] = scale * v @ rotation.T + shift
        faces = order[f][rng.permutation(len(f))]
        assert np.abs(_vector(moved, faces) - base).sum() < 1e-8 * np.abs(base).sum()


def test_distance_separates_shapes():
    v, f = _bumpy()
    base = _vector(v, f)
    same = _vector(v @ random_rotation(3).T, f)
    other_bump = _vector(*_bumpy(stretch=4.0))
    ring = _vector(*torus(n_major=48, n_minor=16))
    d_same, d_bump, d_ring = (np.abs(x - base).sum() for x in (same, other_bump, ring))
    assert d_same < 0.01 * min(d_bump, d_ring)


@pytest.mark.parametrize(
    "mesh", [disk(), open_cylinder(), icosphere(0)], ids=["disk", "cylinder", "tiny"]
)
def test_open_and_tiny_meshes_give_finite_vectors(mesh):
    vector = _vector(*mesh)
    assert vector.shape == (intrinsic.LENGTH,) and np.all(np.isfinite(vector))


def test_the_copy_falls_back_to_the_mesh_when_it_fails(monkeypatch):
    mesh = clean_mesh(*_bumpy(levels=5))  # 20,480 faces: more than the copy's
    assert len(mesh.faces) > intrinsic.COARSE
    on_copy = compute_signature(mesh, DEFAULT)
    assert on_copy.n_components == 1
    solve = intrinsic.laplacian_solver

    def fails(laplacian, labels, solver="auto"):
        if laplacian.shape[0] < len(mesh.vertices):
            raise SolverError("the copy's Laplacian is singular")
        return solve(laplacian, labels, solver)

    monkeypatch.setattr(intrinsic, "laplacian_solver", fails)
    on_mesh = compute_signature(mesh, DEFAULT).vector
    ops = operators(mesh)
    expected = intrinsic.weigh(
        intrinsic.channels(ops, intrinsic.spectrum_of(ops, None, "auto"), cells=False)
    )
    assert np.array_equal(on_mesh, expected) and not np.allclose(on_mesh, on_copy.vector)


def test_no_phi_unless_asked():
    mesh = clean_mesh(*_bumpy())
    assert not descriptors.get("intrinsic").needs_phi and descriptors.get("cf").needs_phi
    sig = compute_signature(mesh, DEFAULT)
    assert sig.phi is None and np.isnan(sig.curvature_error) and np.isnan(sig.phi_range).all()
    asked = compute_signature(mesh, DEFAULT, phi=True)
    assert np.array_equal(asked.vector, sig.vector)
    assert np.array_equal(asked.phi, conformal_factor(mesh).phi)


def test_unknown_descriptors_and_options_are_refused():
    with pytest.raises(
        ValueError, match="unknown descriptor 'shapedna'; choose from intrinsic, cf"
    ):
        descriptors.get("shapedna")
    with pytest.raises(ValueError, match="intrinsic descriptor only"):
        Params(descriptor="cf", partial_cells=True)
    old = json.loads(DEFAULT.to_json()) | {"version": 9}
    with pytest.raises(ValueError, match="unknown parameters"):
        Params.from_json(json.dumps(old))


@pytest.fixture
def collection(tmp_path):
    for i, stretch in enumerate((1.0, 1.3)):
        v, f = _bumpy(stretch)
        write_off(tmp_path / "shapes" / "bump" / f"{i}.off", v @ random_rotation(i).T, f)
    for i, r in enumerate((0.3, 0.35)):
        write_off(tmp_path / "shapes" / "ring" / f"{i}.off", *torus(r=r, n_major=40, n_minor=14))
    return tmp_path / "shapes"


def test_index_and_query_use_the_index_descriptor(collection, tmp_path):
    runner = CliRunner()
    index = tmp_path / "index"
    result = runner.invoke(main, ["index", str(collection), "-o", str(index), "--jobs", "1"])
    assert result.exit_code == 0, result.output
    rows = read_plain(index)
    assert rows["attrs"]["params"] == DEFAULT.to_json() and len(rows["names"]) == 4
    for key in ("phi_min", "phi_max", "curvature_error"):
        assert np.isnan(rows[key]).all()  # the default solves no phi
    assert check_index(index) == []
    with IndexReader(index) as reader:
        assert reader.params == DEFAULT and reader.signatures.shape == (4, intrinsic.LENGTH)
    query = str(collection / "bump" / "1.off")
    result = runner.invoke(main, ["query", str(index), query, "-k", "2", "--json"])
    assert result.exit_code == 0, result.output
    hits = json.loads(result.stdout)
    assert hits[0]["name"] == "bump/1.off" and hits[0]["distance"] < 1e-5
    assert hits[1]["label"] == "bump"


def test_evaluate_side_by_side(collection):
    runner = CliRunner()
    args = ["evaluate", str(collection), "--descriptor", "cf,intrinsic", "--jobs", "1"]
    result = runner.invoke(main, args)
    assert result.exit_code == 0, result.output
    lines = result.stdout.splitlines()
    assert lines[0] == "4 queries"
    assert lines[2].startswith("cf ") and lines[3].startswith("intrinsic ")
    assert "first tier (FT) per class:" in lines
    # the generated meshes are closed manifolds; each descriptor's routes are counted
    assert lines[-2:] == ["cf repair: 4 clean", "intrinsic repair: 4 clean"]


@pytest.mark.parametrize("given", ["cf,shapedna", "cf,cf", ","])
def test_evaluate_rejects_bad_descriptor_lists(collection, given):
    result = CliRunner().invoke(main, ["evaluate", str(collection), "--descriptor", given])
    assert result.exit_code == 2 and "--descriptor" in result.output
