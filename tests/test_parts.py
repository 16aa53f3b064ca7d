"""Tests for cfsig.search.partial and evaluate_queries: partial queries against whole shapes."""

import json
from dataclasses import replace

import numpy as np
import pytest
from click.testing import CliRunner

from cfsig.cli import main
from cfsig.descriptors import intrinsic as cfhks
from cfsig.descriptors import layout
from cfsig.descriptors.parts import (
    SHARES,
    curvature_columns,
    measure_part,
    one_sidedness,
    partial_file,
    partial_vectors,
    share_curvatures,
)
from cfsig.descriptors.signature import compute_signature, signature_file
from cfsig.errors import PartialError
from cfsig.evaluation import collections
from cfsig.evaluation.collections import evaluate_partial
from cfsig.evaluation.measures import evaluate_queries
from cfsig.files.mesh import clean_mesh
from cfsig.index.store import IndexReader
from cfsig.params import Params
from cfsig.repair.stage import drop_small_pieces
from cfsig.search.partial import (
    CANDIDATES,
    CLOSED_SCALE,
    HISTOGRAM_WEIGHT,
    candidates,
    expanded_distances,
    fused_scores,
    partial_distances,
    partial_scores,
    query_part,
    share_queries,
)
from tests.crashing import part_or_crash
from tests.helpers import icosphere, open_cylinder, torus, write_off

DEFAULT = Params()


def _bumpy(levels=3):
    v, f = icosphere(levels)
    v = v * [1.0, 0.6, 0.5]
    v[:, 0] += 1.5 * np.clip(v[:, 0], 0, None) ** 4
    return v, f


def _cut(v, f, keep):
    """The faces whose centroid has x < keep, their vertices renumbered."""
    kept = f[v[f].mean(axis=1)[:, 0] < keep]
    used, inverse = np.unique(kept, return_inverse=True)
    return v[used], inverse.reshape(-1, 3)


def test_only_the_curvature_channel_takes_partial_queries():
    columns = curvature_columns(DEFAULT)
    assert columns.stop == cfhks.LENGTH == layout(DEFAULT).length
    assert columns.stop - columns.start == np.prod(cfhks.CURVATURE_SHAPE)
    with pytest.raises(PartialError, match="build one with 'cfsig index FOLDER -o NEW'"):
        curvature_columns(Params(descriptor="cf"))


@pytest.mark.parametrize("levels", [3, 4])
def test_a_whole_as_its_own_part_matches_its_signature(levels):
    """A whole of more than 4000 faces (levels 4) is measured on its simplified copy, and so is
    its part: each share is solved alone, from the same guesses as the whole, so the two agree.
    A smaller one up to the curvature's conjugate gradients, which start from other guesses
    here: to 1e-3, within 5% of the distance to another shape."""
    params = DEFAULT
    mesh = clean_mesh(*_bumpy(levels=levels))
    vectors = partial_vectors(mesh, params)
    columns = curvature_columns(params)
    assert vectors.shape == (len(SHARES), columns.stop - columns.start) and SHARES[0] == 1.0
    stored = compute_signature(mesh, params).vector[columns]
    if levels == 4:
        assert np.allclose(vectors[0], stored)
    else:
        other = compute_signature(clean_mesh(*torus()), params).vector[columns]
        assert np.abs(vectors[0] - stored).sum() < 0.05 * np.abs(other - stored).sum()


def test_share_curvatures_are_what_partial_vectors_histogram():
    mesh = clean_mesh(*_bumpy(levels=4))  # more faces than a copy: measured on copies
    ((values, areas),) = share_curvatures(mesh, DEFAULT, (SHARES[2],))
    assert values.shape == (len(areas), len(cfhks.SCALES)) and np.all(areas > 0)
    histograms = cfhks.curvature_histograms(values, areas)
    assert np.array_equal(cfhks.weigh_curvature(histograms), partial_vectors(mesh, DEFAULT)[2])


def test_evaluate_queries_by_hand():
    distances = np.array([[0.1, 0.5, 0.2], [0.3, 0.2, 0.1]])
    report = evaluate_queries(distances, ["a", "b"], ["a", "a", "b"])
    a, b = report.per_class["a"], report.per_class["b"]
    assert a["NN"] == 1 and a["FT"] == 0.5 and a["mAP"] == pytest.approx((1 + 2 / 3) / 2)
    assert b["NN"] == 1 and b["FT"] == 1 and report.count == 2
    assert np.array_equal(report.per_query[:, 1], [0.5, 1.0])
    with pytest.raises(ValueError, match="no query's class"):
        evaluate_queries(distances, ["c", "c"], ["a", "a", "b"])


@pytest.fixture(scope="module", params=["columns", "cells"])
def wholes(request, tmp_path_factory):
    """An index of four kinds of whole shape, two of each, and parts cut from them: without
    fine cells (partial queries by the curvature columns) and with them."""
    root = tmp_path_factory.mktemp("parts")
    shapes = {
        "torus": torus(),
        "bumpy": _bumpy(),
        "sphere": icosphere(3),
        "tube": open_cylinder(),  # open at both ends: the index's repair stage closes it
    }
    for name, (v, f) in shapes.items():
        for copy in range(2):
            write_off(root / "wholes" / name / f"{copy}.off", v * (1 + copy), f)
    for name in ("torus", "bumpy"):
        v, f = shapes[name]
        write_off(root / "parts" / name / "cut.off", *_cut(v, f, 0.3))
    index = root / "index"
    cells = ["--partial-cells"] if request.param == "cells" else []
    result = CliRunner().invoke(main, ["index", str(root / "wholes"), "-o", str(index), *cells])
    assert result.exit_code == 0, result.output
    return root, index


def test_query_partial_finds_the_whole(wholes):
    root, index = wholes
    for name in ("torus", "bumpy"):
        part = root / "parts" / name / "cut.off"
        result = CliRunner().invoke(main, ["query", str(index), str(part), "--partial", "--json"])
        assert result.exit_code == 0, result.output
        hits = json.loads(result.output)
        assert hits[0]["label"] == name and hits[0]["distance"] == 0.0
        assert [h["rank"] for h in hits] == list(range(1, len(hits) + 1))
        text = CliRunner().invoke(main, ["query", str(index), str(part), "--partial"]).output
        with IndexReader(index) as reader:
            fit = query_part(reader, partial_file(part, reader.params), 3)[1]
        assert text.splitlines()[0] == f"# {part}  (partial distance {fit:.4f})" and fit > 0
        assert hits[0]["partial_distance"] == fit
        assert all("partial_distance" not in h for h in hits[1:])


def test_partial_scores_are_the_unexplained_share_plus_the_distance():
    rng = np.random.default_rng(0)

    def histograms(n):  # two scales of four bins, each summing to 1: mass 2
        h = rng.random((n, 2, 4))
        return (h / h.sum(axis=2, keepdims=True)).reshape(n, 8)

    wholes, part = histograms(5), histograms(len(SHARES))
    l1 = np.abs(share_queries(part)[:, None, :] - wholes[None]).sum(axis=2)
    direct = [
        np.maximum(f * p - wholes, 0).sum(axis=1) / (2 * f)
        + HISTOGRAM_WEIGHT * np.abs(p - wholes).sum(axis=1) / 2
        for f, p in zip(SHARES, part, strict=True)
    ]
    assert np.allclose(partial_scores(l1, 2.0), np.min(direct, axis=0))


def test_a_whole_that_holds_the_part_explains_it():
    # Half the whole's mass in each bin; the part all in the first: the whole holds it at the
    # share 1/2, only half of it at the share 1.
    whole, part = np.array([[0.5, 0.5]]), np.tile([1.0, 0.0], (len(SHARES), 1))
    l1 = np.abs(share_queries(part)[:, None, :] - whole[None]).sum(axis=2)
    assert partial_scores(l1, 1.0)[0] == pytest.approx(HISTOGRAM_WEIGHT * 1.0)
    assert partial_scores(np.zeros((2 * len(SHARES), 1)), 1.0)[0] == 0.0


def test_partial_search_scores_as_partial_distances(wholes):
    root, index = wholes
    with IndexReader(index) as reader:
        signatures = reader.signatures[:]
        for name in ("torus", "bumpy"):
            part = partial_file(root / "parts" / name / "cut.off", reader.params)
            hits, distance = query_part(reader, part, 3)
            in_memory = partial_distances(part, signatures, reader.params, reader.cells())
            assert hits[0].entry.label == name
            assert distance == pytest.approx(in_memory.min(), rel=1e-5)


def test_evaluate_partial(wholes):
    root, index = wholes
    args = ["evaluate", "--index", str(index), "--partial", str(root / "parts"), "--json"]
    result = CliRunner().invoke(main, args)
    assert result.exit_code == 0, result.output
    report = json.loads(result.output)
    assert report["count"] == 2 and report["measures"]["NN"] == 1.0


def test_a_part_that_crashes_its_worker_fails_alone(wholes, tmp_path, monkeypatch):
    root, index = wholes
    parts = tmp_path / "parts"
    for name in ("torus", "bumpy"):
        (parts / name).mkdir(parents=True)
        (parts / name / "cut.off").write_bytes((root / "parts" / name / "cut.off").read_bytes())
    (parts / "torus" / "crash.off").write_bytes((parts / "torus" / "cut.off").read_bytes())
    monkeypatch.setattr(collections, "_part_file", part_or_crash)
    report, failures = evaluate_partial(index, parts, jobs=2)
    assert report.count == 2 and report.measures["NN"] == 1.0
    assert len(failures) == 1 and "crash.off" in failures[0] and "crashed" in failures[0]


def test_partial_query_of_an_old_index_is_refused(tmp_path, wholes):
    root, _ = wholes
    index = tmp_path / "v2"
    args = ["index", str(root / "wholes"), "-o", str(index), "--descriptor", "cf"]
    assert CliRunner().invoke(main, args).exit_code == 0
    part = root / "parts" / "torus" / "cut.off"
    result = CliRunner().invoke(main, ["query", str(index), str(part), "--partial"])
    assert result.exit_code != 0 and "build one with" in result.output
    assert "Traceback" not in result.output and len(result.output.strip().splitlines()) == 1


def test_fused_scores_weigh_the_closed_distance_by_how_near_it_comes():
    partial = np.array([1.0, 1.2, 2.0])
    assert np.array_equal(fused_scores(partial, None), partial)
    # The closed part is one of the wholes: that whole stands for the part.
    assert np.argmin(fused_scores(partial, np.array([3.0, 0.0, 3.0]))) == 1
    # It lies far from every whole: the partial distance decides.
    far = 50 * CLOSED_SCALE + np.array([0.5, 0.0, 0.5])
    assert np.argmin(fused_scores(partial, far)) == 0
    # Near one: it decides against a small lead of the partial distance.
    near = CLOSED_SCALE * np.array([1.0, 0.2, 1.0])
    assert np.argmin(fused_scores(partial, near)) == 1
    # The partial distance counts relative to its least: its unit does not matter.
    assert np.allclose(fused_scores(7 * partial, near), fused_scores(partial, near))


def test_candidates_are_the_nearest_by_each_measure():
    partial = np.arange(100.0)
    assert np.array_equal(candidates(partial, None), np.arange(CANDIDATES))
    both = candidates(partial, partial[::-1].copy())
    assert np.array_equal(both, np.r_[0:CANDIDATES, 100 - CANDIDATES : 100])


def test_a_part_is_also_measured_closed_as_its_file_is_computed(wholes):
    root, _ = wholes
    path = root / "parts" / "torus" / "cut.off"
    part = partial_file(path, DEFAULT)
    assert part.closed is not None
    assert np.array_equal(part.closed, signature_file(path, DEFAULT).vector)


def test_a_partial_query_ranks_the_index_as_in_memory(wholes):
    root, index = wholes
    with IndexReader(index) as reader:
        signatures, cells = reader.signatures[:], reader.cells()
        for name in ("torus", "bumpy"):
            part = partial_file(root / "parts" / name / "cut.off", reader.params)
            hits, _ = query_part(reader, part, 8)
            in_memory = expanded_distances(part, signatures, reader.params, cells)
            order = np.argsort(in_memory, kind="stable")
            assert [h.entry for h in hits] == reader.entries(order[: len(hits)])


def test_a_single_view_is_one_sided_and_a_closed_surface_is_not():
    v, f = icosphere(3)
    upper = f[v[f].mean(axis=1)[:, 2] > 0.05]  # a cap seen from above: every face turns up
    assert one_sidedness(clean_mesh(v, upper)) == 1.0
    assert one_sidedness(clean_mesh(v, f)) < 0.05
    half = f[v[f].mean(axis=1)[:, 0] < 0.3]  # a cut that wraps around: faces turn many ways
    assert 0.2 < one_sidedness(clean_mesh(v, half)) < 0.9


def test_a_single_view_is_ranked_by_its_closed_distance():
    partial, closed = np.array([1.0, 3.0]), CLOSED_SCALE * np.array([9.0, 8.0])
    assert np.argmin(fused_scores(partial, closed)) == 0
    assert np.argmin(fused_scores(partial, closed, one_sided=1.0)) == 1


def test_a_part_whose_closed_copy_is_a_whole_ranks_that_whole_first(wholes):
    root, index = wholes
    with IndexReader(index) as reader:
        signatures, cells = reader.signatures[:], reader.cells()
        part = partial_file(root / "parts" / "torus" / "cut.off", reader.params)
        sphere = int(reader.find(["sphere/0.off"])[0])
        part = replace(part, closed=signatures[sphere].astype(np.float64))
        hits, _ = query_part(reader, part, 8)
        assert hits[0].entry.label == "sphere" and hits[0].distance == 0.0
        in_memory = expanded_distances(part, signatures, reader.params, cells)
        order = np.argsort(in_memory, kind="stable")
        assert [h.entry for h in hits] == reader.entries(order[: len(hits)])


def _with_confetti(v, f, count):
    """The mesh and ``count`` small triangles beside it, each its own piece."""
    corner = v.max(axis=0) + 1.0
    size = 0.01 * np.ptp(v, axis=0).max()
    bits = (
        corner
        + size * np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0]])
        + 3 * size * np.arange(count)[:, None, None]
    )
    faces = len(v) + np.arange(3 * count).reshape(-1, 3)
    return np.concatenate([v, bits.reshape(-1, 3)]), np.concatenate([f, faces])


def test_a_part_is_measured_without_its_confetti():
    v, f = _cut(*_bumpy(), 0.3)
    part = clean_mesh(v, f)
    littered = clean_mesh(*_with_confetti(v, f, 40))
    kept = drop_small_pieces(littered)
    assert np.array_equal(kept.vertices, part.vertices) and np.array_equal(kept.faces, part.faces)
    cells = Params(partial_cells=True)
    plain, measured = measure_part(part, cells), measure_part(littered, cells)
    assert plain.cells is not None and measured.cells is not None
    for (c1, w1), (c2, w2) in zip(plain.cells, measured.cells, strict=True):
        assert np.array_equal(c1, c2) and np.array_equal(w1, w2)
    assert np.array_equal(plain.closed, measured.closed)


def test_pieces_of_a_part_that_hold_their_share_are_kept():
    v, f = icosphere(2)
    two = clean_mesh(np.concatenate([v, v + 3.0]), np.concatenate([f, f + len(v)]))
    assert drop_small_pieces(two) is two  # each holds half the area
    triangle = np.array([[0.0, 0, 0], [1, 0, 0], [0, 1, 0]])
    grains = triangle + 2.0 * np.arange(200)[:, None, None]  # 200 equal triangles apart
    dust = clean_mesh(grains.reshape(-1, 3), np.arange(600).reshape(-1, 3))
    assert drop_small_pieces(dust) is dust  # no piece holds 1%: nothing to prefer
