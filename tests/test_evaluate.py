"""Tests for cfsig.evaluation.measures, cfsig.files.cla and cfsig.evaluation.collections: PSB
measures, .cla files, collections."""

import json
import math
from pathlib import Path

import numpy as np
import pytest

from cfsig.descriptors.signature import signature_file
from cfsig.errors import IndexFileError, MeshError
from cfsig.evaluation.collections import (
    Collection,
    collection_from_index,
    compute_collection,
    evaluate_collections,
)
from cfsig.evaluation.measures import MEASURES, RetrievalReport, evaluate_distances
from cfsig.files.cla import read_cla
from cfsig.files.demo import write_off
from cfsig.index.store import IndexReader
from cfsig.params import Params
from tests.helpers import icosphere, torus

SHREC07_CLA = Path("/work/shared/data/shrec07.cla")


def _from_rankings(rankings: list[list[int]], diagonal: float = 0.0) -> np.ndarray:
    """Distance matrix whose row i ranks the other models in the order rankings[i]."""
    n = len(rankings)
    d = np.full((n, n), diagonal)
    for i, ranking in enumerate(rankings):
        d[i, ranking] = np.arange(1, n)
    return d


def _reference(distances: np.ndarray, labels: list[str]) -> tuple[dict, np.ndarray, int]:
    """Straightforward per-query loop implementation of the PSB measures."""
    n = len(labels)
    scores, curves = [], []
    for q in range(n):
        ranking = sorted((j for j in range(n) if j != q), key=lambda j: (distances[q, j], j))
        rel = [labels[j] == labels[q] for j in ranking]
        nrel = sum(rel)
        if nrel == 0:
            continue
        hits = np.cumsum(rel)
        top = rel[:32]
        p, r = sum(top) / len(top), sum(top) / nrel
        dcg = sum(g / (1.0 if i == 1 else math.log2(i)) for i, g in enumerate(rel, 1))
        ideal = 1 + sum(1 / math.log2(j) for j in range(2, nrel + 1))
        precision = [h / i for i, h in enumerate(hits, 1)]
        ap = np.mean([p_i for p_i, g in zip(precision, rel, strict=True) if g])
        curve = [
            max(p_i for p_i, h in zip(precision, hits, strict=True) if 20 * h >= level * nrel)
            for level in range(1, 21)
        ]
        e = 0.0 if p == 0 else 2 / (1 / p + 1 / r)
        nn, ft, st = rel[0], hits[nrel - 1] / nrel, hits[min(2 * nrel, n - 1) - 1] / nrel
        scores.append([nn, ft, st, e, dcg / ideal, ap])
        curves.append(curve)
    return (
        dict(zip(MEASURES, np.mean(scores, axis=0), strict=True)),
        np.mean(curves, axis=0),
        len(scores),
    )


def test_perfect_retrieval_scores_one():
    labels = ["a"] * 4 + ["b"] * 3 + ["c"] * 5
    codes = np.unique(labels, return_inverse=True)[1]
    d = (codes[:, None] != codes[None, :]).astype(float)  # 0 within class (ties), 1 across
    report = evaluate_distances(d, labels)
    assert report.count == 12
    perfect = dict.fromkeys(("NN", "FT", "ST", "DCG", "mAP"), 1.0)
    for m in [report.measures, *report.per_class.values()]:
        assert {k: m[k] for k in perfect} == pytest.approx(perfect)
    assert set(report.per_class) == {"a", "b", "c"}
    # E over the top 32, here all 11 results: P = (C-1)/11, R = 1, so E = 2(C-1)/(11 + C-1).
    e = [2 * (c - 1) / (11 + c - 1) for c in (4, 3, 5)]
    assert report.measures["E"] == pytest.approx((4 * e[0] + 3 * e[1] + 5 * e[2]) / 12)
    assert report.precision_recall.shape == (20, 2)
    np.testing.assert_allclose(report.precision_recall[:, 0], np.arange(1, 21) / 20)
    np.testing.assert_allclose(report.precision_recall[:, 1], 1.0)


def test_hand_computed_example():
    labels = ["a", "a", "a", "b", "b"]
    d = _from_rankings(
        [
            [1, 3, 2, 4],  # q0 (a): relevant at ranks 1, 3
            [3, 4, 0, 2],  # q1 (a): relevant at ranks 3, 4
            [0, 1, 3, 4],  # q2 (a): relevant at ranks 1, 2 (perfect)
            [4, 0, 1, 2],  # q3 (b): relevant at rank 1 (perfect)
            [0, 3, 1, 2],  # q4 (b): relevant at rank 2
        ]
    )
    # Per query, class a has C-1 = 2 relevant, class b has 1; there are 4 results in all.
    # NN : 1, 0, 1, 1, 0                                      -> mean 3/5
    # FT : top 2 / top 2 / top 2 / top 1 / top 1 -> 1/2, 0, 1, 1, 0   -> mean 1/2
    # ST : top 4 for a, top 2 for b -> all 1                  -> mean 1
    # E  : top 32 = all 4 results: a: P=2/4, R=1 -> 2/3; b: P=1/4, R=1 -> 2/5 -> mean 2.8/5
    # DCG: ideal a = 1 + 1/log2(2) = 2, ideal b = 1
    #      q0 (1 + 1/log2 3)/2, q1 (1/log2 3 + 1/log2 4)/2, q2 1, q3 1, q4 1/log2(2) = 1
    # AP : q0 (1 + 2/3)/2 = 5/6, q1 (1/3 + 2/4)/2 = 5/12, q2 1, q3 1, q4 1/2 -> mean 3/4
    # P/R: interpolated precision: q0 1 up to recall 0.5 then 2/3, q1 1/2, q2 1, q3 1, q4 1/2
    #      -> mean 4/5 for recall <= 0.5, (2/3 + 1/2 + 1 + 1 + 1/2)/5 = 11/15 above
    report = evaluate_distances(d, labels)
    dcg = [(1 + 1 / math.log2(3)) / 2, (1 / math.log2(3) + 0.5) / 2, 1, 1, 1]
    expected = {"NN": 0.6, "FT": 0.5, "ST": 1.0, "E": 0.56, "DCG": np.mean(dcg), "mAP": 0.75}
    assert report.measures == pytest.approx(expected)
    assert report.count == 5
    assert report.per_class["a"]["NN"] == pytest.approx(2 / 3)
    assert report.per_class["a"]["mAP"] == pytest.approx((5 / 6 + 5 / 12 + 1) / 3)
    assert report.per_class["b"] == pytest.approx(
        {"NN": 0.5, "FT": 0.5, "ST": 1.0, "E": 0.4, "DCG": 1.0, "mAP": 0.75}
    )
    expected_curve = np.where(np.arange(1, 21) <= 10, 4 / 5, 11 / 15)
    np.testing.assert_allclose(report.precision_recall[:, 1], expected_curve)


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_matches_loop_reference_with_ties(seed):
    rng = np.random.default_rng(seed)
    n = 60
    labels = [f"c{k}" for k in rng.integers(0, 7, n)]
    d = rng.integers(0, 5, (n, n)).astype(float)  # many ties: exercises the index tie-break
    report = evaluate_distances(d, labels)
    measures, curve, count = _reference(d, labels)
    assert report.count == count
    assert report.measures == pytest.approx(measures)
    np.testing.assert_allclose(report.precision_recall[:, 1], curve)


def test_random_distances_near_chance():
    rng = np.random.default_rng(42)
    n, classes = 2000, 20
    labels = [str(i % classes) for i in range(n)]
    report = evaluate_distances(rng.random((n, n)), labels)
    chance = (n // classes - 1) / (n - 1)
    assert report.measures["FT"] == pytest.approx(chance, abs=0.005)
    assert report.measures["ST"] == pytest.approx(2 * chance, abs=0.01)
    assert report.measures["NN"] == pytest.approx(chance, abs=0.02)
    assert report.measures["mAP"] < 2 * chance


def test_query_is_left_out_of_its_own_ranking():
    # Pairs (0, 1) and (2, 3); each model's nearest other model is in the other pair.
    labels = ["a", "a", "b", "b"]
    d = _from_rankings([[2, 1, 3], [3, 0, 2], [0, 3, 1], [1, 2, 0]])
    for diagonal in (0.0, -1.0, np.inf):
        np.fill_diagonal(d, diagonal)
        report = evaluate_distances(d, labels)
        assert report.measures["NN"] == 0.0
        assert report.measures["FT"] == 0.0
        assert report.measures["mAP"] == pytest.approx(0.5)


def test_single_member_classes_are_excluded():
    labels = ["a", "b", "a", "c"]
    d = np.zeros((4, 4))  # all ties: ranking by index
    report = evaluate_distances(d, labels)
    # q0 ranks 1(b), 2(a), 3(c): NN 0; q2 ranks 0(a), 1, 3: NN 1. Queries 1 and 3 excluded.
    assert report.count == 2
    assert set(report.per_class) == {"a"}
    assert report.measures["NN"] == pytest.approx(0.5)
    assert report.measures["mAP"] == pytest.approx((1 / 2 + 1) / 2)


@pytest.mark.parametrize(
    ("distances", "labels", "match"),
    [
        (np.zeros((3, 4)), ["a", "a", "b"], "square"),
        (np.zeros(3), ["a", "a", "b"], "square"),
        (np.zeros((3, 3)), ["a", "a"], "labels"),
        (np.array([[0, np.nan], [1, 0]]), ["a", "a"], "NaN"),
        (np.zeros((3, 3)), ["a", "b", "c"], "two members"),
    ],
)
def test_bad_input_raises(distances, labels, match):
    with pytest.raises(ValueError, match=match):
        evaluate_distances(distances, labels)


def test_to_dict_is_json_serialisable():
    report = evaluate_distances(_from_rankings([[1, 2], [0, 2], [0, 1]]), ["a", "a", "b"])
    assert isinstance(report, RetrievalReport)
    data = json.loads(json.dumps(report.to_dict()))
    assert set(data) == {"measures", "per_class", "precision_recall", "count"}
    assert set(data["measures"]) == set(MEASURES)
    assert data["count"] == 2
    assert len(data["precision_recall"]) == 20 and data["precision_recall"][-1] == [1.0, 1.0]


def _write_cla(path: Path, classes: dict[str, list[str]]) -> None:
    """Write a PSB classification file with blank lines between classes."""
    lines = ["PSB 1", f"{len(classes)} {sum(map(len, classes.values()))}", ""]
    for name, ids in classes.items():
        lines += [f"{name} 0 {len(ids)}", *ids, ""]
    path.write_text("\n".join(lines))


def test_read_cla_round_trip(tmp_path):
    classes = {"human": ["1", "2", "007"], "cup": ["m10", "4"], "empty": []}
    path = tmp_path / "test.cla"
    _write_cla(path, classes)
    assert read_cla(path) == {m: name for name, ids in classes.items() for m in ids}


@pytest.mark.parametrize(
    ("text", "match"),
    [
        ("PSB 2\n1 1\na 0 1\n1\n", "PSB 1"),
        ("", "PSB 1"),
        ("PSB 1\n1\na 0 1\n1\n", "numClasses numModels"),
        ("PSB 1\n1 x\na 0 1\n1\n", "integer"),
        ("PSB 1\n1 1\na 0 one\n1\n", "integer"),
        ("PSB 1\n1 2\na 0 3\n1\n2\n", "3 model ids"),
        ("PSB 1\n2 2\na 0 1\n1\n2\nb 0 0\n", "name parentName count"),
        ("PSB 1\n2 2\na 0 1\n1\n", "ends before"),
        ("PSB 1\n1 2\na 0 1\n1\n2\n", "extra lines"),
        ("PSB 1\n1 3\na 0 2\n1\n2\n", "declares 3 models"),
        ("PSB 1\n2 2\na 0 1\n1\nb 0 1\n1\n", "duplicate model id"),
    ],
)
def test_read_cla_malformed(tmp_path, text, match):
    path = tmp_path / "bad.cla"
    path.write_text(text)
    with pytest.raises(ValueError, match=match):
        read_cla(path)


@pytest.mark.skipif(not SHREC07_CLA.exists(), reason=f"{SHREC07_CLA} not available")
def test_read_cla_shrec07():
    classes = read_cla(SHREC07_CLA)
    assert set(classes) == {str(i) for i in range(1, 401)}
    names, counts = np.unique(list(classes.values()), return_counts=True)
    assert len(names) == 20 and (counts == 20).all()
    assert classes["1"] == "human"


@pytest.fixture(scope="module")
def folder(tmp_path_factory):
    """Five small meshes in two class folders, one directly inside, and a broken file."""
    root = tmp_path_factory.mktemp("collection") / "shapes"
    (root / "round").mkdir(parents=True)
    (root / "ring").mkdir()
    v, f = icosphere(1)
    for name, scale in zip("abc", ([1, 1, 1], [1, 0.8, 0.6], [1.5, 1, 1]), strict=True):
        write_off(root / "round" / f"{name}.off", v * scale, f)
    for name, r in (("d", 0.35), ("e", 0.2)):
        write_off(root / "ring" / f"{name}.off", *torus(r=r, nu=16, nv=6))
    write_off(root / "loose.off", v * [1, 1, 2], f)
    (root / "ring" / "broken.off").write_text("OFF\n3 1 0\n0 0 0\n")
    return root


@pytest.fixture(scope="module")
def computed(folder):
    """The cf collection of ``folder``, its failures and what the progress callback saw."""
    seen = []

    def progress(outcomes, total):
        for outcome in outcomes:
            seen.append((total(), outcome.path.name))
            yield outcome

    collection, failures = compute_collection(
        folder, Params(descriptor="cf"), jobs=1, progress=progress
    )
    return collection, failures, seen


def test_compute_collection_in_file_order_with_folder_labels(folder, computed):
    collection, failures, seen = computed
    names = ("loose.off", "ring/d.off", "ring/e.off", "round/a.off", "round/b.off", "round/c.off")
    assert collection.names == names
    assert collection.labels == ("shapes", "ring", "ring", "round", "round", "round")
    assert collection.paths == tuple(str(folder / name) for name in names)
    assert collection.signatures.shape == (6, Params(descriptor="cf").bins)
    expected = signature_file(folder / "round" / "b.off", Params(descriptor="cf"), "auto").vector
    assert np.array_equal(collection.signatures[4], expected)
    assert collection.seconds.shape == (6,) and (collection.seconds > 0).all()
    assert len(failures) == 1 and failures[0].startswith(f"{folder / 'ring' / 'broken.off'}: ")
    files = [Path(name).name for name in names] + ["broken.off"]
    assert sorted(seen) == sorted((7, name) for name in files)


def test_compute_collection_every_file_failing(tmp_path):
    for name in ("x.off", "y.off"):
        (tmp_path / "a" / name).parent.mkdir(exist_ok=True)
        (tmp_path / "a" / name).write_text("OFF\n")
    collection, failures = compute_collection(tmp_path, Params(descriptor="cf", bins=50), jobs=1)
    assert len(collection) == 0 and collection.signatures.shape == (0, 50)
    assert sorted(line.split(":")[0] for line in failures) == [  # in order of completion
        str(tmp_path / "a" / "x.off"),
        str(tmp_path / "a" / "y.off"),
    ]
    _, failures = compute_collection(
        tmp_path, Params(descriptor="cf", bins=50), jobs=1, strict=True
    )
    assert len(failures) == 1


def test_compute_collection_empty_folder(tmp_path):
    (tmp_path / "notes.txt").write_text("no meshes here")
    with pytest.raises(MeshError, match="no mesh files"):
        compute_collection(tmp_path, Params(descriptor="cf"))


def test_collection_from_index(tmp_path, build_index):
    hists = build_index(tmp_path / "i.h5", 5, Params(descriptor="cf"))
    descriptor, collection = collection_from_index(tmp_path / "i.h5")
    assert descriptor == "cf" and collection.seconds is None
    assert collection.names == tuple(f"c{i % 3}/{i}.off" for i in range(5))
    assert collection.labels == tuple(f"c{i % 3}" for i in range(5))
    assert collection.paths == tuple(f"/data/c{i % 3}/{i}.off" for i in range(5))
    with IndexReader(tmp_path / "i.h5") as reader:
        assert np.array_equal(collection.signatures, reader.signatures[:])
    assert np.allclose(collection.signatures, hists, atol=1e-7)
    with pytest.raises(IndexFileError):
        collection_from_index(tmp_path / "missing.h5")


def _collection(names, labels, seed, seconds=None) -> Collection:
    """Random histograms for some names; timed when ``seconds`` is given."""
    rows = np.random.default_rng(seed).random((len(names), 8))
    seconds = None if seconds is None else np.asarray(seconds, float)
    paths = tuple(f"/m/{name}" for name in names)
    return Collection(
        tuple(names), tuple(labels), paths, rows / rows.sum(1, keepdims=True), seconds
    )


def test_evaluate_collections_on_the_common_labelled_meshes():
    first = _collection(["a1", "a2", "b1", "b2", "b3", "x"], "aabbbz", 1, [1, 2, 3, 4, 5, 60])
    second = _collection(["b3", "a1", "b1", "a2", "b2"], "baaab", 2)  # no "x", other order
    results = evaluate_collections({"one": first, "two": second})
    assert list(results) == ["one", "two"]
    one, two = results["one"], results["two"]
    assert one.collection.names == ("a1", "a2", "b1", "b2", "b3")
    assert two.collection.names == ("b3", "a1", "b1", "a2", "b2")
    assert two.collection.labels == tuple("baaab")
    rows = first.signatures[:5]
    expected = np.abs(rows[:, None, :] - rows[None, :, :]).sum(axis=2)
    assert np.allclose(one.distances, expected, atol=1e-6)
    report = evaluate_distances(one.distances, list("aabbb"))
    assert one.report.measures == report.measures and one.report.count == 5
    assert one.seconds_per_mesh == 3.5  # over the whole collection, "x" included
    assert two.seconds_per_mesh is None


def test_evaluate_collections_with_classes_from_a_cla_mapping():
    collection = _collection(["m1", "2", "3", "4", "5"], "zzzzz", 3)
    classes = {"1": "p", "2": "p", "4": "q", "5": "q"}  # "3" has no class
    (result,) = evaluate_collections({"cf": collection}, classes).values()
    assert result.collection.names == ("m1", "2", "4", "5")
    assert result.collection.labels == ("p", "p", "q", "q")
    assert set(result.report.per_class) == {"p", "q"} and result.report.count == 4


def test_evaluate_collections_errors():
    with pytest.raises(ValueError, match="no collection"):
        evaluate_collections({})
    disjoint = _collection(["a", "b"], "cc", 4), _collection(["d", "e"], "cc", 5)
    with pytest.raises(ValueError, match="at least two members"):
        evaluate_collections(dict(zip("xy", disjoint, strict=True)))


def test_collection_columns_must_agree():
    with pytest.raises(ValueError, match="one name, label, path"):
        Collection(("a", "b"), ("c",), ("/a", "/b"), np.zeros((2, 4)))
    with pytest.raises(ValueError, match="one name, label, path"):
        Collection(("a",), ("c",), ("/a",), np.zeros((1, 4)), np.ones(2))
    sub = _collection(["a", "b", "c"], "xyz", 6, [1, 2, 3]).subset([2, 0])
    assert sub.names == ("c", "a") and sub.labels == ("z", "x") and list(sub.seconds) == [3, 1]
