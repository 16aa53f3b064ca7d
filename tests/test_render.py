"""Pictures: colours follow phi, files are valid, non-blank, of the expected size, reproducible."""

import subprocess
import sys

import numpy as np
import pytest
from click.testing import CliRunner

from cfsig.cli import main
from cfsig.errors import MissingDependencyError
from cfsig.evaluation.collections import Collection, Evaluation
from cfsig.evaluation.measures import evaluate_distances
from cfsig.figures import plots as figures
from cfsig.figures import raster
from cfsig.figures.report import write_comparison, write_report
from cfsig.files.mesh import Mesh, clean_mesh, read_mesh
from tests.helpers import icosphere, open_cylinder, random_rotation, torus, write_off

matplotlib = pytest.importorskip("matplotlib")
PNG_SIGNATURE = b"\x89PNG\r\n\x1a\n"
MISSING = "missing (no such file: moved or deleted since it was indexed?)"


def _png(path):
    """Check the PNG signature; return the header's (width, height) and the pixels."""
    data = path.read_bytes()
    assert data[:8] == PNG_SIGNATURE and data[12:16] == b"IHDR"
    size = int.from_bytes(data[16:20], "big"), int.from_bytes(data[20:24], "big")
    pixels = matplotlib.image.imread(path)
    assert pixels.shape[1::-1] == size
    return size, pixels


def _assert_picture(path, size):
    """A valid PNG of that size that is not a blank page."""
    found, pixels = _png(path)
    assert found == size
    assert pixels[..., :3].std() > 0.05


def _ellipsoid(stretch=(2.5, 1.0, 0.6), levels=2) -> Mesh:
    v, f = icosphere(levels)
    return clean_mesh(v * np.array(stretch), f)


@pytest.fixture
def collection(tmp_path):
    """Two classes of two meshes each, as OFF files in class folders."""
    root = tmp_path / "shapes"
    for i, s in enumerate((2.5, 2.8)):
        mesh = _ellipsoid((s, 1.0, 0.6))
        write_off(root / "long" / f"{i}.off", mesh.vertices, mesh.faces)
    for i, r in enumerate((0.3, 0.4)):
        mesh = clean_mesh(*torus(r=r, nu=24, nv=10))
        write_off(root / "ring" / f"{i}.off", mesh.vertices, mesh.faces)
    return root


def test_unit_interval_and_colours_follow_phi():
    phi = np.array([3.0, -1.0, 7.0, 0.5])
    assert np.allclose(raster.unit_interval(phi), [0.5, 0.0, 1.0, 0.1875])
    colors = figures.phi_colors(phi)
    cmap = matplotlib.colormaps[raster.CMAP]
    assert colors.shape == (4, 4) and colors.dtype == np.uint8
    assert np.array_equal(colors[2], np.round(np.array(cmap(1.0)) * 255))
    assert np.array_equal(colors[1], np.round(np.array(cmap(0.0)) * 255))
    assert np.array_equal(figures.phi_colors(np.ones(3))[0], np.round(np.array(cmap(0.5)) * 255))


def test_default_view_is_a_rotation_showing_the_long_axis_upright():
    mesh = _ellipsoid((0.5, 1.0, 3.0))  # longest along z, thinnest along x
    view = raster.default_view(mesh.vertices)
    assert np.allclose(view @ view.T, np.eye(3)) and np.isclose(np.linalg.det(view), 1.0)
    projected = mesh.vertices @ view.T
    extent = np.ptp(projected, axis=0)
    assert extent[1] > 2 * extent[0]  # the long axis runs up the screen
    assert extent[2] < extent[1]


def test_rendered_colour_at_the_largest_phi_is_the_top_colour():
    v, f = icosphere(3)
    mesh = clean_mesh(v, f)
    phi = v @ raster.LIGHT  # largest where the surface faces the light: full brightness there
    image = raster.shade_mesh(mesh, raster.unit_interval(phi), view=np.eye(3), size=(200, 200))
    assert image.shape == (200, 200, 4) and image.dtype == np.float32
    x, y, _ = raster.screen_coordinates(v, np.eye(3), (200, 200))[np.argmax(phi)]
    pixel = image[int(y), int(x)]
    top = np.array(matplotlib.colormaps[raster.CMAP](1.0)[:3])
    assert pixel[3] == 1.0
    assert np.abs(pixel[:3] - top).max() < 0.03
    middle = np.argmin(np.abs(phi) - v[:, 2])  # mid-range phi, facing the viewer
    x, y, _ = raster.screen_coordinates(v, np.eye(3), (200, 200))[middle]
    assert np.abs(image[int(y), int(x), :3] - top).max() > 0.3  # elsewhere another colour
    assert image[0, 0, 3] == 0 and image[100, 100, 3] == 1  # background clear, sphere opaque


@pytest.mark.parametrize("shape", ["sphere", "torus", "flipped torus"])
def test_culling_back_faces_changes_no_pixel(shape):
    v, f = icosphere(2) if shape == "sphere" else torus(nu=24, nv=10)
    mesh = clean_mesh(v, f[:, ::-1] if shape == "flipped torus" else f)
    view = random_rotation(3)
    visible = raster._visible_faces(mesh, view[2])
    assert 0.3 * len(mesh.faces) < len(visible) < 0.7 * len(mesh.faces)
    points = raster.screen_coordinates(mesh.vertices, view, (120, 120))
    all_faces, _ = raster.rasterize(points, mesh.faces, 120, 120)
    culled, _ = raster.rasterize(points, visible, 120, 120)
    assert np.array_equal(culled >= 0, all_faces >= 0)
    drawn = culled >= 0
    assert np.array_equal(visible[culled[drawn]], mesh.faces[all_faces[drawn]])


def test_open_surfaces_are_not_culled():
    mesh = clean_mesh(*open_cylinder())
    assert len(raster._visible_faces(mesh, np.array([0.0, 0.0, 1.0]))) == len(mesh.faces)


def test_shading_is_lit_from_the_light():
    v, f = icosphere(3)
    image = raster.shade_mesh(clean_mesh(v, f), view=np.eye(3), size=(100, 100))
    points = raster.screen_coordinates(v, np.eye(3), (100, 100))
    lit, dark = (points[np.argmax(s * v @ raster.LIGHT)] for s in (1, -1))
    brightness = [image[int(p[1]), int(p[0]), :3].mean() for p in (lit, dark)]
    assert brightness[0] > brightness[1] + 0.3


def test_render_phi_png_size_content_and_determinism(tmp_path):
    mesh = _ellipsoid()
    items = [(mesh, mesh.vertices[:, 0], "a"), (mesh, -mesh.vertices[:, 1], "b")]
    figures.render_phi(items, tmp_path / "a.png", panel=200)
    figures.render_phi(items, tmp_path / "b.png", panel=200)
    _assert_picture(tmp_path / "a.png", (2 * 200 + 110, 200 + 40))
    assert (tmp_path / "a.png").read_bytes() == (tmp_path / "b.png").read_bytes()
    assert b"Software" not in (tmp_path / "a.png").read_bytes()


def test_write_ply_round_trips_colours_and_phi(tmp_path):
    trimesh = pytest.importorskip("trimesh")
    mesh = _ellipsoid()
    phi = mesh.vertices[:, 0] ** 2
    figures.write_ply(mesh, phi, tmp_path / "m.ply")
    loaded = trimesh.load(tmp_path / "m.ply", process=False)
    assert np.allclose(loaded.vertices, mesh.vertices, atol=1e-6)
    assert np.array_equal(loaded.faces, mesh.faces)
    colors = np.asarray(loaded.visual.vertex_colors)
    assert np.array_equal(colors, figures.phi_colors(phi))
    top = np.round(np.array(matplotlib.colormaps[raster.CMAP](1.0)) * 255)
    assert np.array_equal(colors[np.argmax(phi)], top)
    quality = loaded.metadata["_ply_raw"]["vertex"]["data"]["quality"]
    assert np.allclose(quality.ravel(), phi, rtol=1e-6)


def test_histogram_and_precision_recall_plots(tmp_path):
    rng = np.random.default_rng(0)
    hists = rng.random((3, 200)) * (np.arange(200) > 90) * (np.arange(200) < 130)
    hists /= hists.sum(axis=1, keepdims=True)
    figures.plot_histograms(
        hists, ["a/1.off", "a/2.off", "b/1.off"], (-99.5, 100.5), tmp_path / "h.png"
    )
    _assert_picture(tmp_path / "h.png", (800, 450))
    labels = ["x"] * 3 + ["y"] * 3 + ["z"] * 3
    report = evaluate_distances(rng.random((9, 9)), labels)
    assert set(report.class_precision_recall) == {"x", "y", "z"}
    curves = np.array(list(report.class_precision_recall.values()))
    assert np.allclose(curves.mean(axis=0), report.precision_recall[:, 1])  # equal classes
    figures.plot_precision_recall({"one": report}, tmp_path / "pr.png")
    _assert_picture(tmp_path / "pr.png", (4 * 260, 230))
    other = evaluate_distances(rng.random((9, 9)), labels)
    two = {"one": report, "other": other}
    figures.plot_precision_recall(two, tmp_path / "pr2.png", classes=["z", "x"])
    _assert_picture(tmp_path / "pr2.png", (3 * 260, 230))
    with pytest.raises(ValueError, match="classes w"):
        figures.plot_precision_recall(two, tmp_path / "pr3.png", classes=["w"])


def test_grid_frames_results_and_marks_missing_files(tmp_path):
    long, ring = _ellipsoid(), clean_mesh(*torus(nu=24, nv=10))
    a = write_off(tmp_path / "long" / "a.off", long.vertices, long.faces)
    b = write_off(tmp_path / "ring" / "b.off", ring.vertices, ring.faces)
    gone = tmp_path / "long" / "gone.off"
    row = figures.retrieval_row(
        (str(a), "long/a.off", "long"),
        [(str(a), "a", "long", 0.0), (str(b), "b", "ring", 0.5), (str(gone), "g", "long", 0.7)],
    )
    assert [t.role for t in row] == ["query", "right", "wrong", "right"]
    assert row[2].caption == "2: 0.5000\nb"
    problems = figures.render_grid([row[:2], row[2:]], tmp_path / "g.png", tile=80)
    assert problems == [f"{gone}: {MISSING}"]
    size, pixels = _png(tmp_path / "g.png")
    assert size == (2 * 80, 2 * (80 + 34)) and pixels[..., :3].std() > 0.05
    green, orange = (np.array(figures._FRAMES[k]) for k in ("right", "wrong"))
    assert np.abs(pixels[2, 80 + 2, :3] - green).max() < 0.02  # frame of result 1
    assert np.abs(pixels[114 + 2, 2, :3] - orange).max() < 0.02  # frame of result 2
    unlabeled = figures.retrieval_row((str(a), "a", None), [(str(b), "b", "ring", 0.5)])
    assert unlabeled[1].role == "result"
    figures.render_grid([row[:2], row[2:]], tmp_path / "again.png", tile=80)
    assert (tmp_path / "g.png").read_bytes() == (tmp_path / "again.png").read_bytes()


def test_grid_marks_unreadable_files(tmp_path):
    bad = tmp_path / "bad.off"
    bad.write_text("OFF\n3 1 0\n0 0 0\n1 0 0\n")
    problems = figures.render_grid([[figures.Thumb(str(bad), "bad")]], tmp_path / "g.png", tile=80)
    assert len(problems) == 1 and problems[0].startswith(f"{bad}: unreadable (")
    _assert_picture(tmp_path / "g.png", (80, 80 + 34))


def test_report_page(tmp_path, collection):
    paths = sorted(str(p) for p in collection.rglob("*.off"))
    names = [p.split("shapes/")[1] for p in paths]
    labels = [n.split("/")[0] for n in names]
    distances = np.abs(np.subtract.outer(np.arange(4.0), np.arange(4.0)))
    report = evaluate_distances(distances, labels)
    (collection / "ring" / "1.off").unlink()
    problems = write_report(tmp_path / "rep", report, names, labels, paths, distances)
    assert problems == [f"{paths[3]}: {MISSING}"]
    page = (tmp_path / "rep" / "index.html").read_text()
    assert page.startswith("<!DOCTYPE html>") and page.rstrip().endswith("</html>")
    assert "<td>long</td>" in page and "<td>ring</td>" in page and "<th>mAP</th>" in page
    for image in ("precision_recall.png", "query_01.png", "query_02.png"):
        assert f'src="{image}"' in page
        assert _png(tmp_path / "rep" / image)[1][..., :3].std() > 0.05


def test_missing_matplotlib_is_a_typed_error(monkeypatch, tmp_path):
    for name in ("matplotlib", "matplotlib.figure", "matplotlib.backends.backend_agg"):
        monkeypatch.setitem(sys.modules, name, None)
    with pytest.raises(MissingDependencyError, match=r"pip install 'cfsig\[plots\]'"):
        figures.plot_histograms([np.ones(4) / 4], ["a"], (0, 1), tmp_path / "h.png")


def test_cli_without_matplotlib_says_how_to_install(monkeypatch, tmp_path, collection):
    for name in ("matplotlib", "matplotlib.figure", "matplotlib.backends.backend_agg"):
        monkeypatch.setitem(sys.modules, name, None)
    mesh = str(collection / "long" / "0.off")
    run = CliRunner().invoke(
        main, ["compute", mesh, "--descriptor", "cf", "--hist", str(tmp_path / "h.png")]
    )
    assert run.exit_code == 1
    assert (
        run.output.splitlines()[-1] == "Error: pictures need matplotlib: pip install 'cfsig[plots]'"
    )


def test_cli_imports_no_matplotlib():
    code = "import sys, cfsig.cli; print('matplotlib' in sys.modules)"
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    assert out.stdout.strip() == "False"


def test_cli_compute_pictures(tmp_path, collection):
    a, b = collection / "long" / "0.off", collection / "ring" / "0.off"
    run = CliRunner().invoke(
        main,
        [
            "compute",
            "--descriptor",
            "cf",
            str(a),
            str(b),
            "--png",
            str(tmp_path / "p.png"),
            "--hist",
            str(tmp_path / "h.png"),
        ],
    )
    assert run.exit_code == 0, run.output
    _assert_picture(tmp_path / "p.png", (2 * 480 + 110, 480 + 40))
    _assert_picture(tmp_path / "h.png", (800, 450))
    run = CliRunner().invoke(main, ["compute", str(a), "--ply", str(tmp_path / "a.ply")])
    assert run.exit_code == 0, run.output
    assert (tmp_path / "a.ply").read_bytes().startswith(b"ply\nformat binary_little_endian")
    assert len(read_mesh(tmp_path / "a.ply").vertices) == len(read_mesh(a).vertices)
    run = CliRunner().invoke(main, ["compute", str(a), str(b), "--ply", str(tmp_path / "x.ply")])
    assert run.exit_code == 2 and "--ply writes one mesh" in run.output


def test_cli_compute_picture_shows_the_mesh_as_read_beside_the_repaired(tmp_path):
    v, f = icosphere(2)
    path = write_off(
        tmp_path / "two.off", np.vstack([v, v + [1.2, 0, 0]]), np.vstack([f, f + len(v)])
    )
    out = tmp_path / "p.png"
    run = CliRunner().invoke(main, ["compute", str(path), "--png", str(out)])
    assert run.exit_code == 0 and ", repaired" in run.output, run.output  # joined by their union
    _, pixels = _png(out)
    assert pixels.shape[1] == 2 * 480 + 110  # as read, then as repaired: two panels
    as_read, repaired = (pixels[40:480, k * 480 : (k + 1) * 480, :3] for k in (0, 1))
    colour = [float(np.ptp(p, axis=2).max()) for p in (as_read, repaired)]
    assert colour[0] < 0.35 < colour[1]  # clay, then coloured by phi


def test_cli_picture_write_failure_is_one_line(tmp_path, collection):
    out = tmp_path / "no" / "such" / "dir" / "p.png"
    run = CliRunner().invoke(
        main, ["compute", str(collection / "long" / "0.off"), "--png", str(out)]
    )
    assert run.exit_code == 1
    assert run.output.splitlines()[-1] == f"Error: {out}: cannot write: No such file or directory"


def test_cli_query_and_evaluate_pictures(tmp_path, collection):
    index = tmp_path / "i.h5"
    runner = CliRunner()
    run = runner.invoke(main, ["index", str(collection), "-o", str(index), "-j", "1"])
    assert run.exit_code == 0, run.output
    query = collection / "long" / "1.off"
    run = runner.invoke(
        main, ["query", str(index), str(query), "-k", "3", "--png", str(tmp_path / "q.png")]
    )
    assert run.exit_code == 0, run.output
    _assert_picture(tmp_path / "q.png", (4 * 160, 160 + 34))
    two = [str(query), str(collection / "ring" / "0.off")]
    run = runner.invoke(
        main, ["query", str(index), *two, "-k", "2", "--png", str(tmp_path / "q2.png")]
    )
    assert run.exit_code == 0, run.output
    _assert_picture(tmp_path / "q2.png", (3 * 160, 2 * (160 + 34)))  # one row per query
    pictures = ["--plot", str(tmp_path / "pr"), "--report", str(tmp_path / "rep")]
    run = runner.invoke(main, ["evaluate", str(collection), "-j", "1", *pictures])
    assert run.exit_code == 0, run.output
    _assert_picture(tmp_path / "pr" / "precision_recall.png", (3 * 260, 230))
    assert (tmp_path / "rep" / "index.html").is_file()
    (collection / "ring" / "0.off").rename(tmp_path / "moved.off")
    run = runner.invoke(
        main, ["evaluate", "--index", str(index), "--report", str(tmp_path / "rep2")]
    )
    assert run.exit_code == 0, run.output
    gone = collection.resolve() / "ring" / "0.off"
    warnings = [line for line in run.output.splitlines() if line.startswith("Warning")]
    assert warnings == [f"Warning: {gone}: {MISSING}"]
    run = runner.invoke(
        main, ["query", str(index), str(query), "-k", "4", "--png", str(tmp_path / "q3.png")]
    )
    assert run.exit_code == 0 and f"Warning: {gone}: missing" in run.output


def test_cli_compares_descriptors_side_by_side(tmp_path, collection):
    """--plot with several descriptors: the curves of each class, a curve per descriptor, and
    per class its first model's nearest, a row per descriptor; --report takes one."""
    out = tmp_path / "compare"
    args = ["evaluate", str(collection), "-j", "1", "--descriptor", "cf,gps"]
    run = CliRunner().invoke(main, [*args, "--plot", str(out)])
    assert run.exit_code == 0, run.output
    assert sorted(p.name for p in out.iterdir()) == [
        "precision_recall.png", "query_01_long.png", "query_02_ring.png"
    ]  # fmt: skip
    _assert_picture(out / "precision_recall.png", (3 * 260, 230))
    _assert_picture(out / "query_01_long.png", (2 * 100, 2 * (100 + 34)))  # query + 1 result
    run = CliRunner().invoke(main, [*args, "--report", str(tmp_path / "rep")])
    assert run.exit_code != 0 and "--report takes one descriptor" in run.output


def test_comparison_needs_the_same_meshes(tmp_path):
    labels = ["x", "x", "y", "y"]
    distances = np.abs(np.subtract.outer(np.arange(4.0), np.arange(4.0)))
    report = evaluate_distances(distances, labels)
    names = ("x/0", "x/1", "y/0", "y/1")
    make = lambda n: Evaluation(  # noqa: E731
        report, Collection(n, tuple(labels), n, np.zeros((4, 1))), distances, None
    )
    with pytest.raises(ValueError, match="same meshes"):
        write_comparison(tmp_path, {"a": make(names), "b": make(names[::-1])})
