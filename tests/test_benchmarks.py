"""Smoke tests of the scripts in benchmarks/: each runs on tiny generated data and prints its table.

Each script runs as a subprocess, as a user runs it, from the project folder.
"""

from __future__ import annotations

import re
import shutil
import subprocess
import sys
from pathlib import Path

import pytest

import cfsig
from cfsig.files.demo import make_demo_collection

ROOT = Path(__file__).resolve().parents[1]
NUMBER = r"\d+\.\d+"


def run(script: str, *args: object) -> str:
    """Run ``benchmarks/<script>`` with ``args``; check it succeeds and return its output."""
    command = [sys.executable, f"benchmarks/{script}", *map(str, args)]
    done = subprocess.run(command, cwd=ROOT, capture_output=True, text=True, timeout=300)
    assert done.returncode == 0, done.stderr
    return done.stdout


@pytest.fixture(scope="module")
def data(tmp_path_factory) -> Path:
    """DATA/shrec07/<class>/<file>.off: two classes of the demo collection, three meshes each."""
    root = tmp_path_factory.mktemp("data")
    make_demo_collection(root / "shrec07", per_class=3)
    for folder in (root / "shrec07").iterdir():
        if folder.name not in ("limbs1", "torus"):
            shutil.rmtree(folder)
    return root


def test_results(data, tmp_path):
    doc = tmp_path / "results.md"
    marker = "<!-- measured: what follows is written by benchmarks/results.py -->"
    doc.write_text(f"# Results\n\nKept.\n\n{marker}\nreplaced\n")
    # --every 2: limbs1-0, limbs1-2 and torus-1
    args = ["--data-root", data, "--collections", "shrec07", "--jobs", 1, "--every", 2]
    out = run("results.py", *args, "--doc", doc)
    assert "| collection | descriptor | queries | NN | FT | ST | DCG | mAP | s per mesh |" in out
    # torus-1 alone in its class is not a query
    assert re.search(rf"\| shrec07 \| `cf` \| 2 \|( {NUMBER} \|){{6}}", out)
    assert re.search(rf"\| shrec07 \| `intrinsic` \| 2 \|( {NUMBER} \|){{6}}", out)
    text = doc.read_text()
    assert text.startswith(f"# Results\n\nKept.\n\n{marker}\n\nMeasured by `python benchmarks/")
    assert "replaced" not in text and text.count("| shrec07 |") == 2


def test_world(data, tmp_path):
    doc = tmp_path / "results.md"
    doc.write_text(
        "# Results\n\n<!-- benchmarks/world.py -->\nold\n<!-- /benchmarks/world.py -->\n"
    )
    args = ["--data-root", data, "--collections", "shrec07", "--kinds", "cut,noise", "--jobs", 1]
    out = run("world.py", *args, "--doc", doc)
    # two classes of three: meshes 0 and 2 of each indexed, mesh 1 of each queried
    for kind in ("cut-30", "cut-50", "cut-70"):
        for ranked in ("curvature columns", "fine cells"):
            assert re.search(rf"\| shrec07 \| {kind} \| {ranked} \| 2 \|( {NUMBER} \|){{3}}", out)
    assert re.search(rf"\| shrec07 \| noise-1 \| whole shape \| 2 \|( {NUMBER} \|){{3}}", out)
    for kind in ("cut-50",):  # near-duplicate: 4 queries
        assert re.search(rf"\| shrec07 \| {kind} \| fine cells \| 4 \|( {NUMBER} \|){{3}}", out)
    for kind in ("noise-0.25", "noise-0.5", "noise-1", "shot-10"):  # copies of all six
        assert re.search(rf"\| shrec07 \| {kind} \| {NUMBER} \|( {NUMBER} \|){{2}}", out), kind
    assert "holes-" not in out and "scan-" not in out
    text = doc.read_text()
    assert "old" not in text and text.endswith("<!-- /benchmarks/world.py -->\n")


def test_partial_speed(tmp_path):
    out = run("partial_speed.py", "--index-dir", tmp_path, "--rows", 2000, "--repeat", 1)
    assert "2,000 rows" in out
    assert re.search(rf"--partial`, 2,000 rows .*: median {NUMBER} s over 1 \(range", out)


def test_partial_speed_from_a_real_index(data, tmp_path):
    real = tmp_path / "real"
    command = [sys.executable, "-m", "cfsig", "index", data / "shrec07", "-o", real]
    subprocess.run([*map(str, command), "--partial-cells"], check=True, capture_output=True)
    args = ["--index-dir", tmp_path, "--rows", 1500, "--real", real, "--repeat", 1]
    out = run("partial_speed.py", *args)
    assert re.search(rf"--partial`, 1,500 rows .*: median {NUMBER} s over 1 \(range", out)
    with cfsig.IndexReader(tmp_path / "rows-1500") as made, cfsig.IndexReader(real) as wholes:
        assert len(made) == 1500
        held = {tuple(c) for c in wholes.cells()[0]}
        assert {tuple(c) for c in made.cells()[0][:50]} <= held  # each row a whole's cells
    plain = tmp_path / "plain"  # no fine cells: refused in one line
    subprocess.run([*map(str, command[:-1]), plain], check=True, capture_output=True)
    args = ["--index-dir", tmp_path / "other", "--rows", "10", "--real", plain]
    refused = subprocess.run(
        [sys.executable, "benchmarks/partial_speed.py", *map(str, args)],
        cwd=ROOT, capture_output=True, text=True, timeout=300,
    )  # fmt: skip
    assert refused.returncode == 1
    assert (
        refused.stderr.strip()
        == f"{plain}: not an index of the default parameters with --partial-cells"
    )


def test_cells_kernel(data, tmp_path):
    pytest.importorskip("cfsig.search.cells_compiled", reason="built when cfsig is installed")
    index = tmp_path / "i"
    command = [sys.executable, "-m", "cfsig", "index", data / "shrec07", "-o", index]
    subprocess.run([*map(str, command), "--partial-cells"], check=True, capture_output=True)
    part = next((data / "shrec07" / "torus").glob("*.off"))
    out = run("cells_kernel.py", "--index", index, "--part", part, "--rows", 4, "--repeat", 1)
    assert out.startswith("4 rows, ")
    assert re.search(rf"portable loop, 2 thread\(s\): {NUMBER} s per 1M rows", out)


def test_per_mesh(data):
    args = ["--data", data / "shrec07", "--every", 2, "--descriptors", "cf", "--repeat", 1]
    out = run("per_mesh.py", *args)
    assert "| descriptor | CPU | wall | wall / `intrinsic` | whole run | ratio |" in out
    assert re.search(rf"\| `intrinsic` \| {NUMBER} \| {NUMBER} \| 1.00 \| {NUMBER} \| 1.00 \|", out)
    assert re.search(rf"\| `cf` \|( {NUMBER} \|){{5}}", out)


def test_messy(data, tmp_path):
    doc = tmp_path / "results.md"
    section = "<!-- benchmarks/messy.py shrec07 -->\nold\n<!-- /benchmarks/messy.py shrec07 -->"
    doc.write_text(f"# Results\n\nKept.\n\n{section}\n\nAlso kept.\n")
    args = ["--data", data / "shrec07", "--every", 2, "--kinds", "holes-10", "proxy", "--check", 1]
    out = run("messy.py", "run", *args, "--jobs", 1, "--doc", doc)
    assert (
        "| kind | copies | failed | rank 1 % | rank 1 %, duplicates as one | top 5 % | proxy % |"
        in out
    )
    assert re.search(r"\| holes-10 \| 3 \| 0 \| [\d.]+ \| [\d.]+ \| [\d.]+ \| 0 \|", out)
    assert re.search(r"\| proxy \| 3 \| 0 \| [\d.]+ \| [\d.]+ \| [\d.]+ \| 100 \|", out)
    assert "| collection | meshes | left out | NN | FT | ST | mAP |" in out
    text = doc.read_text()
    assert text.startswith("# Results\n\nKept.\n\n<!-- benchmarks/messy.py shrec07 -->\n")
    assert text.endswith("<!-- /benchmarks/messy.py shrec07 -->\n\nAlso kept.\n")
    assert "old" not in text and "Measured by `python benchmarks/messy.py run" in text
    assert "| kind | rank 1 % | duplicates as one | proxy % | FT |" in text
    assert re.search(r"\| holes-10 \| [\d.]+ \| [\d.]+ \| 0 \| [\d.]+ \|", text)


def test_index_scale(tmp_path):
    args = ["--dir", tmp_path, "--sizes", 2000, "--repeat", 2, "--duplicates"]
    out = run("index_scale.py", *args)
    assert "| rows | rows now | build | commit of 1,000 rows s (median) | max | query s |" in out
    assert "| `cfsig info` s | removal of 1,000 rows s (median) | max |" in out
    # two commits of 1,000 rows, then two removals of 1,000
    numbers = rf"( {NUMBER} \|){{6}} \d+ \(\d+ CPU\) \|"
    assert re.search(rf"\| 2,000 \| 2,000 \| \d+ s \|{numbers}", out)


def test_peers(data, tmp_path):
    pytest.importorskip("matplotlib")
    figures = tmp_path / "figures"
    args = ["--data", data / "shrec07", "--descriptors", "cf,gps", "--classes", "torus"]
    out = run("peers.py", *args, "--out", figures, "--jobs", 1)
    assert "| descriptor | NN | FT | ST | DCG | mAP | s per mesh |" in out
    for name in ("cf", "gps"):
        assert re.search(rf"\| `{name}` \|( {NUMBER} \|){{5}} [0-9.e-]+ \|", out)
    assert re.search(rf"\| torus \| {NUMBER} \| {NUMBER} \|", out)
    found = sorted(p.name for p in figures.iterdir())
    assert found == ["precision_recall.png", "query_02_torus.png"]
