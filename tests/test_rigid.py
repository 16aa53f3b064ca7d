"""The descriptor ``rigid`` (cfsig.descriptors.rigid): the channels of ``intrinsic``, the
panorama and ``lf`` weighed together, and the search by its own distance."""

from dataclasses import replace

import numpy as np
import pytest
from click.testing import CliRunner

from cfsig import descriptors
from cfsig.cli import main
from cfsig.descriptors import intrinsic, lf, panorama, rigid, sh
from cfsig.descriptors.signature import compute_signature
from cfsig.files.mesh import clean_mesh
from cfsig.index.store import read_manifest, write_manifest
from cfsig.params import Layout, Params
from cfsig.repair.stage import repair_mesh
from cfsig.search.l1 import l1_numpy
from tests.helpers import (
    SHAPES,
    assert_command_line_round_trip,
    assert_search_equals_full_scan,
    open_cylinder,
    random_rotation,
    two_classes,
)

RIGID = Params(descriptor="rigid")
FLOATS = rigid.LIGHTS.start  # the entries before the light field features, which are whole
TAIL = rigid.LENGTH - FLOATS


def _vector(v, f):
    return rigid.rigid_vector(clean_mesh(v, f), RIGID, None, "auto").vector


def _distance(a, b):
    return float(rigid.rigid_distances(np.float32([a]), np.float32([b]), l1_numpy)[0, 0])


@pytest.fixture(scope="module")
def vectors():
    return {name: _vector(*make()) for name, make in SHAPES.items()}


def _nearest_other(vectors, name):
    return min(_distance(vectors[name], vectors[o]) for o in vectors if o != name)


def test_the_distance_weighs_the_channels():
    """The distance of two meshes sums over the four channels each one's distance, as its own
    module measures it (``lf``'s on the first light fields), over its median, to the power,
    times its weight."""
    meshes = [clean_mesh(*make()) for make in (SHAPES["limbs3"], SHAPES["capsule"])]
    parts = {
        "intrinsic": [intrinsic.intrinsic_vector(m, RIGID, None, "auto").vector for m in meshes],
        "panorama": [
            panorama.panorama_features(*sh.surface_samples(m.vertices, m.faces, RIGID.seed))
            for m in meshes
        ],
        "lf": [lf.light_field_features(m, rigid.FIELDS) for m in meshes],
    }
    cut = (intrinsic.EIGENPAIRS, intrinsic.EIGENPAIRS + intrinsic.QUANTILES * len(intrinsic.TIMES))
    a, b = parts["intrinsic"]
    channel = {
        "heat": np.abs(a[cut[0] : cut[1]] - b[cut[0] : cut[1]]).sum(),
        "curvature": np.abs(a[cut[1] :] - b[cut[1] :]).sum(),
        "panorama": panorama.panorama_distances(
            *(np.float32([v]) for v in parts["panorama"]), l1_numpy
        )[0, 0],
        "lf": lf.lf_distances(*(np.float32([v]) for v in parts["lf"]), l1_numpy)[0, 0],
    }
    expected = sum(
        rigid.WEIGHTS[name] * (value / rigid.MEDIANS[name]) ** rigid.POWER
        for name, value in channel.items()
    )
    found = [rigid.rigid_vector(m, RIGID, None, "auto").vector for m in meshes]
    assert found[0].shape == (rigid.LENGTH,) == (descriptors.layout(RIGID).length,)
    assert _distance(*found) == pytest.approx(expected, rel=1e-5)
    assert all(rigid.WEIGHTS[name] > 0 for name in rigid.CHANNELS)


@pytest.mark.parametrize("name", sorted(SHAPES))
def test_rotation_invariance(vectors, name):
    """A rotated shape lies nearer its unrotated self than any other shape does, not much: the
    light fields, three of them only, see it from other directions, and the power of the
    distance (0.3) lifts small differences (docs/method.md)."""
    v, f = SHAPES[name]()
    turned = _vector(v @ random_rotation(len(name)).T, f)
    assert _distance(vectors[name], turned) < _nearest_other(vectors, name)


def test_translation_and_scale_invariance(vectors):
    """Moved and scaled, a shape stays within half its distance to any other: only round-off (a
    pixel of a silhouette, a feature's last quantum) moves it, lifted by the power 0.3."""
    v, f = SHAPES["limbs3"]()
    nearest = _nearest_other(vectors, "limbs3")
    for factor, shift in ((0.01, [3.0, -1.0, 2.0]), (250.0, [-40.0, 7.0, 0.5])):
        moved = _vector(v * factor + shift, f)
        assert _distance(vectors["limbs3"], moved) < 0.5 * nearest


def test_the_bound_is_below_the_distance(vectors):
    rng = np.random.default_rng(3)
    real = np.float32(list(vectors.values()))
    noisy = real.copy()
    noisy[:, :FLOATS] *= rng.uniform(0.8, 1.2, noisy[:, :FLOATS].shape)
    noisy[:, FLOATS:] = np.clip(
        noisy[:, FLOATS:] + rng.integers(-30, 30, (len(real), TAIL)), 0, 255
    )
    rows = np.vstack([real, noisy])
    exact = rigid.rigid_distances(rows, rows, l1_numpy)
    bounds = rigid.rigid_bounds(rows, rows, l1_numpy)
    assert np.all(bounds <= np.float32(exact)) and np.all(np.diag(exact) == 0)
    np.testing.assert_allclose(exact, exact.T, rtol=1e-6)
    assert bounds[exact > 0].mean() > 0.3 * exact[exact > 0].mean()  # bounds that prune


def test_search_equals_a_full_scan(tmp_path, vectors):
    """Rows near a few shapes, duplicates among them (ties), in two segments with a row
    superseded: the bounded search returns the full scan's rows and distances."""
    rng = np.random.default_rng(7)
    base = np.float32(list(vectors.values()))
    rows = []
    for i in range(30):
        row = base[i % 4].copy()
        row[:FLOATS] *= rng.uniform(0.9, 1.1, FLOATS)
        row[FLOATS:] = np.clip(row[FLOATS:] + rng.integers(-40, 40, TAIL), 0, 255)
        rows.append(row)
    rows[5] = rows[9] = rows[2]
    assert_search_equals_full_scan(tmp_path / "index", RIGID, rows, base)


def test_the_command_line_computes_indexes_queries_evaluates_and_checks(tmp_path):
    assert_command_line_round_trip(tmp_path, "rigid")
    one = str(tmp_path / "data/long/a.off")
    out = CliRunner().invoke(
        main, ["compute", one, "--descriptor", "rigid", "--save", str(tmp_path)]
    )
    assert out.exit_code == 0, out.output
    assert np.load(tmp_path / "a.npz")["signature"].shape == (rigid.LENGTH,)


def test_signature_goes_through_the_repair_stage():
    """An open tube is mended locally under ``auto``, as for ``intrinsic``, and rebuilt under
    ``proxy``; either way it is measured like the mesh the repair stage made of it."""
    mesh = clean_mesh(*open_cylinder())
    for mode, route in (("auto", "repaired"), ("proxy", "proxy")):
        params = Params(descriptor="rigid", repair=mode)
        sig = compute_signature(mesh, params)
        assert sig.route == route and sig.phi is None
        made = repair_mesh(mesh, mode)
        assert np.array_equal(sig.vector, rigid.rigid_vector(made, params, None, "auto").vector)
        assert sig.vector.shape == (rigid.LENGTH,) and np.isfinite(sig.vector).all()
        assert np.array_equal(sig.vector[FLOATS:], np.round(sig.vector[FLOATS:]))


@pytest.mark.parametrize("earlier", [2661, 7217])
def test_an_index_of_an_earlier_rigid_is_refused(tmp_path, earlier):
    """An index whose rows another version of the descriptor made (``rigid`` kept 2,661
    entries a row before the panorama, 7,217 before its wavelet features and real and
    imaginary parts) is refused in one line that says how to rebuild it, by a query, an
    evaluation and a writer alike."""
    two_classes(tmp_path / "data")
    index = tmp_path / "index"
    runner = CliRunner()
    args = ["index", str(tmp_path / "data"), "-o", str(index), "--descriptor", "rigid"]
    assert runner.invoke(main, args).exit_code == 0
    write_manifest(index, replace(read_manifest(index), layout=Layout(earlier)))
    for command in (
        ["query", str(index), str(tmp_path / "data/long/a.off")],
        ["evaluate", "--index", str(index)],
        args,
    ):
        out = runner.invoke(main, command)
        assert out.exit_code != 0 and "rebuild it: cfsig index" in out.output, out.output
        assert "Traceback" not in out.output
