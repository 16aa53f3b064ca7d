"""An index that follows its folders: pruning, removal, labels from a .cla file, `info`,
queries by an indexed name, near-duplicates of the whole index, and folders reached by links."""

import json
import shutil
from collections import Counter
from dataclasses import replace
from datetime import datetime, timezone

import numpy as np
import pytest
from click.testing import CliRunner

import cfsig
import cfsig.search.nearest
from cfsig.cli import main
from cfsig.files.demo import make_demo_collection
from cfsig.index.segments import write_segment
from cfsig.index.store import (
    Entry,
    IndexReader,
    SegmentInfo,
    check_index,
    file_crc,
    index_info,
    read_manifest,
    write_manifest,
)
from cfsig.search.duplicates import duplicate_groups, nearest_all
from cfsig.search.nearest import l1_distances
from tests.helpers import build_index, open_writer, random_signature


@pytest.fixture(scope="module")
def meshes(tmp_path_factory):
    """Six classes of two generated meshes each."""
    folder = tmp_path_factory.mktemp("upkeep") / "meshes"
    make_demo_collection(folder, per_class=2)
    return folder


@pytest.fixture(scope="module")
def indexed(meshes, tmp_path_factory):
    """An index of `meshes`, to copy before changing it."""
    index = tmp_path_factory.mktemp("upkeep-index") / "index"
    result = _run("index", meshes, "-o", index, "-j", "2")
    assert result.exit_code == 0, result.output
    return index


def _run(*args):
    return CliRunner().invoke(main, [str(a) for a in args])


def _names(index):
    with IndexReader(index) as reader:
        return set(reader.column("names"))


def _queried(index, mesh, k=50):
    """The names a query of a mesh file ranks (every entry, with k large)."""
    result = _run("query", index, mesh, "-k", k, "--json")
    assert result.exit_code == 0, result.output
    return [hit["name"] for hit in json.loads(result.stdout)]


def _rows(index):
    """Name -> (label, vector, sha256) of every entry."""
    with IndexReader(index) as reader:
        columns = [reader.column(key) for key in ("names", "labels", "sha256")]
        vectors = reader.signatures[:]
    names, labels, hashes = columns
    return {n: (lab, v, h) for n, lab, v, h in zip(names, labels, vectors, hashes, strict=True)}


def _one_line_error(result, *words):
    assert result.exit_code == 1, result.output
    (line,) = result.output.strip().splitlines()
    assert line.startswith("Error: ") and "Traceback" not in result.output
    for word in words:
        assert word in line


def _state(index):
    """The bytes of every file of an index but its lock."""
    return {p.name: p.read_bytes() for p in sorted(index.iterdir()) if p.name != "lock"}


def test_prune_and_remove_drop_rows_from_queries_at_once(meshes, indexed, tmp_path):
    folder, index = tmp_path / "meshes", tmp_path / "index"
    shutil.copytree(meshes, folder)
    shutil.copytree(indexed, index)
    result = _run("index", folder, "-o", index, "-j", "1")  # the same files, moved
    assert result.exit_code == 0 and "0 meshes added or updated, 12 relabelled or moved" in (
        result.output
    )
    (folder / "torus" / "torus-0.off").unlink()
    shutil.rmtree(folder / "capsule")
    gone = {"torus/torus-0.off", "capsule/capsule-0.off", "capsule/capsule-1.off"}
    query = folder / "torus" / "torus-1.off"
    result = _run("index", folder, "-o", index, "-j", "1")  # without --prune nothing is dropped
    assert result.exit_code == 0 and gone <= _names(index)
    result = _run("index", folder, "-o", index, "-j", "1", "--prune")
    assert result.exit_code == 0, result.output
    assert "0 meshes added or updated, 3 dropped (their files are gone), 9 in the index" in (
        result.output
    )
    assert not gone & _names(index) and not gone & set(_queried(index, query))
    result = _run("remove", index, "limbs1/limbs1-0.off", "limbs2/limbs2-1.off")
    assert result.exit_code == 0 and "2 entries removed, 7 in the index" in result.output
    ranked = _queried(index, query)
    assert len(ranked) == 7 and not {"limbs1/limbs1-0.off", "limbs2/limbs2-1.off"} & set(ranked)
    assert index_info(index).rows == 7 and check_index(index) == []
    with IndexReader(index) as reader:
        stored = reader.physical_rows
    assert _run("compact", index).exit_code == 0  # the rows leave the disk
    with IndexReader(index) as reader:
        assert reader.physical_rows == len(reader) == 7 < stored
    assert _queried(index, query) == ranked and check_index(index) == []


def test_remove_refuses_unknown_names_and_a_locked_index(indexed, tmp_path):
    index = tmp_path / "index"
    shutil.copytree(indexed, index)
    before = _state(index)
    result = _run("remove", index, "torus/torus-0.off", "no/such.off")
    _one_line_error(result, str(index), "no/such.off")
    assert _state(index) == before
    with open_writer(index, read_manifest(index).params):  # another writer holds the lock
        result = _run("remove", index, "torus/torus-0.off")
    _one_line_error(result, "another process is writing this index")
    assert _state(index) == before
    _one_line_error(_run("remove", tmp_path / "none", "a.off"), "no such index")


def test_info_gives_the_counts(indexed, tmp_path):
    index = tmp_path / "index"
    shutil.copytree(indexed, index)
    assert _run("remove", index, "torus/torus-0.off").exit_code == 0
    result = _run("info", index, "--json")
    assert result.exit_code == 0, result.output
    facts = json.loads(result.stdout)
    with IndexReader(index) as reader:
        labels = Counter(reader.column("labels"))
        segments = len(reader.segments)
    assert facts["rows"] == 11 and facts["classes"] == dict(sorted(labels.items()))
    assert facts["classes"]["torus"] == 1 and facts["classes"]["capsule"] == 2
    assert facts["segments"] == segments >= 2  # the removal is a segment of its own
    assert facts["bytes"] == sum(p.stat().st_size for p in index.iterdir() if p.name != "lock")
    assert facts["descriptor"] == "intrinsic" and facts["params"] == json.loads(
        read_manifest(index).params.to_json()
    )
    assert facts["partial_cells"] is False and facts["cfsig_version"] == cfsig.__version__
    age = datetime.now(timezone.utc) - datetime.fromisoformat(facts["committed"])
    assert 0 <= age.total_seconds() < 600
    text = _run("info", index).output
    assert "11 in 6 classes" in text and "torus" in text and "intrinsic" in text


def test_query_by_name_ranks_as_the_file_without_itself(meshes, indexed):
    name = "limbs3/limbs3-1.off"
    by_file = json.loads(_run("query", indexed, meshes / name, "-k", 12, "--json").stdout)
    result = _run("query", indexed, "--name", name, "-k", 11, "--json")
    assert result.exit_code == 0, result.output
    by_name = json.loads(result.stdout)
    assert by_file[0]["name"] == name and by_file[0]["distance"] == 0
    expected = [{**hit, "rank": hit["rank"] - 1} for hit in by_file[1:]]
    assert by_name == expected and len(by_name) == 11
    shown = _run("query", indexed, "--name", name, "-k", 3).output.splitlines()
    assert shown[0] == f"# {name}" and len(shown) == 4
    _one_line_error(_run("query", indexed, "--name", "no/such.off"), "no/such.off")
    assert _run("query", indexed, "--name", name, meshes / name).exit_code == 2


def test_classes_label_rows_and_relabel_without_recomputing(meshes, indexed, tmp_path):
    index = tmp_path / "index"
    shutil.copytree(indexed, index)
    cla = tmp_path / "two.cla"  # the demo's file stems are "<class>-<pose>"
    cla.write_text("PSB 1\n2 3\nround 0 2\ntorus-0\ncapsule-1\nlimbs 0 1\nlimbs5-0\n")
    before = _rows(index)
    result = _run("index", meshes, "-o", index, "-j", "1", "--classes", cla)
    assert result.exit_code == 0, result.output
    assert "0 meshes added or updated, 3 relabelled or moved, 12 in the index" in result.output
    after = _rows(index)
    labels = {name: label for name, (label, _, _) in after.items()}
    assert labels["torus/torus-0.off"] == labels["capsule/capsule-1.off"] == "round"
    assert labels["limbs5/limbs5-0.off"] == "limbs" and labels["torus/torus-1.off"] == "torus"
    for name, (_, vector, sha) in after.items():  # not recomputed: the stored rows, copied
        assert np.array_equal(vector, before[name][1]) and sha == before[name][2]
    assert index_info(index).classes["round"] == 2 and check_index(index) == []
    again = _run("index", meshes, "-o", index, "-j", "1", "--classes", cla)
    assert "0 meshes added or updated, 0 relabelled or moved" in again.output


def test_classes_naming_missing_files_change_nothing(meshes, indexed, tmp_path):
    index = tmp_path / "index"
    shutil.copytree(indexed, index)
    cla = tmp_path / "more.cla"
    cla.write_text("PSB 1\n1 2\nround 0 2\ntorus-0\n999\n")
    before = _state(index)
    result = _run("index", meshes, "-o", index, "-j", "1", "--classes", cla)
    _one_line_error(result, str(cla), "'999'")
    assert _state(index) == before


def test_links_to_folders_index_as_the_folders_and_a_cycle_ends(meshes, indexed, tmp_path):
    linked = tmp_path / "linked"
    linked.mkdir()
    for folder in sorted(meshes.iterdir()):
        (linked / folder.name).symlink_to(folder, target_is_directory=True)
    (meshes / "torus" / "loop").symlink_to(meshes, target_is_directory=True)  # a cycle
    try:
        index = tmp_path / "index"
        result = _run("index", linked, "-o", index, "-j", "2")
    finally:
        (meshes / "torus" / "loop").unlink()
    assert result.exit_code == 0, result.output
    real, via_links = _rows(indexed), _rows(index)
    assert sorted(via_links) == sorted(real)
    for name, (label, vector, _) in via_links.items():
        assert label == real[name][0] and np.array_equal(vector, real[name][1])
    with IndexReader(index) as reader:  # stored under the links, so that --prune follows them
        assert all(p.startswith(str(linked)) for p in reader.column("paths"))


def test_a_path_without_meshes_is_an_error(tmp_path):
    empty = tmp_path / "empty"
    (empty / "sub").mkdir(parents=True)
    (empty / "sub" / "readme.txt").write_text("no meshes here")
    index = tmp_path / "index"
    _one_line_error(_run("index", empty, "-o", index), str(empty), "no mesh file")
    assert not index.exists()


def _planted(path, n=60, copies=((3, 40), (7, 8), (8, 50))):
    """An index of n random `cf` rows where some rows (the second of each pair) are nearly the
    first; return the vectors."""
    vectors = [random_signature(i).vector for i in range(n)]
    for a, b in copies:
        vectors[b] = vectors[a] + 1e-6 * np.random.default_rng(b).standard_normal(len(vectors[a]))
    with open_writer(path) as writer:
        for i, vector in enumerate(vectors):
            signature = random_signature(i)
            writer.add(Entry(f"c/{i}.off", "c", f"/c/{i}.off"), type(signature)(
                **{**vars(signature), "vector": vector}
            ))  # fmt: skip
    return np.array(vectors)


@pytest.mark.parametrize("pruned", [False, True], ids=["scan", "pruned"])
def test_duplicates_equal_brute_force(tmp_path, monkeypatch, pruned):
    if pruned:  # the sketches' pruned search, as over a large index
        monkeypatch.setattr(cfsig.search.nearest, "PRUNE_MIN_ROWS", 1)
        monkeypatch.setattr(cfsig.search.nearest, "_FIRST", 4)
        monkeypatch.setattr(cfsig.search.nearest, "_SCAN_RATIO", 1)
        monkeypatch.setattr(cfsig.search.nearest, "_FIRST_MANY", 2)
        monkeypatch.setattr(cfsig.search.nearest, "_MANY", 8)  # batches of 16 go together
    monkeypatch.setattr(cfsig.search.duplicates, "BATCH", 16)  # several batches
    index = tmp_path / "index"
    vectors = _planted(index)
    with open_writer(index) as writer:
        writer.remove(["c/5.off"])
    vectors = np.delete(vectors, 5, axis=0)
    distances = l1_distances(vectors, vectors).astype(np.float32)
    np.fill_diagonal(distances, np.inf)
    done = []
    with IndexReader(index) as reader:
        groups = duplicate_groups(reader, 1e-3, done.append)
        top = list(nearest_all(reader, 4))
        names = list(reader.column("names"))
    assert [[e.name for e in g.entries] for g in groups] == [
        ["c/3.off", "c/40.off"], ["c/7.off", "c/8.off", "c/50.off"]
    ]  # fmt: skip
    assert sum(done) == len(vectors) == 59 and all(g.distance < 1e-3 for g in groups)
    for row, (entry, hits) in enumerate(top):
        assert entry.name == names[row]
        expected = np.lexsort((np.arange(len(vectors)), distances[row]))[:4]
        assert [h.entry.name for h in hits] == [names[i] for i in expected]
        assert np.allclose([h.distance for h in hits], distances[row, expected])


def test_duplicates_command(tmp_path):
    index = tmp_path / "index"
    _planted(index)
    _one_line_error(_run("duplicates", tmp_path / "none", "--below", 0.1), "no such index")
    assert _run("duplicates", index).exit_code == 2  # the default is the intrinsic descriptor's
    result = _run("duplicates", index, "--below", 1e-3, "--json")
    assert result.exit_code == 0, result.output
    groups = json.loads(result.stdout)
    assert [g["names"] for g in groups] == [
        ["c/3.off", "c/40.off"],
        ["c/7.off", "c/8.off", "c/50.off"],
    ]
    result = _run("duplicates", index, "--top", 2, "--json")
    rows = json.loads(result.stdout)
    assert len(rows) == 60 and rows[3]["nearest"][0]["name"] == "c/40.off"
    assert all(len(r["nearest"]) == 2 and r["name"] not in str(r["nearest"]) for r in rows)


def test_check_covers_the_class_counts_and_the_drops(tmp_path):
    index = tmp_path / "index"
    build_index(index, 6)
    with open_writer(index) as writer:
        writer.remove(["c0/3.off"])
    assert check_index(index) == []
    manifest = read_manifest(index)
    write_manifest(index, replace(manifest, classes=(("c0", 2),)))
    (problem,) = check_index(index)
    assert "class counts do not match" in problem


def test_check_names_a_drop_of_a_row_no_older_segment_holds(tmp_path):
    index = tmp_path / "index"
    build_index(index, 6)
    manifest = read_manifest(index)
    (first,) = manifest.segments
    bogus = SegmentInfo(manifest.next_id, 0, 0, 0)  # a removal of row 99 of a 6-row segment
    write_segment(index / bogus.file, bogus.id, manifest.layout, 0, [], np.array([[first.id, 99]]))
    bogus = replace(bogus, crc32=file_crc(index / bogus.file))
    segments = (replace(first, live=first.live - 1), bogus)
    write_manifest(index, replace(manifest, segments=segments, next_id=bogus.id + 1))
    problems = check_index(index)
    assert any(
        p.endswith(f"{bogus.file}: drops a row that is not in an older segment") for p in problems
    )
