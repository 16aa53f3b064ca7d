"""Partial queries by joint histograms of the curvature at adjacent scales: a study (partial.md).

    python benchmarks/partial_joint.py --data-root /work/data

Makes the parts of ``benchmarks/partial.py`` (the same cuts, bodies with holes and scans, from
the same seeds) of every mesh of SHREC 2007, McGill and FAUST, and ranks the whole shapes for
each part by the partial distance (`cfsig.search.partial.partial_scores`: unexplained share plus L1
distance, at the best share) of features of the curvature at version 8's four scales,
measured on the same surfaces (`cfsig.search.partial.share_curvatures`):

- ``marginal``: its histograms per scale, version 8's curvature channel;
- ``joint B``: the histograms of each pair of adjacent scales jointly, on B x B bins of the same
  axis (``asinh(value / CURVATURE_UNIT)`` on [-CURVATURE_RANGE, CURVATURE_RANGE]), three pairs:
  where a vertex's curvature lies at one scale and at the next, which the marginals forget;
- ``band B D``: the joint histograms with the second scale's bin taken relative to the first's
  and clipped to within D bins of it: B x (2 D + 1) cells a pair, where nearly all the mass of
  the B x B lies (adjacent scales' values are close);
- ``both B``: the marginal and the joint partial distances summed.

For each, NN per collection and kind, and the first tier of the ``--partial`` ranking (the
nearest whole first, then the others by their whole-shape distance to it). The best feature is
the one with the best mean NN over SHREC 2007's three kinds, as the partial distance's weight
was chosen; McGill and FAUST are reported, not used. A second table asks what each feature
would do for whole shapes in place of version 8's curvature channel: version 8's vectors
with their curvature columns replaced by the feature, weighed by version 7's rule (its median
distance over the pairs, averaged over SHREC 2007 and FAUST, is its unit, as version 8's
marginals' is), every mesh a query against the rest of its collection.

Version 9's channel (`cfsig.descriptors.intrinsic`) is chosen by version 8's rule: of the bands with an odd B
(zero curvature mid-bin, version 5's reason) that meet issue 14's bars as the whole-shape
channel on version 8's training collections (SHREC 2007 and FAUST), the one of fewest columns
(the cost of a partial query's scan) within 0.01 of the best mean NN over SHREC 2007's parts.
"""

from __future__ import annotations

import os

os.environ.update(
    dict.fromkeys(["OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS"], "1")
)

import argparse
from concurrent.futures import ProcessPoolExecutor
from dataclasses import replace
from pathlib import Path

import numpy as np
from descriptors import collection_paths
from partial import COLLECTIONS, KINDS, cut, holes, scan

from cfsig.descriptors.intrinsic import (
    DESIGNS,
    curvature_histograms,
    curvature_shape,
    weigh_curvature,
)
from cfsig.descriptors.signature import compute_signature
from cfsig.evaluation.measures import evaluate_distances, evaluate_queries
from cfsig.files.mesh import read_mesh
from cfsig.params import Params
from cfsig.repair.stage import repair_mesh
from cfsig.search.nearest import l1_distances
from cfsig.search.partial import (
    SHARES,
    curvature_columns,
    partial_scores,
    share_curvatures,
    share_queries,
)

ROOT = Path(__file__).resolve().parents[1]
# Version 8, whose curvature channel (the marginals) version 9 replaces by what this chose.
DEFAULT = Params(descriptor="cfhks", version=8)
DESIGN = DESIGNS[8]
# Version 8's training collections, on which version 9's choice meets issue 14's bars, and
# ShapeDNA's first tier on them (docs/descriptors.md, "All ten on the three collections"): the
# bars are FT at least ShapeDNA's + 0.02, and on SHREC 2007 NN at least 0.90 and FT at least 0.60.
TRAINING = ("shrec07", "faust")
SHAPEDNA_FT = {"shrec07": 0.511, "faust": 0.866}
BINS = (8, 12, 16, 24)  # B, bins per axis of the joint histograms
BANDS = (  # (B, D) of the banded joint histograms; odd B puts zero curvature mid-bin
    *((b, d) for b in (11, 13, 15, 17) for d in (2, 3)),
    (16, 3),
    (24, 4),
)


def _features(curvatures: list[tuple[np.ndarray, np.ndarray]]) -> dict[str, np.ndarray]:
    """Each feature of a surface's curvature, one row per share measured. A joint histogram
    is the band of B - 1 bins, which holds all B x B cells (and empty ones, which add nothing
    to an L1 distance)."""
    rows = {
        "marginal": [
            weigh_curvature(curvature_histograms(v, a, DESIGN.bins), DESIGN) for v, a in curvatures
        ]
    }
    for b in BINS:
        rows[f"joint {b}"] = [curvature_histograms(v, a, b, b - 1).ravel() for v, a in curvatures]
    for b, d in BANDS:
        rows[f"band {b} {d}"] = [curvature_histograms(v, a, b, d).ravel() for v, a in curvatures]
    return {name: np.array(r) for name, r in rows.items()}


def _columns(name: str) -> int:
    """The columns a row of a feature takes (`measure`'s names)."""
    match name.split():
        case ["marginal"]:
            return int(np.prod(curvature_shape(DESIGN)))
        case ["joint", b]:
            return (len(DESIGN.scales) - 1) * int(b) ** 2
        case ["band", b, d]:
            return int(np.prod(curvature_shape(replace(DESIGN, bins=int(b), band=int(d)))))
        case ["both", b]:
            return _columns("marginal") + _columns(f"joint {b}")
    raise ValueError(name)


def _one(item: tuple[Path, int]) -> dict:
    """A whole's default signature and features, and its parts' features per share."""
    path, seed = item
    rng = np.random.default_rng(seed)  # as benchmarks/partial.py draws the parts
    mesh = read_mesh(path)
    row = {
        "default": compute_signature(mesh, DEFAULT).vector,
        "whole": _features(share_curvatures(repair_mesh(mesh), DEFAULT, (1.0,))),
    }
    for kind, make in (("cut", cut), ("holes", holes), ("scan", scan)):
        row[kind] = _features(share_curvatures(make(mesh, rng), DEFAULT))
    return row


def _scores(parts: list[dict], wholes: np.ndarray, name: str) -> np.ndarray:
    """Partial distances (parts, wholes) by one feature."""
    return np.array(
        [
            partial_scores(l1_distances(share_queries(p[name]), wholes), float(p[name][0].sum()))
            for p in parts
        ]
    )


def measure(name: str, data_root: Path, jobs: int) -> dict:
    """One collection: ``"parts"``, (NN, --partial FT) of each feature and kind; ``"labels"``,
    ``"signatures"`` and ``"wholes"`` (each single feature's rows) of its meshes."""
    paths = collection_paths(data_root, name)
    labels = [p.parent.name for p in paths]
    with ProcessPoolExecutor(jobs) as pool:
        rows = list(pool.map(_one, [(p, i) for i, p in enumerate(paths)], chunksize=2))
    signatures = np.array([r["default"] for r in rows])
    whole_distances = l1_distances(signatures, signatures)
    joint = [*(f"joint {b}" for b in BINS), *(f"band {b} {d}" for b, d in BANDS)]
    names = ["marginal", *joint, *(f"both {b}" for b in BINS)]
    results: dict[str, dict[str, tuple[float, float]]] = {n: {} for n in names}
    for kind in KINDS:
        parts = [r[kind] for r in rows]
        single = {
            feature: _scores(parts, np.array([r["whole"][feature][0] for r in rows]), feature)
            for feature in ("marginal", *joint)
        }
        for n in names:
            scores = (
                single["marginal"] + single[n.replace("both", "joint")]
                if n.startswith("both")
                else single[n]
            )
            first = scores.argmin(axis=1)
            expanded = whole_distances[first]
            expanded[np.arange(len(first)), first] = -1.0
            nn = evaluate_queries(scores, labels, labels).measures["NN"]
            ft = evaluate_queries(expanded, labels, labels).measures["FT"]
            results[n][kind] = (nn, ft)
        print(name, kind, "done", flush=True)
    wholes = {f: np.array([r["whole"][f][0] for r in rows]) for f in ("marginal", *joint)}
    return {
        "parts": results,
        "labels": labels,
        "signatures": signatures,
        "wholes": wholes,
    }


def whole_measures(measured: dict[str, dict]) -> dict[str, dict[str, tuple[float, float]]]:
    """Whole-shape (NN, FT) per collection with each single feature as the curvature channel,
    and under ``"scale"`` the factor it is weighed by (version 7's rule, `TRAINING`)."""
    columns = curvature_columns(DEFAULT)
    results: dict[str, dict] = {}
    for feature in measured["shrec07"]["wholes"]:
        medians = []
        for name in TRAINING:
            rows = measured[name]["wholes"][feature]
            medians.append(np.median(l1_distances(rows, rows)[np.triu_indices(len(rows), 1)]))
        scale = 1.0 / float(np.mean(medians))
        results[feature] = {"scale": scale}
        for name in COLLECTIONS:
            data = measured[name]
            head = data["signatures"][:, : columns.start]  # the channels before the curvature
            vectors = np.hstack([head, scale * data["wholes"][feature]])
            m = evaluate_distances(l1_distances(vectors, vectors), data["labels"]).measures
            results[feature][name] = (m["NN"], m["FT"])
    return results


def meets_bars(whole: dict[str, tuple[float, float]]) -> bool:
    """Whether whole-shape measures meet issue 14's bars on `TRAINING`."""
    nn, ft = whole["shrec07"]
    return nn >= 0.90 and ft >= 0.60 and all(whole[c][1] >= SHAPEDNA_FT[c] + 0.02 for c in TRAINING)


def choose(parts: dict[str, dict], whole: dict[str, dict]) -> str:
    """Version 9's channel: of the bands with odd B that meet the bars as the whole-shape
    channel, the one of fewest columns within 0.01 of the best SHREC 2007 mean NN."""
    bands = [f"band {b} {d}" for b, d in BANDS if b % 2 and meets_bars(whole[f"band {b} {d}"])]
    top = max(_mean_nn(parts[n]) for n in bands)
    return min((n for n in bands if _mean_nn(parts[n]) >= top - 0.01), key=_columns)


def main() -> None:
    """Measure and print the Markdown tables."""
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--data-root", type=Path, default=ROOT.parent / "shared" / "data")
    parser.add_argument("--jobs", type=int, default=os.cpu_count() or 1)
    args = parser.parse_args()
    measured = {name: measure(name, args.data_root, args.jobs) for name in COLLECTIONS}
    results = {name: data["parts"] for name, data in measured.items()}
    whole = whole_measures(measured)
    best = max(results["shrec07"], key=lambda n: _mean_nn(results["shrec07"][n]))
    chosen = choose(results["shrec07"], whole)
    heads = [f"{name} {kind}" for name in COLLECTIONS for kind in KINDS]
    print(f"\nNN, then the `--partial` ranking's FT, of {len(SHARES)} shares per part:\n")
    print(f"| feature | columns a row | {' | '.join(heads)} | SHREC 2007 mean NN |")
    print("|---|" + "---|" * (len(heads) + 2))
    for n in results["shrec07"]:
        cells = [
            f"{results[c][n][k][0]:.3f} / {results[c][n][k][1]:.3f}"
            for c in COLLECTIONS
            for k in KINDS
        ]
        mean = _mean_nn(results["shrec07"][n])
        mark = " (best)" if n == best else " (version 9)" if n == chosen else ""
        print(f"| {n}{mark} | {_columns(n)} | {' | '.join(cells)} | {mean:.3f} |")
    print("\nWhole shapes, each feature in place of version 8's curvature channel:\n")
    heads = " | ".join(f"{c} NN | {c} FT" for c in COLLECTIONS)
    print(f"| curvature channel | scale | {heads} | bars |\n|---|---|" + "---|---|" * 3 + "---|")
    for feature, row in whole.items():
        cells = " | ".join(f"{row[c][0]:.3f} | {row[c][1]:.3f}" for c in COLLECTIONS)
        bars = "yes" if meets_bars(row) else "no"
        print(f"| {feature} | {row['scale']:.4f} | {cells} | {bars} |")
    print(f"\nVersion 9's curvature channel: {chosen}")


def _mean_nn(kinds: dict[str, tuple[float, float]]) -> float:
    """The mean NN over the kinds of parts."""
    return float(np.mean([kinds[k][0] for k in KINDS]))


if __name__ == "__main__":
    main()
