import json
from dataclasses import replace

import numpy as np
import pytest
from click.testing import CliRunner

from cfsig.cli import main
from cfsig.descriptors import intrinsic as cfhks
from cfsig.descriptors.signature import compute_signature, needs_phi
from cfsig.errors import SolverError
from cfsig.files.mesh import clean_mesh
from cfsig.index.store import IndexReader, IndexWriter, check_index
from cfsig.operators.conformal import conformal_factor, operators
from cfsig.operators.curvature import smoothed_curvature
from cfsig.params import DEFAULT_VERSIONS, VERSIONS, Params, curvature_slice, signature_length
from cfsig.repair import simplify
from tests.helpers import (
    disk,
    icosphere,
    open_cylinder,
    random_rotation,
    read_plain,
    torus,
    write_off,
)

CFHKS = Params(descriptor="cfhks")


def _bumpy(stretch=1.5, levels=3):
    v, f = icosphere(levels)
    v = v * [1.0, 0.6, 0.5]
    v[:, 0] += stretch * np.clip(v[:, 0], 0, None) ** 4
    return v, f


def _vector(v, f):
    return compute_signature(clean_mesh(v, f), CFHKS).vector


def test_weighted_quantiles():
    q = cfhks.weighted_quantiles(np.array([3.0, 1.0, 2.0]), np.array([1.0, 1.0, 2.0]), 4)
    assert np.array_equal(q, [1.0, 2.0, 2.0, 3.0])


@pytest.mark.parametrize("version", VERSIONS["cfhks"])
def test_length_and_channels(version):
    v, f = _bumpy()
    design = cfhks.DESIGNS[version]
    cf = conformal_factor(clean_mesh(v, f))
    parts = cfhks.channels(
        cf.operators, cfhks.spectrum_of(cf.operators, count=design.eigenpairs)[0], design, cf.phi
    )
    assert parts["phi"].shape == (cfhks.QUANTILES,)
    assert parts["curvature"].shape == cfhks.curvature_shape(design)
    assert np.allclose(parts["curvature"].sum(axis=1), 1.0)
    assert parts["spectrum"].shape == (design.eigenpairs,)
    assert parts["heat"].shape == (len(design.times), cfhks.QUANTILES)
    assert np.all(np.diff(parts["spectrum"]) >= 0) and np.all(np.diff(parts["heat"]) >= 0)
    params = Params(descriptor="cfhks", version=version)
    vector = compute_signature(clean_mesh(v, f), params).vector
    assert vector.shape == (design.length,) == (signature_length(params),)
    assert np.array_equal(vector, cfhks.weigh(parts, design))


def test_versions():
    assert CFHKS.version == DEFAULT_VERSIONS["cfhks"] == 9 and Params().version == 1
    assert max(VERSIONS["cfhks"]) == 10  # asked for by name (cfsig.params)
    with pytest.raises(ValueError, match="cf has no version 2"):
        Params(descriptor="cf", version=2)
    old = json.loads(Params(descriptor="cfhks", version=1).to_json())
    del old["version"]  # an index written before descriptors had versions
    assert Params.from_json(json.dumps(old)).version == 1
    assert Params().with_descriptor("cfhks") == CFHKS
    assert Params.from_json(json.dumps(old)).with_descriptor("cfhks").version == 1


def test_invariant_to_rigid_motion_and_scale():
    v, f = _bumpy()
    base = _vector(v, f)
    moved = _vector(0.2 * v @ random_rotation(7).T + [5.0, 1.0, -2.0], f)
    assert np.abs(moved - base).sum() < 1e-6 * np.abs(base).sum()


def test_deterministic():
    v, f = _bumpy()
    assert np.array_equal(_vector(v, f), _vector(v, f))


def test_distance_separates_shapes():
    v, f = _bumpy()
    base = _vector(v, f)
    same = _vector(v @ random_rotation(3).T, f)
    other_bump = _vector(*_bumpy(stretch=4.0))
    ring = _vector(*torus(nu=48, nv=16))
    d_same, d_bump, d_ring = (np.abs(x - base).sum() for x in (same, other_bump, ring))
    assert d_same < 0.01 * min(d_bump, d_ring)


@pytest.mark.parametrize(
    "mesh", [disk(), open_cylinder(), icosphere(0)], ids=["disk", "cylinder", "tiny"]
)
def test_open_and_tiny_meshes_give_finite_vectors(mesh):
    vector = _vector(*mesh)
    assert vector.shape == (signature_length(CFHKS),) and np.all(np.isfinite(vector))


def test_params_name_the_descriptor():
    assert Params().descriptor == "cf"
    with pytest.raises(ValueError, match="unknown descriptor"):
        Params(descriptor="shapedna")
    old = json.loads(Params().to_json())
    del old["descriptor"]  # an index written before descriptors had names
    assert Params.from_json(json.dumps(old)) == Params()


@pytest.fixture
def collection(tmp_path):
    for i, stretch in enumerate((1.0, 1.3)):
        v, f = _bumpy(stretch)
        write_off(tmp_path / "shapes" / "bump" / f"{i}.off", v @ random_rotation(i).T, f)
    for i, r in enumerate((0.3, 0.35)):
        write_off(tmp_path / "shapes" / "ring" / f"{i}.off", *torus(r=r, nu=40, nv=14))
    return tmp_path / "shapes"


def test_index_and_query_use_the_index_descriptor(collection, tmp_path):
    runner = CliRunner()
    index = tmp_path / "i.h5"
    args = ["index", str(collection), "-o", str(index), "--descriptor", "cfhks", "--jobs", "1"]
    result = runner.invoke(main, args)
    assert result.exit_code == 0, result.output
    with IndexReader(index) as reader:
        assert reader.params.descriptor == "cfhks"
        assert reader.params == CFHKS
        assert reader.signatures.shape == (4, signature_length(CFHKS))
    query = str(collection / "bump" / "1.off")
    result = runner.invoke(main, ["query", str(index), query, "-k", "2", "--json"])
    assert result.exit_code == 0, result.output
    hits = json.loads(result.stdout)
    assert hits[0]["name"] == "bump/1.off" and hits[0]["distance"] < 1e-5
    assert hits[1]["label"] == "bump"


def test_an_index_of_an_older_version_answers_with_its_own(collection, tmp_path):
    old = Params(descriptor="cfhks", version=1)
    index = tmp_path / "old.h5"
    with IndexWriter(index, old):
        pass  # an empty index of version 1; indexing into it keeps its version
    runner = CliRunner()
    result = runner.invoke(main, ["index", str(collection), "-o", str(index), "--jobs", "1"])
    assert result.exit_code == 0, result.output
    with IndexReader(index) as reader:
        assert reader.params == old
        assert reader.signatures.shape == (4, signature_length(old))
    query = collection / "ring" / "0.off"
    result = runner.invoke(main, ["query", str(index), str(query), "-k", "1", "--json"])
    assert result.exit_code == 0, result.output
    hit = json.loads(result.stdout)[0]
    assert hit["name"] == "ring/0.off" and hit["distance"] < 1e-5


def test_evaluate_side_by_side(collection):
    runner = CliRunner()
    args = ["evaluate", str(collection), "--descriptor", "cf,cfhks", "--jobs", "1"]
    result = runner.invoke(main, args)
    assert result.exit_code == 0, result.output
    lines = result.stdout.splitlines()
    assert lines[0] == "4 queries"
    assert lines[2].startswith("cf ") and lines[3].startswith("cfhks ")
    assert "first tier (FT) per class:" in lines
    assert lines[-2].startswith("ring")
    assert lines[-1] == "repair: 4 clean"  # the generated meshes are closed manifolds


@pytest.mark.parametrize("given", ["cf,shapedna", "cf,cf", ","])
def test_evaluate_rejects_bad_descriptor_lists(collection, given):
    result = CliRunner().invoke(main, ["evaluate", str(collection), "--descriptor", given])
    assert result.exit_code == 2 and "--descriptor" in result.output


def test_version_3_extends_version_2():
    mesh = clean_mesh(*_bumpy())
    v2 = compute_signature(mesh, Params(descriptor="cfhks", version=2)).vector
    v3 = compute_signature(mesh, Params(descriptor="cfhks", version=3)).vector
    assert np.array_equal(v3[: len(v2)], v2)
    assert len(v3) == len(v2) + len(cfhks.DESIGNS[3].scales) * cfhks.DESIGNS[3].bins


def _fine_bumpy(stretch=1.5):
    """`_bumpy` at 20480 faces: more than version 4's copy."""
    return _bumpy(stretch, levels=5)


V4 = Params(descriptor="cfhks", version=4)
V5 = Params(descriptor="cfhks", version=5)
V6 = Params(descriptor="cfhks", version=6)


def test_version_4_is_version_3_on_a_mesh_smaller_than_its_copy():
    mesh = clean_mesh(*_bumpy())
    assert len(mesh.faces) <= cfhks.DESIGNS[4].coarse
    v3 = compute_signature(mesh, Params(descriptor="cfhks", version=3)).vector
    assert np.array_equal(compute_signature(mesh, V4).vector, v3)


def test_version_4_takes_only_the_spectrum_and_heat_from_the_copy():
    v, f = _fine_bumpy()
    mesh = clean_mesh(v, f)
    v3 = compute_signature(mesh, Params(descriptor="cfhks", version=3)).vector
    v4 = compute_signature(mesh, V4).vector
    curvature = cfhks.DESIGNS[4].bins * len(cfhks.DESIGNS[4].scales)
    assert np.array_equal(v4[-curvature:], v3[-curvature:])
    assert not np.array_equal(v4, v3)
    other = compute_signature(clean_mesh(*_fine_bumpy(stretch=4.0)), V4).vector
    # the copy's spectrum and heat stand for the mesh's: far closer than another shape's
    assert np.abs(v4 - v3).sum() < 0.25 * np.abs(other - v4).sum()


@pytest.mark.parametrize("version", [4, 5, 6])
def test_the_copy_is_nearly_invariant_to_rigid_motion_and_scale(version):
    params = Params(descriptor="cfhks", version=version)
    v, f = _fine_bumpy()
    base = compute_signature(clean_mesh(v, f), params).vector
    moved = compute_signature(
        clean_mesh(0.2 * v @ random_rotation(7).T + [5.0, 1.0, -2.0], f), params
    )
    other = compute_signature(clean_mesh(*_fine_bumpy(stretch=4.0)), params).vector
    # the simplification's collapse order may differ in the last bits, so not exactly
    assert np.abs(moved.vector - base).sum() < 0.05 * np.abs(other - base).sum()


@pytest.mark.parametrize("version", [4, 5, 6])
def test_the_copy_falls_back_to_the_mesh_when_it_fails(monkeypatch, version):
    mesh = clean_mesh(*_fine_bumpy())
    params = Params(descriptor="cfhks", version=version)
    on_mesh = compute_signature(mesh, Params(descriptor="cfhks", version=3)).vector
    copy_factorisation = cfhks.laplacian_solver

    def fails(laplacian, labels, solver="auto"):
        if laplacian.shape[0] < len(mesh.vertices):
            raise SolverError("the copy's Laplacian is singular")
        return copy_factorisation(laplacian, labels, solver)

    monkeypatch.setattr(cfhks, "laplacian_solver", fails)
    vector = compute_signature(mesh, params).vector
    spectrum_and_heat = signature_length(replace(params, version=2))
    assert np.array_equal(vector[:spectrum_and_heat], on_mesh[:spectrum_and_heat])


def test_the_default_solves_no_phi_unless_asked():
    mesh = clean_mesh(*_bumpy())
    assert not needs_phi(CFHKS)
    sig = compute_signature(mesh, CFHKS)
    assert sig.phi is None and np.isnan(sig.curvature_error) and np.isnan(sig.phi_range).all()
    asked = compute_signature(mesh, CFHKS, phi=True)
    assert np.array_equal(asked.vector, sig.vector)
    assert np.array_equal(asked.phi, conformal_factor(mesh).phi)
    assert needs_phi(Params()) and needs_phi(Params(descriptor="cfhks", version=1))


def test_version_5_is_version_4_with_the_curvature_binned_apart():
    """Same spectrum and heat; the curvature channel as close as its looser solve allows."""
    mesh = clean_mesh(*_fine_bumpy())
    v4 = compute_signature(mesh, V4).vector
    v5 = compute_signature(mesh, V5).vector
    head = signature_length(replace(CFHKS, version=2))
    assert np.array_equal(v5[:head], v4[:head])
    design = cfhks.DESIGNS[5]
    ops = conformal_factor(mesh).operators
    exact = cfhks.curvature_histograms(
        smoothed_curvature(ops, design.scales), ops.vertex_area, design.bins
    )
    assert np.abs(cfhks.weigh_curvature(exact, design) - v5[head:]).sum() < 1e-3


def test_version_6_is_version_5_with_the_curvature_solved_more_loosely():
    """Same spectrum and heat; the curvature channel moves far less than to another shape's."""
    mesh = clean_mesh(*_fine_bumpy())
    v5 = compute_signature(mesh, V5).vector
    v6 = compute_signature(mesh, V6).vector
    head = signature_length(replace(CFHKS, version=2))
    assert np.array_equal(v6[:head], v5[:head])
    assert not np.array_equal(v6, v5)  # else the looser tolerance would not be in use
    other = compute_signature(clean_mesh(*_fine_bumpy(stretch=4.0)), V6).vector
    assert np.abs(v6[head:] - v5[head:]).sum() < 0.05 * np.abs(other[head:] - v6[head:]).sum()


@pytest.mark.parametrize(("version", "pairs"), [(7, 60), (8, 45)])
def test_versions_7_and_8_compute_every_channel_on_the_simplified_copy(version, pairs):
    """Their eigenpairs and the curvature at their scales, all of the copy."""
    mesh = clean_mesh(*_fine_bumpy())
    design = cfhks.DESIGNS[version]
    copy = simplify.simplified_mesh(mesh, design.coarse)
    assert copy is not None and len(copy.vertices) < len(mesh.vertices)
    vector = compute_signature(mesh, Params(descriptor="cfhks", version=version)).vector
    ops = operators(copy)
    spectrum, surface = cfhks.spectrum_of(ops, count=design.eigenpairs)
    assert surface is ops and len(spectrum.eigenvalues) == pairs
    assert np.allclose(vector, cfhks.weigh(cfhks.channels(ops, spectrum, design), design))
    on_mesh = replace(design, curvature_on_copy=False)
    columns = cfhks.channel_columns(design)["curvature"]
    full = conformal_factor(mesh).operators
    moved = cfhks.weigh(cfhks.channels(full, spectrum, on_mesh), on_mesh)
    assert not np.allclose(vector[columns], moved[columns])


def test_a_copy_only_version_needs_not_the_mesh_operators_and_counts_its_components():
    """Versions 7 and later skip the mesh's own operators when the copy exists: same vector as
    through them, same component count."""
    v, f = _fine_bumpy()
    mesh = clean_mesh(np.vstack([v, v + [9.0, 0.0, 0.0]]), np.vstack([f, f + len(v)]))
    version = max(VERSIONS["cfhks"])
    sig = compute_signature(mesh, Params(descriptor="cfhks", version=version, repair="off"))
    ops = operators(mesh)
    assert sig.n_components == ops.n_components == 2
    vector, cells = cfhks.cfhks_vector(mesh, ops, version)
    assert np.array_equal(sig.vector, vector)
    assert sig.cells is not None and cells is not None  # version 10 keeps fine cells
    assert all(np.array_equal(a, b) for a, b in zip(sig.cells, cells, strict=True))
    assert cfhks.copy_vector(mesh, 6) is None  # version 6's curvature is on the mesh itself
    small = clean_mesh(*_bumpy())
    assert cfhks.copy_vector(small, version) is None  # nothing to simplify


def test_an_index_of_the_default_keeps_no_phi_and_checks_clean(collection, tmp_path):
    out = tmp_path / "default.h5"
    result = CliRunner().invoke(main, ["index", str(collection), "-o", str(out), "--jobs", "1"])
    assert result.exit_code == 0, result.output
    rows = read_plain(out)
    assert rows["attrs"]["params"] == CFHKS.to_json() and len(rows["names"]) > 0
    for key in ("phi_min", "phi_max", "curvature_error"):
        assert np.isnan(rows[key]).all()
    assert check_index(out) == []
    with IndexReader(out) as reader:
        assert np.isfinite(reader.signatures[:]).all()


@pytest.mark.parametrize("version", sorted(cfhks.DESIGNS))
def test_channel_columns_are_where_weigh_puts_each_channel(version):
    design = cfhks.DESIGNS[version]
    parts = {
        "phi": np.full(cfhks.QUANTILES, 1.0),
        "spectrum": np.full(design.eigenpairs, 2.0),
        "heat": np.full((len(design.times), cfhks.QUANTILES), 3.0),
        "curvature": np.full(cfhks.curvature_shape(design), 4.0),
    }
    vector = cfhks.weigh(parts, design)
    columns = cfhks.channel_columns(design)
    assert list(columns) == [c for c in parts if c != "phi" or design.phi is not None]
    covered = np.concatenate([np.arange(len(vector))[s] for s in columns.values()])
    assert np.array_equal(covered, np.arange(design.length))
    for name, where in columns.items():
        expected = cfhks.weigh({**parts, name: 0 * parts[name]}, design)
        changed = np.flatnonzero(vector != expected)
        assert np.array_equal(changed, np.arange(len(vector))[where])
    stored = curvature_slice(Params(descriptor="cfhks", version=version))
    assert stored == (columns["curvature"] if design.scales else None)


def test_index_builds_an_older_version_when_asked_and_refuses_an_unknown_one(collection, tmp_path):
    out = tmp_path / "v6.h5"
    runner = CliRunner()
    made = runner.invoke(
        main, ["index", str(collection), "-o", str(out), "-j", "1", "--descriptor-version", "6"]
    )
    assert made.exit_code == 0, made.output
    with IndexReader(out) as reader:
        assert reader.params == Params(descriptor="cfhks", version=6)
        assert reader.signatures.shape[1] == signature_length(reader.params)
    other = runner.invoke(
        main, ["index", str(collection), "-o", str(out), "-j", "1", "--descriptor-version", "7"]
    )
    assert other.exit_code != 0 and "Traceback" not in other.output
    unknown = runner.invoke(
        main, ["index", str(collection), "-o", str(tmp_path / "x.h5"), "--descriptor-version", "99"]
    )
    assert unknown.exit_code != 0 and "no version 99" in unknown.output
    assert not (tmp_path / "x.h5").exists()
