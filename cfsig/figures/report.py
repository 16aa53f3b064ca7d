"""The evaluation's pictures: the report, one HTML page with the measures, the precision/recall
curves and the results of one query per class, its pictures written next to it; and the
comparison of several descriptors, their curves and queries side by side."""

from __future__ import annotations

import html
import os
import re
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from cfsig.evaluation.measures import RetrievalReport
from cfsig.figures.plots import Thumb, plot_precision_recall, render_grid, retrieval_row

if TYPE_CHECKING:
    from cfsig.evaluation.collections import Evaluation

PAGE = "index.html"
_RESULTS = 10
_TILE = 140
_COMPARED, _COMPARED_TILE = 20, 100  # results per descriptor of `write_comparison`, pixels


def write_report(
    folder: str | os.PathLike,
    report: RetrievalReport,
    names: Sequence[str],
    labels: Sequence[str],
    paths: Sequence[str],
    distances: np.ndarray,
    title: str = "cfsig retrieval report",
) -> list[str]:
    """Write ``folder/index.html`` and its PNG images (referenced relatively).

    The page holds the measures overall and per class, the precision/recall curves, and for
    the first model of each class (by name, numbers in names compared as numbers, so
    ``ant/81.off`` before ``ant/100.off``) its 10 nearest other models as framed thumbnails
    (green: same class, orange: another class).

    Parameters
    ----------
    folder : str or path-like
        Output folder, created if needed; existing files of the same names are replaced.
    report : RetrievalReport
        The evaluation of ``distances`` and ``labels``.
    names, labels, paths : sequence of str
        Length n: each model's name, class and mesh file (to draw it).
    distances : (n, n) float
        The distance matrix that was evaluated.
    title : str
        Page heading.

    Returns
    -------
    problems : list of str
        ``<file>: <reason>`` for each mesh that could not be drawn (missing or unreadable);
        its tiles say so.

    Raises
    ------
    MissingDependencyError
        matplotlib is not installed.
    """
    folder = Path(folder)
    folder.mkdir(parents=True, exist_ok=True)
    plot_precision_recall({title: report}, folder / "precision_recall.png")
    labels = [str(label) for label in labels]
    problems: dict[str, None] = {}
    sections = []
    for number, cls in enumerate(report.per_class, 1):
        query = class_query(names, labels, cls)
        row, ranking = _nearest(names, labels, paths, distances, query, _RESULTS, names[query])
        image = f"query_{number:02d}.png"
        problems.update(dict.fromkeys(render_grid([row], folder / image, tile=_TILE)))
        right = sum(labels[j] == cls for j in ranking)
        sections.append(
            f"<h3>{html.escape(cls)}</h3>\n<p>Query {html.escape(names[query])}: {right} of "
            f"the {len(ranking)} nearest are {html.escape(cls)}.</p>\n"
            f'<img src="{image}" alt="results of {html.escape(names[query])}">'
        )
    page = _page(title, report, sections)
    (folder / PAGE).write_text(page, encoding="utf-8")
    return list(problems)


def write_comparison(
    folder: str | os.PathLike,
    evaluations: Mapping[str, Evaluation],
    classes: Sequence[str] | None = None,
) -> list[str]:
    """Pictures of several descriptors' evaluations of the same meshes side by side, as the
    paper's Figures 7 to 11.

    Writes ``folder/precision_recall.png``, the precision/recall curves of all queries and of
    each class, a curve per descriptor (`plot_precision_recall`), and for each class
    ``folder/query_<number>_<class>.png``: its first model by name (numbers in names compared
    as numbers) and, a row per descriptor, the nearest other models, as many as the class has
    other members (at most `_COMPARED`), framed green when of its class and orange otherwise.
    ``number`` is the class's position among the first evaluation's classes, from 01, and
    ``class`` its name with anything but letters, digits, ``.`` and ``-`` turned into ``_``.

    Parameters
    ----------
    folder : str or path-like
        Output folder, created if needed; existing files of the same names are replaced.
    evaluations : mapping of str to Evaluation
        Descriptor name -> its evaluation (`cfsig.evaluation.collections.evaluate_collections`
        of one folder: the same meshes), in the order to draw.
    classes : sequence of str, optional
        The classes to draw, in order; default: every class evaluated.

    Returns
    -------
    problems : list of str
        ``<file>: <reason>`` for each mesh that could not be drawn (missing or unreadable);
        its tiles say so.

    Raises
    ------
    MissingDependencyError
        matplotlib is not installed.
    ValueError
        The evaluations are not of the same meshes, or a class asked for was not evaluated.
    """
    folder = Path(folder)
    kept = [e.collection for e in evaluations.values()]
    if any(c.names != kept[0].names or c.labels != kept[0].labels for c in kept):
        raise ValueError("the evaluations compared must be of the same meshes")
    reports = {name: e.report for name, e in evaluations.items()}
    order = list(next(iter(reports.values())).per_class)
    chosen = order if classes is None else list(classes)
    folder.mkdir(parents=True, exist_ok=True)
    plot_precision_recall(reports, folder / "precision_recall.png", chosen)
    names, labels = kept[0].names, kept[0].labels
    problems: dict[str, None] = {}
    for cls in chosen:
        query = class_query(names, labels, cls)
        count = min(labels.count(cls) - 1, _COMPARED)
        rows = [
            _nearest(names, labels, e.collection.paths, e.distances, query, count,
                     f"{name}: {names[query]}")[0]
            for name, e in evaluations.items()
        ]  # fmt: skip
        slug = re.sub(r"[^\w.-]+", "_", cls)
        image = f"query_{order.index(cls) + 1:02d}_{slug}.png"
        problems.update(dict.fromkeys(render_grid(rows, folder / image, tile=_COMPARED_TILE)))
    return list(problems)


def class_query(names: Sequence[str], labels: Sequence[str], cls: str) -> int:
    """The query drawn for a class: its first model by name, numbers compared as numbers.

    Parameters
    ----------
    names, labels : sequence of str
        Length n: each model's name and class.
    cls : str
        A class with at least one model.

    Returns
    -------
    row : int
        The model's position.
    """
    return min((i for i, label in enumerate(labels) if label == cls),
               key=lambda i: _natural(names[i]))  # fmt: skip


def _nearest(
    names: Sequence[str],
    labels: Sequence[str],
    paths: Sequence[str],
    distances: np.ndarray,
    query: int,
    count: int,
    caption: str,
) -> tuple[list[Thumb], np.ndarray]:
    """The tiles of a query and its ``count`` nearest other models, and their rows."""
    ranking = np.argsort(distances[query], kind="stable")
    ranking = ranking[ranking != query][:count]
    row = retrieval_row(
        (paths[query], caption, labels[query]),
        [(paths[j], names[j], labels[j], float(distances[query, j])) for j in ranking],
    )
    return row, ranking


def _natural(name: str) -> list:
    """Sort key comparing the digit runs of a name as numbers."""
    return [int(part) if part.isdigit() else part for part in re.split(r"(\d+)", name)]


def _page(title: str, report: RetrievalReport, sections: list[str]) -> str:
    """The HTML text of the report."""
    keys = list(report.measures)
    head = "".join(f"<th>{k}</th>" for k in keys)
    rows = [("all", report.measures), *sorted(report.per_class.items())]
    body = "\n".join(
        f"<tr><td>{html.escape(name)}</td>" + "".join(f"<td>{m[k]:.3f}</td>" for k in keys)
        + "</tr>"
        for name, m in rows
    )  # fmt: skip
    return f"""<!DOCTYPE html>
<html lang="en">
<head>
<meta charset="utf-8">
<title>{html.escape(title)}</title>
<style>
body {{ font-family: sans-serif; margin: 2em; max-width: 1600px; }}
table {{ border-collapse: collapse; }}
td, th {{ padding: 0.2em 0.8em; text-align: right; border-bottom: 1px solid #ddd; }}
td:first-child, th:first-child {{ text-align: left; }}
tr:nth-child(2) td {{ font-weight: bold; }}
img {{ max-width: 100%; }}
</style>
</head>
<body>
<h1>{html.escape(title)}</h1>
<p>{report.count} queries, leave-one-out. NN: nearest neighbour, FT/ST: first/second tier,
E: E-measure at 32, DCG: discounted cumulative gain, mAP: mean average precision.</p>
<h2>Measures</h2>
<table>
<tr><th>class</th>{head}</tr>
{body}
</table>
<h2>Precision and recall</h2>
<img src="precision_recall.png" alt="precision/recall curves overall and per class">
<h2>One query per class</h2>
<p>The first model of each class and its {_RESULTS} nearest other models; frames: purple the
query, green the same class, orange another class.</p>
{chr(10).join(sections)}
</body>
</html>
"""
