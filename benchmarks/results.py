"""Retrieval measures of cfsig's descriptors on labelled collections: docs/results.md.

    python benchmarks/results.py --data-root DATA [--doc docs/results.md]
        [--collections shrec07,mcgill,faust] [--jobs N] [--every K]

``DATA/NAME/<class>/<file>.off`` holds each collection (``../shared/data/unpack all DATA``);
``--every K`` takes every k-th mesh in sorted order (a quick look).

Whole shapes: for each collection, ``cf`` and ``intrinsic`` signatures of every mesh
(`cfsig.compute_collection`), ranked leave-one-out (`cfsig.evaluate_collections`): NN, FT, ST,
DCG, mAP and the median wall seconds per mesh (reading included, in a worker). The classes
are the folders, or for ``psb-train`` (not measured by default: ``benchmarks/peers.py``
measures it beside the descriptors for rigid objects) PSB's own ``DATA/psb-train.cla`` when it
is there.

Partial queries (shrec07, mcgill, faust): each mesh at sorted position i gives three parts, made
in this order from ``np.random.default_rng(i)``:

- ``cut``: the mesh cut by a plane of random direction, keeping a random 20-80% of its area
  (the largest connected piece; if no plane of 20 tries keeps 20-80% in one piece, a geodesic
  disc of that area around a random point, 20 tries; else the try closest to the range);
- ``holes``: 5 to 20 geodesic discs around random points removed, 10-40% of the area together,
  the largest connected piece kept if it holds at least half the area (20 tries; else the try
  with the largest);
- ``scan``: a second cut, simplified to half its faces by quadric edge collapses, then every
  vertex moved by Gaussian noise of a tenth of the mean edge length.

The parts are written as OFF files ``PARTS/<kind>/<class>/<name>.off`` and evaluated against an
index of the collection's whole shapes (`cfsig.evaluate_partial`), once with the default
``Params()`` (ranked by the curvature columns) and once with ``Params(partial_cells=True)``
(ranked by fine curvature cells).

With ``--doc``, everything after the line
``<!-- measured: what follows is written by benchmarks/results.py -->`` of that file is replaced
by the tables, preceded by a line naming the command.
"""

from __future__ import annotations

import argparse
import multiprocessing
import sys
import tempfile
from concurrent.futures import ProcessPoolExecutor
from pathlib import Path

import numpy as np
import scipy.sparse as sp
from common import command, table
from scipy.sparse.csgraph import connected_components, dijkstra

import cfsig
from cfsig.files.demo import write_off
from cfsig.files.mesh import Mesh, clean_mesh
from cfsig.repair.simplify import decimate

COLLECTIONS = ("shrec07", "mcgill", "faust")
PARTIAL = ("shrec07", "mcgill", "faust")
DESCRIPTORS = ("cf", "intrinsic")
WHOLE_MEASURES = ("NN", "FT", "ST", "DCG", "mAP")
PART_MEASURES = ("NN", "FT", "mAP")
KINDS = ("cut", "holes", "scan")
RANKINGS = {"curvature columns": cfsig.Params(), "fine cells": cfsig.Params(partial_cells=True)}
MARKER = "<!-- measured: what follows is written by benchmarks/results.py -->"


# --- the parts: as benchmarks/partial.py and messy.py made them at commit 35f8114 ------------


def face_graph(vertices: np.ndarray, faces: np.ndarray) -> sp.csr_matrix:
    """Faces sharing an edge, weighted by the distance of their centroids."""
    edges = np.sort(faces[:, [0, 1, 1, 2, 2, 0]].reshape(-1, 2), axis=1)
    order = np.lexsort((edges[:, 1], edges[:, 0]))
    same = np.flatnonzero((np.diff(edges[order], axis=0) == 0).all(axis=1))
    face = np.repeat(np.arange(len(faces)), 3)[order]
    a, b = face[same], face[same + 1]
    centroids = vertices[faces].mean(axis=1)
    weight = np.linalg.norm(centroids[a] - centroids[b], axis=1) + 1e-12
    return sp.coo_matrix((weight, (a, b)), shape=(len(faces),) * 2).tocsr()


def piece(mesh: Mesh, keep: np.ndarray) -> Mesh:
    """The largest connected piece of the kept faces, as a checked mesh."""
    faces = mesh.faces[keep]
    _, labels = connected_components(face_graph(mesh.vertices, faces), directed=False)
    faces = faces[labels == np.argmax(np.bincount(labels))]
    used, inverse = np.unique(faces, return_inverse=True)
    return clean_mesh(mesh.vertices[used], inverse.reshape(-1, 3))


def area(mesh: Mesh) -> np.ndarray:
    """Face areas."""
    p = mesh.vertices[mesh.faces]
    return 0.5 * np.linalg.norm(np.cross(p[:, 1] - p[:, 0], p[:, 2] - p[:, 0]), axis=1)


def nearest_faces(mesh: Mesh, seeds: np.ndarray, share: float) -> np.ndarray:
    """The faces nearest to the seed faces (geodesically) that hold ``share`` of the area."""
    areas = area(mesh)
    distance = dijkstra(face_graph(mesh.vertices, mesh.faces), indices=seeds, min_only=True)
    order = np.argsort(distance, kind="stable")
    chosen = np.zeros(len(areas), bool)
    chosen[order[: np.searchsorted(np.cumsum(areas[order]) / areas.sum(), share) + 1]] = True
    return chosen


def closest(candidates: list[Mesh], whole: float, low: float, high: float) -> Mesh:
    """The first candidate whose share of the whole's area is in [low, high], else the closest."""
    shares = [area(c).sum() / whole for c in candidates]
    misses = [max(low - share, share - high, 0.0) for share in shares]
    return candidates[int(np.argmin(misses))]


def cut(mesh: Mesh, rng: np.random.Generator) -> Mesh:
    """A plane cut keeping 20-80% of the area in one piece (see the module's docstring)."""
    areas = area(mesh)
    share = rng.uniform(0.2, 0.8)
    centroids = mesh.vertices[mesh.faces].mean(axis=1)
    candidates = []
    for attempt in range(40):
        if attempt < 20:
            order = np.argsort(centroids @ rng.normal(size=3))
            keep = np.zeros(len(areas), bool)
            keep[order[: np.searchsorted(np.cumsum(areas[order]) / areas.sum(), share) + 1]] = True
        else:  # a geodesic disc of that area
            seed = np.array([rng.choice(len(areas), p=areas / areas.sum())])
            keep = nearest_faces(mesh, seed, share)
        candidates.append(piece(mesh, keep))
        if 0.2 <= area(candidates[-1]).sum() / areas.sum() <= 0.8:
            break
    return closest(candidates, areas.sum(), 0.2, 0.8)


def holes(mesh: Mesh, rng: np.random.Generator) -> Mesh:
    """The mesh with 5-20 geodesic discs, 10-40% of the area, removed, one piece kept that
    holds at least half the area (20 tries, else the largest)."""
    areas = area(mesh)
    candidates = []
    for _ in range(20):
        count = int(rng.integers(5, 21))
        seeds = rng.choice(len(areas), count, replace=False, p=areas / areas.sum())
        candidates.append(piece(mesh, ~nearest_faces(mesh, seeds, rng.uniform(0.1, 0.4))))
        if area(candidates[-1]).sum() / areas.sum() >= 0.5:
            break
    return closest(candidates, areas.sum(), 0.5, 1.0)


def remesh(mesh: tuple[np.ndarray, np.ndarray], rng: np.random.Generator) -> tuple:
    """Simplified to half its faces by quadric edge collapses (``rng`` unused: deterministic)."""
    vertices, faces = mesh
    return decimate(vertices, faces, len(faces) // 2)


def noise(mesh: tuple[np.ndarray, np.ndarray], rng: np.random.Generator) -> tuple:
    """Gaussian noise of 10% of the mean edge length on every vertex."""
    vertices, faces = mesh
    edges = vertices[faces] - vertices[np.roll(faces, 1, axis=1)]
    sigma = 0.1 * float(np.linalg.norm(edges, axis=2).mean())
    return vertices + rng.normal(scale=sigma, size=vertices.shape), faces


def scan(mesh: Mesh, rng: np.random.Generator) -> Mesh:
    """A cut (`cut`) remeshed (`remesh`) and perturbed (`noise`) as a scan would be."""
    part = cut(mesh, rng)
    return clean_mesh(*noise(remesh((part.vertices, part.faces), rng), rng))


def write_parts(item: tuple[Path, int, Path]) -> None:
    """Write the three parts of one mesh, seeded by its sorted position, under ``parts``."""
    path, position, parts = item
    mesh, rng = cfsig.read_mesh(path), np.random.default_rng(position)
    for kind, make in (("cut", cut), ("holes", holes), ("scan", scan)):
        part = make(mesh, rng)
        out = parts / kind / path.parent.name / f"{path.stem}.off"
        out.parent.mkdir(parents=True, exist_ok=True)
        write_off(out, part.vertices, part.faces)


# --- measures -------------------------------------------------------------------------------


def wholes(data: Path, every: int, folder: Path) -> list[Path]:
    """Link every k-th mesh ``data/<class>/<file>.off`` (sorted) into ``folder``; the meshes."""
    paths = sorted(data.glob("*/*.off"))[::every]
    if not paths:
        sys.exit(f"no meshes under {data}: expected {data}/<class>/<file>.off")
    for path in paths:
        (folder / path.parent.name).mkdir(parents=True, exist_ok=True)
        (folder / path.parent.name / path.name).symlink_to(path.resolve())
    return paths


def whole_rows(name: str, folder: Path, data_root: Path, jobs: int) -> list[list]:
    """Leave-one-out measures of each descriptor on one collection: one row each."""
    cla = data_root / f"{name}.cla"
    classes = cfsig.read_cla(cla) if name == "psb-train" and cla.exists() else None
    found = {}
    for descriptor in DESCRIPTORS:
        params = cfsig.Params(descriptor=descriptor)
        found[descriptor], failures = cfsig.compute_collection(folder, params, jobs=jobs)
        for line in failures:
            print(f"{name}, {descriptor}: {line}", file=sys.stderr)
    rows = []
    for descriptor, evaluation in cfsig.evaluate_collections(found, classes).items():
        report = evaluation.report
        rows.append(
            [name, f"`{descriptor}`", report.count]
            + [f"{report.measures[m]:.3f}" for m in WHOLE_MEASURES]
            + [evaluation.seconds_per_mesh]
        )
    return rows


def partial_rows(name: str, folder: Path, paths: list[Path], tmp: Path, jobs: int) -> list[list]:
    """Measures of the parts of one collection against two indexes of its whole shapes."""
    parts = tmp / "parts"
    items = [(path, i, parts) for i, path in enumerate(paths)]
    if jobs == 1:
        list(map(write_parts, items))
    else:
        with ProcessPoolExecutor(jobs, mp_context=multiprocessing.get_context("spawn")) as pool:
            list(pool.map(write_parts, items, chunksize=2))
    indexes = {}
    for ranked, params in RANKINGS.items():
        indexes[ranked] = tmp / f"index-{params.partial_cells}"
        with cfsig.IndexWriter(indexes[ranked], params, cfsig.layout(params)) as writer:
            failures = cfsig.index_meshes(writer, [folder], jobs=jobs).failures
        for line in failures:
            print(f"{name}, index: {line}", file=sys.stderr)
    rows = []
    for kind in KINDS:
        for ranked, index in indexes.items():
            report, failures = cfsig.evaluate_partial(index, parts / kind, jobs)
            for line in failures:
                print(f"{name}, {kind}: {line}", file=sys.stderr)
            measures = [f"{report.measures[m]:.3f}" for m in PART_MEASURES]
            rows.append([name, kind, ranked, report.count, *measures])
    return rows


def main() -> None:
    """Measure every collection asked for, print the tables and write them into ``--doc``."""
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--data-root", type=Path, required=True, help="DATA/NAME/<class>/<file>")
    parser.add_argument("--doc", type=Path, help="write the tables after the marker of this file")
    parser.add_argument("--collections", default=",".join(COLLECTIONS), help="comma-separated")
    parser.add_argument("--jobs", type=int, default=2, help="worker processes")
    parser.add_argument("--every", type=int, default=1, help="every k-th mesh (a quick look)")
    args = parser.parse_args()
    if args.doc is not None and MARKER not in args.doc.read_text():
        sys.exit(f"{args.doc}: no line {MARKER}")
    whole, partial = [], []
    for name in args.collections.split(","):
        with tempfile.TemporaryDirectory(prefix=f"cfsig-results-{name}-") as tmp:
            folder = Path(tmp) / "wholes"
            paths = wholes(args.data_root / name, args.every, folder)
            whole += whole_rows(name, folder, args.data_root, args.jobs)
            if name in PARTIAL:
                partial += partial_rows(name, folder, paths, Path(tmp), args.jobs)
        print(f"{name}: {len(paths)} meshes measured", file=sys.stderr, flush=True)
    lines = [
        "### Whole shapes, leave-one-out",
        "",
        table(["collection", "descriptor", "queries", *WHOLE_MEASURES, "s per mesh"], whole),
    ]
    if partial:
        lines += [
            "",
            "### Partial queries against the whole shapes (`intrinsic`)",
            "",
            table(["collection", "parts", "ranked by", "queries", *PART_MEASURES], partial),
        ]
    text = "\n".join([f"Measured by `{command('results.py')}`.", "", *lines])
    print(text)
    if args.doc is not None:
        head = args.doc.read_text().split(MARKER)[0]
        args.doc.write_text(f"{head}{MARKER}\n\n{text}\n")


if __name__ == "__main__":
    main()
