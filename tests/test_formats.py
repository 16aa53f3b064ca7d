"""Scene formats of the web (glTF, GLB, 3MF): read as one mesh in world coordinates."""

import io
import subprocess
import sys

import numpy as np
import pytest
import trimesh
from scipy.spatial import cKDTree

from cfsig.descriptors.signature import compute_signature, signature_file
from cfsig.errors import MeshError, MissingDependencyError
from cfsig.files.demo import capsule, torus
from cfsig.files.mesh import clean_mesh, read_mesh
from cfsig.params import Params
from tests.helpers import random_rotation


def _scene(vertices, faces, pieces=3, seed=0):
    """The mesh cut into ``pieces`` nodes, each stored in its own frame and placed back in the
    scene by its node's transform, as modelling tools export parts."""
    rng = np.random.default_rng(seed)
    order = np.argsort(vertices[faces].mean(axis=1)[:, 0], kind="stable")
    scene = trimesh.Scene()
    for i, part in enumerate(np.array_split(order, pieces)):
        transform = np.eye(4)
        transform[:3, :3] = random_rotation(seed + i) * rng.uniform(0.5, 2.0)
        transform[:3, 3] = rng.normal(size=3) * 10
        local = (vertices - transform[:3, 3]) @ np.linalg.inv(transform[:3, :3]).T
        piece = trimesh.Trimesh(local, faces[part], process=False)
        piece.remove_unreferenced_vertices()
        scene.add_geometry(piece, node_name=f"part{i}", transform=transform)
    return scene


def _collada(scene: trimesh.Scene) -> bytes:
    """A COLLADA file of a scene's nodes, each its geometry and transform (trimesh writes
    COLLADA only for meshes, without nodes)."""
    collada = pytest.importorskip("collada", reason="COLLADA needs the collada extra")
    doc = collada.Collada()
    nodes = []
    for i, name in enumerate(scene.graph.nodes_geometry):
        transform, geometry_name = scene.graph[name]
        mesh = scene.geometry[geometry_name]
        source = collada.source.FloatSource(f"v{i}", mesh.vertices.ravel(), ("X", "Y", "Z"))
        geometry = collada.geometry.Geometry(doc, f"g{i}", f"g{i}", [source])
        inputs = collada.source.InputList()
        inputs.addInput(0, "VERTEX", f"#v{i}")
        geometry.primitives.append(geometry.createTriangleSet(mesh.faces.ravel(), inputs, ""))
        doc.geometries.append(geometry)
        placed = collada.scene.MatrixTransform(np.asarray(transform, dtype=float).ravel())
        children = [collada.scene.GeometryNode(geometry, [])]
        nodes.append(collada.scene.Node(f"n{i}", children=children, transforms=[placed]))
    doc.scenes.append(collada.scene.Scene("scene", nodes))
    doc.scene = doc.scenes[0]
    out = io.BytesIO()
    doc.write(out)
    return out.getvalue()


def _scene_file(vertices, faces, suffix: str) -> bytes:
    """`_scene` written as a GLB, 3MF or COLLADA file."""
    if suffix == "dae":
        return _collada(_scene(vertices, faces))
    if suffix == "3mf":
        for name in ("networkx", "lxml"):
            pytest.importorskip(name, reason="3MF needs the 3mf extra")
    return _scene(vertices, faces).export(file_type=suffix)


@pytest.mark.parametrize("descriptor", ["intrinsic", "cf"])
@pytest.mark.parametrize("suffix", ["glb", "3mf", "dae"])
def test_a_scene_is_the_mesh_it_was_cut_from(tmp_path, descriptor, suffix):
    v, f = torus(wave=0.3, n_major=60, n_minor=20)  # below the copy's faces: no simplification
    path = tmp_path / f"ring.{suffix}"
    path.write_bytes(_scene_file(v, f, suffix))
    read = read_mesh(path)
    assert len(read.faces) == len(f) and len(read.vertices) == len(v)  # the seams welded
    # In world coordinates: the nodes put back where they were cut, to float32's rounding.
    assert np.allclose(np.sort(read.vertices, axis=0), np.sort(v, axis=0), atol=1e-5)
    params = Params(descriptor=descriptor)
    original = compute_signature(clean_mesh(v, f), params)
    sig = signature_file(path, params)
    assert sig.route == "clean" and sig.n_components == 1
    # cf's histograms sum to 1 and the L1 distance of two is at most 2
    scale = 2.0 if descriptor == "cf" else np.abs(original.vector).sum()
    assert np.abs(original.vector - sig.vector).sum() < 1e-3 * scale


def test_scene_parts_apart_stay_apart(tmp_path):
    """Welding joins only what meets to float32's rounding: two separate parts stay two."""
    v, f = capsule()
    scene = trimesh.Scene()
    for i in range(2):
        place = np.eye(4)
        place[0, 3] = 3.0 * i
        scene.add_geometry(trimesh.Trimesh(v, f, process=False), node_name=f"c{i}", transform=place)
    path = tmp_path / "two.glb"
    path.write_bytes(scene.export(file_type="glb"))
    read = read_mesh(path)
    assert len(read.vertices) == 2 * len(v) and len(read.faces) == 2 * len(f)


def test_gltf_with_its_buffer_beside_it(tmp_path):
    v, f = capsule()
    files = trimesh.Scene(trimesh.Trimesh(v, f, process=False)).export(file_type="gltf")
    for name, data in files.items():
        (tmp_path / name).write_bytes(data)
    (gltf,) = tmp_path.glob("*.gltf")
    assert np.allclose(read_mesh(gltf).vertices, v, atol=1e-6)
    for buffer in tmp_path.glob("*.bin"):
        buffer.unlink()
    with pytest.raises(MeshError, match=str(gltf)):
        read_mesh(gltf)


def test_a_broken_glb_is_one_line_naming_the_file(tmp_path):
    path = tmp_path / "broken.glb"
    path.write_bytes(b"glTF" + bytes(40))
    with pytest.raises(MeshError, match=f"^{path}: malformed GLB") as caught:
        read_mesh(path)
    assert "\n" not in str(caught.value)


def test_the_glb_bytes_are_hashed_as_read(tmp_path):
    v, f = capsule()
    data = trimesh.Trimesh(v, f, process=False).export(file_type="glb")
    path = tmp_path / "c.glb"
    path.write_bytes(data)
    assert (
        signature_file(path, Params(descriptor="cf")).sha256
        == __import__("hashlib").sha256(io.BytesIO(data).getvalue()).hexdigest()
    )


def _draco_glb(vertices, faces) -> bytes:
    """A GLB scene of three nodes (`_scene`), each mesh Draco-compressed."""
    pytest.importorskip("DracoPy", reason="Draco-compressed glTF needs the draco extra")
    data = _scene(vertices, faces).export(file_type="glb", extension_draco=True)
    assert b"KHR_draco_mesh_compression" in data
    return data


def test_a_draco_compressed_glb_is_the_mesh_it_was_cut_from(tmp_path):
    v, f = torus(wave=0.3, n_major=60, n_minor=20)
    path = tmp_path / "ring.glb"
    path.write_bytes(_draco_glb(v, f))
    read = read_mesh(path)
    assert len(read.faces) == len(f)
    # Draco stores positions quantized: each within a ten-thousandth of the size of the torus.
    gap = cKDTree(v).query(read.vertices)[0]
    assert gap.max() < 1e-4 * np.ptp(v, axis=0).max()


@pytest.mark.parametrize(("suffix", "module"), [("3mf", "lxml"), ("dae", "collada")])
def test_a_format_without_its_extra_says_how_to_install(tmp_path, monkeypatch, suffix, module):
    path = tmp_path / f"c.{suffix}"
    path.write_bytes(b"not read: the check comes first")
    monkeypatch.setitem(sys.modules, module, None)
    extra = {"3mf": "3mf", "dae": "collada"}[suffix]
    with pytest.raises(MissingDependencyError, match=rf"^{path}: .*pip install 'cfsig\[{extra}\]'"):
        read_mesh(path)


def test_a_draco_glb_without_dracopy_says_how_to_install(tmp_path, monkeypatch):
    v, f = capsule()
    path = tmp_path / "c.glb"
    path.write_bytes(_draco_glb(v, f))
    monkeypatch.setitem(sys.modules, "DracoPy", None)
    with pytest.raises(MissingDependencyError, match=rf"^{path}: .*pip install 'cfsig\[draco\]'"):
        read_mesh(path)


def test_a_broken_draco_glb_fails_in_one_line_and_logs_nothing(tmp_path):
    v, f = capsule()
    data = _draco_glb(v, f)
    # The compressed bytes zeroed: the extension is declared, its data undecodable.
    start = data.index(b"BIN\x00") + 4
    path = tmp_path / "broken.glb"
    path.write_bytes(data[:start] + bytes(len(data) - start))
    # A process of its own: pytest's log capture would hide what trimesh logs.
    command = [sys.executable, "-m", "cfsig", "compute", str(path)]
    out = subprocess.run(command, capture_output=True, text=True)
    assert out.returncode != 0
    assert out.stderr.splitlines() == [out.stderr.strip()]
    assert out.stderr.startswith(f"Error: {path}: ")
