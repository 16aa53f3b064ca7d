"""The descriptors on SHREC 2007, McGill and FAUST in one run: cf, cfhks 1 to 9, ShapeDNA.

Stages (each prints Markdown for docs/descriptors.md; run from the repository root):

    python benchmarks/descriptors.py measure    # every descriptor of every mesh, CPU timed -> cache
    python benchmarks/descriptors.py study      # how version 2 was chosen: leave one collection out
    python benchmarks/descriptors.py study3     # how version 3 was chosen
    python benchmarks/descriptors.py study7     # how version 7 was chosen: scans and models
    python benchmarks/descriptors.py study8     # how version 8 was chosen: version 7 for less
    python benchmarks/descriptors.py divisor    # a version's curvature divisor (version 3's rule)
    python benchmarks/descriptors.py tolerance  # version 6's conjugate gradients' tolerance
    python benchmarks/descriptors.py compare    # measures and CPU seconds per mesh, all eleven
    python benchmarks/descriptors.py cost       # whole `cfsig index` runs, cf to ShapeDNA
    python benchmarks/descriptors.py noise      # which curvature scales survive vertex noise
    python benchmarks/descriptors.py coarse     # version 4: the spectrum of a simplified copy
    python benchmarks/descriptors.py stages     # CPU seconds of each stage of versions 3 to 8
    python benchmarks/descriptors.py lanczos    # the Lanczos iteration's steps against its cap

``measure`` computes, for every mesh of the three collections (``--data-root``, where
``../shared/data/unpack`` puts them), eleven descriptors from the file, each timed in CPU seconds
of its worker process with one BLAS thread, reading included: ``cf`` (the paper's), ``cfhks``
versions 1 to 9 (`cfsig.descriptors.intrinsic.DESIGNS`) and ShapeDNA (lapy, the 50 smallest nonzero
eigenvalues times the area divided by their index, compared by L2, as in the issue's table). It
also keeps the unweighted channels of version 2 (phi, the spectrum, heat at eight times), from
which ``study`` builds every candidate weighting. Caches go under ``--cache`` (never commit).

With ``--only NAME...``, ``measure`` computes those descriptors alone and replaces theirs in the
existing cache (a new version added to an old cache).

``study7`` chooses version 7 (every channel on the simplified copy) by the first tier of clean
queries and of noisy copies of them against the clean meshes, and prints the best candidate of
each number of eigenpairs, the channel that sets the cost; its own cache of candidate channels,
for every mesh and its scan-like copies, goes under ``--cache`` too.

``study8`` chooses version 8: ``study7``'s candidates on copies of 1000, 2000, 3000 and 4000
faces (a cache of each), the best of each copy and number of eigenpairs timed on every
``--every``-th SHREC 2007 mesh, and the cheapest within 0.01 of the best that meets the issue's
quality bars on the training collections (ShapeDNA's first tier from ``measure``'s cache).

``study`` chooses the channel weights and heat times over a small grid, each candidate's
channel divisors being the medians of its channel distances averaged over the training
collections (label-free), by the mean first tier (FT) on the training collections: once for each
collection left out, reporting the left-out one, then on SHREC 2007 and McGill, which gives
version 2 (FAUST is held out).

``cost`` times whole processes, alternating, ``--rounds`` rounds (three unless asked), medians
and each round's own ratios: ``cfsig index`` with one job on every 10th SHREC 2007 mesh (40)
with the default descriptor and with ``--descriptor cf``, ShapeDNA on the same files in one
process (this script's ``shapedna`` stage), and ``cfsig index`` with two jobs on all 400 for
both descriptors. The bars are on wall time; beside it, the CPU time of each whole process, its
workers included (with two jobs, how busy the run kept the machine's cores).

``noise`` measures, per scale of the curvature ladder, how far noise on a mesh's vertices moves
its histogram, and what that does to a noisy query against clean models (docs/descriptors.md,
"Scans").

``tolerance`` chooses version 6's: the loosest of `TOLERANCES` at which version 5's curvature
histograms move from the 1e-10 solve's, on average over a collection's meshes, by at most
`TOLERANCE_SHARE` of the median distance between two meshes' histograms, on SHREC 2007 and
FAUST (version 3's training collections).

``lanczos`` counts the operator applications (solves) of every Lanczos iteration that version
8 runs on every mesh of the three collections, and of PSB's training half when it is unpacked
under ``--data-root``: per eigenpair for the first search, and in all for the search for missed
copies of a repeated eigenvalue (one eigenpair), against the iteration's cap.

``coarse`` chooses version 4's copy: version 3 with the spectrum and heat computed on a copy of
each mesh simplified by fast-simplification to each of ``--faces`` faces (meshes with fewer are
used as they are), FT and CPU seconds per mesh against version 3 on the full mesh; the copy
chosen is the smallest whose mean FT on SHREC 2007 and FAUST (version 3's training
collections) is within 0.01 of version 3's.
"""

from __future__ import annotations

import os

os.environ.update(
    dict.fromkeys(["OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS"], "1")
)

import argparse
import contextlib
import io
import itertools
import resource
import shutil
import subprocess
import sys
import tempfile
import time
from concurrent.futures import ProcessPoolExecutor
from dataclasses import replace
from functools import partial
from pathlib import Path
from unittest import mock

import messy
import numpy as np
import scipy.sparse as sp

from cfsig.descriptors import intrinsic as cfhks
from cfsig.descriptors.signature import signature_file
from cfsig.errors import MeshError
from cfsig.evaluation.measures import RetrievalReport, evaluate_distances
from cfsig.files.mesh import clean_mesh, read_mesh
from cfsig.operators import spectrum
from cfsig.operators.conformal import conformal_factor, factorize, laplacian_solver, operators
from cfsig.operators.curvature import smoothed_curvature
from cfsig.operators.spectrum import Spectrum, laplace_spectrum
from cfsig.params import DEFAULT_VERSIONS, Params
from cfsig.repair.simplify import simplified_mesh
from cfsig.repair.stage import repair_mesh

ROOT = Path(__file__).resolve().parents[1]
DATA_ROOT = ROOT.parent / "shared" / "data"
CACHE = Path(tempfile.gettempdir()) / "cfsig-descriptors"
COLLECTIONS = ("shrec07", "mcgill", "faust")
CHOSEN_ON = ("shrec07", "mcgill")
SHAPEDNA_EIGENVALUES = 50
DESCRIPTORS = {
    "cf": Params(),
    "cfhks 1": Params(descriptor="cfhks", version=1),
    "cfhks 2": Params(descriptor="cfhks", version=2),
    "cfhks 3": Params(descriptor="cfhks", version=3),
    "cfhks 4": Params(descriptor="cfhks", version=4),
    "cfhks 5": Params(descriptor="cfhks", version=5),
    "cfhks 6": Params(descriptor="cfhks", version=6),
    "cfhks 7": Params(descriptor="cfhks", version=7),
    "cfhks 8": Params(descriptor="cfhks", version=8),
    "cfhks 9": Params(descriptor="cfhks", version=9),
}
NAMES = (*DESCRIPTORS, "ShapeDNA")
V2 = cfhks.DESIGNS[2]
# The curvature scales measured for version 3's study: quadrupling from version 3's smallest,
# at half steps (2 ** j * 0.0000625, j = -2 .. 11).
LADDER = tuple(0.0000625 * 2.0**j for j in range(-2, 12))
# The grid of `study`: heat times as slices of version 2's eight, and channel weights.
TIME_SETS = {"all 8": slice(0, 8), "version 1's 4": slice(1, 5), "middle 4": slice(2, 6),
             "first 4": slice(0, 4), "last 4": slice(4, 8)}  # fmt: skip
PHI_WEIGHTS = (0.0, 0.5, 1.0)
HEAT_WEIGHTS = (1.0, 2.0, 3.0)


def shapedna(path: Path) -> np.ndarray:
    """ShapeDNA of a mesh file: lapy's 50 smallest nonzero eigenvalues x area / index.

    Read by lapy; a mesh whose degenerate triangles make lapy's values NaN is read by cfsig,
    which drops them, and given to lapy again.
    """
    from lapy import Solver, TriaMesh

    with contextlib.redirect_stdout(io.StringIO()), np.errstate(invalid="ignore"):
        mesh = TriaMesh.read_off(str(path))
        values = Solver(mesh).eigs(k=SHAPEDNA_EIGENVALUES + 1, rng=0)[0][1:] * mesh.area()
        if not np.all(np.isfinite(values)):
            checked = read_mesh(path)
            mesh = TriaMesh(checked.vertices, checked.faces)
            values = Solver(mesh).eigs(k=SHAPEDNA_EIGENVALUES + 1, rng=0)[0][1:] * mesh.area()
    return values / np.arange(1, SHAPEDNA_EIGENVALUES + 1)


def _measure_one(path: Path) -> dict:
    """Every descriptor of one mesh with its CPU seconds, and version 2's raw channels."""
    row = _measure_some(path, tuple(DESCRIPTORS))
    start = time.process_time()
    row["ShapeDNA"] = shapedna(path)
    row["ShapeDNA s"] = time.process_time() - start
    cf = conformal_factor(repair_mesh(read_mesh(path)), Params().mollify)
    spectrum = cfhks.spectrum_of(cf.operators, solve=cf.solve)[0]
    row.update(cfhks.channels(cf.operators, spectrum, replace(V2, scales=LADDER), cf.phi))
    return row


def _measure_some(path: Path, names: tuple[str, ...]) -> dict:
    """Some of `DESCRIPTORS` of one mesh, with their CPU seconds."""
    row: dict = {}
    for name in names:
        start = time.process_time()
        row[name] = signature_file(path, DESCRIPTORS[name]).vector
        row[f"{name} s"] = time.process_time() - start
    return row


def collection_paths(data_root: Path, name: str) -> list[Path]:
    """The OFF files of one collection, in sorted order."""
    paths = sorted((data_root / name).glob("*/*.off"))
    if not paths:
        sys.exit(f"no meshes under {data_root / name}: ../shared/data/unpack {name}")
    return paths


def measure(args: argparse.Namespace) -> None:
    """Compute and cache every descriptor of every mesh of the three collections; with
    ``--only``, those descriptors only, replacing theirs in the existing cache."""
    args.cache.mkdir(parents=True, exist_ok=True)
    for name in COLLECTIONS:
        paths = collection_paths(args.data_root, name)
        work = partial(_measure_some, names=tuple(args.only)) if args.only else _measure_one
        with ProcessPoolExecutor(args.jobs) as pool:
            rows = list(pool.map(work, paths, chunksize=2))
        arrays = dict(np.load(args.cache / f"{name}.npz")) if args.only else {}
        arrays.update({key: np.array([row[key] for row in rows]) for key in rows[0]})
        arrays["labels"] = np.array([p.parent.name for p in paths])
        np.savez(args.cache / f"{name}.npz", **arrays)
        print(f"{name}: {len(paths)} meshes -> {args.cache / name}.npz", flush=True)


def _load(cache: Path) -> dict[str, dict[str, np.ndarray]]:
    """The cached arrays of each collection."""
    if not all((cache / f"{c}.npz").exists() for c in COLLECTIONS):
        sys.exit(f"no cache under {cache}: run the measure stage first")
    return {c: dict(np.load(cache / f"{c}.npz")) for c in COLLECTIONS}


def _pairwise(x: np.ndarray, order: int = 1) -> np.ndarray:
    """All-pairs L1 (order 1, as a mean over entries) or L2 (order 2) distances of rows."""
    x = x.reshape(len(x), -1)
    diff = x[:, None, :] - x[None, :, :]
    return np.abs(diff).mean(axis=-1) if order == 1 else np.sqrt((diff**2).sum(axis=-1))


def _median(d: np.ndarray) -> float:
    """Median over the distinct pairs."""
    return float(np.median(d[np.triu_indices(len(d), 1)]))


def _report(d: np.ndarray, labels: np.ndarray) -> RetrievalReport:
    """Leave-one-out retrieval measures of a distance matrix."""
    return evaluate_distances(d, [str(label) for label in labels])


class Channels:
    """The channel distances of version 2's raw channels, per collection, computed once."""

    def __init__(self, data: dict[str, dict[str, np.ndarray]]) -> None:
        self.data = data
        self._cache: dict[tuple[str, str], np.ndarray] = {}

    def distance(self, collection: str, channel: str) -> np.ndarray:
        """One channel's all-pairs distance: ``phi``, ``spectrum`` or a key of TIME_SETS."""
        key = (collection, channel)
        if key not in self._cache:
            arrays = self.data[collection]
            x = arrays["heat"][:, TIME_SETS[channel]] if channel in TIME_SETS else arrays[channel]
            self._cache[key] = _pairwise(x)
        return self._cache[key]

    def combined(self, collection: str, weights: dict[str, float], train: tuple[str, ...]):
        """Weighted sum of channel distances, each divided by its median over ``train``."""
        total = np.zeros((len(self.data[collection]["labels"]),) * 2)
        for channel, weight in weights.items():
            if weight:
                scale = np.mean([_median(self.distance(t, channel)) for t in train])
                total += weight * self.distance(collection, channel) / scale
        return total

    def first_tier(self, weights: dict[str, float], train: tuple[str, ...]) -> dict[str, float]:
        """FT of every collection with these weights and divisors from ``train``."""
        return {
            c: _report(self.combined(c, weights, train), self.data[c]["labels"]).measures["FT"]
            for c in self.data
        }


def _grid() -> list[dict[str, float]]:
    """Every candidate of the study: phi and heat weights, heat times; spectrum weight 1."""
    return [
        {"phi": phi, "spectrum": 1.0, times: heat}
        for times, phi, heat in itertools.product(TIME_SETS, PHI_WEIGHTS, HEAT_WEIGHTS)
    ]


def _choose(
    channels: Channels, train: tuple[str, ...], phi: float | None = None
) -> tuple[dict, dict[str, float]]:
    """The candidate with the best mean FT over ``train`` (of those with this weight of phi,
    if given), and its FT on every collection."""
    grid = [w for w in _grid() if phi is None or w["phi"] == phi]
    scored = [(w, channels.first_tier(w, train)) for w in grid]
    return max(scored, key=lambda item: np.mean([item[1][c] for c in train]))


def _describe(weights: dict[str, float]) -> str:
    """A candidate in words."""
    times = next(k for k in weights if k in TIME_SETS)
    return f"phi {weights['phi']:g}, spectrum 1, heat {weights[times]:g} ({times} times)"


def study(args: argparse.Namespace) -> None:
    """Leave-one-collection-out choice of version 2's weights, then the choice itself."""
    data = _load(args.cache)
    channels = Channels(data)
    print("Medians of the channel distances over all pairs (label-free):\n")
    print("| collection | phi | spectrum | heat, all 8 times |\n|---|---|---|---|")
    for c in COLLECTIONS:
        meds = [_median(channels.distance(c, ch)) for ch in ("phi", "spectrum", "all 8")]
        print(f"| {c} | " + " | ".join(f"{m:.4f}" for m in meds) + " |")
    print("\nLeave one collection out: chosen on the other two, FT on each.\n")
    print("| left out | chosen | " + " | ".join(COLLECTIONS) + " |\n|---|---|" + "---|" * 3)
    for left_out in COLLECTIONS:
        train = tuple(c for c in COLLECTIONS if c != left_out)
        weights, ft = _choose(channels, train)
        cells = [f"**{ft[c]:.3f}**" if c == left_out else f"{ft[c]:.3f}" for c in COLLECTIONS]
        print(f"| {left_out} | {_describe(weights)} | " + " | ".join(cells) + " |")
    print(f"\nThe best candidate on {' and '.join(CHOSEN_ON)} for each weight of phi:\n")
    print("| weight of phi | candidate | mean FT of the two | " + " | ".join(COLLECTIONS) + " |")
    print("|---|---|---|" + "---|" * 3)
    for phi in PHI_WEIGHTS:
        weights, ft = _choose(channels, CHOSEN_ON, phi)
        mean = np.mean([ft[c] for c in CHOSEN_ON])
        cells = " | ".join(f"{ft[c]:.3f}" for c in COLLECTIONS)
        print(f"| {phi:g} | {_describe(weights)} | {mean:.4f} | {cells} |")
    weights, ft = _choose(channels, CHOSEN_ON)
    print(f"\nChosen on {' and '.join(CHOSEN_ON)} (version 2): {_describe(weights)}")
    print("FT: " + ", ".join(f"{c} {ft[c]:.3f}" for c in COLLECTIONS))
    for channel in ("phi", "spectrum", "all 8"):
        divisor = np.mean([_median(channels.distance(t, channel)) for t in CHOSEN_ON])
        print(f"- {channel}: median distance averaged over {', '.join(CHOSEN_ON)} {divisor:.4f}")


CURVATURE_WEIGHTS = (0.5, 1.0, 2.0)
V3_CHOSEN_ON = ("shrec07", "faust")
TOLERANCES = (1e-10, 1e-5, 1e-4, 1e-3, 1e-2)  # the first is the reference, versions 3 and 4's
TOLERANCE_SHARE = 0.05


def _ladders() -> list[tuple[int, ...]]:
    """Version 3's candidate scale sets: 1 to 4 quadrupling scales of LADDER, as indices."""
    return [
        tuple(range(start, start + 2 * count, 2))
        for count in (1, 2, 3, 4)
        for start in range(len(LADDER) - 2 * (count - 1))
    ]


class Curvature:
    """Version 2's distance plus a weighted curvature channel, per collection."""

    def __init__(self, data: dict[str, dict[str, np.ndarray]]) -> None:
        self.data = data
        self.v2 = {c: _distances("cfhks 2", data[c]["cfhks 2"]) for c in data}
        self.scale = {
            c: [_pairwise(data[c]["curvature"][:, j]) for j in range(len(LADDER))] for c in data
        }

    def ladder(self, collection: str, scales: tuple[int, ...]) -> np.ndarray:
        """The curvature distance of some scales: the mean of their histograms' distances."""
        return sum(self.scale[collection][j] for j in scales) / len(scales)

    def medians(self, scales: tuple[int, ...], train: tuple[str, ...]) -> tuple[float, float]:
        """Version 2's and the curvature's median distances, averaged over ``train``."""
        v2 = np.mean([_median(self.v2[t]) for t in train])
        return float(v2), float(np.mean([_median(self.ladder(t, scales)) for t in train]))

    def first_tier(self, scales: tuple[int, ...], weight: float, train: tuple[str, ...]):
        """FT of every collection with these scales and weight, divisors from ``train``."""
        v2, curvature = self.medians(scales, train)
        return {
            c: _report(
                self.v2[c] / v2 + weight * self.ladder(c, scales) / curvature,
                self.data[c]["labels"],
            ).measures["FT"]
            for c in self.data
        }

    def choose(self, train: tuple[str, ...]) -> tuple[tuple[int, ...], float, dict[str, float]]:
        """The scales and weight with the best mean FT over ``train``, and every FT."""
        scored = [
            (scales, weight, self.first_tier(scales, weight, train))
            for scales in _ladders()
            for weight in CURVATURE_WEIGHTS
        ]
        return max(scored, key=lambda item: np.mean([item[2][c] for c in train]))


def _scales_text(scales: tuple[int, ...]) -> str:
    """Scale indices of LADDER in words."""
    return ", ".join(f"{LADDER[j]:.3g}" for j in scales)


def study3(args: argparse.Namespace) -> None:
    """Leave-one-collection-out choice of version 3's curvature channel, then the choice."""
    curvature = Curvature(_load(args.cache))
    print("Version 2 plus curvature at scales; chosen on the other two, FT on each.\n")
    print("| left out | scales | weight | " + " | ".join(COLLECTIONS) + " |")
    print("|---|---|---|" + "---|" * 3)
    for left_out in COLLECTIONS:
        train = tuple(c for c in COLLECTIONS if c != left_out)
        scales, weight, ft = curvature.choose(train)
        cells = [f"**{ft[c]:.3f}**" if c == left_out else f"{ft[c]:.3f}" for c in COLLECTIONS]
        print(f"| {left_out} | {_scales_text(scales)} | {weight:g} | " + " | ".join(cells) + " |")
    scales, weight, ft = curvature.choose(V3_CHOSEN_ON)
    v2, median = curvature.medians(scales, V3_CHOSEN_ON)
    # weigh() divides each of the len(scales) * CURVATURE_BINS entries by CURVATURE_BINS * d,
    # version 2's vector has V2.length entries and _pairwise averages over entries.
    divisor = len(scales) * median / (weight * V2.length * v2)
    print(f"\nChosen on {' and '.join(V3_CHOSEN_ON)} (version 3): scales {_scales_text(scales)}")
    print(f"(times the area), weight {weight:g}; curvature divisor {divisor:.6f}")
    print("FT: " + ", ".join(f"{c} {ft[c]:.3f}" for c in COLLECTIONS))


def divisor(args: argparse.Namespace) -> None:
    """A version's curvature divisor, on version 3's training collections, by its rule.

    Versions 3 to 6 (version 3's rule): the curvature channel weighs as much as the rest of the
    vector, its median L1 distance over the pairs (averaged over the collections) made equal to
    the rest's. Version 7 and later (version 7's rule, weight 1): the channel's own median L1
    distance over the pairs, averaged over its histograms and over the collections, is its
    distance's unit. The cached vectors' own divisor cancels out, so the cache may be measured
    before or after it is set."""
    data = _load(args.cache)
    design = cfhks.DESIGNS[args.version]
    head = cfhks.channel_columns(design)["curvature"].start
    count, width = cfhks.curvature_shape(design)
    curvature, rest = [], []
    for name in V3_CHOSEN_ON:
        vectors = data[name][f"cfhks {args.version}"]
        # back to the unweighted histograms, whose L1 the divisor scales
        raw = vectors[:, head:] * width * design.curvature
        curvature.append(_median(_pairwise(raw)) * raw.shape[1])
        rest.append(_median(_pairwise(vectors[:, :head])) * head)
    if args.version >= 7:
        value = np.mean(curvature) / width
        rule = "version 7's: the channel's median"
    else:
        value = np.mean(curvature) / (width * np.mean(rest))
        rule = "version 3's: the channel weighs as the rest"
    print(f"Median L1 over the pairs of {' and '.join(V3_CHOSEN_ON)}: curvature histograms ")
    print(f"{', '.join(f'{c:.4f}' for c in curvature)} (all {count}); the rest of the vector ")
    print(f"{', '.join(f'{r:.4f}' for r in rest)}. Version {args.version}'s curvature divisor ")
    print(f"by {rule}: {value:.6f} (set: {design.curvature}, for {width} bins)")


def _tolerance_one(path: Path) -> dict:
    """Version 5's curvature histograms of one mesh at each of TOLERANCES, and their CPU seconds."""
    design = cfhks.DESIGNS[5]
    ops = operators(repair_mesh(read_mesh(path)))
    row: dict = {}
    for tolerance in TOLERANCES:
        start = time.process_time()
        values = smoothed_curvature(ops, design.scales, tolerance, design.predict)
        row[f"{tolerance} s"] = time.process_time() - start
        row[tolerance] = cfhks.curvature_histograms(values, ops.vertex_area, design.bins).ravel()
    return row


def tolerance(args: argparse.Namespace) -> None:
    """Version 6's tolerance: how far the curvature histograms move from the tight solve's (1e-10)
    at each looser tolerance, against the median distance between two meshes' histograms, on
    version 3's training collections; the loosest at which the mean movement stays within
    TOLERANCE_SHARE of that median on each is chosen. Also, for all three collections, the CPU
    seconds of the curvature and the first tier of version 5 with its curvature so solved."""
    data = _load(args.cache)
    design = cfhks.DESIGNS[5]
    head = cfhks.channel_columns(design)["curvature"].start
    print("| collection | tolerance | curvature CPU s | mean movement / median distance | "
          "largest movement | FT |\n|---|---|---|---|---|---|")  # fmt: skip
    within: dict[float, bool] = dict.fromkeys(TOLERANCES, True)
    for name in COLLECTIONS:
        with ProcessPoolExecutor(args.jobs) as pool:
            rows = list(
                pool.map(_tolerance_one, collection_paths(args.data_root, name), chunksize=4)
            )
        tight = np.array([row[TOLERANCES[0]] for row in rows])
        median = _median(_pairwise(tight)) * tight.shape[1]
        for tol in TOLERANCES:
            raw = np.array([row[tol] for row in rows])
            moved = np.abs(raw - tight).sum(axis=1)
            share = moved.mean() / median
            if name in V3_CHOSEN_ON:
                within[tol] &= bool(share <= TOLERANCE_SHARE)
            vectors = np.hstack(
                [data[name]["cfhks 5"][:, :head], raw / (design.bins * design.curvature)]
            )
            ft = _report(_pairwise(vectors), data[name]["labels"]).measures["FT"]
            seconds = sum(row[f"{tol} s"] for row in rows)
            print(
                f"| {name} | {tol:g} | {seconds:.2f} | {share:.4f} | {moved.max():.4f} | {ft:.3f} |"
            )
    chosen = max(tol for tol, ok in within.items() if ok)
    print(
        f"\nThe loosest tolerance whose mean movement is within {TOLERANCE_SHARE:.0%} of the median"
    )
    print(
        f"distance on {' and '.join(V3_CHOSEN_ON)}: {chosen:g} "
        f"(version 6: {cfhks.DESIGNS[6].tolerance:g})"
    )


def _noise_one(item: tuple[Path, int]) -> dict:
    """The curvature histograms of one mesh at every scale of `LADDER`, as version 6 solves and
    bins them, for the mesh and for its copy with `messy.noise`'s vertex noise."""
    path, seed = item
    design = replace(cfhks.DESIGNS[6], scales=LADDER)
    mesh = repair_mesh(read_mesh(path))
    vertices, faces = messy.noise((mesh.vertices, mesh.faces), np.random.default_rng(seed))
    row = {}
    for key, copy in (("clean", mesh), ("noisy", clean_mesh(vertices, faces))):
        ops = operators(copy)
        values = smoothed_curvature(ops, design.scales, design.tolerance, design.predict)
        row[key] = cfhks.curvature_histograms(values, ops.vertex_area, design.bins)
    return row


def noise(args: argparse.Namespace) -> None:
    """Which curvature scales survive noise: per scale of `LADDER`, how far each mesh's histogram
    moves when Gaussian noise of a tenth of the mean edge length moves its vertices (messy.py's
    ``noise``), against the median distance between two clean meshes' histograms; the first
    tier of that scale alone on the clean collection; and of each noisy copy queried against
    the clean others."""
    print("| collection | scale | mean movement / median distance | clean FT | noisy against "
          "clean FT |\n|---|---|---|---|---|")  # fmt: skip
    for name in COLLECTIONS:
        paths = collection_paths(args.data_root, name)
        with ProcessPoolExecutor(args.jobs) as pool:
            rows = list(pool.map(_noise_one, [(p, i) for i, p in enumerate(paths)], chunksize=4))
        labels = [p.parent.name for p in paths]
        for j, scale in enumerate(LADDER):
            clean = np.array([row["clean"][j] for row in rows])
            noisy = np.array([row["noisy"][j] for row in rows])
            pairs = _pairwise(clean)
            share = np.abs(noisy - clean).sum(axis=1).mean() / (_median(pairs) * clean.shape[1])
            across = np.abs(noisy[:, None] - clean[None]).sum(axis=-1)
            print(
                f"| {name} | {scale:g} | {share:.2f} | {_report(pairs, labels).measures['FT']:.3f}"
                f" | {_report(across, labels).measures['FT']:.3f} |",
                flush=True,
            )


# --- version 7: chosen for scans as well as models -------------------------------------------

V7_FACES = 4000  # faces of version 7's copy, versions 4-6's
V7_PAIRS = (30, 45, 60)  # eigenpairs of the copy's spectrum, the heat computed from them
V7_HEAT_WEIGHTS = (1.0, 2.0, 3.0)  # the heat channel's weight, the spectrum's being 1
V7_QUERIES = ("clean", "noise")  # the queries whose first tiers the choice averages
SCAN_QUERIES = ("clean", "light-noise", "noise", "remesh")  # reported for the chosen version


def _study7_one(item: tuple[Path, int], faces: int = V7_FACES) -> dict:
    """Version 7's candidate channels of one mesh and of its scan-like copies (messy.py's
    kinds, seeded by the mesh's index), all on the copy simplified to ``faces`` faces,
    unweighted: per count of `V7_PAIRS`, the log spectrum and the heat quantiles; the curvature
    histograms at every scale of `LADDER`."""
    path, seed = item
    design = replace(cfhks.DESIGNS[6], coarse=faces)
    mesh = repair_mesh(read_mesh(path))
    row: dict = {}
    for kind in SCAN_QUERIES:
        copy = mesh
        if kind != "clean":
            shaken = messy.KINDS[kind]((mesh.vertices, mesh.faces), np.random.default_rng(seed))
            copy = clean_mesh(*shaken)
        ops = operators(copy)
        spectrum, surface = cfhks.spectrum_of(
            ops, simplified_mesh(copy, design.coarse), count=max(V7_PAIRS)
        )
        for k in V7_PAIRS:
            part = Spectrum(spectrum.eigenvalues[:k], spectrum.eigenvectors[:, :k],
                            spectrum.vertex_area, spectrum.labels)  # fmt: skip
            channels = cfhks.channels(surface, part, replace(design, eigenpairs=k, scales=()))
            row[f"{kind} spectrum {k}"] = channels["spectrum"]
            row[f"{kind} heat {k}"] = channels["heat"].ravel()
        values = smoothed_curvature(surface, LADDER, design.tolerance, design.predict)
        row[f"{kind} curvature"] = cfhks.curvature_histograms(
            values, surface.vertex_area, design.bins
        )
    return row


def _study7_cache(
    args: argparse.Namespace, faces: int = V7_FACES
) -> dict[str, dict[str, np.ndarray]]:
    """`_study7_one` of every mesh of the three collections with copies of ``faces`` faces,
    cached under ``--cache``."""
    data = {}
    for name in COLLECTIONS:
        suffix = "" if faces == V7_FACES else f"-{faces}"
        cache = args.cache / f"study7-{name}{suffix}.npz"
        if not cache.exists():
            args.cache.mkdir(parents=True, exist_ok=True)
            paths = collection_paths(args.data_root, name)
            with ProcessPoolExecutor(args.jobs) as pool:
                items = [(p, i) for i, p in enumerate(paths)]
                rows = list(pool.map(partial(_study7_one, faces=faces), items, chunksize=4))
            arrays = {key: np.array([row[key] for row in rows]) for key in rows[0]}
            np.savez(cache, labels=[p.parent.name for p in paths], **arrays)
        data[name] = dict(np.load(cache))
    return data


class Scans:
    """Version 7's candidates: each channel's distances from every kind of query to the clean
    meshes, combined with divisors from training collections, and their first tiers."""

    def __init__(self, data: dict[str, dict[str, np.ndarray]]) -> None:
        self.data = data
        self.distances: dict[tuple[str, str], dict[str, np.ndarray]] = {}
        self.medians: dict[tuple[str, tuple[str, ...]], float] = {}

    def channel(self, collection: str, key: str) -> dict[str, np.ndarray]:
        """L1 distances of one unweighted channel (``"spectrum 45"``, ``"heat 45"``, or
        ``"curvature 4,6"`` for scales of LADDER by index, averaged over them) from each kind of
        query to the clean meshes."""
        if (collection, key) not in self.distances:
            arrays, name = self.data[collection], key.split()[0]
            if name == "curvature":
                scales = [int(j) for j in key.split()[1].split(",")]
                rows = {q: arrays[f"{q} curvature"][:, scales] / len(scales) for q in SCAN_QUERIES}
            else:
                rows = {q: arrays[f"{q} {key}"] for q in SCAN_QUERIES}
            rows = {q: x.reshape(len(x), -1) for q, x in rows.items()}
            self.distances[collection, key] = {
                q: np.abs(x[:, None] - rows["clean"][None]).sum(axis=-1) for q, x in rows.items()
            }
        return self.distances[collection, key]

    def combined(
        self, collection: str, weights: dict[str, float], train: tuple[str, ...]
    ) -> dict[str, np.ndarray]:
        """The weighted sum of channels, each divided by its median clean distance over the
        pairs, averaged over ``train`` (label-free), per kind of query."""
        total: dict[str, np.ndarray] = {}
        for key, weight in weights.items():
            median = self.median(key, train)
            for q, d in self.channel(collection, key).items():
                total[q] = total.get(q, 0.0) + weight / median * d
        return total

    def median(self, key: str, train: tuple[str, ...]) -> float:
        """A channel's median clean distance over the pairs, averaged over ``train``."""
        if (key, train) not in self.medians:
            clean = [_median(self.channel(t, key)["clean"]) for t in train]
            self.medians[key, train] = float(np.mean(clean))
        return self.medians[key, train]

    def first_tiers(
        self,
        weights: dict[str, float],
        train: tuple[str, ...],
        queries: tuple[str, ...],
        collections: tuple[str, ...] = COLLECTIONS,
    ) -> dict[tuple[str, str], float]:
        """FT per collection and kind of query (each query's own clean mesh left out)."""
        return {
            (c, q): _report(d, self.data[c]["labels"]).measures["FT"]
            for c in collections
            for q, d in self.combined(c, weights, train).items()
            if q in queries
        }

    def scores(self, train: tuple[str, ...]) -> list[tuple[dict[str, float], float]]:
        """Every candidate with its mean FT over ``train`` and `V7_QUERIES`."""
        scored = []
        for pairs, heat, (scales, weight) in itertools.product(
            V7_PAIRS, V7_HEAT_WEIGHTS, itertools.product(_ladders(), CURVATURE_WEIGHTS)
        ):
            weights = {f"spectrum {pairs}": 1.0, f"heat {pairs}": heat,
                       "curvature " + ",".join(map(str, scales)): weight}  # fmt: skip
            ft = self.first_tiers(weights, train, V7_QUERIES, train)
            scored.append((weights, float(np.mean([ft[c, q] for c in train for q in V7_QUERIES]))))
        return scored


def _candidate_text(weights: dict[str, float]) -> str:
    """A version 7 candidate in words."""
    parts = []
    for key, weight in weights.items():
        name, detail = key.split()
        if name == "curvature":
            detail = _scales_text(tuple(int(j) for j in detail.split(",")))
        parts.append(f"{name} {detail} x{weight:g}")
    return "; ".join(parts)


def study7(args: argparse.Namespace) -> None:
    """Version 7's choice: every channel on the simplified copy, chosen by the mean first tier of
    clean queries and of noisy copies (messy.py's ``noise``) against the clean meshes; leave one
    collection out, then on version 3's training collections; with the chosen candidate's
    divisors and its first tiers for every kind of scan-like query."""
    scans = Scans(_study7_cache(args))
    _left_out_table(scans, V7_PAIRS)
    scored = scans.scores(V3_CHOSEN_ON)
    weights, score = max(scored, key=lambda item: item[1])
    print(f"\nChosen on {' and '.join(V3_CHOSEN_ON)} (mean FT {score:.3f}): "
          f"{_candidate_text(weights)}\n")  # fmt: skip
    print("The best candidate of each number of eigenpairs (their cost), on the same collections:")
    print("\n| eigenpairs | candidate | mean FT | " + " | ".join(COLLECTIONS) + " (clean) |")
    print("|---|---|---|" + "---|" * 3)
    for pairs in V7_PAIRS:
        best, mean = _best_of(scored, pairs)
        ft = scans.first_tiers(best, V3_CHOSEN_ON, ("clean",))
        cells = " | ".join(f"{ft[c, 'clean']:.3f}" for c in COLLECTIONS)
        print(f"| {pairs} | {_candidate_text(best)} | {mean:.3f} | {cells} |")
    _scan_table(scans, weights)
    _divisors(scans, weights)


def _divisors(scans: Scans, weights: dict[str, float]) -> None:
    """Print a candidate's divisors as `cfsig.descriptors.intrinsic.DESIGNS` records them."""
    print("\nDivisors (each channel's median clean distance over the pairs, averaged over")
    print(f"{' and '.join(V3_CHOSEN_ON)}, divided by its weight):")
    for key, weight in weights.items():
        print(f"- {key}: {scans.median(key, V3_CHOSEN_ON) / weight:.6f}")


def _left_out_table(scans: Scans, pairs: tuple[int, ...]) -> None:
    """Print the candidate chosen with each collection left out, among those of ``pairs``
    eigenpairs, and its first tiers (the left-out collection's in bold)."""
    header = " | ".join(f"{c} {q}" for c in COLLECTIONS for q in V7_QUERIES)
    print(f"| left out | candidate | {header} |\n|---|---|" + "---|" * 6)
    for left_out in COLLECTIONS:
        train = tuple(c for c in COLLECTIONS if c != left_out)
        weights, _ = max(
            (item for item in scans.scores(train) if _pairs_of(item[0]) in pairs),
            key=lambda item: item[1],
        )
        ft = scans.first_tiers(weights, train, V7_QUERIES)
        cells = [f"**{ft[c, q]:.3f}**" if c == left_out else f"{ft[c, q]:.3f}"
                 for c in COLLECTIONS for q in V7_QUERIES]  # fmt: skip
        print(f"| {left_out} | {_candidate_text(weights)} | " + " | ".join(cells) + " |")


def _scan_table(scans: Scans, weights: dict[str, float]) -> None:
    """Print a candidate's first tiers for every kind of scan-like query."""
    ft = scans.first_tiers(weights, V3_CHOSEN_ON, SCAN_QUERIES)
    print("\n| collection | " + " | ".join(SCAN_QUERIES) + " |\n|---|" + "---|" * 4)
    for c in COLLECTIONS:
        print(f"| {c} | " + " | ".join(f"{ft[c, q]:.3f}" for q in SCAN_QUERIES) + " |")


def _pairs_of(weights: dict[str, float]) -> int:
    """The number of eigenpairs of a version 7 candidate."""
    return next(int(key.split()[1]) for key in weights if key.startswith("spectrum"))


def _best_of(
    scored: list[tuple[dict[str, float], float]], pairs: int
) -> tuple[dict[str, float], float]:
    """The best-scored candidate with ``pairs`` eigenpairs, and its score."""
    return max((item for item in scored if _pairs_of(item[0]) == pairs), key=lambda item: item[1])


# --- version 8: version 7's channels, the copy and the eigenpairs chosen with their cost -------

V8_FACES = (1000, 2000, 3000, V7_FACES)  # faces of the candidate copies
# The cheapest candidate within this of the best mean FT is chosen, as version 4's copy was,
# among those that meet the quality bars on the training collections (`_meets_bars`).
V8_MARGIN = 0.01


def _candidate_design(scans: Scans, weights: dict[str, float], faces: int) -> cfhks.Design:
    """A version 7 candidate as a `cfhks.Design` on a copy of ``faces`` faces: each channel's
    divisor is its median clean distance over `V3_CHOSEN_ON`'s pairs divided by its weight,
    per entry as `cfhks.weigh` divides."""
    design = cfhks.DESIGNS[7]
    divisor = {key.split()[0]: scans.median(key, V3_CHOSEN_ON) / w for key, w in weights.items()}
    scales = next(key.split()[1] for key in weights if key.startswith("curvature"))
    chosen = tuple(LADDER[int(j)] for j in scales.split(","))
    pairs = _pairs_of(weights)
    return replace(
        design,
        coarse=faces,
        eigenpairs=pairs,
        spectrum=divisor["spectrum"] / pairs,
        heat=(divisor["heat"] / cfhks.QUANTILES,) * len(design.times),
        scales=chosen,
        curvature=divisor["curvature"] * len(chosen) / design.bins,
    )


def _candidate_seconds(path: Path, designs: list[cfhks.Design]) -> list[float]:
    """CPU seconds of each design's vector of one repaired mesh: the copy, its operators, its
    spectrum and the channels (reading and repair, alike for every design, left out)."""
    mesh = repair_mesh(read_mesh(path))
    seconds = []
    for design in designs:
        start = time.process_time()
        copy = simplified_mesh(mesh, design.coarse)
        ops = operators(mesh if copy is None else copy)
        spectrum, surface = cfhks.spectrum_of(ops, count=design.eigenpairs)
        cfhks.weigh(cfhks.channels(surface, spectrum, design), design)
        seconds.append(time.process_time() - start)
    return seconds


def _meets_bars(scans: Scans, weights: dict[str, float], shapedna: dict[str, float]) -> bool:
    """Whether a candidate's clean queries meet issue 14's quality bars on the training
    collections: FT at least ShapeDNA's + 0.02 on each, and on SHREC 2007 NN >= 0.90 and FT
    >= 0.60."""
    reports = {
        c: _report(scans.combined(c, weights, V3_CHOSEN_ON)["clean"], scans.data[c]["labels"])
        for c in V3_CHOSEN_ON
    }
    ft = {c: r.measures["FT"] for c, r in reports.items()}
    shrec = reports["shrec07"].measures
    return (
        all(ft[c] >= shapedna[c] + 0.02 for c in V3_CHOSEN_ON)
        and shrec["NN"] >= 0.90
        and shrec["FT"] >= 0.60
    )


def study8(args: argparse.Namespace) -> None:
    """Version 8's choice: version 7's candidates on copies of each of `V8_FACES` faces, the
    best of each copy and number of eigenpairs by version 7's objective, timed on every
    ``--every``-th SHREC 2007 mesh; the cheapest within `V8_MARGIN` of the best that meets the
    quality bars on the training collections is chosen (ShapeDNA's FT from ``measure``'s
    cache). The weightings of smaller copies or fewer eigenpairs that would also meet them are
    listed (`_cheaper_table`)."""
    measured = _load(args.cache)
    shapedna = {c: _ft("ShapeDNA", measured[c]) for c in V3_CHOSEN_ON}
    rows, every = [], {}
    for faces in V8_FACES:
        scans = Scans(_study7_cache(args, faces))
        every[faces] = scans, scans.scores(V3_CHOSEN_ON)
        for pairs in V7_PAIRS:
            weights, mean = _best_of(every[faces][1], pairs)
            rows.append((faces, pairs, scans, weights, mean))
    designs = [_candidate_design(scans, w, faces) for faces, _, scans, w, _ in rows]
    paths = sorted(collection_paths(args.data_root, "shrec07"), key=lambda p: int(p.stem))
    paths = paths[:: args.every]
    seconds = np.median([_candidate_seconds(path, designs) for path in paths], axis=0)
    best = max(mean for *_, mean in rows)
    bars = [_meets_bars(scans, weights, shapedna) for _, _, scans, weights, _ in rows]
    chosen = min(
        (i for i, row in enumerate(rows) if row[-1] >= best - V8_MARGIN and bars[i]),
        key=lambda i: seconds[i],
    )
    print(f"Best candidate of each copy and number of eigenpairs, chosen on "
          f"{' and '.join(V3_CHOSEN_ON)}; CPU ms per mesh: median over {len(paths)} SHREC 2007 "
          "meshes of the copy, its spectrum and the channels:\n")  # fmt: skip
    columns = " | ".join(COLLECTIONS)
    print(f"| copy faces | eigenpairs | candidate | mean FT | {columns} (clean) | bars | CPU ms |")
    print("|---|---|---|---|" + "---|" * 5)
    for i, (faces, pairs, scans, weights, mean) in enumerate(rows):
        ft = scans.first_tiers(weights, V3_CHOSEN_ON, ("clean",))
        cells = " | ".join(f"{ft[c, 'clean']:.3f}" for c in COLLECTIONS)
        mark = " (chosen)" if i == chosen else ""
        print(f"| {faces}{mark} | {pairs} | {_candidate_text(weights)} | {mean:.3f} | {cells} "
              f"| {'yes' if bars[i] else 'no'} | {1000 * seconds[i]:.1f} |")  # fmt: skip
    faces, pairs, scans, weights, mean = rows[chosen]
    print("\nShapeDNA's FT: " + ", ".join(f"{c} {v:.3f}" for c, v in shapedna.items()))
    print(f"\nBest mean FT {best:.3f}; chosen: the cheapest within {V8_MARGIN} of it that meets "
          f"the bars on {' and '.join(V3_CHOSEN_ON)}, a copy of {faces} faces with {pairs} "
          f"eigenpairs (mean FT {mean:.3f}).\n")  # fmt: skip
    _cheaper_table(every, best - V8_MARGIN, (faces, pairs), shapedna)
    _left_out_table(scans, (pairs,))
    _scan_table(scans, weights)
    _divisors(scans, weights)


def _cheaper_table(
    every: dict[int, tuple[Scans, list[tuple[dict[str, float], float]]]],
    floor: float,
    chosen: tuple[int, int],
    shapedna: dict[str, float],
) -> None:
    """Every candidate, not only the best of its copy and eigenpairs, that scores at least
    ``floor``, meets the bars, and has a smaller copy or fewer eigenpairs than ``chosen``."""
    print("Every candidate within the margin that meets the bars on a smaller copy, or with fewer "
          "eigenpairs, than the chosen (not only the best of each; untimed: the table above "
          "times each copy and number of eigenpairs):\n")  # fmt: skip
    print("| copy faces | eigenpairs | candidate | mean FT | " + " | ".join(COLLECTIONS) + " |")
    print("|---|---|---|---|" + "---|" * len(COLLECTIONS))
    found = 0
    for faces, (scans, scored) in every.items():
        for weights, mean in sorted(scored, key=lambda item: -item[1]):
            pairs = _pairs_of(weights)
            cheaper = faces < chosen[0] or (faces == chosen[0] and pairs < chosen[1])
            if mean < floor or not cheaper or not _meets_bars(scans, weights, shapedna):
                continue
            ft = scans.first_tiers(weights, V3_CHOSEN_ON, ("clean",))
            cells = " | ".join(f"{ft[c, 'clean']:.3f}" for c in COLLECTIONS)
            print(f"| {faces} | {pairs} | {_candidate_text(weights)} | {mean:.3f} | {cells} |")
            found += 1
    print(f"\n{found} such candidates.\n")


def _distances(name: str, vectors: np.ndarray) -> np.ndarray:
    """A descriptor's all-pairs distance: L2 for ShapeDNA, L1 (the index's) otherwise."""
    return _pairwise(vectors, order=2 if name == "ShapeDNA" else 1)


def compare(args: argparse.Namespace) -> None:
    """Measures and CPU seconds per mesh of all four descriptors on the three collections."""
    data = _load(args.cache)
    print("| collection | descriptor | NN | FT | ST | mAP | CPU s per mesh (median) |")
    print("|---|---|---|---|---|---|---|")
    ft: dict[tuple[str, str], float] = {}
    for c in COLLECTIONS:
        for name in NAMES:
            m = _report(_distances(name, data[c][name]), data[c]["labels"]).measures
            ft[c, name] = m["FT"]
            cells = [f"{m[k]:.3f}" for k in ("NN", "FT", "ST", "mAP")]
            print(
                f"| {c} | {name} | "
                + " | ".join(cells)
                + f" | {np.median(data[c][name + ' s']):.3f} |"
            )
    default = f"cfhks {DEFAULT_VERSIONS['cfhks']}"
    shrec = _report(_distances(default, data["shrec07"][default]), data["shrec07"]["labels"])
    checks = {
        f"{c}: FT >= ShapeDNA's + 0.02": ft[c, default] >= ft[c, "ShapeDNA"] + 0.02
        for c in COLLECTIONS
    }
    checks["shrec07: NN >= 0.90"] = shrec.measures["NN"] >= 0.90
    checks["shrec07: FT >= 0.60"] = shrec.measures["FT"] >= 0.60
    print(f"\nThe issue's quality bars, for the default ({default}):\n")
    print("\n".join(f"- {k}: {'yes' if v else 'NO'}" for k, v in checks.items()))


def _cfsig_index(
    folder: Path, descriptor: str | None, jobs: int, version: int | None = None
) -> tuple[float, float]:
    """Wall and CPU seconds of one whole ``cfsig index`` process into a new index."""
    with tempfile.TemporaryDirectory() as tmp:
        command = [str(Path(sys.executable).with_name("cfsig")), "index", str(folder), "-o",
                   f"{tmp}/i.h5", "--jobs", str(jobs)]  # fmt: skip
        if descriptor:
            command += ["--descriptor", descriptor]
        if version:
            command += ["--descriptor-version", str(version)]
        return _timed_process(command)


def _shapedna_process(files: list[Path]) -> tuple[float, float]:
    """Wall and CPU seconds of one whole process computing ShapeDNA of ``files``."""
    return _timed_process([sys.executable, __file__, "shapedna", *map(str, files)])


def _timed_process(command: list[str]) -> tuple[float, float]:
    """Wall seconds of a command, and the user and system CPU seconds of it and of the worker
    processes it waited for."""
    before = resource.getrusage(resource.RUSAGE_CHILDREN)
    start = time.perf_counter()
    subprocess.run(command, check=True, capture_output=True)
    wall = time.perf_counter() - start
    after = resource.getrusage(resource.RUSAGE_CHILDREN)
    return wall, (after.ru_utime - before.ru_utime) + (after.ru_stime - before.ru_stime)


def cost(args: argparse.Namespace) -> None:
    """Whole-process times of indexing with the default, with cf, with version 10 (the default's
    vector and the fine cells), and of ShapeDNA."""
    paths = sorted(collection_paths(args.data_root, "shrec07"), key=lambda p: int(p.stem))
    subset = paths[:: args.every]
    runs: dict[str, list[tuple[float, float]]] = {}
    with tempfile.TemporaryDirectory() as tmp:
        folder = Path(tmp) / "subset"
        for path in subset:
            (folder / path.parent.name).mkdir(parents=True, exist_ok=True)
            shutil.copy(path, folder / path.parent.name / path.name)
        for round_ in range(args.rounds):
            timings = {
                "default, 1 job": lambda: _cfsig_index(folder, None, 1),
                "cf, 1 job": lambda: _cfsig_index(folder, "cf", 1),
                "ShapeDNA, 1 process": lambda: _shapedna_process(subset),
                "default, all, 2 jobs": lambda: _cfsig_index(args.data_root / "shrec07", None, 2),
                "cf, all, 2 jobs": lambda: _cfsig_index(args.data_root / "shrec07", "cf", 2),
                "version 10, all, 2 jobs": lambda: _cfsig_index(
                    args.data_root / "shrec07", None, 2, version=10
                ),
            }
            order = list(timings) if round_ % 2 == 0 else list(timings)[::-1]
            for name in order:
                runs.setdefault(name, []).append(timings[name]())
            last = ", ".join(f"{k} {v[-1][0]:.2f} s ({v[-1][1]:.2f} CPU)" for k, v in runs.items())
            print(f"round {round_ + 1}: {last}", flush=True)
    wall = {name: np.array([w for w, _ in v]) for name, v in runs.items()}
    cpu = {name: np.array([c for _, c in v]) for name, v in runs.items()}
    print(f"\nMedians of {args.rounds} rounds ({len(subset)} meshes unless 'all'):\n")
    print("| run | wall s | CPU s |\n|---|---|---|")
    for name in runs:
        print(f"| {name} | {np.median(wall[name]):.2f} | {np.median(cpu[name]):.2f} |")
    print("\n| ratio | of wall medians | wall, round by round (median) | of CPU medians |")
    print("|---|---|---|---|")
    ratios = {
        "default / cf": ("default, 1 job", "cf, 1 job"),
        "ShapeDNA / default": ("ShapeDNA, 1 process", "default, 1 job"),
        "ShapeDNA / cf": ("ShapeDNA, 1 process", "cf, 1 job"),
        "version 10 / default, all": ("version 10, all, 2 jobs", "default, all, 2 jobs"),
    }
    for name, (top, bottom) in ratios.items():
        rounds = wall[top] / wall[bottom]
        listed = ", ".join(f"{r:.2f}" for r in rounds)
        print(
            f"| {name} | {np.median(wall[top]) / np.median(wall[bottom]):.2f} | {listed} "
            f"({np.median(rounds):.2f}) | {np.median(cpu[top]) / np.median(cpu[bottom]):.2f} |"
        )
    default, cf = np.median(wall["default, 1 job"]), np.median(wall["cf, 1 job"])
    checks = {
        "default <= 1.5x cf (40 meshes, 1 job)": default <= 1.5 * cf,
        "ShapeDNA >= 6x default": np.median(wall["ShapeDNA, 1 process"]) >= 6 * default,
        "all 400 with 2 jobs <= 20 s": np.median(wall["default, all, 2 jobs"]) <= 20,
    }
    print("\n" + "\n".join(f"- {k}: {'yes' if v else 'NO'}" for k, v in checks.items()))


def _coarse_one(item: tuple[Path, int]) -> tuple[np.ndarray, float, np.ndarray]:
    """Version 3 of one mesh with the spectrum and heat of a copy of ``faces`` faces (version 4's
    design with that copy) and its CPU seconds, reading included; and, untimed, version 3 with
    every channel, the curvature too, computed on the copy."""
    path, faces = item
    design = replace(cfhks.DESIGNS[4], coarse=faces)
    start = time.process_time()
    mesh = repair_mesh(read_mesh(path))
    ops = operators(mesh, Params().mollify)
    copy = simplified_mesh(mesh, faces)
    vector = cfhks.weigh(cfhks.channels(ops, cfhks.spectrum_of(ops, copy)[0], design), design)
    seconds = time.process_time() - start
    if copy is None:
        return vector, seconds, vector
    on_copy = operators(copy, Params().mollify)
    return (
        vector,
        seconds,
        cfhks.weigh(cfhks.channels(on_copy, cfhks.spectrum_of(on_copy)[0], design), design),
    )


def coarse(args: argparse.Namespace) -> None:
    """FT and CPU seconds of version 3 with the spectrum of simplified copies (version 4's
    choice of the copy's size), against version 3 on the full mesh from the cache; and the FT
    with the curvature taken from the copy too."""
    data = _load(args.cache)
    rows = {"all (version 3)": {c: (_ft("cfhks 3", data[c]), data[c]["cfhks 3 s"]) for c in data}}
    on_copy: dict[int, dict[str, float]] = {}
    for faces in args.faces:
        rows[str(faces)], on_copy[faces] = {}, {}
        for c in COLLECTIONS:
            items = [(path, faces) for path in collection_paths(args.data_root, c)]
            with ProcessPoolExecutor(args.jobs) as pool:
                measured = list(pool.map(_coarse_one, items, chunksize=2))
            labels = data[c]["labels"]
            ft = _report(_distances("cfhks", np.array([m[0] for m in measured])), labels)
            rows[str(faces)][c] = (ft.measures["FT"], np.array([m[1] for m in measured]))
            all_copy = _report(_distances("cfhks", np.array([m[2] for m in measured])), labels)
            on_copy[faces][c] = all_copy.measures["FT"]
    print("| faces of the copy | " + " | ".join(f"{c} FT" for c in COLLECTIONS), end=" | ")
    print(" | ".join(f"{c} CPU s" for c in COLLECTIONS) + " |\n|---|" + "---|" * 6)
    for name, row in rows.items():
        cells = [f"{row[c][0]:.3f}" for c in COLLECTIONS]
        cells += [f"{np.median(row[c][1]):.3f}" for c in COLLECTIONS]
        print(f"| {name} | " + " | ".join(cells) + " |")
    full = np.mean([rows["all (version 3)"][c][0] for c in V3_CHOSEN_ON])
    fits = [
        f for f in args.faces if np.mean([rows[str(f)][c][0] for c in V3_CHOSEN_ON]) >= full - 0.01
    ]
    print(
        f"\nThe smallest copy whose mean FT on {' and '.join(V3_CHOSEN_ON)} is within 0.01 of "
        f"version 3's ({full:.4f}): {min(fits) if fits else 'none'} faces"
    )
    print("\nWith the curvature computed on the copy too, FT:\n")
    print("| faces of the copy | " + " | ".join(COLLECTIONS) + " |\n|---|" + "---|" * 3)
    for faces, fts in on_copy.items():
        print(f"| {faces} | " + " | ".join(f"{fts[c]:.3f}" for c in COLLECTIONS) + " |")


def _stages_one(path: Path) -> dict[str, float]:
    """CPU seconds of each stage of versions 3 to 8 on one mesh; the curvature's agreement with
    four sparse factorisations; and how far version 5's looser conjugate gradients move its
    curvature histograms."""
    design, v5, v6 = cfhks.DESIGNS[4], cfhks.DESIGNS[5], cfhks.DESIGNS[6]
    seconds: dict[str, float] = {}

    def timed(name, step):
        start = time.process_time()
        result = step()
        seconds[name] = time.process_time() - start
        return result

    mesh = timed("read and repair", lambda: repair_mesh(read_mesh(path)))
    ops = timed("operators (Laplacian, curvature, areas)", lambda: operators(mesh))
    cf = timed("phi (the conformal solve; cf only)", lambda: conformal_factor(mesh))
    values = timed(
        "curvature, conjugate gradients to 1e-10 (versions 3, 4)",
        lambda: smoothed_curvature(ops, design.scales),
    )
    loose = timed(
        "curvature, conjugate gradients to 1e-5 (version 5)",
        lambda: smoothed_curvature(ops, v5.scales, v5.tolerance, v5.predict),
    )
    timed(
        "curvature, conjugate gradients to 1e-3 (version 6)",
        lambda: smoothed_curvature(ops, v6.scales, v6.tolerance, v6.predict),
    )
    area = ops.vertex_area.sum()
    defect = np.where(ops.boundary, 0.0, ops.curvature)

    def factorised():
        systems = [sp.diags(ops.vertex_area) - (s * area) * ops.laplacian for s in design.scales]
        return np.array([factorize(sp.csc_matrix(a), "auto")(defect) for a in systems]).T * area

    exact = timed("curvature, four factorisations", factorised)
    heat = replace(design, scales=())
    timed(
        "spectrum and heat, full mesh",
        lambda: cfhks.channels(ops, cfhks.spectrum_of(ops, solve=cf.solve)[0], heat),
    )
    copy = timed("simplified copy", lambda: simplified_mesh(mesh, design.coarse))
    timed(
        "spectrum and heat, copy",
        lambda: cfhks.channels(ops, cfhks.spectrum_of(ops, copy)[0], heat),
    )
    v8 = cfhks.DESIGNS[8]
    surface = timed("the copy's operators", lambda: ops if copy is None else operators(copy))
    solve = timed(
        "the copy's factorisation",
        lambda: laplacian_solver(surface.laplacian, surface.labels, "auto"),
    )
    for pairs, label in ((60, "version 7"), (v8.eigenpairs, "version 8")):
        spectrum = timed(
            f"the copy's spectrum, {pairs} eigenpairs ({label})",
            lambda pairs=pairs: laplace_spectrum(
                surface.laplacian, surface.vertex_area, surface.labels, solve, pairs
            ),
        )
    timed(
        "the copy's curvature (versions 7 and 8)",
        lambda: smoothed_curvature(surface, v8.scales, v8.tolerance, v8.predict),
    )
    timed(
        "heat and quantiles of version 8's spectrum",
        lambda: cfhks.channels(surface, spectrum, replace(v8, scales=())),
    )
    seconds["difference"] = float(np.abs(values - exact).max() / np.abs(exact).max())
    for key, bins in (("moved", v5.bins), ("moved, 48 bins", design.bins)):
        tight, near = (
            cfhks.curvature_histograms(x, ops.vertex_area, bins) for x in (values, loose)
        )
        seconds[key] = float(np.abs(tight - near).sum())
    return seconds


def stages(args: argparse.Namespace) -> None:
    """CPU seconds of each stage of versions 3 to 8, summed over every k-th mesh of SHREC 2007
    (the cost stage's 40) and of FAUST."""
    table: dict[str, list[float]] = {}
    difference, moved = 0.0, {"moved": [], "moved, 48 bins": []}
    for name in ("shrec07", "faust"):
        paths = collection_paths(args.data_root, name)
        if name == "shrec07":
            paths.sort(key=lambda p: int(p.stem))
        paths = paths[:: args.every]
        with ProcessPoolExecutor(args.jobs) as pool:
            rows = list(pool.map(_stages_one, paths))
        for key in rows[0]:
            table.setdefault(key, []).append(sum(r[key] for r in rows))
        difference = max(difference, *(r["difference"] for r in rows))
        for key, values in moved.items():
            values += [r[key] for r in rows]
        print(f"{name}: {len(paths)} meshes (every {args.every}th)")
    print("\nCPU seconds summed over those meshes:\n")
    print("| stage | shrec07 | faust |\n|---|---|---|")
    for key, sums in table.items():
        if key != "difference" and key not in moved:
            print(f"| {key} | {sums[0]:.2f} | {sums[1]:.2f} |")
    print(f"\nLargest difference of the curvature, relative to its largest value: {difference:.1e}")
    for key, bins in (("moved", 49), ("moved, 48 bins", 48)):
        print(
            f"Curvature histograms (4 scales, {bins} bins) at 1e-5 against 1e-10, L1 summed over "
            f"the scales: largest {max(moved[key]):.1e}, mean {np.mean(moved[key]):.1e}"
        )


def _lanczos_one(path: Path) -> list[tuple[int, int]]:
    """(eigenpairs asked, operator applications) of every Lanczos iteration of version 8 on one
    mesh file; a file that fails keeps the iterations it ran."""
    real, calls = spectrum.lanczos, []

    def counted(apply, fresh, dimension, count, tolerance):
        applied = [0]

        def counting(u: np.ndarray) -> np.ndarray:
            applied[0] += 1
            return apply(u)

        try:
            return real(counting, fresh, dimension, count, tolerance)
        finally:
            calls.append((count, applied[0]))

    with mock.patch.object(spectrum, "lanczos", counted), contextlib.suppress(MeshError):
        signature_file(path, DESCRIPTORS["cfhks 8"])
    return calls


def lanczos(args: argparse.Namespace) -> None:
    """Steps of version 8's Lanczos iterations on every mesh, against the iteration's cap."""
    print(
        "| collection | meshes | first search: steps per eigenpair, largest (99th percentile, "
        "median) | search for missed copies: steps, largest (99th percentile, median) |"
    )
    print("|---|---|---|---|")
    for name in (*COLLECTIONS, "psb-train"):
        paths = sorted((args.data_root / name).glob("*/*.off"))
        if not paths:
            continue
        with ProcessPoolExecutor(args.jobs) as pool:
            rows = list(pool.map(_lanczos_one, paths, chunksize=4))
        first = np.array([n / c for row in rows for c, n in row if c > 1])
        probe = np.array([n for row in rows for c, n in row if c == 1])
        print(
            f"| {name} | {len(paths)} | {first.max():.1f} ({np.percentile(first, 99):.1f}, "
            f"{np.median(first):.1f}) | {probe.max()} ({np.percentile(probe, 99):.0f}, "
            f"{np.median(probe):.0f}) |",
            flush=True,
        )
    per, more, pairs = spectrum._STEPS_PER_PAIR, spectrum._STEPS_MORE, cfhks.DESIGNS[8].eigenpairs
    print(
        f"\nThe cap: {per} steps per eigenpair and {more} more ({per * pairs + more} for version "
        f"8's {pairs} eigenpairs, {per + more} for one)."
    )


def _ft(name: str, arrays: dict[str, np.ndarray]) -> float:
    """A cached descriptor's first tier on its collection."""
    return _report(_distances(name, arrays[name]), arrays["labels"]).measures["FT"]


def main() -> None:
    """Parse the command line and run one stage."""
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    runs = {
        "measure": measure,
        "study": study,
        "study3": study3,
        "study7": study7,
        "study8": study8,
        "divisor": divisor,
        "tolerance": tolerance,
        "noise": noise,
        "compare": compare,
        "cost": cost,
        "coarse": coarse,
        "stages": stages,
        "lanczos": lanczos,
    }
    parser.add_argument("stage", choices=(*runs, "shapedna"))
    parser.add_argument("files", nargs="*", type=Path, help="the shapedna stage's meshes")
    parser.add_argument("--data-root", type=Path, default=DATA_ROOT, help="unpacked collections")
    parser.add_argument("--cache", type=Path, default=CACHE, help="folder of the caches")
    parser.add_argument("--jobs", type=int, default=2, help="worker processes of measure, lanczos")
    parser.add_argument(
        "--every", type=int, default=10, help="cost, stages, study8: every k-th SHREC07 mesh"
    )
    parser.add_argument(
        "--only", nargs="+", choices=DESCRIPTORS, help="measure: these descriptors only"
    )
    parser.add_argument("--rounds", type=int, default=3, help="cost: rounds of timings")
    parser.add_argument(
        "--version", type=int, default=9, help="divisor: cfhks version, 3 and later"
    )
    parser.add_argument(
        "--faces", type=int, nargs="+", default=[2000, 4000, 8000], help="coarse: copies' faces"
    )
    args = parser.parse_args()
    if args.stage == "shapedna":
        for path in args.files:
            shapedna(path)
        return
    runs[args.stage](args)


if __name__ == "__main__":
    main()
