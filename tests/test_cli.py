import json
import subprocess
import sys

import numpy as np
import pytest
from click.testing import CliRunner

import cfsig.cli
from cfsig import __version__
from cfsig.cli import EXIT_SKIPPED, main
from cfsig.evaluation.collections import compute_collection
from cfsig.files.demo import make_demo_collection
from tests.helpers import read_plain


@pytest.fixture(scope="module")
def collection(tmp_path_factory):
    folder = tmp_path_factory.mktemp("demo") / "meshes"
    make_demo_collection(folder, per_class=3)
    return folder


@pytest.fixture(scope="module")
def built_index(collection, tmp_path_factory):
    path = tmp_path_factory.mktemp("index") / "demo.h5"
    result = CliRunner().invoke(main, ["index", str(collection), "-o", str(path), "-j", "2"])
    assert result.exit_code == 0, result.output
    return path


def _run(*args):
    return CliRunner().invoke(main, [str(a) for a in args])


def test_version_and_help():
    assert __version__ in _run("--version").output
    for command in ["compute", "index", "query", "evaluate", "demo"]:
        result = _run(command, "--help")
        assert result.exit_code == 0 and "Example" in result.output


def test_the_command_exits_with_its_status_and_all_its_output(tmp_path):
    def command(*args):
        done = subprocess.run(
            [sys.executable, "-m", "cfsig", *map(str, args)],
            capture_output=True, text=True, timeout=120,
        )  # fmt: skip
        return done.returncode, done.stdout, done.stderr

    code, out, _ = command("--help")  # to its last line: every command listed
    listed = [line.split()[0] for line in out.split("Commands:\n")[1].splitlines()]
    assert code == 0 and listed == sorted(main.commands)
    code, _, err = command("query", tmp_path / "none", tmp_path / "x.off")
    assert code == 1 and err == f"Error: {tmp_path / 'none'}: no such index\n"
    code, _, err = command("query")
    assert code == 2 and "Missing argument" in err


def test_compute_text_json_and_save(collection, tmp_path):
    mesh = collection / "limbs2" / "limbs2-0.off"
    result = _run("compute", mesh)
    assert result.exit_code == 0
    assert "1 component(s)" in result.output and "vertices" in result.output
    result = _run("compute", "--json", "--save", tmp_path, mesh)
    row = json.loads(result.stdout)[0]
    assert row["components"] == 1 and row["phi_min"] < 0 < row["phi_max"]
    saved = np.load(tmp_path / "limbs2-0.npz")
    assert saved["signature"].shape == (812,) and len(saved["phi"]) == row["vertices"]
    # compute reports phi for every descriptor, also those that do not need it
    row = json.loads(_run("compute", "--json", "--descriptor", "cf", mesh).stdout)[0]
    assert row["phi_min"] < 0 < row["phi_max"] and row["curvature_error"] >= 0


def test_compute_bad_file_one_line_error(tmp_path):
    bad = tmp_path / "bad.off"
    bad.write_text("OFF\n3 1 0\n0 0 0\n1 0 0\n")
    result = _run("compute", bad)
    assert result.exit_code == 1
    assert result.output.strip().splitlines() == [
        f"Error: {bad}: truncated OFF: the header declares 3 vertices and 1 faces but the file "
        "holds only 6 numbers"
    ]
    assert "Traceback" not in result.output


def test_index_stores_names_labels_and_metadata(built_index):
    f = read_plain(built_index)  # with plain h5py, as docs/index-format.md says
    names, labels = list(f["names"]), list(f["labels"])
    assert len(names) == 18 and "torus/torus-1.off" in names
    assert labels[names.index("torus/torus-1.off")] == "torus"
    params = json.loads(f["attrs"]["params"])
    assert params["descriptor"] == "intrinsic"  # the default
    assert f["signatures"].shape[0] == 18
    assert np.isfinite(f["signatures"]).all()
    assert (f["n_vertices"] > 1000).all()
    assert f["attrs"]["format_version"] == 6


def test_index_again_adds_only_new_and_changed(collection, tmp_path):
    index = tmp_path / "i.h5"
    assert _run("index", collection / "capsule", "-o", index, "-j", "1").exit_code == 0
    before = read_plain(index)["signatures"]
    (collection / "capsule" / "extra").mkdir(exist_ok=True)
    extra = collection / "capsule" / "extra" / "c.off"
    extra.write_bytes((collection / "torus" / "torus-0.off").read_bytes())
    try:
        result = _run("index", collection / "capsule", "-o", index, "-j", "1")
    finally:
        extra.unlink()
        extra.parent.rmdir()
    assert result.exit_code == 0 and "1 meshes added or updated, 4 in the index" in result.output
    f = read_plain(index)
    assert np.array_equal(f["signatures"][:3], before)
    assert f["names"][3] == "extra/c.off"


def test_index_skips_bad_files_with_distinct_status(collection, tmp_path):
    folder = tmp_path / "mixed" / "cls"
    folder.mkdir(parents=True)
    (folder / "good.off").write_bytes((collection / "capsule" / "capsule-0.off").read_bytes())
    (folder / "bad.off").write_text("garbage")
    result = _run("index", folder.parent, "-o", tmp_path / "i.h5", "-j", "1")
    assert result.exit_code == EXIT_SKIPPED
    assert "1 in the index" in result.output and "bad.off" in result.output
    strict = _run("index", folder.parent, "-o", tmp_path / "j.h5", "-j", "1", "--strict")
    assert strict.exit_code == 1


def test_progress_into_a_log_is_redrawn_once_a_minute(collection, tmp_path, monkeypatch):
    quick = _run("index", collection, "-o", tmp_path / "a", "-j", "1")
    assert quick.exit_code == 0 and quick.stderr.count("indexing") == 1  # its first draw only
    monkeypatch.setattr(cfsig.cli, "LOG_SECONDS", 0.0)
    every = _run("index", collection, "-o", tmp_path / "b", "-j", "1")
    assert every.stderr.count("indexing") > len(list(collection.rglob("*.off")))


def test_query_text_and_json(built_index, collection):
    mesh = collection / "limbs3" / "limbs3-1.off"
    result = _run("query", built_index, mesh, "-k", "3")
    assert result.exit_code == 0 and "limbs3/limbs3-1.off" in result.output
    hits = json.loads(_run("query", built_index, mesh, "-k", "3", "--json").stdout)
    assert [h["rank"] for h in hits] == [1, 2, 3]
    assert set(hits[0]) == {"rank", "distance", "name", "label"}
    assert hits[0]["distance"] == pytest.approx(0, abs=1e-6)
    assert all(h["label"] == "limbs3" for h in hits)
    both = json.loads(_run("query", built_index, mesh, mesh, "-k", "2", "--json").stdout)
    assert len(both) == 2 and len(both[0]) == 2


def test_query_errors(tmp_path, collection):
    result = _run("query", tmp_path / "none.h5", collection / "torus" / "torus-0.off")
    assert result.exit_code == 1 and "no such index" in result.output


def test_evaluate_folder_index_and_cla(collection, built_index, tmp_path):
    result = _run("evaluate", collection, "--json", "-j", "1")
    report = json.loads(result.stdout)
    computed = {"repair", "seconds_per_mesh"}  # from a folder only
    assert set(report) == {"measures", "per_class", "precision_recall", "count", *computed}
    assert report["seconds_per_mesh"] > 0
    assert report["repair"] == {"clean": 18}  # the generated meshes are closed manifolds
    assert set(report["measures"]) == {"NN", "FT", "ST", "E", "DCG", "mAP"}
    assert report["count"] == 18 and len(report["precision_recall"]) == 20
    from_index = json.loads(_run("evaluate", "--index", built_index, "--json").stdout)
    assert from_index["measures"] == pytest.approx(report["measures"], abs=1e-6)
    # a .cla file that puts everything in two classes by file stem
    lines = ["PSB 1", "2 18"]
    names = sorted(p.stem for p in collection.rglob("*.off"))
    for c, group in enumerate([names[:9], names[9:]]):
        lines += ["", f"class{c} 0 {len(group)}", *group]
    (tmp_path / "x.cla").write_text("\n".join(lines) + "\n")
    cla = json.loads(
        _run("evaluate", "--index", built_index, "--classes", tmp_path / "x.cla", "--json").output
    )
    assert set(cla["per_class"]) == {"class0", "class1"}
    text = _run("evaluate", "--index", built_index)
    assert "FT" in text.output and "torus" in text.output


def test_evaluate_class_file_errors_name_the_file_once(built_index, tmp_path):
    missing = tmp_path / "missing.cla"
    result = _run("evaluate", "--index", built_index, "--classes", missing)
    assert result.exit_code == 1
    assert result.output.strip() == f"Error: {missing}: No such file or directory"
    bad = tmp_path / "bad.cla"
    bad.write_text("not a class file\n")
    result = _run("evaluate", "--index", built_index, "--classes", bad)
    assert result.exit_code == 1 and result.output.count(str(bad)) == 1
    # every mesh in a class of its own: nothing to retrieve, and the message names the index
    names = sorted(read_plain(built_index)["names"])
    lines = ["PSB 1", f"{len(names)} {len(names)}"]
    for i, name in enumerate(names):
        lines += ["", f"c{i} 0 1", name.split("/")[-1].removesuffix(".off")]
    alone = tmp_path / "alone.cla"
    alone.write_text("\n".join(lines) + "\n")
    result = _run("evaluate", "--index", built_index, "--classes", alone)
    assert result.exit_code == 1
    assert result.output.startswith(f"Error: {built_index}: no class has at least two members")


def test_demo_command(tmp_path):
    result = _run("demo", "--out", tmp_path)
    assert result.exit_code == 0, result.output
    assert "30 in the index" in result.output and "queries" in result.output


def test_evaluate_strict_stops_before_the_next_descriptor(collection, tmp_path, monkeypatch):
    import cfsig.cli

    folder = tmp_path / "set"
    for name in ("capsule", "torus"):
        (folder / name).mkdir(parents=True)
        for i in range(2):
            source = collection / name / f"{name}-{i}.off"
            (folder / name / source.name).write_bytes(source.read_bytes())
    (folder / "torus" / "bad.off").write_text("garbage")
    computed = []

    def recording(folder, params, *args):
        computed.append(params.descriptor)
        return compute_collection(folder, params, *args)

    monkeypatch.setattr(
        cfsig.evaluation.collections, "compute_collection", recording
    )  # cli imports it per call
    result = _run("evaluate", folder, "--descriptor", "cf,intrinsic", "-j", "1", "--strict")
    assert result.exit_code == 1 and "bad.off" in result.output
    assert computed == ["cf"]
    result = _run("evaluate", folder, "--descriptor", "cf,intrinsic", "-j", "1")
    assert result.exit_code == EXIT_SKIPPED and computed == ["cf", "cf", "intrinsic"]
