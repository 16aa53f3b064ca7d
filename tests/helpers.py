"""Helpers of the tests: meshes they generate, OFF files, small indexes. No external data."""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np
from click.testing import CliRunner

from cfsig.cli import main
from cfsig.descriptors import get, layout
from cfsig.descriptors.signature import Signature, compute_signature
from cfsig.files.demo import capsule, limbed_body
from cfsig.files.demo import torus as demo_torus
from cfsig.files.mesh import clean_mesh
from cfsig.index.store import Entry, IndexReader, IndexWriter
from cfsig.params import Params
from cfsig.search.nearest import distances, nearest_by, query


def icosphere(levels: int = 3) -> tuple[np.ndarray, np.ndarray]:
    """A unit icosphere, subdivided ``levels`` times (chi = 2)."""
    import igl

    t = (1 + 5**0.5) / 2
    v = np.array(
        [[-1, t, 0], [1, t, 0], [-1, -t, 0], [1, -t, 0], [0, -1, t], [0, 1, t],
         [0, -1, -t], [0, 1, -t], [t, 0, -1], [t, 0, 1], [-t, 0, -1], [-t, 0, 1]], float,
    )  # fmt: skip
    f = np.array(
        [[0, 11, 5], [0, 5, 1], [0, 1, 7], [0, 7, 10], [0, 10, 11], [1, 5, 9], [5, 11, 4],
         [11, 10, 2], [10, 7, 6], [7, 1, 8], [3, 9, 4], [3, 4, 2], [3, 2, 6], [3, 6, 8],
         [3, 8, 9], [4, 9, 5], [2, 4, 11], [6, 2, 10], [8, 6, 7], [9, 8, 1]],
    )  # fmt: skip
    for _ in range(levels):
        v, f = igl.upsample(v, f)
    return v / np.linalg.norm(v, axis=1, keepdims=True), np.asarray(f, dtype=np.int64)


def grid_surface(nu: int, nv: int, closed_u: bool, closed_v: bool, point) -> tuple:
    """Triangulate a (u, v) grid mapped by ``point(u, v) -> (..., 3)``; u, v in [0, 1)."""
    us = np.arange(nu) / nu if closed_u else np.linspace(0, 1, nu)
    vs = np.arange(nv) / nv if closed_v else np.linspace(0, 1, nv)
    uu, vv = np.meshgrid(us, vs, indexing="ij")
    vertices = point(uu.ravel(), vv.ravel())
    idx = np.arange(nu * nv).reshape(nu, nv)
    i_end, j_end = (nu if closed_u else nu - 1), (nv if closed_v else nv - 1)
    faces = []
    for i in range(i_end):
        for j in range(j_end):
            a, b = idx[i, j], idx[(i + 1) % nu, j]
            c, d = idx[(i + 1) % nu, (j + 1) % nv], idx[i, (j + 1) % nv]
            faces += [[a, b, c], [a, c, d]]
    return vertices, np.array(faces, dtype=np.int64)


def torus(R: float = 1.0, r: float = 0.35, nu: int = 48, nv: int = 16) -> tuple:
    """A torus (chi = 0)."""

    def point(u, v):
        a, b = 2 * np.pi * u, 2 * np.pi * v
        return np.column_stack(
            [(R + r * np.cos(b)) * np.cos(a), (R + r * np.cos(b)) * np.sin(a), r * np.sin(b)]
        )

    return grid_surface(nu, nv, True, True, point)


def open_cylinder(n_around: int = 32, n_along: int = 12) -> tuple:
    """An open cylinder with two boundary loops (chi = 0)."""

    def point(u, v):
        return np.column_stack([np.cos(2 * np.pi * u), np.sin(2 * np.pi * u), 2 * v])

    return grid_surface(n_around, n_along, True, False, point)


def disk(n_around: int = 32, n_rings: int = 8) -> tuple:
    """A flat disk with one boundary loop (chi = 1): a centre vertex and rings."""
    vertices = [[0.0, 0.0, 0.0]]
    faces = []
    for ring in range(1, n_rings + 1):
        angles = 2 * np.pi * np.arange(n_around) / n_around + 0.1 * ring
        vertices += [[ring * np.cos(a), ring * np.sin(a), 0.0] for a in angles]
    for k in range(n_around):
        faces.append([0, 1 + k, 1 + (k + 1) % n_around])
    for ring in range(1, n_rings):
        inner, outer = 1 + (ring - 1) * n_around, 1 + ring * n_around
        for k in range(n_around):
            k1 = (k + 1) % n_around
            faces += [[inner + k, outer + k, outer + k1], [inner + k, outer + k1, inner + k1]]
    return np.array(vertices), np.array(faces, dtype=np.int64)


def random_rotation(seed: int) -> np.ndarray:
    """A random proper rotation matrix."""
    q, r = np.linalg.qr(np.random.default_rng(seed).standard_normal((3, 3)))
    q *= np.sign(np.diag(r))
    return q * np.linalg.det(q)


def signature_vector(vertices: np.ndarray, faces: np.ndarray, params: Params | None = None):
    """The signature vector of a mesh given as arrays, cleaned by `clean_mesh`."""
    return compute_signature(clean_mesh(vertices, faces), params or Params(descriptor="cf")).vector


def l1(a: np.ndarray, b: np.ndarray) -> float:
    """The L1 distance between two signature vectors."""
    return float(np.abs(a - b).sum())


def off_text(vertices: np.ndarray, faces) -> str:
    """An ASCII OFF file of a mesh: coordinates exactly (``repr``), faces of any length."""
    lines = ["OFF", f"{len(vertices)} {len(faces)} 0"]
    lines += [" ".join(map(repr, map(float, p))) for p in vertices]
    lines += [f"{len(face)} " + " ".join(map(str, face)) for face in faces]
    return "\n".join(lines) + "\n"


def write_off(path: str | os.PathLike, vertices: np.ndarray, faces) -> Path:
    """Write `off_text` to ``path``, creating its folder; return the path."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(off_text(vertices, faces))
    return path


def random_signature(seed: int, bins: int = 200) -> Signature:
    """A signature of random values summing to 1, with a hash made of the seed."""
    h = np.random.default_rng(seed).random(bins)
    return Signature(
        vector=h / h.sum(), phi=np.zeros(3), n_vertices=3, n_faces=1, n_components=1,
        curvature_error=0.0, repairs=(), route="clean", seconds=0.0, sha256=f"{seed:064d}",
    )  # fmt: skip


def open_writer(path: str | os.PathLike, params: Params | None = None, **options) -> IndexWriter:
    """An `IndexWriter` of ``params`` (the ``cf`` descriptor's by default) with its layout."""
    params = params or Params(descriptor="cf")
    return IndexWriter(path, params, layout(params), **options)


def build_index(path: str | os.PathLike, n: int = 10, params: Params | None = None) -> list:
    """An index of ``n`` random signatures in classes c0, c1, c2; return their vectors."""
    with open_writer(path, params) as w:
        for i in range(n):
            entry = Entry(f"c{i % 3}/{i}.off", f"c{i % 3}", f"/data/c{i % 3}/{i}.off")
            w.add(entry, random_signature(i))
    return [random_signature(i).vector for i in range(n)]


def read_plain(index: str | os.PathLike) -> dict:
    """Every live row of an index read with plain h5py, as docs/index-format.md says.

    Returns the manifest's attributes under ``"attrs"`` and each dataset of the segments,
    rows of superseded entries left out, in row order.
    """
    import h5py

    index = Path(index)
    with h5py.File(index / "manifest.h5", "r") as m:
        attrs = dict(m.attrs)
        files = list(m["segment_files"].asstr()[:])
        ids = list(m["segment_ids"][:])
    segments = [h5py.File(index / name, "r") for name in files]
    try:
        dropped = np.concatenate([np.zeros((0, 2), np.int64)] + [s["drops"][:] for s in segments])
        out: dict = {"attrs": attrs}
        for key in segments[0] if segments else []:
            if segments[0][key].shape[:1] != segments[0]["names"].shape:
                continue  # not a column of rows
            parts = []
            for seg_id, s in zip(ids, segments, strict=True):
                live = np.ones(len(s["names"]), bool)
                live[dropped[dropped[:, 0] == seg_id, 1]] = False
                data = s[key].asstr()[:] if s[key].dtype.kind == "O" else s[key][:]
                parts.append(data[live])
            out[key] = np.concatenate(parts)
        return out
    finally:
        for s in segments:
            s.close()


def assert_search_equals_full_scan(
    path: Path, params: Params, rows: list, base: np.ndarray
) -> None:
    """Index ``rows`` (float32 vectors of ``params``' descriptor) in two segments, supersede
    row 3 by ``base[1]``, and check that the descriptor's bounded search returns the full
    scan's rows and distances for several k, ties included."""
    descriptor = get(params.descriptor)

    def signature(vector: np.ndarray, seed: int) -> Signature:
        return Signature(
            vector=vector, phi=None, n_vertices=3, n_faces=1, n_components=1,
            curvature_error=float("nan"), repairs=(), route="clean", seconds=0.0,
            sha256=f"{seed:064d}",
        )  # fmt: skip

    for first, last in ((0, 18), (18, len(rows))):
        with open_writer(path, params) as writer:
            for i in range(first, last):
                writer.add(Entry(f"c/{i}.off", "c", f"/c/{i}.off"), signature(rows[i], i))
    with open_writer(path, params) as writer:
        rows[3] = np.float32(base[1])
        writer.add(Entry("c/3.off", "c", "/c/3.off"), signature(rows[3], 99))
    queries = np.float32([rows[2], base[0], base[3], rows[20]])
    full = distances(params.descriptor, queries, np.array(rows))
    with IndexReader(path) as reader:
        order = [int(n.split("/")[1].split(".")[0]) for n in reader.column("names")]
        for k in (1, 3, 7):
            found, dist = nearest_by(reader, queries, k, descriptor.distance)
            for j in range(len(queries)):
                scan = full[j, order]
                expected = np.lexsort((np.arange(len(order)), scan))[:k]
                np.testing.assert_array_equal(found[j], expected)
                np.testing.assert_array_equal(dist[j], np.float32(scan[expected]))
        hits = query(reader, queries[:1], 3)[0]
        assert [h.distance for h in hits] == [0.0, 0.0, 0.0]


# Shapes far enough apart that a descriptor tells them from one another, for the invariance
# tests of the extrinsic descriptors.
SHAPES = {
    "limbs3": lambda: limbed_body(3, pose=1),
    "limbs5": lambda: limbed_body(5, pose=2),
    "torus": lambda: demo_torus(wave=0.2),
    "capsule": lambda: capsule(bend=0.6),
}


def two_classes(folder: Path) -> None:
    """Write a labelled folder of two classes of two meshes: ``round`` and ``long``."""
    v, f = icosphere(2)
    meshes = {
        "round/a.off": (v, f),
        "round/b.off": (v * [1.0, 1.1, 0.9], f),
        "long/a.off": capsule(length=2.0),
        "long/b.off": capsule(length=2.2, bend=0.2),
    }
    for name, (vertices, faces) in meshes.items():
        write_off(folder / name, vertices, faces)


def assert_command_line_round_trip(folder: Path, descriptor: str) -> None:
    """`two_classes` in ``folder/data``, indexed with ``descriptor`` by the command line into
    ``folder/index``: a query finds its own mesh first and its class next, the index evaluates
    to NN 1 and checks healthy."""
    two_classes(folder / "data")
    runner = CliRunner()
    index = str(folder / "index")
    args = ["index", str(folder / "data"), "-o", index, "--descriptor", descriptor]
    out = runner.invoke(main, args)
    assert out.exit_code == 0, out.output
    out = runner.invoke(main, ["query", index, str(folder / "data/long/a.off"), "-k", "2"])
    assert out.exit_code == 0, out.output
    lines = out.output.splitlines()
    assert lines[1].split()[1:] == ["0.0000", "long/a.off", "long"]
    assert lines[2].split()[3] == "long"
    out = runner.invoke(main, ["evaluate", "--index", index, "--json"])
    assert out.exit_code == 0 and '"NN": 1.0' in out.output, out.output
    out = runner.invoke(main, ["check", index])
    assert out.exit_code == 0 and "healthy (4 entries" in out.output
