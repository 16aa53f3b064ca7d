"""A first stage for version 10's partial queries: which cheap score keeps its answer (partial.md).

    python benchmarks/partial_stage.py --data-root /work/data --doc docs/partial.md

A study, not what ``cfsig query --partial`` computes. Version 10 ranks the wholes for a part by
`cfsig.descriptors.cells.cell_scores`, which reads every stored cell of every row: 106.7 s over 1M rows
(partial.md, "Scale"). A search within 1 s would score every row by something far cheaper, keep
the first few, and rescore only those by the cells. This measures, for the parts of
``benchmarks/partial.py`` (the same cuts and bodies with holes, from the same seeds) of every
mesh of SHREC 2007, McGill and FAUST, where each candidate first score ranks version 10's own
nearest whole: the share of the parts for which it lies among the candidate's first 5%, 10% and
20% of the collection (what a second stage given that many rows would still find), its median
and largest rank, and the candidate's own NN.

The candidates are similarities to be maximised over the 13 shares of `cfsig.search.partial.FINE_SHARES`,
each an inner product, so that a dense one is a matrix product over the rows (BLAS):

- ``Bhattacharyya``: ``sum(sqrt(p w))`` over the cells, the part's histogram ``p`` at a share and
  a whole's ``w``; on all of a whole's stored cells (a sparse product reading every stored cell,
  as version 10 does), or on only its 64 or 128 largest;
- the same on coarser cells, summed from the fine ones: the first scale's 33 bins and the step
  to the second (297 cells); half as many first bins and the steps to the second and third
  (1,377);
- the same on a random projection of ``sqrt(w)`` to 512 dimensions (Gaussian, fixed seed),
  which needs no choice made on a collection.

"Values a row" is what each stores per indexed row, and so what it reads per row of a query.
"""

from __future__ import annotations

import os

os.environ.update(
    dict.fromkeys(["OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS"], "1")
)

from collections.abc import Callable
from concurrent.futures import ProcessPoolExecutor
from pathlib import Path

import numpy as np
import scipy.sparse as sp
from descriptors import collection_paths
from partial import FINE, cut, holes
from partial_fine import run_study

from cfsig.descriptors.cells import cell_scores
from cfsig.descriptors.intrinsic import DESIGNS
from cfsig.descriptors.signature import compute_signature
from cfsig.files.mesh import read_mesh
from cfsig.search.partial import FINE_SHARES, measure_part

TITLE = "## A first stage for version 10: a study"
KINDS = ("cut", "holes")
BINS, BAND = DESIGNS[FINE.version or 0].fine or (0, 0)  # version 10's: 33 bins, steps within 4
WIDTH = 2 * BAND + 1
CELLS = (
    BINS * WIDTH**3
)  # its four scales: the first's bin and three steps (cfsig.descriptors.cells)
KEPT = (0.05, 0.10, 0.20)


def _one(item: tuple[Path, int]) -> dict:
    """A whole's version 10 cells, and its cut's and body with holes' cells at each share."""
    path, seed = item
    rng = np.random.default_rng(seed)  # partial.py's seed: it makes its cut, then its holes
    mesh = read_mesh(path)
    whole = compute_signature(mesh, FINE)
    assert whole.cells is not None  # version 10 keeps them
    row: dict = {"cells": whole.cells}
    for kind, make in (("cut", cut), ("holes", holes)):
        part = measure_part(make(mesh, rng), FINE)
        assert part.cells is not None
        row[kind] = part.cells
    return row


def _dense(cells: np.ndarray, fractions: np.ndarray) -> np.ndarray:
    """A sparse cell histogram as a (CELLS,) vector."""
    out = np.zeros(CELLS)
    np.add.at(out, np.asarray(cells, np.int64), fractions)
    return out


def _largest(wholes: np.ndarray, count: int) -> np.ndarray:
    """Each whole's histogram with only its ``count`` largest cells."""
    top = np.argsort(-wholes, axis=1)[:, :count]
    out = np.zeros_like(wholes)
    np.put_along_axis(out, top, np.take_along_axis(wholes, top, 1), 1)
    return out


def _coarse(levels: Callable[[np.ndarray], np.ndarray]) -> sp.csr_matrix:
    """The (CELLS, coarse cells) 0/1 matrix summing fine cells into coarser ones."""
    cell = np.arange(CELLS)
    first, steps = cell // WIDTH**3, [(cell // WIDTH**k) % WIDTH for k in (2, 1, 0)]
    coarse = levels(np.stack([first, *steps]))
    return sp.csr_matrix((np.ones(CELLS), (cell, coarse)))


def _summed(into: sp.csr_matrix) -> Callable[[np.ndarray], np.ndarray]:
    """The square roots of (n, CELLS) histograms summed into coarser cells."""
    return lambda h: np.sqrt(np.asarray(into.T @ h.T).T)


# Each first score: what it stores per indexed row, and how many of a whole's largest cells it
# keeps (None: all it stores).
CANDIDATES: dict[str, tuple[str, int | None]] = {
    "Bhattacharyya, all stored cells": ("up to 1,024 cells", None),
    "Bhattacharyya, 128 largest cells": ("128 cells", 128),
    "Bhattacharyya, 64 largest cells": ("64 cells", 64),
    "first bin and one step (297 cells)": ("297 numbers", None),
    "half the first bins, two steps (1,377 cells)": ("1,377 numbers", None),
    "random projection to 512": ("512 numbers", None),
}


def _embeddings() -> dict[str, Callable[[np.ndarray], np.ndarray]]:
    """Each first score's map from (n, CELLS) histograms to the vectors whose inner products it
    takes (square roots included)."""
    first_step = _coarse(lambda c: c[0] * WIDTH + c[1])
    two_steps = _coarse(lambda c: ((c[0] // 2) * WIDTH + c[1]) * WIDTH + c[2])
    projection = np.random.default_rng(0).standard_normal((CELLS, 512)) / np.sqrt(512)
    embeddings = [np.sqrt] * 3 + [_summed(first_step), _summed(two_steps)]
    embeddings.append(lambda h: np.sqrt(h) @ projection)
    return dict(zip(CANDIDATES, embeddings, strict=True))


def measure(name: str, data_root: Path, jobs: int) -> dict[str, dict[str, tuple]]:
    """Per kind of part and first score: the ranks of version 10's nearest whole by the first
    score, the first score's NN, and the collection's size."""
    paths = collection_paths(data_root, name)
    with ProcessPoolExecutor(jobs) as pool:
        rows = list(pool.map(_one, [(p, i) for i, p in enumerate(paths)], chunksize=2))
    labels = np.array([p.parent.name for p in paths])
    stored = np.array([r["cells"][0] for r in rows]), np.array([r["cells"][1] for r in rows])
    wholes = np.array([_dense(*r["cells"]) for r in rows])
    scores = _embeddings()
    embedded = {
        title: embed(wholes if keep is None else _largest(wholes, keep))
        for (title, embed), (_, keep) in zip(scores.items(), CANDIDATES.values(), strict=True)
    }
    out: dict[str, dict[str, tuple]] = {}
    for kind in KINDS:
        best = np.array([cell_scores(r[kind], FINE_SHARES, *stored).argmin() for r in rows])
        found: dict[str, list[np.ndarray]] = {title: [] for title in scores}
        for r in rows:
            part = np.array([_dense(*share) for share in r[kind]])  # (shares, CELLS)
            for title, embed in scores.items():
                found[title].append((embed(part) @ embedded[title].T).max(axis=0))
        out[kind] = {}
        for title, rows_scores in found.items():
            similarity = np.array(rows_scores)
            at_best = similarity[np.arange(len(best)), best][:, None]
            rank = (similarity > at_best).sum(axis=1) + 1
            nn = float(np.mean(labels[similarity.argmax(axis=1)] == labels))
            out[kind][title] = (rank, nn, len(paths))
    return out


def table(results: dict[str, dict[str, dict[str, tuple]]]) -> list[str]:
    """The Markdown table: a row per candidate, a column group per collection and kind."""
    lines = [
        "| first score | values a row | "
        + " | ".join(f"{name} {kind}" for name in results for kind in KINDS)
        + " |",
        "|---|---|" + "---|" * (len(results) * len(KINDS)),
    ]
    for title, (values, _) in CANDIDATES.items():
        cells = []
        for data in results.values():
            for kind in KINDS:
                rank, nn, n = data[kind][title]
                shares = " / ".join(f"{np.mean(rank <= np.ceil(k * n)):.2f}" for k in KEPT)
                cells.append(f"{shares}; {np.median(rank):.0f} ({rank.max()}); NN {nn:.2f}")
        lines.append(f"| {title} | {values} | " + " | ".join(cells) + " |")
    return lines


if __name__ == "__main__":
    run_study(__doc__.splitlines()[0], measure, table, TITLE)
