"""Helpers shared by the benchmark scripts: the meshes of a data folder and Markdown tables."""

from __future__ import annotations

import argparse
import json
import shlex
import statistics
import sys
from collections.abc import Sequence
from pathlib import Path


def data_arguments(parser: argparse.ArgumentParser) -> None:
    """Add ``--data FOLDER`` (required: ``<class>/<file>`` meshes) and ``--every K``."""
    parser.add_argument("--data", type=Path, required=True, help="folder of <class>/<file> meshes")
    parser.add_argument("--every", type=int, default=1, help="every k-th mesh in sorted order")


def arguments(description: str) -> argparse.ArgumentParser:
    """A parser with the data options (`data_arguments`) and ``--json``, for a script to extend."""
    parser = argparse.ArgumentParser(description=description)
    data_arguments(parser)
    parser.add_argument("--json", type=Path, help="also write every measurement here")
    return parser


def collection_parser(description: str, collections: tuple[str, ...]) -> argparse.ArgumentParser:
    """A parser of ``--data-root`` (``DATA/NAME/<class>/<file>``), ``--doc``, ``--collections``,
    ``--jobs`` and ``--every``, for the scripts that measure whole collections."""
    parser = argparse.ArgumentParser(description=description)
    parser.add_argument("--data-root", type=Path, required=True, help="DATA/NAME/<class>/<file>")
    parser.add_argument("--doc", type=Path, help="write the tables into this file")
    parser.add_argument("--collections", default=",".join(collections), help="comma-separated")
    parser.add_argument("--jobs", type=int, default=2, help="worker processes")
    parser.add_argument("--every", type=int, default=1, help="every k-th mesh (a quick look)")
    return parser


def save_rows(path: Path | None, rows: list[dict]) -> None:
    """Write the measurements as JSON when ``--json`` was given."""
    if path is not None:
        path.write_text(json.dumps(rows, indent=1))


def meshes(data: Path, every: int = 1) -> list[Path]:
    """The OFF files ``data/<class>/<file>.off``, sorted, every k-th one."""
    files = sorted(data.glob("*/*.off"))
    if not files:
        raise SystemExit(f"no meshes under {data}: expected {data}/<class>/<file>.off")
    return files[::every]


def median(values: Sequence[float]) -> float:
    """The median of a non-empty sequence."""
    return statistics.median(values)


def command(script: str) -> str:
    """The command line running, as one could type it again from the project folder."""
    return shlex.join(["python", f"benchmarks/{script}", *sys.argv[1:]])


def table(headers: Sequence[str], rows: Sequence[Sequence[object]]) -> str:
    """A Markdown table; floats with three significant digits."""

    def cell(value: object) -> str:
        return f"{value:.3g}" if isinstance(value, float) else str(value)

    lines = ["| " + " | ".join(headers) + " |", "|" + "---|" * len(headers)]
    lines += ["| " + " | ".join(map(cell, row)) + " |" for row in rows]
    return "\n".join(lines)
