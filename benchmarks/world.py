"""Queries from the world: parts, scans and noisy copies of shapes whose own file is not indexed.

    python benchmarks/world.py --data-root DATA [--doc docs/results.md]
        [--collections shrec07,mcgill,faust] [--kinds cut,holes,scan,noise] [--jobs N]
        [--every K]

``DATA/NAME/<class>/<file>.off`` holds each collection (``../shared/data/unpack all DATA``);
``--every K`` keeps every k-th mesh of each half (a quick look).

Each class is split in two halves by sorted position: the even-numbered meshes are indexed
(default ``Params()``), the odd-numbered ones make the queries, so that no query's own whole is in
the index it is ranked against. On FAUST, where the class is the person, that indexes five poses
of each person and queries the other five. Each query mesh at sorted position i gives one query
per kind and amount, each from ``np.random.default_rng(i)``:

- ``cut-S``: the faces on one side of a plane of random direction, placed to keep the share S of
  the area (every piece on that side);
- ``holes-S``: geodesic discs around 5 random points, grown together until they hold the share
  S of the area, removed;
- ``scan-N``: what a depth sensor sees from one random direction: a 128 x 128 depth image of the
  surface, triangulated pixel by pixel where neighbouring depths agree, islands of less than 2%
  dropped, with Gaussian noise of N% of the bounding-box diagonal along the view;
- ``noise-N``: the whole shape with Gaussian noise of N% of the diagonal on every vertex;
- ``shot-R`` (copies of every mesh only): 0.1% of the vertices thrown R% of the diagonal, R
  each of `SHOTS`.

Cuts and holes are re-tessellated (`retessellate`: split, slid along the surface and simplified
to about 60% of the faces), so that no part shares a triangle with any indexed mesh; a scan is a
new tessellation by construction. Parts are ranked by `cfsig.evaluate_partial` as ``cfsig query
--partial`` ranks them, against an index of ``Params()`` (by the curvature columns) and one of
``Params(partial_cells=True)`` (by fine cells); noisy wholes as whole shapes (``cfsig query``).

Near-duplicate search, the protocol where each query's own whole is in the index, is one line
per kind at its middle amount: the same kinds made from the indexed meshes. For noise it is the
share of noisy copies of every mesh whose own original is the nearest clean mesh, and the first
tier of the noisy copies as a collection, leave-one-out.

With ``--doc``, the section between ``<!-- benchmarks/world.py -->`` and
``<!-- /benchmarks/world.py -->`` of that file is replaced by the tables.
"""

from __future__ import annotations

import multiprocessing
import sys
import tempfile
from concurrent.futures import ProcessPoolExecutor
from pathlib import Path

import numpy as np
import scipy.sparse as sp
from common import collection_parser, command, table
from scipy.sparse.csgraph import connected_components, dijkstra

import cfsig
from cfsig.evaluation.collections import Collection
from cfsig.evaluation.measures import evaluate_queries
from cfsig.figures.raster import rasterize, screen_coordinates
from cfsig.files.demo import write_off
from cfsig.files.elements import mesh_edges
from cfsig.files.mesh import Mesh, clean_mesh
from cfsig.repair.simplify import decimate
from cfsig.search.nearest import distances

COLLECTIONS = ("shrec07", "mcgill", "faust")
AMOUNTS = {
    "cut": (0.3, 0.5, 0.7),
    "holes": (0.1, 0.25, 0.4),
    "scan": (0.001, 0.0025, 0.005),
    "noise": (0.0025, 0.005, 0.01),
}
RANKINGS = {"curvature columns": cfsig.Params(), "fine cells": cfsig.Params(partial_cells=True)}
SHOTS = (0.02, 0.1, 0.5)  # how far, over the diagonal, shot noise throws 0.1% of the vertices
MEASURES = ("NN", "FT", "mAP")
SCAN_PIXELS = 128
# Depths a 2 x 2 block of a scan's pixels may span: a surface up to about 75 degrees from
# facing the sensor, as depth sensors see.
SCAN_STEP = 6
SCAN_ISLAND = 0.02  # a scan's smallest piece kept, over its faces
RETESSELLATED = 0.6  # faces of a re-tessellated part over its own
SECTION = "<!-- benchmarks/world.py -->", "<!-- /benchmarks/world.py -->"

# --- the queries ----------------------------------------------------------------------------


def face_areas(vertices: np.ndarray, faces: np.ndarray) -> np.ndarray:
    """(m,) triangle areas."""
    p = vertices[faces]
    return 0.5 * np.linalg.norm(np.cross(p[:, 1] - p[:, 0], p[:, 2] - p[:, 0]), axis=1)


def diagonal(vertices: np.ndarray) -> float:
    """The bounding box's diagonal."""
    return float(np.linalg.norm(np.ptp(vertices, axis=0)))


def cut(mesh: Mesh, share: float, rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray]:
    """The faces on one side of a plane of random direction that hold ``share`` of the area."""
    areas = face_areas(mesh.vertices, mesh.faces)
    height = mesh.vertices[mesh.faces].mean(axis=1) @ rng.normal(size=3)
    order = np.argsort(height, kind="stable")
    kept = order[: np.searchsorted(np.cumsum(areas[order]), share * areas.sum()) + 1]
    return mesh.vertices, mesh.faces[np.sort(kept)]


def holes(mesh: Mesh, share: float, rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray]:
    """The mesh without geodesic discs around 5 random points that together hold ``share`` of
    the area: grown together, a face goes once its farthest corner is within the radius of a
    point, by distance along the edges, so that each hole's rim follows a circle."""
    areas = face_areas(mesh.vertices, mesh.faces)
    seeds = mesh.faces[rng.choice(len(areas), 5, replace=False, p=areas / areas.sum()), 0]
    near = dijkstra(edge_graph(mesh), directed=False, indices=seeds, min_only=True)
    distance = near[mesh.faces].max(axis=1)
    order = np.argsort(distance, kind="stable")
    removed = order[: np.searchsorted(np.cumsum(areas[order]), share * areas.sum()) + 1]
    kept = np.ones(len(areas), bool)
    kept[removed] = False
    return mesh.vertices, mesh.faces[kept]


def edge_graph(mesh: Mesh) -> sp.csr_matrix:
    """Vertices joined by an edge, weighted by its length."""
    n = len(mesh.vertices)
    edges = (mesh.edges or mesh_edges(mesh.faces, n)).ends
    length = np.linalg.norm(np.subtract(*mesh.vertices[edges.T]), axis=1) + 1e-12
    return sp.coo_matrix((length, (edges[:, 0], edges[:, 1])), shape=(n, n)).tocsr()


def scan(mesh: Mesh, noise: float, rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray]:
    """What a depth sensor sees of the mesh from a random direction, with noise along the view.

    The surface nearest the sensor at each pixel of a `SCAN_PIXELS`-wide orthographic depth
    image is a vertex; each 2 x 2 block of pixels that all see the surface, at depths within
    `SCAN_STEP` pixels of each other, gives two triangles. Gaussian noise of ``noise`` times the
    bounding-box diagonal moves each vertex along the view.
    """
    toward = rng.normal(size=3)
    toward /= np.linalg.norm(toward)
    right = np.cross(toward, rng.normal(size=3))
    right /= np.linalg.norm(right)
    view = np.array([right, np.cross(toward, right), toward])
    points = screen_coordinates(mesh.vertices, view, (SCAN_PIXELS, SCAN_PIXELS))
    face, bary = rasterize(points, mesh.faces, SCAN_PIXELS, SCAN_PIXELS)
    seen = face >= 0
    corners = mesh.faces[face[seen]]
    where = np.einsum("pk,pkj->pj", bary[seen], mesh.vertices[corners])
    where += np.outer(rng.normal(scale=noise * diagonal(mesh.vertices), size=len(where)), toward)
    depth = np.full(len(face), np.nan)  # in pixels, before the noise
    depth[seen] = np.einsum("pk,pk->p", bary[seen], points[corners, 2])
    number = np.full(len(face), -1)
    number[seen] = np.arange(seen.sum())
    grid, depth = number.reshape(SCAN_PIXELS, -1), depth.reshape(SCAN_PIXELS, -1)
    a, b, c, d = grid[:-1, :-1], grid[:-1, 1:], grid[1:, :-1], grid[1:, 1:]
    span = np.stack([depth[:-1, :-1], depth[:-1, 1:], depth[1:, :-1], depth[1:, 1:]])
    with np.errstate(invalid="ignore"):  # NaN where a pixel sees nothing: no block
        block = np.ptp(span, axis=0) < SCAN_STEP
    a, b, c, d = a[block], b[block], c[block], d[block]
    faces = np.concatenate([np.column_stack([a, c, b]), np.column_stack([b, c, d])])
    # islands of less than `SCAN_ISLAND` of the faces are dropped, as scanning software does
    ends = np.concatenate([faces[:, [0, 1]], faces[:, [1, 2]]])
    graph = sp.coo_matrix((np.ones(len(ends)), (ends[:, 0], ends[:, 1])), shape=(len(where),) * 2)
    labels = connected_components(graph, directed=False)[1][faces[:, 0]]
    return where, faces[np.bincount(labels)[labels] >= SCAN_ISLAND * len(faces)]


def noisy(mesh: Mesh, noise: float, rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray]:
    """The whole mesh with Gaussian noise of ``noise`` times the diagonal on every vertex."""
    sigma = noise * diagonal(mesh.vertices)
    return mesh.vertices + rng.normal(scale=sigma, size=mesh.vertices.shape), mesh.faces


def retessellate(
    vertices: np.ndarray, faces: np.ndarray, rng: np.random.Generator
) -> tuple[np.ndarray, np.ndarray]:
    """The same surface on new triangles: every face split in four at its edges' midpoints,
    every vertex slid along the surface by up to a quarter of its shortest edge (in the plane
    of its normal), then simplified by quadric edge collapses to `RETESSELLATED` times the
    faces given."""
    import trimesh

    vertices, split = trimesh.remesh.subdivide(vertices, faces)
    surface = trimesh.Trimesh(vertices, split, process=False)
    normals = surface.vertex_normals
    step = rng.normal(size=vertices.shape)
    step -= (step * normals).sum(axis=1)[:, None] * normals
    step /= np.maximum(np.linalg.norm(step, axis=1), 1e-12)[:, None]
    edges = surface.edges_unique
    lengths = surface.edges_unique_length
    shortest = np.full(len(vertices), np.inf)
    np.minimum.at(shortest, edges.ravel(), np.repeat(lengths, 2))
    reach = np.where(np.isfinite(shortest), shortest, 0.0) * rng.uniform(0, 0.25, len(vertices))
    return decimate(vertices + step * reach[:, None], split, round(RETESSELLATED * len(faces)))


def shot(mesh: Mesh, reach: float, rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray]:
    """The whole mesh with 0.1% of its vertices (at least one) each thrown ``reach`` times the
    diagonal in a random direction, as a scanner's outliers are."""
    vertices = mesh.vertices.copy()
    thrown = rng.choice(len(vertices), max(1, round(0.001 * len(vertices))), replace=False)
    away = rng.normal(size=(len(thrown), 3))
    away *= reach * diagonal(vertices) / np.linalg.norm(away, axis=1)[:, None]
    vertices[thrown] += away
    return vertices, mesh.faces


MAKERS = {"cut": cut, "holes": holes, "scan": scan, "noise": noisy, "shot": shot}


def query_mesh(mesh: Mesh, kind: str, amount: float, rng: np.random.Generator) -> Mesh:
    """One query of a kind and amount made from a mesh, checked (`clean_mesh`)."""
    vertices, faces = MAKERS[kind](mesh, amount, rng)
    if kind in ("cut", "holes"):
        vertices, faces = retessellate(*_used(vertices, faces), rng)
    return clean_mesh(*_used(vertices, faces))


def _used(vertices: np.ndarray, faces: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The vertices that faces use, renumbered."""
    used, inverse = np.unique(faces, return_inverse=True)
    return vertices[used], inverse.reshape(-1, 3)


def kind_name(kind: str, amount: float) -> str:
    """``cut-50``, ``scan-0.25``: the amount in percent."""
    return f"{kind}-{100 * amount:g}"


def write_queries(item: tuple[Path, int, Path, tuple[tuple[str, float], ...]]) -> list[str]:
    """Write one mesh's queries of the kinds asked under ``out/<kind-amount>/<class>/``; the
    lines of those that could not be made."""
    path, position, out, kinds = item
    mesh, failed = cfsig.read_mesh(path), []
    for kind, amount in kinds:
        rng = np.random.default_rng(position)
        try:
            made = query_mesh(mesh, kind, amount, rng)
        except cfsig.CfsigError as exc:
            failed.append(f"{path} {kind_name(kind, amount)}: {exc}")
            continue
        target = out / kind_name(kind, amount) / path.parent.name / f"{path.stem}.off"
        target.parent.mkdir(parents=True, exist_ok=True)
        write_off(target, made.vertices, made.faces)
    return failed


# --- measures -------------------------------------------------------------------------------


def halves(data: Path, every: int) -> tuple[list[Path], list[Path]]:
    """The even- and odd-numbered meshes of each class (sorted), every k-th of each."""
    indexed, queried = [], []
    classes = sorted(p for p in data.iterdir() if p.is_dir())
    for folder in classes:
        files = sorted(folder.glob("*.off"))
        indexed += files[::2][::every]
        queried += files[1::2][::every]
    if not indexed:
        sys.exit(f"no meshes under {data}: expected {data}/<class>/<file>.off")
    return indexed, queried


def link(paths: list[Path], folder: Path) -> None:
    """Link meshes into ``folder/<class>/``."""
    for path in paths:
        (folder / path.parent.name).mkdir(parents=True, exist_ok=True)
        (folder / path.parent.name / path.name).symlink_to(path.resolve())


def make_queries(
    paths: list[Path], out: Path, kinds: tuple[tuple[str, float], ...], jobs: int
) -> None:
    """Write every mesh's queries of the kinds asked, in worker processes."""
    items = [(path, i, out, kinds) for i, path in enumerate(paths)]
    context = multiprocessing.get_context("spawn")
    with ProcessPoolExecutor(jobs, mp_context=context) as pool:
        for failed in pool.map(write_queries, items, chunksize=2):
            for line in failed:
                print(line, file=sys.stderr)


def whole_queries(index: Path, folder: Path, jobs: int) -> cfsig.RetrievalReport:
    """Whole-shape queries of a folder against an index (no query is in it)."""
    with cfsig.IndexReader(index) as reader:
        params, stored = reader.params, reader.signatures[:]
        labels = [str(label) for label in reader.column("labels")]
    found, failures = cfsig.compute_collection(folder, params, jobs=jobs)
    for line in failures:
        print(line, file=sys.stderr)
    return evaluate_queries(
        distances(params.descriptor, found.signatures, stored), found.labels, labels
    )


def noise_duplicates(
    clean: Collection, paths: list[Path], kind: str, amount: float, tmp: Path, jobs: int
) -> list[str]:
    """Rank 1 of each noisy copy's own original among the clean meshes (the collection of
    ``paths``), and the first tier of the noisy copies, leave-one-out."""
    make_queries(paths, tmp, ((kind, amount),), jobs)
    copies, _ = cfsig.compute_collection(tmp / kind_name(kind, amount), cfsig.Params(), jobs=jobs)
    assert clean.names == copies.names  # the same files, in the same order
    nearest = np.argmin(distances(clean.descriptor, copies.signatures, clean.signatures), axis=1)
    rank1 = float(np.mean(nearest == np.arange(len(nearest))))
    first = cfsig.evaluate_collections({kind: copies})[kind].report.measures["FT"]
    return [f"{100 * rank1:.1f}", f"{first:.3f}"]


def collection_rows(
    name: str, data: Path, every: int, jobs: int, chosen: list[str]
) -> tuple[list[list], list[list], list[list]]:
    """The tables' rows of one collection, for the kinds chosen: own wholes out,
    near-duplicate, noise copies."""
    indexed, queried = halves(data, every)
    amounts = {kind: AMOUNTS[kind] for kind in chosen}
    kinds = tuple((kind, amount) for kind, values in amounts.items() for amount in values)
    middle = tuple((kind, values[1]) for kind, values in amounts.items())
    out, duplicate = [], []
    with tempfile.TemporaryDirectory(prefix=f"cfsig-world-{name}-") as folder:
        tmp = Path(folder)
        link(indexed, tmp / "wholes")
        indexes = {}
        for ranked, params in RANKINGS.items():
            indexes[ranked] = tmp / f"index-{params.partial_cells}"
            with cfsig.IndexWriter(indexes[ranked], params, cfsig.layout(params)) as writer:
                failures = cfsig.index_meshes(writer, [tmp / "wholes"], jobs=jobs).failures
            for line in failures:
                print(line, file=sys.stderr)
        for rows, paths, asked, parts in (
            (out, queried, kinds, tmp / "queries"),
            (duplicate, indexed, middle, tmp / "duplicates"),
        ):
            make_queries(paths, parts, asked, jobs)
            for kind, amount in asked:
                found = parts / kind_name(kind, amount)
                for ranked, index in indexes.items():
                    if kind == "noise":  # a whole shape, ranked by its vector alone
                        ranked = "whole shape"
                        report = whole_queries(index, found, jobs)
                    else:
                        report, failures = cfsig.evaluate_partial(index, found, jobs)
                        for line in failures:
                            print(line, file=sys.stderr)
                    measures = [f"{report.measures[m]:.3f}" for m in MEASURES]
                    rows.append([name, kind_name(kind, amount), ranked, report.count, *measures])
                    if kind == "noise":
                        break
        copies = []
        if "noise" in amounts:
            everything = sorted(indexed + queried)
            link(everything, tmp / "clean")
            clean, _ = cfsig.compute_collection(tmp / "clean", cfsig.Params(), jobs=jobs)
            clean_ft = cfsig.evaluate_collections({"clean": clean})["clean"].report.measures["FT"]
            noisy_kinds = [("noise", a) for a in amounts["noise"]] + [("shot", a) for a in SHOTS]
            for kind, amount in noisy_kinds:
                found = noise_duplicates(clean, everything, kind, amount, tmp, jobs)
                copies.append([name, kind_name(kind, amount), *found, f"{clean_ft:.3f}"])
    return out, duplicate, copies


def main() -> None:
    """Measure every collection asked for, print the tables and write them into ``--doc``."""
    parser = collection_parser(__doc__.splitlines()[0], COLLECTIONS)
    parser.add_argument("--kinds", default=",".join(AMOUNTS), help="comma-separated")
    args = parser.parse_args()
    kinds = args.kinds.split(",")
    if not set(kinds) <= set(AMOUNTS):
        sys.exit(f"--kinds: choose from {','.join(AMOUNTS)}")
    if args.doc is not None and not all(s in args.doc.read_text() for s in SECTION):
        sys.exit(f"{args.doc}: no section {SECTION[0]} ... {SECTION[1]}")
    out, duplicate, copies = [], [], []
    for name in args.collections.split(","):
        rows = collection_rows(name, args.data_root / name, args.every, args.jobs, kinds)
        out, duplicate, copies = out + rows[0], duplicate + rows[1], copies + rows[2]
        print(f"{name}: measured", file=sys.stderr, flush=True)
    head = ["collection", "queries", "ranked by", "count", *MEASURES]
    text = "\n".join(
        [
            f"Measured by `{command('world.py')}`.",
            "",
            "Own wholes out: each query against the indexed half of its collection.",
            "",
            table(head, out),
            "",
            "Near-duplicate search: the same kinds made from the indexed meshes themselves.",
            "",
            table(head, duplicate),
            "",
            "Near-duplicate search: noisy copies of every mesh against the clean collection, "
            "rank 1 of its own original, and the first tier of the noisy copies as a collection "
            "beside the clean one's.",
            "",
            table(["collection", "copies", "rank 1 %", "noisy FT", "clean FT"], copies),
        ]
    )
    print(text)
    if args.doc is not None:
        before, rest = args.doc.read_text().split(SECTION[0], 1)
        after = rest.split(SECTION[1], 1)[1]
        args.doc.write_text(f"{before}{SECTION[0]}\n\n{text}\n\n{SECTION[1]}{after}")


if __name__ == "__main__":
    main()
