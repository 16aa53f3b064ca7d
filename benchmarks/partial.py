"""Partial queries and genus changes on SHREC 2007, McGill and FAUST (docs/partial.md).

    python benchmarks/partial.py --data-root /work/data --doc docs/partial.md
    python benchmarks/partial.py --scale 1000000 --real INDEX --dir DIR   # one query's time

(``--scale`` builds synthetic rows of the version of INDEX, an index of SHREC 2007: 9 or 10;
for 10, ``--fill real`` fills each row's cells as the real index's rows do, not every slot.)

For every mesh of each collection (``--data-root``, where ``../shared/data/unpack`` puts them)
the script makes two parts, seeded by the mesh's position so that every run makes the same:

- ``cut``: the mesh cut by a plane of random direction, keeping a random 20-80% of its area
  (the largest connected piece; if no plane of 20 tries keeps 20-80% in one piece, a geodesic
  disc of that area around a random point, 20 tries; else the try closest to the range);
- ``holes``: 5 to 20 geodesic discs around random points removed, 10-40% of the area together,
  the largest connected piece kept if it holds at least half the area (20 tries; else the try
  with the largest);
- ``scan``: a second cut, as ``cut`` makes them, then remeshed and perturbed as a scan of the
  object would be rather than a subset of its mesh, by ``benchmarks/messy.py``'s ``remesh`` and
  ``noise``: simplified to half its faces by quadric edge collapses (new vertices and
  triangles), then every vertex moved by Gaussian noise of a tenth of the mean edge length.

Each part is a query against the collection's whole shapes, the part's own whole among them,
relevant the wholes of its class (`cfsig.evaluation.measures.evaluate_queries`), ranked three ways: as a
whole shape (its default ``cfhks`` signature, what ``cfsig query`` does), by the partial distance of
the curvature channel alone (`cfsig.search.partial.partial_distances`), and as ``cfsig query --partial``
ranks (`cfsig.search.partial.expanded_distances`); the last two also on an index of version 10, the
part measured at 13 shares and ranked by its fine curvature cells (`cfsig.search.partial.measure_part`,
the wholes' cells from their version 10 signatures, whose vectors are the default's); and by
the partial distance for each weight of
`WEIGHTS`, which is how its weight was chosen (on SHREC 2007). It also lists SHREC 2007's
genus outliers, the meshes whose Euler characteristic is not their class's most common one,
with their first tier (FT) against the other queries of their classes, for every ``cfhks``
version from 2 to the default, for each channel of the default alone, and for ShapeDNA
(`descriptors.shapedna`, lapy: the ``bench`` extra): whether any of them ranks the outliers as
well as their classes' others. The others are compared two ways: pooled (every other query of
a class that has an outlier, as the issue measured them) and matched (for each outlier, the
mean over the other queries of its own class), and per class for the default.
"""

from __future__ import annotations

import os

os.environ.update(
    dict.fromkeys(["OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS"], "1")
)

import collections
import pickle
import statistics
import subprocess
import sys
import time
from concurrent.futures import ProcessPoolExecutor
from pathlib import Path

import messy
import numpy as np
import scipy.sparse as sp
from common import report_measured, study_parser
from descriptors import collection_paths, shapedna
from scipy.sparse.csgraph import connected_components, dijkstra

from cfsig.descriptors import intrinsic as cfhks
from cfsig.descriptors.signature import compute_signature
from cfsig.evaluation.measures import evaluate_distances, evaluate_queries
from cfsig.files.elements import mesh_edges
from cfsig.files.mesh import Mesh, clean_mesh, read_mesh
from cfsig.params import VERSIONS, Params
from cfsig.search.nearest import l1_distances
from cfsig.search.partial import (
    HISTOGRAM_WEIGHT,
    SHARES,
    Part,
    expanded_distances,
    measure_part,
    partial_distances,
    partial_scores,
    partial_vectors,
    share_queries,
)

ROOT = Path(__file__).resolve().parents[1]
COLLECTIONS = ("shrec07", "mcgill", "faust")
KINDS = ("cut", "holes", "scan")
DEFAULT = Params(descriptor="cfhks")  # the default version
# Version 10: the default's vector (the same values, tests/test_cells.py) and fine cells.
FINE = Params(descriptor="cfhks", version=10)
DESIGN = cfhks.DESIGNS[DEFAULT.version or 0]
# The earlier versions of the genus table (SHREC 2007 only).
EARLIER = tuple(v for v in VERSIONS["cfhks"] if 2 <= v < (DEFAULT.version or 0))
MEASURES = ("NN", "FT", "mAP")
WEIGHTS = (0.0, 0.5, 0.7, 1.0, 1.5, 2.0, 4.0)  # of the L1 distance in the partial distance
MARKER = "<!-- measured: what follows is written by benchmarks/partial.py -->"


def _face_graph(vertices: np.ndarray, faces: np.ndarray) -> sp.csr_matrix:
    """Faces sharing an edge, weighted by the distance of their centroids."""
    edges = np.sort(faces[:, [0, 1, 1, 2, 2, 0]].reshape(-1, 2), axis=1)
    order = np.lexsort((edges[:, 1], edges[:, 0]))
    same = np.flatnonzero((np.diff(edges[order], axis=0) == 0).all(axis=1))
    face = np.repeat(np.arange(len(faces)), 3)[order]
    a, b = face[same], face[same + 1]
    centroids = vertices[faces].mean(axis=1)
    weight = np.linalg.norm(centroids[a] - centroids[b], axis=1) + 1e-12
    return sp.coo_matrix((weight, (a, b)), shape=(len(faces),) * 2).tocsr()


def _piece(mesh: Mesh, keep: np.ndarray) -> Mesh:
    """The largest connected piece of the kept faces, as a checked mesh."""
    faces = mesh.faces[keep]
    _, labels = connected_components(_face_graph(mesh.vertices, faces), directed=False)
    faces = faces[labels == np.argmax(np.bincount(labels))]
    used, inverse = np.unique(faces, return_inverse=True)
    return clean_mesh(mesh.vertices[used], inverse.reshape(-1, 3))


def _area(mesh: Mesh) -> np.ndarray:
    """Face areas."""
    p = mesh.vertices[mesh.faces]
    return 0.5 * np.linalg.norm(np.cross(p[:, 1] - p[:, 0], p[:, 2] - p[:, 0]), axis=1)


def _nearest_faces(mesh: Mesh, seeds: np.ndarray, share: float) -> np.ndarray:
    """The faces nearest to the seed faces (geodesically) that hold ``share`` of the area."""
    area = _area(mesh)
    distance = dijkstra(_face_graph(mesh.vertices, mesh.faces), indices=seeds, min_only=True)
    order = np.argsort(distance, kind="stable")
    chosen = np.zeros(len(area), bool)
    chosen[order[: np.searchsorted(np.cumsum(area[order]) / area.sum(), share) + 1]] = True
    return chosen


def _closest(candidates: list[Mesh], whole: float, low: float, high: float) -> Mesh:
    """The first candidate whose share of the whole's area is in [low, high], else the closest."""
    shares = [_area(c).sum() / whole for c in candidates]
    misses = [max(low - share, share - high, 0.0) for share in shares]
    return candidates[int(np.argmin(misses))]


def cut(mesh: Mesh, rng: np.random.Generator) -> Mesh:
    """A plane cut keeping 20-80% of the area in one piece (see the module's docstring)."""
    area = _area(mesh)
    share = rng.uniform(0.2, 0.8)
    centroids = mesh.vertices[mesh.faces].mean(axis=1)
    candidates = []
    for attempt in range(40):
        if attempt < 20:
            order = np.argsort(centroids @ rng.normal(size=3))
            keep = np.zeros(len(area), bool)
            keep[order[: np.searchsorted(np.cumsum(area[order]) / area.sum(), share) + 1]] = True
        else:  # a geodesic disc of that area
            seed = np.array([rng.choice(len(area), p=area / area.sum())])
            keep = _nearest_faces(mesh, seed, share)
        candidates.append(_piece(mesh, keep))
        if 0.2 <= _area(candidates[-1]).sum() / area.sum() <= 0.8:
            break
    return _closest(candidates, area.sum(), 0.2, 0.8)


def holes(mesh: Mesh, rng: np.random.Generator) -> Mesh:
    """The mesh with 5-20 geodesic discs, 10-40% of the area, removed, one piece kept that
    holds at least half the area (20 tries, else the largest)."""
    area = _area(mesh)
    candidates = []
    for _ in range(20):
        count = int(rng.integers(5, 21))
        seeds = rng.choice(len(area), count, replace=False, p=area / area.sum())
        candidates.append(_piece(mesh, ~_nearest_faces(mesh, seeds, rng.uniform(0.1, 0.4))))
        if _area(candidates[-1]).sum() / area.sum() >= 0.5:
            break
    return _closest(candidates, area.sum(), 0.5, 1.0)


def scan(mesh: Mesh, rng: np.random.Generator) -> Mesh:
    """A cut (`cut`) remeshed and perturbed as `messy.py`'s ``remesh`` and ``noise`` kinds."""
    part = cut(mesh, rng)
    return clean_mesh(*messy.noise(messy.remesh((part.vertices, part.faces), rng), rng))


def _one(item: tuple[Path, int, bool]) -> dict:
    """The wholes' signatures of one mesh (and its ShapeDNA if ``genus``), and its parts'
    vectors, shares and signatures."""
    path, seed, genus = item
    rng = np.random.default_rng(seed)
    mesh = read_mesh(path)
    whole = compute_signature(mesh, FINE)
    assert whole.cells is not None  # version 10 keeps them
    row: dict = {
        "default": whole.vector,
        "cells": whole.cells[0],
        "fractions": whole.cells[1],
        "chi": len(mesh.vertices)
        - len(mesh_edges(mesh.faces, len(mesh.vertices)).ends)
        + len(mesh.faces),
    }
    if genus:
        row["ShapeDNA"] = shapedna(path)
        for version in EARLIER:
            params = Params(descriptor="cfhks", version=version)
            row[f"v{version}"] = compute_signature(mesh, params).vector
    for kind, make in (("cut", cut), ("holes", holes), ("scan", scan)):
        part = make(mesh, rng)
        row[f"{kind} share"] = _area(part).sum() / _area(mesh).sum()
        row[f"{kind} partial"] = partial_vectors(part, DEFAULT)
        row[f"{kind} fine"] = measure_part(part, FINE)
        row[f"{kind} whole"] = compute_signature(part, DEFAULT).vector
    return row


def _measure(name: str, data_root: Path, jobs: int, every: int) -> dict:
    """Every row of one collection (every k-th mesh), its labels, and the partial distance of
    each part of a kind (rows) to each whole (columns), for the tables that rank by it."""
    paths = collection_paths(data_root, name)[::every]
    with ProcessPoolExecutor(jobs) as pool:
        items = [(p, i, name == "shrec07") for i, p in enumerate(paths)]
        rows = list(pool.map(_one, items, chunksize=2))
    data = {key: np.array([row[key] for row in rows]) for key in rows[0] if "fine" not in key}
    data |= {key: [row[key] for row in rows] for key in rows[0] if "fine" in key}
    cells = data["cells"], data["fractions"]
    for kind in KINDS:
        data[f"{kind} partial distances"] = np.array(
            [
                partial_distances(Part(vectors=v), data["default"], DEFAULT)
                for v in data[f"{kind} partial"]
            ]
        )
        data[f"{kind} fine distances"] = np.array(
            [partial_distances(p, data["default"], FINE, cells) for p in data[f"{kind} fine"]]
        )
    return {
        "labels": [p.parent.name for p in paths],
        "names": [f"{p.parent.name}/{p.name}" for p in paths],
        **data,
    }


def _partial_table(results: dict[str, dict]) -> list[str]:
    """The measures of the parts, per collection, kind and ranking."""
    lines = [
        "| collection | parts | share of the area (median, range) | ranked | NN | FT | mAP |",
        "|---|---|---|---|---|---|---|",
    ]
    for name, data in results.items():
        labels = data["labels"]
        wholes = data["default"]
        for kind in KINDS:
            share = data[f"{kind} share"]
            cells = data["cells"], data["fractions"]
            rankings = {
                "as a whole shape": l1_distances(data[f"{kind} whole"], wholes),
                "partial distance": data[f"{kind} partial distances"],
                "--partial": np.array(
                    [
                        expanded_distances(Part(vectors=v), wholes, DEFAULT)
                        for v in data[f"{kind} partial"]
                    ]
                ),
                "partial distance, version 10": data[f"{kind} fine distances"],
                "--partial, version 10": np.array(
                    [expanded_distances(p, wholes, FINE, cells) for p in data[f"{kind} fine"]]
                ),
            }
            for ranked, distances in rankings.items():
                m = evaluate_queries(distances, labels, labels).measures
                spread = f"{np.median(share):.2f} ({share.min():.2f}-{share.max():.2f})"
                cells = " | ".join(f"{m[k]:.3f}" for k in MEASURES)
                lines.append(f"| {name} | {kind} | {spread} | {ranked} | {cells} |")
    return lines


def _weight_table(results: dict[str, dict]) -> list[str]:
    """NN of the partial distance for each weight of its L1 term, and for the L1 distance alone
    (the partial distance before the unexplained share): how `HISTOGRAM_WEIGHT` was chosen."""
    heads = [f"{name} {kind}" for name in results for kind in KINDS]
    lines = [f"| partial distance | {' | '.join(heads)} |", "|---|" + "---|" * len(heads)]
    scores: dict[str, list[float]] = collections.defaultdict(list)
    for data in results.values():
        stored = data["default"][:, cfhks.channel_columns(DESIGN)["curvature"]]
        for kind in KINDS:
            l1 = [l1_distances(share_queries(v), stored) for v in data[f"{kind} partial"]]
            rankings = {"L1 distance alone": [d[len(SHARES) :].min(axis=0) for d in l1]}
            for weight in WEIGHTS:
                rankings[f"weight {weight:g}"] = [
                    partial_scores(d, float(v[0].sum()), weight)
                    for d, v in zip(l1, data[f"{kind} partial"], strict=True)
                ]
            for title, rows in rankings.items():
                report = evaluate_queries(np.array(rows), data["labels"], data["labels"])
                scores[title].append(report.measures["NN"])
    for title, row in scores.items():
        chosen = " (chosen)" if title == f"weight {HISTOGRAM_WEIGHT:g}" else ""
        lines.append(f"| {title}{chosen} | " + " | ".join(f"{x:.3f}" for x in row) + " |")
    return lines


def _own_whole_table(results: dict[str, dict]) -> list[str]:
    """Where each part's own whole ranks by the partial distance, per collection and kind:
    what a second stage that checked the first candidates against the part could reach."""
    lines = [
        "| collection | parts | own whole first | own whole in the first 20 | its median rank |",
        "|---|---|---|---|---|",
    ]
    for name, data in results.items():
        for kind in KINDS:
            distances = data[f"{kind} partial distances"]
            rank = (distances < np.diag(distances)[:, None]).sum(axis=1) + 1
            lines.append(
                f"| {name} | {kind} | {np.mean(rank == 1):.3f} | {np.mean(rank <= 20):.3f} | "
                f"{np.median(rank):.0f} |"
            )
    return lines


def _genus_table(data: dict) -> list[str]:
    """SHREC 2007's genus outliers and their FT against their classes' other queries."""
    labels = np.array(data["labels"])
    if max(collections.Counter(labels).values()) < 2:
        return ["Not measured: no class has two meshes at this --every."]
    chi = data["chi"]
    common = {c: collections.Counter(chi[labels == c]).most_common(1)[0][0] for c in set(labels)}
    outlier = np.array([chi[i] != common[c] for i, c in enumerate(labels)])
    mixed = np.isin(labels, labels[outlier])
    # Each outlier's own class's other queries, one mean per outlier: the pooled mean weighs each
    # class by its other queries, not by its outliers (vase, the hardest class, holds 11 of 32).
    classmates = [(labels == labels[i]) & ~outlier for i in np.flatnonzero(outlier)]
    lines = [
        "| descriptor | outliers FT | other queries of their classes FT (pooled) | "
        "their own class's other queries FT (matched) | all NN | all FT |",
        "|---|---|---|---|---|---|",
    ]
    default = data["default"]
    distances = {
        f"cfhks {version}": l1_distances(data[f"v{version}"], data[f"v{version}"])
        for version in EARLIER
    }
    distances[f"cfhks {DEFAULT.version}"] = l1_distances(default, default)
    for channel, columns in cfhks.channel_columns(DESIGN).items():
        part = default[:, columns]
        distances[f"cfhks {DEFAULT.version}, {channel} alone"] = l1_distances(part, part)
    dna = data["ShapeDNA"]
    distances["ShapeDNA (L2)"] = np.linalg.norm(dna[:, None] - dna[None], axis=-1)
    reports = {title: evaluate_distances(d, labels) for title, d in distances.items()}
    for title, report in reports.items():
        ft = report.per_query[:, 1]
        lines.append(
            f"| {title} | {ft[outlier].mean():.3f} | {ft[mixed & ~outlier].mean():.3f} | "
            f"{np.mean([ft[c].mean() for c in classmates]):.3f} | "
            f"{report.measures['NN']:.3f} | {report.measures['FT']:.3f} |"
        )
    default_ft = reports[f"cfhks {DEFAULT.version}"].per_query[:, 1]
    names = [
        f"{data['names'][i]} (chi {chi[i]}, class {common[labels[i]]})"
        for i in np.flatnonzero(outlier)
    ]
    per_class = [
        f"Per class, cfhks {DEFAULT.version}:",
        "",
        "| class | outliers | their FT | the class's other queries | their FT |",
        "|---|---|---|---|---|",
    ]
    for c in sorted(set(labels[outlier])):
        odd, rest = outlier & (labels == c), ~outlier & (labels == c)
        per_class.append(
            f"| {c} | {odd.sum()} | {default_ft[odd].mean():.3f} | {rest.sum()} | "
            f"{default_ft[rest].mean():.3f} |"
        )
    outliers = f"The {len(names)} outliers: " + "; ".join(names) + "."
    return [*lines, "", *per_class, "", outliers]


def scale(rows: int, real: str, folder: Path, fill: str = "full", processes: int = 1) -> str:
    """Seconds of one partial query over ``rows`` synthetic rows, in a fresh process.

    The rows are `benchmarks/index_scale.py`'s mixed ones (two real signatures of the index
    ``real`` blended, plus noise), written by its ``build``, of the real index's version. For
    version 9 the query's vectors for the seven shares are the curvature columns of seven more
    such rows; for version 10, whose rows also get fine cells mixed from two real rows'
    (`index_scale.synthetic_cells`: with ``fill="full"`` nearly every row fills all its slots,
    with ``"real"`` as many as the real index's rows do), the query's cells at the 13 shares are
    13 more such rows' with every slot filled (the synthetic query), and then the real parts of
    `real_parts`. Open,
    `cfsig.search.partial.query_part` for 20 results and their names: the first query of the
    process (imports and compiled code loaded), then three more of each query. For version 10,
    each in processes of its own, whatever `cfsig.descriptors.cells.part_scorer` would choose for so many
    rows: with the compiled kernel (in ``processes`` processes one after another: the first after
    the files are read back meets pages read only once); with NumPy's (the synthetic query
    alone); and scoring nothing, what reading the cells costs. Last, what a user waits for at
    the shell: ``cfsig query INDEX PART.off --partial`` of each real part's mesh, a fresh
    interpreter each time (`_time_shell`).
    """
    sys.path.insert(0, str(ROOT))
    from benchmarks.index_scale import build, real_rows, synthetic_query
    from cfsig.index.store import IndexReader

    with IndexReader(real) as reader:
        params, cells = reader.params, reader.cells()
    # Not index_scale.py's name for the same rows: its commit timings add rows to what it reuses.
    kind = "mixed" if cells is None else {"full": "fine", "real": "fine-real-fill"}[fill]
    path = folder / f"partial-{kind}-{rows}"
    built = None
    if not (path / "manifest.h5").exists():
        built = build(path, rows, real_rows(real, params), params, cells, fill)
    how = "reused" if built is None else f"built in {built:.0f} s"
    lines = [
        f"One partial query over {rows:,} rows of version {params.version}"
        + ("" if cells is None else f", cells filled {fill}")
        + f" ({how}; its files "
        f"dropped from the page cache and read back in order in {_read_back(path):.0f} s):"
    ]
    parts = folder / "partial-real-parts.pickle"
    if cells is not None:
        named = real_parts(real, parts)
    kernels = ["compiled"] * processes + ["NumPy", "reading alone"] if cells is not None else [""]
    for n, kernel in enumerate(kernels):
        out = _time_partial(real, path, kernel, parts if kernel != "NumPy" else None)
        if kernel == "compiled" and processes > 1:
            kernel = f"compiled, process {n + 1}"
        lines.append(
            f"- {kernel or 'query'}, synthetic query: **{statistics.median(out['times']):.3f} "
            "s** (median of 3; "
            + ", ".join(f"{t:.3f}" for t in out["times"])
            + f"); first of the process {out['first']:.3f} s; peak {out['peak_mb']:.0f} MB; "
            f"load average {os.getloadavg()[0]:.1f}."
        )
        if out["real"]:
            each = [statistics.median(times) for times in out["real"]]
            lines.append(
                f"- {kernel}, real parts: **{statistics.median(each):.3f} s** (median of the "
                f"{len(each)} parts' medians of 3; {min(each):.3f} to {max(each):.3f})."
            )
    if cells is not None:
        each, first = _time_shell(path, sorted(parts.with_suffix("").glob("*.off")))
        lines.append(
            f"- the shell, `cfsig query INDEX PART.off --partial`, real parts: **"
            f"{statistics.median(each):.3f} s** (median of the {len(each)} parts' medians of 3; "
            f"{min(each):.3f} to {max(each):.3f}); the first command {first:.3f} s."
        )
        synthetic = synthetic_query(cells)
        distinct = [d for _, d in named]
        lines += [
            "Real parts: " + "; ".join(name for name, _ in named) + ".",
            "Distinct cells over the 13 shares: synthetic query "
            f"{len(np.unique(np.concatenate([c for c, _ in synthetic])))}; real parts "
            f"median {statistics.median(distinct):.0f} ({min(distinct)} to {max(distinct)}).",
        ]
    return "\n".join(lines)


def _read_back(index: Path) -> float:
    """Drop the page cache's copy of an index's files and read them back in order, as after a
    restart: how the pages came into the page cache changes what mapping them costs
    (docs/partial.md, "Scale"), so every run starts from the same state. The other indexes
    beside it are dropped first: two synthetic indexes of 1M rows of version 10 do not both
    fit in the memory of the test host, and the query's pages would be evicted as it ran.
    Returns the seconds taken."""
    start = time.perf_counter()
    others = [f for d in index.parent.iterdir() if d.is_dir() and d != index for f in d.iterdir()]
    for file in [*others, *sorted(index.iterdir())]:
        handle = os.open(file, os.O_RDONLY)
        try:
            os.posix_fadvise(handle, 0, 0, os.POSIX_FADV_DONTNEED)
            while file.parent == index and os.read(handle, 64 << 20):
                pass
        finally:
            os.close(handle)
    return time.perf_counter() - start


def real_parts(real: str, path: Path, count: int = 5) -> list[tuple[str, int]]:
    """Parts of ``count`` meshes of the index ``real`` as the benchmark makes them, a cut and a
    body with holes of each (rows spread over the index, seeded by their row), measured with
    its parameters; pickled to ``path`` for `_time_partial`, their meshes written as OFF files
    to the folder ``path`` without its suffix for `_time_shell`. Returns each one's name and
    the distinct cells of its histograms at all shares."""
    from cfsig.index.store import IndexReader

    with IndexReader(real) as reader:
        params, n = reader.params, len(reader)
        rows = np.linspace(0, n - 1, count).astype(int)
        entries = reader.entries(rows)
    parts, named = [], []
    folder = path.with_suffix("")
    folder.mkdir(exist_ok=True)
    for row, entry in zip(rows, entries, strict=True):
        mesh = read_mesh(entry.path)
        rng = np.random.default_rng(int(row))
        for kind, make in (("cut", cut), ("holes", holes)):
            made = make(mesh, rng)
            messy.write_off(folder / f"{len(parts):02d}.off", (made.vertices, made.faces))
            part = measure_part(made, params)
            assert part.cells is not None  # version 10
            parts.append(part)
            distinct = np.unique(np.concatenate([c for c, _ in part.cells]))
            named.append((f"{entry.name} {kind}", len(distinct)))
    path.write_bytes(pickle.dumps(parts))
    return named


def _time_shell(index: Path, meshes: list[Path]) -> tuple[list[float], float]:
    """Wall seconds of ``cfsig query INDEX MESH --partial``, each run in a fresh interpreter,
    three times a mesh in turn: each mesh's median, and the first command's time."""
    from benchmarks.index_scale import K

    runs: list[list[float]] = [[] for _ in meshes]
    for _ in range(3):
        for times, mesh in zip(runs, meshes, strict=True):
            command = [sys.executable, "-m", "cfsig", "query", str(index), str(mesh)]
            start = time.perf_counter()
            subprocess.run([*command, "--partial", "-k", str(K)], check=True, capture_output=True)
            times.append(time.perf_counter() - start)
    return [statistics.median(times) for times in runs], runs[0][0]


def _time_partial(real: str, path: Path, kernel: str, parts: Path | None) -> dict:
    """`scale`'s query in a fresh process: the first, then three more; with ``kernel`` for the
    fine cells ("compiled" or "NumPy"; "reading alone" scores every row 0), else as cfsig
    chooses. Then three of each real part pickled in ``parts`` (`real_parts`), if given."""
    from benchmarks.index_scale import K, in_child

    force = {
        "compiled": "cfsig.descriptors.cells.FAST_MIN_ROWS = 0",
        "NumPy": "cfsig.descriptors.cells.FAST_MIN_ROWS = 1 << 62",
        "reading alone": "cfsig.search.partial.part_scorer = lambda *_: lambda c, f: np.zeros(len(c))",
    }.get(kernel, "")
    code = f"""
import numpy as np
import cfsig.descriptors.cells, cfsig.search.partial
from cfsig.index.store import IndexReader
from cfsig.search.partial import SHARES, Part, curvature_columns, query_part
from benchmarks.index_scale import real_rows, synthetic_query, synthetic_rows
{force}
with IndexReader({real!r}) as reader:
    params, cells = reader.params, reader.cells()
if cells is None:
    rows = synthetic_rows(np.random.default_rng(6), len(SHARES), real_rows({real!r}, params))
    part = Part(vectors=rows[:, curvature_columns(params)])
else:
    part = Part(cells=synthetic_query(cells))
def once(part):
    t = time.perf_counter()
    with IndexReader({str(path)!r}) as r:
        hits, _ = query_part(r, part, {K})
    return time.perf_counter() - t
out = {{'first': once(part), 'times': [once(part) for _ in range(3)], 'real': []}}
if {str(parts) if parts else ""!r}:
    import pickle
    for real_part in pickle.loads(open({str(parts)!r}, 'rb').read()):
        out['real'].append([once(real_part) for _ in range(3)])
"""
    return in_child(code)


def main() -> None:
    """Measure, print and write the Markdown."""
    parser = study_parser(__doc__.splitlines()[0])
    parser.add_argument("--scale", type=int, help="time one partial query over this many rows")
    parser.add_argument("--real", help="--scale: an index of real cfhks signatures")
    parser.add_argument("--dir", type=Path, help="--scale: folder of the synthetic index")
    parser.add_argument(
        "--fill",
        choices=["full", "real"],
        default="full",
        help="--scale, version 10: rows' cells fill every slot, or as many as real rows do",
    )
    parser.add_argument(
        "--processes",
        type=int,
        default=1,
        help="--scale, version 10: the compiled kernel's query timed in N",
    )
    args = parser.parse_args()
    if args.scale:
        if not (args.real and args.dir):
            parser.error("--scale needs --real INDEX and --dir DIR")
        print(scale(args.scale, args.real, args.dir, args.fill, args.processes))
        return
    results = {}
    for name in COLLECTIONS:
        results[name] = _measure(name, args.data_root, args.jobs, args.every)
        print(f"{name}: {len(results[name]['labels'])} meshes", flush=True)
    sections = [
        ("Parts against the whole collections", _partial_table(results)),
        ("The partial distance's weight (NN)", _weight_table(results)),
        ("Where each part's own whole ranks by the partial distance", _own_whole_table(results)),
        ("Genus outliers of SHREC 2007", _genus_table(results["shrec07"])),
    ]
    lines = [line for title, rows in sections for line in (f"### {title}", "", *rows, "")]
    report_measured(args, "partial.py", MARKER, lines[:-1])


if __name__ == "__main__":
    main()
