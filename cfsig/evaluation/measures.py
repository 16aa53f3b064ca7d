"""Retrieval measures of the Princeton Shape Benchmark and SHREC.

Every model is used as a query against all the other models (leave-one-out), which are ranked
by ascending distance. For a query whose class has ``C`` members, the ``C - 1`` other members
are relevant and the measures are (Shilane, Min, Kazhdan and Funkhouser, "The Princeton Shape
Benchmark", Shape Modeling International 2004):

- ``NN`` (nearest neighbour): 1 if the top result is relevant, else 0.
- ``FT`` (first tier): fraction of the relevant models found in the top ``C - 1`` results.
- ``ST`` (second tier): fraction of the relevant models found in the top ``2 (C - 1)``.
- ``E`` (E-measure): ``2 / (1/P + 1/R)`` with precision ``P`` and recall ``R`` in the top 32
  results (all results if there are fewer; 0 when none of them is relevant).
- ``DCG`` (discounted cumulative gain): ``G_1 + sum_{i>=2} G_i / log2(i)`` over the whole
  ranking, where ``G_i`` is 1 for a relevant result, normalised by its ideal value
  ``1 + sum_{j=2}^{C-1} 1 / log2(j)``.
- ``mAP``: average precision (mean precision at the rank of each relevant result).
- Precision/recall curve: interpolated precision at recall 0.05, 0.10, ..., 1.00, i.e. the
  maximum precision over ranks whose recall is at least that level.

Overall measures are micro averages (mean over all queries, as in PSB); per-class measures
average over the queries of one class.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field

import numpy as np

MEASURES = ("NN", "FT", "ST", "E", "DCG", "mAP")
RECALL_LEVELS = np.arange(1, 21) / 20.0
_E_DEPTH = 32


@dataclass(frozen=True)
class RetrievalReport:
    """Retrieval measures of a leave-one-out evaluation.

    Attributes
    ----------
    measures : dict[str, float]
        Mean over all evaluated queries of ``NN``, ``FT``, ``ST``, ``E``, ``DCG`` and ``mAP``.
    per_class : dict[str, dict[str, float]]
        Class name -> the same six measures averaged over that class's queries (only classes
        with at least two members).
    precision_recall : np.ndarray
        Shape (20, 2): rows ``[recall, precision]`` at recall 0.05, 0.10, ..., 1.00, the
        interpolated precision averaged over all evaluated queries.
    count : int
        Number of queries evaluated.
    class_precision_recall : dict[str, np.ndarray]
        Class name -> shape (20,): interpolated precision at recall 0.05, ..., 1.00 averaged
        over that class's queries (the classes of ``per_class``).
    per_query : np.ndarray
        Shape (q, 6): the six measures of each query, in the order of the distance matrix's
        rows; NaN for a query that was not evaluated.
    """

    measures: dict[str, float]
    per_class: dict[str, dict[str, float]]
    precision_recall: np.ndarray
    count: int
    class_precision_recall: dict[str, np.ndarray] = field(default_factory=dict)
    per_query: np.ndarray = field(default_factory=lambda: np.zeros((0, len(MEASURES))))

    def to_dict(self) -> dict:
        """Return the report as plain JSON-serialisable Python.

        Returns
        -------
        dict
            Keys ``measures`` (dict of float), ``per_class`` (dict of dict of float),
            ``precision_recall`` (list of 20 ``[recall, precision]`` pairs) and ``count``.
        """
        return {
            "measures": {k: float(v) for k, v in self.measures.items()},
            "per_class": {
                c: {k: float(v) for k, v in m.items()} for c, m in self.per_class.items()
            },
            "precision_recall": [[float(r), float(p)] for r, p in self.precision_recall],
            "count": int(self.count),
        }


def _stable_argsort(rows: np.ndarray) -> np.ndarray:
    """Row-wise argsort with ties broken by index, using the faster quicksort on tie-free rows."""
    order = np.argsort(rows, axis=1)
    ordered = np.take_along_axis(rows, order, axis=1)
    tied = (ordered[:, 1:] == ordered[:, :-1]).any(axis=1)
    if tied.any():
        order[tied] = np.argsort(rows[tied], axis=1, kind="stable")
    return order


def _class_scores(
    distances: np.ndarray, codes: np.ndarray, queries: np.ndarray, code: int
) -> tuple[np.ndarray, np.ndarray]:
    """Per-query measures (q, 6) and interpolated precision (q, 20) for one class's queries."""
    n = distances.shape[0]
    q = queries.size
    order = _stable_argsort(distances[queries])
    order = order[order != queries[:, None]].reshape(q, n - 1)  # leave the query out
    return _ranked_scores(order, codes, code)


def _ranked_scores(
    order: np.ndarray, codes: np.ndarray, code: int
) -> tuple[np.ndarray, np.ndarray]:
    """Per-query measures (q, 6) and interpolated precision (q, 20) of rankings (q, m) of
    models, the relevant ones those of class ``code``."""
    q, m = order.shape
    relevant = codes[order] == code
    nrel = int(relevant[0].sum())
    pos = np.nonzero(relevant)[1].reshape(q, nrel)  # 0-based ranks of the relevant models
    gain = 1.0 / np.log2(np.maximum(np.arange(1, m + 1), 2))  # rank 1 -> 1, i >= 2 -> 1/log2 i
    precision = np.arange(1, nrel + 1) / (pos + 1.0)
    scores = np.column_stack(
        [
            pos[:, 0] == 0,
            np.mean(pos < nrel, axis=1),
            np.mean(pos < 2 * nrel, axis=1),
            2.0 * np.sum(pos < _E_DEPTH, axis=1) / (min(_E_DEPTH, m) + nrel),
            gain[pos].sum(axis=1) / gain[:nrel].sum(),
            precision.mean(axis=1),
        ]
    ).astype(float)
    # Precision only rises at relevant ranks, so the maximum over ranks with recall >= j/20 is
    # the maximum over the k-th relevant ranks with k >= ceil(j * nrel / 20).
    best = np.maximum.accumulate(precision[:, ::-1], axis=1)[:, ::-1]
    first = -(-np.arange(1, 21) * nrel // 20) - 1
    return scores, best[:, first]


def evaluate_distances(distances: np.ndarray, labels: Sequence[str]) -> RetrievalReport:
    """Evaluate a distance matrix with the PSB/SHREC retrieval measures.

    Each model is a query against all the other models (leave-one-out: the query itself is
    removed from its own ranking). Results are ranked by ascending distance, ties broken by
    model index (stable sort), so the ranking does not depend on the diagonal. Queries whose
    class has a single member have no relevant model: they are excluded from every average and
    from ``count`` and their class is absent from ``per_class``; they still take part as
    (irrelevant) results of the other queries.

    Parameters
    ----------
    distances : np.ndarray
        Shape (n, n), float: ``distances[i, j]`` is the distance from query ``i`` to model
        ``j``. It need not be symmetric.
    labels : Sequence[str]
        Length n: class name of each model.

    Returns
    -------
    RetrievalReport
        Overall (micro-averaged) and per-class measures, the 20-point precision/recall curve and
        the number of queries evaluated.

    Raises
    ------
    ValueError
        If ``distances`` is not a square 2-D matrix, its size differs from ``len(labels)``,
        it contains NaN, or no class has at least two members.
    """
    distances = np.asarray(distances, dtype=float)
    if distances.ndim != 2 or distances.shape[0] != distances.shape[1]:
        raise ValueError(f"distances must be a square (n, n) matrix, got shape {distances.shape}")
    if len(labels) != distances.shape[0]:
        raise ValueError(
            f"distances is {distances.shape[0]}x{distances.shape[0]} but there are "
            f"{len(labels)} labels"
        )
    if np.isnan(distances).any():
        raise ValueError("distances contains NaN")
    names, codes, sizes = np.unique(
        np.asarray([str(label) for label in labels]), return_inverse=True, return_counts=True
    )
    if not (sizes >= 2).any():
        raise ValueError("no class has at least two members: nothing to retrieve")
    per_class = {
        str(names[code]): (
            np.flatnonzero(codes == code),
            *_class_scores(distances, codes, np.flatnonzero(codes == code), int(code)),
        )
        for code in np.flatnonzero(sizes >= 2)
    }
    return _report(per_class, len(distances))


def evaluate_queries(
    distances: np.ndarray, query_labels: Sequence[str], labels: Sequence[str]
) -> RetrievalReport:
    """Evaluate queries that are not in the collection, such as parts of its shapes.

    Every model of the collection is a result of every query (nothing is left out) and the
    relevant ones are the ``C`` models of the query's class; the measures are otherwise those
    of `evaluate_distances`. Queries of a class absent from the collection are left out.

    Parameters
    ----------
    distances : np.ndarray
        Shape (q, n), float: ``distances[i, j]`` from query ``i`` to model ``j``.
    query_labels : Sequence[str]
        Length q: class name of each query.
    labels : Sequence[str]
        Length n: class name of each model.

    Returns
    -------
    RetrievalReport
        As `evaluate_distances`, averaged over the queries whose class is in the collection.

    Raises
    ------
    ValueError
        If ``distances`` is not (q, n) for the labels given, contains NaN, or no query's class
        is in the collection.
    """
    distances = np.asarray(distances, dtype=float)
    if distances.shape != (len(query_labels), len(labels)):
        raise ValueError(
            f"distances must be ({len(query_labels)}, {len(labels)}) for the labels given, "
            f"got shape {distances.shape}"
        )
    if np.isnan(distances).any():
        raise ValueError("distances contains NaN")
    names, codes = np.unique(np.asarray([str(label) for label in labels]), return_inverse=True)
    asked = np.asarray([str(label) for label in query_labels])
    per_class = {
        str(name): (
            np.flatnonzero(asked == name),
            *_ranked_scores(_stable_argsort(distances[asked == name]), codes, code),
        )
        for code, name in enumerate(names)
        if (asked == name).any()
    }
    if not per_class:
        raise ValueError("no query's class is in the collection: nothing to retrieve")
    return _report(per_class, len(distances))


def _report(
    per_class: dict[str, tuple[np.ndarray, np.ndarray, np.ndarray]], queries: int
) -> RetrievalReport:
    """The report of (query rows, per-query measures, precision curves) grouped by class."""
    every = np.concatenate([scores for _, scores, _ in per_class.values()])
    precision = np.concatenate([curves for _, _, curves in per_class.values()]).mean(axis=0)
    per_query = np.full((queries, len(MEASURES)), np.nan)
    for rows, scores, _ in per_class.values():
        per_query[rows] = scores
    return RetrievalReport(
        measures=dict(zip(MEASURES, map(float, every.mean(axis=0)), strict=True)),
        per_class={
            name: dict(zip(MEASURES, map(float, scores.mean(axis=0)), strict=True))
            for name, (_, scores, _) in per_class.items()
        },
        precision_recall=np.column_stack([RECALL_LEVELS, precision]),
        count=len(every),
        class_precision_recall={
            name: curves.mean(axis=0) for name, (_, _, curves) in per_class.items()
        },
        per_query=per_query,
    )
