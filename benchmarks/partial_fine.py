"""Partial queries by the joint histogram of all four curvature scales, on finer bins (partial.md).

    python benchmarks/partial_fine.py --data-root /work/data --doc docs/partial.md

A study, not what ``cfsig query --partial`` computes. Version 9's curvature channel
(`cfsig.descriptors.intrinsic`) holds the joint histograms of each pair of adjacent scales, 17 bins per axis:
it forgets where a vertex lies at scales two apart, and a bin is a twelfth of the curvature's
axis wide. This asks what a part gains when the whole's histogram keeps all four scales at once
(one cell per vertex's first bin and its three steps to the next scale, each clipped to within
D bins: B x (2 D + 1)^3 cells), on B bins per axis, B up to 41; and whether such a histogram
needs a finer grid of shares than `cfsig.search.partial.SHARES` (7, a factor sqrt(2) apart in area): 13,
a factor 2^(1/4) apart, of which the 7 are every other one.

It makes the parts of ``benchmarks/partial.py`` (the same cuts, bodies with holes and scans,
from the same seeds) of every mesh of SHREC 2007, McGill and FAUST, measures the curvature of
the wholes and of the parts at each share as version 9 does (`cfsig.search.partial.share_curvatures`),
and ranks the wholes for each part by the partial distance (`cfsig.search.partial.partial_scores`:
unexplained share plus L1 distance, weight 1, at the best share) of each feature. Such a
histogram has far more cells than a whole has vertices (about 2,000 on its copy), so it is
stored sparse: the partial distance needs only, per share ``f``, ``sum(min(f p, w))`` and
``sum(min(p, w))`` over the part's own cells (`_scores`). Reported per collection and kind: NN
by the partial distance, and the first tier of the ``--partial`` ranking (the nearest whole
first, then the others by their version 9 whole-shape distance to it); and per feature the
median and largest number of cells a whole occupies, which is what an index would store per
row, and where version 9's partial distance ranks the feature's nearest whole for the cuts and
bodies with holes (90th percentile and largest): how many candidates a first stage by version
9's stored channel would have to keep for the feature to find what it finds alone; and, per
indexed row, how many entries lists of the rows holding each cell would give for a part's cells
(the union over its shares; median over the cuts and holes): the work of a search that reads
such lists instead of every row; and how much of that a search pruning by bounds (MaxScore, with
the part's own smallest partial distance as its threshold: the best any such search can do)
would still read, and what share of the rows the lists it reads name, which it would then
have to score.

The ``pairs 17 2`` row is version 9's own channel through the same code, and reproduces the
``--partial`` rows of partial.md's tables. The best feature is the one with the best mean NN
over SHREC 2007's three kinds, as version 9's channel and the partial distance's weight were
chosen; McGill and FAUST are reported, not used.
"""

from __future__ import annotations

import os

os.environ.update(
    dict.fromkeys(["OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS"], "1")
)

import argparse
from collections.abc import Callable
from concurrent.futures import ProcessPoolExecutor
from pathlib import Path

import numpy as np
from descriptors import collection_paths
from partial import COLLECTIONS, KINDS, cut, holes, scan

from cfsig.descriptors.cells import cell_histogram
from cfsig.descriptors.signature import compute_signature
from cfsig.evaluation.measures import evaluate_queries
from cfsig.files.mesh import read_mesh
from cfsig.params import Params
from cfsig.repair.stage import repair_mesh
from cfsig.search.nearest import l1_distances
from cfsig.search.partial import FINE_SHARES, SHARES, share_curvatures

ROOT = Path(__file__).resolve().parents[1]
DEFAULT = Params(descriptor="cfhks", version=9)
# (name, B, D, scales jointly, shares): version 9's adjacent pairs, then all four scales on
# finer bins; odd B puts zero curvature mid-bin (version 5's reason), D grows with B to cover as
# much of the axis.
FEATURES = (
    ("pairs 17 2", 17, 2, 2, 7),
    ("four 17 2", 17, 2, 4, 7),
    ("four 25 3", 25, 3, 4, 7),
    ("four 33 4", 33, 4, 4, 7),
    ("four 33 6", 33, 6, 4, 7),
    ("four 41 5", 41, 5, 4, 7),
    ("pairs 17 2, 13 shares", 17, 2, 2, 13),
    ("four 17 2, 13 shares", 17, 2, 4, 13),
    ("four 25 3, 13 shares", 25, 3, 4, 13),
    ("four 33 4, 13 shares", 33, 4, 4, 13),
    ("four 41 5, 13 shares", 41, 5, 4, 13),
)
TITLE = "## Four scales jointly, on finer bins: a study"


def histogram(values: np.ndarray, areas: np.ndarray, feature: tuple) -> tuple:
    """A surface's sparse histogram of one feature (`cfsig.descriptors.cells.cell_histogram`)."""
    _, bins, band, joint, _ = feature
    return cell_histogram(values, areas, bins, band, joint)


def _one(item: tuple[Path, int]) -> dict:
    """A whole's version 9 signature and sparse histograms, and its parts' per share."""
    path, seed = item
    rng = np.random.default_rng(seed)  # as benchmarks/partial.py draws the parts
    mesh = read_mesh(path)
    values, areas = share_curvatures(repair_mesh(mesh), DEFAULT, (1.0,))[0]
    row = {
        "default": compute_signature(mesh, DEFAULT).vector,
        "whole": {f[0]: histogram(values, areas, f) for f in FEATURES},
    }
    for kind, make in (("cut", cut), ("holes", holes), ("scan", scan)):
        measured = share_curvatures(make(mesh, rng), DEFAULT, FINE_SHARES)
        row[kind] = {
            f[0]: [histogram(v, a, f) for v, a in (measured if f[4] == 13 else measured[::2])]
            for f in FEATURES
        }
    return row


def _dense(wholes: list[tuple]) -> tuple[np.ndarray, np.ndarray]:
    """The cells any whole occupies, ascending, and the wholes' fractions in them (wholes,
    cells)."""
    occupied = np.unique(np.concatenate([c for c, _ in wholes]))
    dense = np.zeros((len(wholes), len(occupied)), np.float64)
    for i, (c, w) in enumerate(wholes):
        dense[i, np.searchsorted(occupied, c)] = w
    return occupied, dense


def _scores(
    parts: list[list[tuple]], occupied: np.ndarray, dense: np.ndarray, shares: tuple
) -> np.ndarray:
    """Partial distances (parts, wholes): ``min_f (1 - sum(min(f p, w)) / f) + (2 - 2
    sum(min(p, w)))``, `cfsig.search.partial.partial_scores` for histograms of mass 1, from the wholes'
    histograms laid out densely (`_dense`)."""
    out = np.empty((len(parts), len(dense)))
    for i, part in enumerate(parts):
        best = np.full(len(dense), np.inf)
        for share, (c, p) in zip(shares, part, strict=True):
            at, found = _lookup(occupied, c)
            held = dense[:, at[found]]
            scaled = np.minimum(share * p[found], held).sum(axis=1)
            plain = np.minimum(p[found], held).sum(axis=1)
            best = np.minimum(best, 1 - scaled / share + 2 - 2 * plain)
        out[i] = best
    return out


def _pruned(
    part: list[tuple], shares: tuple, occupied: np.ndarray, dense: np.ndarray, best: float
) -> tuple[float, float]:
    """What a search pruning by bounds (MaxScore) would still do for a part whose smallest
    partial distance is ``best``: the entries per indexed row of the lists it must read, and
    the share of the rows they name (the candidates it must score).

    A cell ``c`` can add at most ``min(f p, m) / f + 2 min(p, m)`` to ``3 -`` a row's score at
    the share ``f``, ``m`` the largest fraction any whole holds in it. The lists of the most held
    cells are left unread as long as what they could add together leaves every row they alone
    hold above ``best`` at every share; the rest, the essential ones, must be read."""
    cells = np.unique(np.concatenate([c for c, _ in part]))
    at, found = _lookup(occupied, cells)
    cells, at = cells[found], at[found]
    fractions = np.zeros((len(cells), len(shares)))
    for j, (c, p) in enumerate(part):
        where, inside = _lookup(cells, c)
        fractions[where[inside], j] = p[inside]
    largest = dense[:, at].max(axis=0)[:, None]
    share = np.asarray(shares)
    bound = np.minimum(share * fractions, largest) / share + 2 * np.minimum(fractions, largest)
    holders = (dense[:, at] > 0).sum(axis=0)
    order = np.argsort(-holders, kind="stable")
    skippable = (3 - np.cumsum(bound[order], axis=0)).min(axis=1) > best
    essential = order[int(np.argmin(skippable)) if not skippable.all() else len(order) :]
    candidates = (dense[:, at[essential]] > 0).any(axis=1).mean()
    return float(holders[essential].sum() / len(dense)), float(candidates)


def _reads(part: list[tuple], held: np.ndarray, holders: np.ndarray) -> float:
    """How many (row, fraction) entries lists of the rows holding each cell give for a part's
    cells (over all its shares): the wholes holding each, summed."""
    at, found = _lookup(held, np.unique(np.concatenate([c for c, _ in part])))
    return float(holders[at[found]].sum())


def _lookup(table: np.ndarray, cells: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Where each cell would sit in the sorted ``table``, and whether it is there."""
    at = np.searchsorted(table, cells)
    return at, (at < len(table)) & (table[np.minimum(at, len(table) - 1)] == cells)


def measure(name: str, data_root: Path, jobs: int) -> dict:
    """One collection: per feature (NN, --partial FT) per kind, the cells a whole occupies
    (median, largest), version 9's rank of its nearest whole (90th percentile, largest) and the
    entries an inverted-list scan of the wholes would read per whole (median)."""
    paths = collection_paths(data_root, name)
    labels = [p.parent.name for p in paths]
    with ProcessPoolExecutor(jobs) as pool:
        rows = list(pool.map(_one, [(p, i) for i, p in enumerate(paths)], chunksize=2))
    signatures = np.array([r["default"] for r in rows])
    whole_distances = l1_distances(signatures, signatures)
    results: dict[str, dict] = {}
    version9: dict[str, np.ndarray] = {}  # the first feature's scores, per kind
    for feature, *_, count in FEATURES:
        shares = SHARES if count == len(SHARES) else FINE_SHARES
        wholes = [r["whole"][feature] for r in rows]
        sizes = [len(c) for c, _ in wholes]
        results[feature] = {"cells": (float(np.median(sizes)), max(sizes))}
        ranks, reads, pruned = [], [], []
        held, holders = np.unique(np.concatenate([c for c, _ in wholes]), return_counts=True)
        occupied, dense = _dense(wholes)
        for kind in KINDS:
            scores = _scores([r[kind][feature] for r in rows], occupied, dense, shares)
            first = scores.argmin(axis=1)
            base = version9.setdefault(kind, scores)
            # Where version 9's partial distance ranks this feature's nearest whole: a first
            # stage by version 9 that keeps at least this many finds it.
            at_first = base[np.arange(len(first)), first][:, None]
            if kind != "scan":  # the kinds of the bars
                ranks.append((base < at_first).sum(axis=1) + 1)
                reads += [_reads(r[kind][feature], held, holders) / len(rows) for r in rows]
                pruned += [
                    _pruned(r[kind][feature], shares, occupied, dense, float(s.min()))
                    for r, s in zip(rows, scores, strict=True)
                ]
            expanded = whole_distances[first]
            expanded[np.arange(len(first)), first] = -1.0
            nn = evaluate_queries(scores, labels, labels).measures["NN"]
            ft = evaluate_queries(expanded, labels, labels).measures["FT"]
            results[feature][kind] = (nn, ft)
        ranked = np.concatenate(ranks)
        results[feature]["rank"] = (float(np.percentile(ranked, 90)), int(ranked.max()))
        results[feature]["reads"] = float(np.median(reads))
        results[feature]["pruned"] = tuple(np.median(pruned, axis=0))
    print(name, "done", flush=True)
    return results


def table(results: dict[str, dict]) -> list[str]:
    """The Markdown table of NN / FT per feature, collection and kind."""
    heads = [f"{name} {kind}" for name in COLLECTIONS for kind in KINDS]
    first = results["shrec07"]
    best = max(first, key=lambda n: _mean_nn(first[n]))
    lines = [
        f"| feature | cells a whole (median / largest: SHREC 2007, McGill, FAUST) | its nearest "
        f"whole's rank by version 9's partial distance, cuts and holes (90th percentile / "
        f"largest) | entries an inverted-list scan reads per indexed row (median over cuts and "
        f"holes) | the same, pruned by bounds (MaxScore): entries per row, share of rows left "
        f"to score (medians) | {' | '.join(heads)} | SHREC 2007 mean NN |",
        "|---|---|---|---|---|" + "---|" * (len(heads) + 1),
    ]
    for n in first:
        counts = ", ".join("{:.0f} / {}".format(*results[c][n]["cells"]) for c in COLLECTIONS)
        ranks = ", ".join("{:.0f} / {}".format(*results[c][n]["rank"]) for c in COLLECTIONS)
        values = [
            f"{results[c][n][k][0]:.3f} / {results[c][n][k][1]:.3f}"
            for c in COLLECTIONS
            for k in KINDS
        ]
        mark = " (best)" if n == best else " (version 9)" if n == FEATURES[0][0] else ""
        reads = ", ".join(f"{results[c][n]['reads']:.0f}" for c in COLLECTIONS)
        mean = _mean_nn(first[n])
        pruned = ", ".join("{:.0f} / {:.2f}".format(*results[c][n]["pruned"]) for c in COLLECTIONS)
        cells = f"{counts} | {ranks} | {reads} | {pruned}"
        lines.append(f"| {n}{mark} | {cells} | {' | '.join(values)} | {mean:.3f} |")
    return lines


def _mean_nn(kinds: dict) -> float:
    """The mean NN over the kinds of parts."""
    return float(np.mean([kinds[k][0] for k in KINDS]))


def write_doc(doc: Path, lines: list[str], title: str = TITLE) -> None:
    """Replace the first table after the section ``title`` in ``doc``."""
    text = doc.read_text()
    start = text.index(title)
    head, _, rest = text[start:].partition("\n|")
    end = rest.find("\n\n")
    body = "\n".join(lines)
    doc.write_text(text[:start] + head + "\n" + body + rest[end:])


def run_study(
    description: str,
    measure: Callable[[str, Path, int], dict],
    table: Callable[[dict], list[str]],
    title: str = TITLE,
) -> None:
    """A study's command line: measure every collection, print the table, and write it into
    ``--doc`` after the section ``title``."""
    parser = argparse.ArgumentParser(description=description)
    parser.add_argument("--data-root", type=Path, default=ROOT.parent / "shared" / "data")
    parser.add_argument("--jobs", type=int, default=os.cpu_count() or 1)
    parser.add_argument("--doc", type=Path, help="a page holding the study's section")
    args = parser.parse_args()
    results = {name: measure(name, args.data_root, args.jobs) for name in COLLECTIONS}
    lines = table(results)
    print("\n".join(lines))
    if args.doc:
        write_doc(args.doc, lines, title)


if __name__ == "__main__":
    run_study(__doc__.splitlines()[0], measure, table)
