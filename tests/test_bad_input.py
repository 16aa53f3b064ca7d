"""Every bad input gives a right answer or a one-line error naming the file, never a crash."""

import json
import warnings

import numpy as np
import pytest
import trimesh
from click.testing import CliRunner

from cfsig.cli import EXIT_SKIPPED, main
from cfsig.descriptors.signature import compute_signature, signature_file
from cfsig.files.mesh import MAX_COORDINATE, MIN_SPAN, read_mesh
from cfsig.params import Params
from tests.helpers import disk, icosphere, off_text, open_cylinder


def _compute(path, *extra):
    return CliRunner().invoke(main, ["compute", *extra, str(path)])


def _tetrahedron(size: float):
    vertices = size * np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0], [0, 0, 1]], float)
    return vertices, [[0, 2, 1], [0, 1, 3], [0, 3, 2], [1, 2, 3]]


BAD_FILES = {
    "empty.off": (b"", "empty file"),
    "garbage.off": (bytes(range(256)) * 4, "not an OFF file"),
    "comment.off": (b"# only a comment\n", "not an OFF file"),  # found by tests/test_fuzz.py
    "truncated.off": (b"OFF\n4 2 0\n0 0 0\n1 0 0\n0 1 0\n", "truncated OFF"),
    "huge.off": (b"OFF\n1000000000 2000000000 0\n0 0 0\n", "truncated OFF"),
    "words.off": (b"OFF\n3 1 0\n0 0 zero\n1 0 0\n0 1 0\n3 0 1 2\n", "malformed OFF"),
    "nan.off": (b"OFF\n3 1 0\n0 0 0\nnan 0 0\n0 1 0\n3 0 1 2\n", "NaN or infinite"),
    "inf.off": (b"OFF\n3 1 0\n0 0 0\ninf 0 0\n0 1 0\n3 0 1 2\n", "NaN or infinite"),
    "range.off": (b"OFF\n3 1 0\n0 0 0\n1 0 0\n0 1 0\n3 0 1 9\n", "out of range"),
    "negative.off": (b"OFF\n3 1 0\n0 0 0\n1 0 0\n0 1 0\n3 0 -1 2\n", "out of range"),
    "allbad.off": (b"OFF\n3 1 0\n0 0 0\n1 0 0\n0 1 0\n3 0 0 1\n", "no triangles left"),
    "flat.off": (b"OFF\n4 2 0\n0 0 0\n1 0 0\n2 0 0\n3 0 0\n3 0 1 2\n3 1 2 3\n", "no area"),
    "large.off": (off_text(*_tetrahedron(1e51)).encode(), "beyond 1e+50"),
    "small.off": (off_text(*_tetrahedron(1e-51)).encode(), "below 1e-50"),
    "garbage.obj": (b"v 1 2\nf 1 2 3 4 5\n" * 3, "OBJ"),
    "garbage.ply": (b"ply\nformat ascii 1.0\nelement vertex 99\nend_header\n1 2\n", "PLY"),
    "garbage.stl": (b"solid x\nfacet normal\nendsolid\n", "no triangles"),
    "mesh.xyz": (b"1 2 3\n", "unknown mesh type"),
}


@pytest.mark.parametrize("name", sorted(BAD_FILES))
def test_bad_file_one_line_error(tmp_path, name):
    content, reason = BAD_FILES[name]
    path = tmp_path / name
    path.write_bytes(content)
    result = _compute(path)
    assert result.exit_code == 1
    lines = result.output.strip().splitlines()
    assert len(lines) == 1, result.output
    assert lines[0].startswith(f"Error: {path}: ") and reason in lines[0]


def test_missing_and_unreadable(tmp_path):
    (tmp_path / "folder.off").mkdir()
    for path in (tmp_path / "missing.off", tmp_path / "folder.off"):
        result = _compute(path)
        assert result.exit_code == 1 and result.output.startswith(f"Error: {path}: cannot read")


def test_json_output_stays_valid_with_errors(tmp_path):
    good, bad = tmp_path / "good.off", tmp_path / "bad.off"
    good.write_text(off_text(*icosphere(2)))
    bad.write_text("OFF\n3 1 0\n")
    result = CliRunner().invoke(main, ["compute", "--json", str(good), str(bad)])
    rows = json.loads(result.stdout)
    assert rows[0]["vertices"] == 162 and "error" in rows[1]
    assert result.exit_code == 1


def test_polygons_and_mixed_ply_are_triangulated(tmp_path):
    cube = trimesh.creation.box()
    quads = ["4 0 1 3 2", "4 4 6 7 5", "4 0 4 5 1", "4 2 3 7 6", "4 0 2 6 4", "4 1 5 7 3"]
    verts = [f"{x} {y} {z}" for x in (0, 1) for y in (0, 1) for z in (0, 1)]
    head = ["ply", "format ascii 1.0", "element vertex 8", "property float x",
            "property float y", "property float z", "element face 7",
            "property list uchar int vertex_indices", "end_header"]  # fmt: skip
    # one quad split into two triangles, the rest quads: triangles and quads mixed
    faces = [*quads[:5], "3 1 5 7", "3 1 7 3"]
    (tmp_path / "mixed.ply").write_text("\n".join(head + verts + faces) + "\n")
    mesh = read_mesh(tmp_path / "mixed.ply")
    assert mesh.faces.shape == (12, 3)
    assert abs(trimesh.Trimesh(mesh.vertices, mesh.faces).area - cube.area) < 1e-9
    obj = "\n".join(
        [f"v {v}" for v in verts]
        + [f"f {' '.join(str(int(i) + 1) for i in q.split()[1:])}" for q in quads]
    )
    (tmp_path / "cube.obj").write_text(obj + "\n")
    assert read_mesh(tmp_path / "cube.obj").faces.shape == (12, 3)
    off = "\n".join(["OFF", "8 6 0", *verts, *quads])
    (tmp_path / "cube.off").write_text(off + "\n")
    sig = signature_file(tmp_path / "cube.off", Params(descriptor="cf"))
    assert np.isfinite(sig.vector).all() and sig.n_faces == 12


def test_repairs_are_reported(tmp_path):
    v, f = icosphere(2)
    v = np.vstack([v, [[5.0, 5, 5]]])  # unreferenced
    f = np.vstack([f, f[:2], [[0, 0, 1]]])  # two duplicates and a face repeating a vertex
    path = tmp_path / "messy.off"
    path.write_text(off_text(v, f))
    result = _compute(path, "--json")
    row = json.loads(result.stdout)[0]
    assert result.exit_code == 0
    assert len(row["repairs"]) == 3 and row["vertices"] == 162
    assert result.output.count("Warning: ") == 3


def test_zero_area_and_needle_triangles_are_mollified():
    v, f = icosphere(2)
    a, b, c = f[0]
    # replace face (a, b, c) by (a, d, c), (d, b, c) and a zero-area face (a, b, d): d on ab
    for d_pos, name in (
        (0.5 * (v[a] + v[b]), "zero"),
        (0.5 * (v[a] + v[b]) + 1e-9 * v[c], "needle"),
    ):
        d = len(v)
        vv = np.vstack([v, d_pos])
        ff = np.vstack([f[1:], [[a, d, c], [d, b, c], [a, b, d]]])
        sig = compute_signature(read_mesh_arrays(vv, ff), Params(descriptor="cf"))
        assert np.isfinite(sig.vector).all() and np.isfinite(sig.phi).all(), name
        assert any("mollified" in r for r in sig.repairs), name
        base = compute_signature(read_mesh_arrays(v, f), Params(descriptor="cf")).vector
        assert np.abs(sig.vector - base).sum() < 0.05, name


def read_mesh_arrays(v, f):
    from cfsig.files.mesh import clean_mesh

    return clean_mesh(v, f)


@pytest.mark.parametrize("make", [disk, open_cylinder], ids=["disk", "cylinder"])
def test_open_boundaries(make):
    sig = compute_signature(read_mesh_arrays(*make()), Params(descriptor="cf"))
    assert np.isfinite(sig.vector).all() and sig.vector.sum() == pytest.approx(1)
    assert abs(sig.phi.mean()) < 1e-12


def test_components_reported(tmp_path):
    v1, f1 = icosphere(1)
    path = tmp_path / "two.off"
    path.write_text(off_text(np.vstack([v1, v1 + 3]), np.vstack([f1, f1 + len(v1)])))
    assert "2 component(s)" in _compute(path, "--repair", "off").output  # solved as read
    # by default the two closed spheres, apart, are kept as two parts of the object
    assert "2 component(s)" in _compute(path).output and ", repaired" in _compute(path).output


def test_evaluate_keeps_going_past_bad_files(tmp_path):
    for cls in ("a", "b"):
        (tmp_path / cls).mkdir()
        for i in range(2):
            (tmp_path / cls / f"{i}.off").write_text(off_text(*icosphere(1 + i)))
    (tmp_path / "b" / "broken.off").write_text("OFF\n")
    result = CliRunner().invoke(main, ["evaluate", str(tmp_path), "-j", "1"])
    assert result.exit_code == EXIT_SKIPPED
    assert "4 queries" in result.output and "broken.off" in result.output
    assert "Traceback" not in result.output


def test_query_mesh_that_fails(tmp_path, build_index):
    build_index(tmp_path / "i.h5", 3)
    (tmp_path / "q.off").write_text("nonsense")
    result = CliRunner().invoke(main, ["query", str(tmp_path / "i.h5"), str(tmp_path / "q.off")])
    assert result.exit_code == 1
    assert result.output.strip() == f"Error: {tmp_path / 'q.off'}: not an OFF file (no OFF header)"


@pytest.mark.parametrize("scale", [3e49, 1e-50], ids=["large", "small"])
def test_meshes_at_the_bounds_of_scale_are_measured_cleanly(scale):
    # Just inside MAX_COORDINATE and MIN_SPAN: every descriptor (the open cylinder through the
    # repair stage) and partial queries (the cylinder as a part) give finite values without a
    # warning.
    from cfsig.descriptors.parts import measure_part

    sphere, cylinder = icosphere(3), open_cylinder()
    for v, _ in (sphere, cylinder):
        largest, span = np.abs(v * scale).max(), np.ptp(v * scale, axis=0).max()
        assert largest <= MAX_COORDINATE and span >= MIN_SPAN
        assert largest >= MAX_COORDINATE / 10 or span <= 10 * MIN_SPAN  # near a bound
    descriptors = (Params(descriptor="cf"), Params(), Params(partial_cells=True))
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        for v, f in (sphere, cylinder):
            mesh = read_mesh_arrays(v * scale, f)
            for params in descriptors:
                assert np.isfinite(compute_signature(mesh, params).vector).all()
        part = read_mesh_arrays(cylinder[0] * scale, cylinder[1])
        for cells in (False, True):
            measured = measure_part(part, Params(partial_cells=cells))
            values = measured.vectors if measured.cells is None else measured.cells[0][1]
            assert np.isfinite(values).all()


@pytest.mark.parametrize("descriptor", ["intrinsic", "cf", "gps", "rigid"])
def test_a_stray_far_vertex_gives_a_signature_or_one_line(tmp_path, descriptor):
    # One vertex of a unit sphere thrown a million radii away, as a bit flip in a file does:
    # the spectrum's iterations once ended in a traceback on it.
    v, f = icosphere(2)
    v[np.argmin(np.abs(v[:, 0] - 0.16)), 0] = 220356.0
    path = tmp_path / "stray.off"
    path.write_text(off_text(v, f))
    result = _compute(path, "--descriptor", descriptor)
    assert "Traceback" not in result.output and not isinstance(result.exception, ValueError)
    errors = [line for line in result.output.splitlines() if line.startswith("Error:")]
    if result.exit_code == 0:
        assert not errors and "nan" not in result.output.lower()
    else:
        assert result.exit_code == 1 and len(errors) == 1 and str(path) in errors[0]
