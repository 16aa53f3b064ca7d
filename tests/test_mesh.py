import numpy as np
import pytest
import trimesh

from cfsig.errors import MeshError
from cfsig.files.folders import find_meshes
from cfsig.files.mesh import clean_mesh, read_mesh
from tests.helpers import icosphere, write_off


def test_off_round_trip(tmp_path):
    v, f = icosphere(1)
    write_off(tmp_path / "s.off", v, f)
    mesh = read_mesh(tmp_path / "s.off")
    assert np.array_equal(mesh.vertices, v) and np.array_equal(mesh.faces, f)
    assert mesh.repairs == ()


def test_off_quads_comments_and_colours(tmp_path):
    text = """OFF # a cube
8 6 0
0 0 0
1 0 0
1 1 0
0 1 0
0 0 1
1 0 1
1 1 1
0 1 1
4 0 3 2 1 255 0 0
4 4 5 6 7
4 0 1 5 4
4 1 2 6 5
4 2 3 7 6
4 3 0 4 7
"""
    (tmp_path / "cube.off").write_text(text)
    mesh = read_mesh(tmp_path / "cube.off")
    assert mesh.faces.shape == (12, 3)
    assert len(mesh.vertices) == 8


def test_off_layouts_parse_to_the_same_bits(tmp_path):
    v, f = icosphere(2)
    v = v * np.random.default_rng(0).lognormal(0, 3, (len(v), 1))  # exponents of every size
    rows = [f"{float(x)!r} {y:.6e} {z:.6f}" for x, y, z in v]
    triangles = [f"3 {a} {b} {c}" for a, b, c in f]
    layouts = {
        "plain": ["OFF", f"{len(v)} {len(f)} 0", *rows, *triangles],
        "counts on the header line": [f"OFF {len(v)} {len(f)} 0", *rows, *triangles],
        "vertex colours": ["OFF", f"{len(v)} {len(f)} 0", *(r + " 0.5 0.5 0.5" for r in rows)]
        + triangles,
    }
    meshes = {}
    for name, lines in layouts.items():
        (tmp_path / f"{name}.off").write_text("\n".join(lines) + "\n")
        meshes[name] = read_mesh(tmp_path / f"{name}.off")
    expected = np.array([[float(t) for t in row.split()] for row in rows])
    for mesh in meshes.values():
        assert np.array_equal(mesh.vertices, expected) and np.array_equal(mesh.faces, f)


@pytest.mark.parametrize("fmt", ["obj", "ply", "stl"])
def test_other_formats_via_trimesh(tmp_path, fmt):
    v, f = icosphere(1)
    trimesh.Trimesh(v, f, process=False).export(tmp_path / f"s.{fmt}")
    mesh = read_mesh(tmp_path / f"s.{fmt}")
    assert len(mesh.faces) == len(f)
    assert len(mesh.vertices) == len(v)  # STL's triangle soup is merged back
    if fmt == "stl":
        assert any("merged" in r for r in mesh.repairs)


@pytest.mark.parametrize(
    ("content", "reason"),
    [
        (b"", "empty file"),
        (b"\x00\x93garbage\xff" * 10, "not an OFF file"),
        (b"OFF\n1000000000 1 0\n0 0 0\n", "truncated OFF"),
        (b"OFF\n3 1 0\n0 0 0\n1 0 0\n0 1 0\n3 0 1 7\n", "face index out of range"),
        (b"OFF\n3 1 0\n0 0 0\nnan 0 0\n0 1 0\n3 0 1 2\n", "NaN or infinite"),
    ],
)
def test_bad_off_files_raise_mesh_error(tmp_path, content, reason):
    path = tmp_path / "bad.off"
    path.write_bytes(content)
    with pytest.raises(MeshError, match=reason) as info:
        read_mesh(path)
    assert str(path) in str(info.value)


def test_missing_and_unknown(tmp_path):
    with pytest.raises(MeshError, match="cannot read"):
        read_mesh(tmp_path / "nope.off")
    (tmp_path / "x.xyz").write_text("1 2 3")
    with pytest.raises(MeshError, match="unknown mesh type"):
        read_mesh(tmp_path / "x.xyz")


def test_clean_repairs():
    v, f = icosphere(1)
    v2 = np.vstack([v, [[9.0, 9, 9]]])  # unreferenced vertex
    f2 = np.vstack([f, f[:1], [[0, 0, 1]]])  # a duplicate face and a face repeating a vertex
    mesh = clean_mesh(v2, f2)
    assert len(mesh.vertices) == len(v) and len(mesh.faces) == len(f)
    assert len(mesh.repairs) == 3


def test_find_meshes(tmp_path):
    (tmp_path / "a" / "b").mkdir(parents=True)
    for name in ["a/1.off", "a/b/2.obj", "a/readme.txt", "a/.hidden.off"]:
        (tmp_path / name).write_text("x")
    found = [name for _, name in find_meshes([tmp_path])]
    assert found == ["a/1.off", "a/b/2.obj"]
    assert [n for _, n in find_meshes([tmp_path / "a" / "readme.txt"])] == ["readme.txt"]
