"""The evaluation report: one HTML page with the measures, the precision/recall curves and the
results of one query per class, its pictures written next to it."""

from __future__ import annotations

import html
import os
import re
from collections.abc import Sequence
from pathlib import Path

import numpy as np

from cfsig.evaluation.measures import RetrievalReport
from cfsig.figures.plots import plot_precision_recall, render_grid, retrieval_row

PAGE = "index.html"
_RESULTS = 10
_TILE = 140


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
    scores = {"all": report.measures["mAP"]} | {c: m["mAP"] for c, m in report.per_class.items()}
    plot_precision_recall(
        report.class_precision_recall, report.precision_recall, folder / "precision_recall.png",
        scores,
    )  # fmt: skip
    labels = [str(label) for label in labels]
    problems: dict[str, None] = {}
    sections = []
    for number, cls in enumerate(report.per_class, 1):
        query = min((i for i, label in enumerate(labels) if label == cls),
                    key=lambda i: _natural(names[i]))  # fmt: skip
        ranking = np.argsort(distances[query], kind="stable")
        ranking = ranking[ranking != query][:_RESULTS]
        row = retrieval_row(
            (paths[query], names[query], cls),
            [(paths[j], names[j], labels[j], float(distances[query, j])) for j in ranking],
        )
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
