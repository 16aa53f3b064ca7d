"""Partial queries by joint histograms of the curvature at adjacent scales: a study (partial.md).

    python benchmarks/partial_joint.py --data-root /work/data

Makes the parts of ``benchmarks/partial.py`` (the same cuts, bodies with holes and scans, from
the same seeds) of every mesh of SHREC 2007, McGill and FAUST, and ranks the whole shapes for
each part by the partial distance (`cfsig.parts.partial_scores`: unexplained share plus L1
distance, at the best share) of features of the curvature at the default's four scales,
measured on the same surfaces (`cfsig.parts.share_curvatures`):

- ``marginal``: its histograms per scale, the index's curvature channel, what ``--partial``
  ranks by today;
- ``joint B``: the histograms of each pair of adjacent scales jointly, on B x B bins of the same
  axis (``asinh(value / CURVATURE_UNIT)`` on [-CURVATURE_RANGE, CURVATURE_RANGE]), three pairs:
  where a vertex's curvature lies at one scale and at the next, which the marginals forget;
- ``band B D``: the joint histograms with the second scale's bin taken relative to the first's
  and clipped to within D bins of it: B x (2 D + 1) cells a pair, where nearly all the mass of
  the B x B lies (adjacent scales' values are close);
- ``both B``: the marginal and the joint partial distances summed.

For each, NN per collection and kind, and the first tier of the ``--partial`` ranking (the
nearest whole first, then the others by their whole-shape distance to it). The feature and B are
chosen on SHREC 2007 alone, by the mean NN over its three kinds, as the partial distance's
weight was; McGill and FAUST are reported, not used. A second table asks what each feature
would do for whole shapes in place of the default's curvature channel: the default's vectors
with their curvature columns replaced by the feature, scaled so that its median distance over
SHREC 2007's pairs is the marginals' (so that the channel weighs what it weighs today), every
mesh a query against the rest of its collection. Nothing here is stored in an index: it
measures what such a channel would buy before it is built.
"""

from __future__ import annotations

import os

os.environ.update(
    dict.fromkeys(["OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS"], "1")
)

import argparse
from concurrent.futures import ProcessPoolExecutor
from pathlib import Path

import numpy as np
from partial import COLLECTIONS, DEFAULT, DESIGN, KINDS, cut, holes, scan

from cfsig.cfhks import CURVATURE_RANGE, CURVATURE_UNIT, curvature_histograms, weigh_curvature
from cfsig.measures import evaluate_distances, evaluate_queries
from cfsig.mesh import read_mesh
from cfsig.nearest import l1_distances
from cfsig.parts import SHARES, curvature_columns, partial_scores, share_curvatures, share_queries
from cfsig.repair import repair_mesh
from cfsig.signature import compute_signature

ROOT = Path(__file__).resolve().parents[1]
BINS = (8, 12, 16, 24)  # B, bins per axis of the joint histograms
BANDS = ((16, 3), (24, 4))  # (B, D) of the banded joint histograms


def joint_histograms(
    values: np.ndarray, areas: np.ndarray, bins: int, band: int | None = None
) -> np.ndarray:
    """The joint histograms of each pair of adjacent scales, area-weighted, each summing to 1.

    Parameters
    ----------
    values : (n, k) float64
        Curvature at k scales (`cfsig.parts.share_curvatures`).
    areas : (n,) float64
        Vertex areas.
    bins : int
        Bins per axis.
    band : int, optional
        Keep only the cells within this many bins of the diagonal, the second scale's bin
        clipped into them.

    Returns
    -------
    histograms : ((k - 1) * bins * width,) float64
        ``width`` is ``bins``, or ``2 * band + 1`` with ``band``.
    """
    position = (np.arcsinh(values / CURVATURE_UNIT) + CURVATURE_RANGE) * (
        bins / (2 * CURVATURE_RANGE)
    )
    cell = np.clip(position, 0, bins - 1).astype(np.intp)
    fractions = areas / areas.sum()
    first, second = cell[:, :-1], cell[:, 1:]
    if band is None:
        width = bins
    else:
        width = 2 * band + 1
        second = np.clip(second - first, -band, band) + band
    pairs = (first * width + second).T
    return np.concatenate(
        [np.bincount(p, weights=fractions, minlength=bins * width) for p in pairs]
    )


def _features(curvatures: list[tuple[np.ndarray, np.ndarray]]) -> dict[str, np.ndarray]:
    """Each feature of a surface's curvature, one row per share measured."""
    rows = {
        "marginal": [
            weigh_curvature(curvature_histograms(v, a, DESIGN.bins), DESIGN) for v, a in curvatures
        ]
    }
    for b in BINS:
        rows[f"joint {b}"] = [joint_histograms(v, a, b) for v, a in curvatures]
    for b, d in BANDS:
        rows[f"band {b} {d}"] = [joint_histograms(v, a, b, d) for v, a in curvatures]
    return {name: np.array(r) for name, r in rows.items()}


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
    """One collection: ``"parts"``, (NN, --partial FT) of each feature and kind; ``"columns"``,
    each feature's columns; ``"labels"``, ``"signatures"`` and ``"wholes"`` (each single
    feature's rows) of its meshes."""
    paths = sorted((data_root / name).glob("*/*.off"))
    if not paths:
        raise SystemExit(f"no meshes under {data_root / name}: ../shared/data/unpack {name}")
    labels = [p.parent.name for p in paths]
    with ProcessPoolExecutor(jobs) as pool:
        rows = list(pool.map(_one, [(p, i) for i, p in enumerate(paths)], chunksize=2))
    signatures = np.array([r["default"] for r in rows])
    whole_distances = l1_distances(signatures, signatures)
    joint = [*(f"joint {b}" for b in BINS), *(f"band {b} {d}" for b, d in BANDS)]
    names = ["marginal", *joint, *(f"both {b}" for b in BINS)]
    results: dict[str, dict[str, tuple[float, float]]] = {n: {} for n in names}
    width = {n: rows[0]["whole"][n.replace("both", "joint")].shape[1] for n in names}
    columns = {n: width[n] + (width["marginal"] if n.startswith("both") else 0) for n in names}
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
        "columns": columns,
        "labels": labels,
        "signatures": signatures,
        "wholes": wholes,
    }


def whole_table(measured: dict[str, dict]) -> list[str]:
    """NN and FT of whole shapes with each single feature as the curvature channel."""
    columns = curvature_columns(DEFAULT)
    heads = " | ".join(f"{c} NN | {c} FT" for c in COLLECTIONS)
    lines = [f"| curvature channel | scale | {heads} |", "|---|---|" + "---|---|" * 3]
    shrec = measured["shrec07"]["wholes"]
    pairs = np.triu_indices(len(shrec["marginal"]), 1)
    median = {f: np.median(l1_distances(x, x)[pairs]) for f, x in shrec.items()}
    for feature in shrec:
        scale = median["marginal"] / median[feature]
        cells = []
        for name in COLLECTIONS:
            data = measured[name]
            head = data["signatures"][:, : columns.start]  # the channels before the curvature
            vectors = np.hstack([head, scale * data["wholes"][feature]])
            m = evaluate_distances(l1_distances(vectors, vectors), data["labels"]).measures
            cells.append(f"{m['NN']:.3f} | {m['FT']:.3f}")
        lines.append(f"| {feature} | {scale:.4f} | {' | '.join(cells)} |")
    return lines


def main() -> None:
    """Measure and print the Markdown table."""
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--data-root", type=Path, default=ROOT.parent / "shared" / "data")
    parser.add_argument("--jobs", type=int, default=os.cpu_count() or 1)
    args = parser.parse_args()
    measured = {name: measure(name, args.data_root, args.jobs) for name in COLLECTIONS}
    results = {name: data["parts"] for name, data in measured.items()}
    columns = measured["shrec07"]["columns"]
    chosen = max(results["shrec07"], key=lambda n: _mean_nn(results["shrec07"][n]))
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
        mark = " (chosen)" if n == chosen else ""
        print(f"| {n}{mark} | {columns[n]} | {' | '.join(cells)} | {mean:.3f} |")
    print("\nWhole shapes, each feature in place of the default's curvature channel:\n")
    print("\n".join(whole_table(measured)))


def _mean_nn(kinds: dict[str, tuple[float, float]]) -> float:
    """The mean NN over the kinds of parts."""
    return float(np.mean([kinds[k][0] for k in KINDS]))


if __name__ == "__main__":
    main()
