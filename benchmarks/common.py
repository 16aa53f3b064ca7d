"""Helpers shared by the benchmark scripts: the data set, medians and Markdown tables."""

from __future__ import annotations

import argparse
import json
import statistics
import subprocess
import time
from collections.abc import Callable, Sequence
from pathlib import Path

THREAD_VARS = ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS")
DEFAULT_DATA = Path(__file__).resolve().parents[2] / "shared" / "data" / "shrec07"
VERTEX_BINS = (0, 2_000, 5_000, 10_000, 20_000)


def data_arguments(parser: argparse.ArgumentParser) -> None:
    """Add the options that choose the meshes: a folder and a deterministic subset."""
    parser.add_argument("--data", type=Path, default=DEFAULT_DATA, help="SHREC07 folder")
    parser.add_argument(
        "--every", type=int, default=1, help="take every k-th mesh in sorted order (default all)"
    )


def arguments(description: str) -> argparse.ArgumentParser:
    """A parser with the data options (`data_arguments`) and ``--json``, for a script to extend."""
    parser = argparse.ArgumentParser(description=description)
    data_arguments(parser)
    parser.add_argument("--json", type=Path, help="also write every measurement here")
    return parser


def save_rows(path: Path | None, rows: list[dict]) -> None:
    """Write the measurements as JSON when ``--json`` was given."""
    if path is not None:
        path.write_text(json.dumps(rows, indent=1))


def meshes(args: argparse.Namespace) -> list[Path]:
    """The OFF files of the data folder, sorted by class then number, every k-th one."""
    files = sorted(args.data.glob("*/*.off"), key=lambda p: (p.parent.name, int(p.stem)))
    if not files:
        raise SystemExit(f"no meshes under {args.data} (unpack SHREC07 or pass --data)")
    return files[:: args.every]


def median(values: Sequence[float]) -> float:
    """The median of a non-empty sequence."""
    return statistics.median(values)


def vertex_bin(n: int) -> tuple[int, str]:
    """The vertex-count bin that holds n: its lower edge (to sort by) and its label."""
    lows = [low for low in VERTEX_BINS if low <= n]
    low = lows[-1]
    following = VERTEX_BINS[len(lows)] if len(lows) < len(VERTEX_BINS) else None
    return low, f"{low // 1000}k+" if following is None else f"{low // 1000}-{following // 1000}k"


def table(headers: Sequence[str], rows: Sequence[Sequence[object]]) -> str:
    """A Markdown table; floats with three significant digits."""

    def cell(value: object) -> str:
        return f"{value:.3g}" if isinstance(value, float) else str(value)

    lines = ["| " + " | ".join(headers) + " |", "|" + "---|" * len(headers)]
    lines += ["| " + " | ".join(map(cell, row)) + " |" for row in rows]
    return "\n".join(lines)


def timed(func: Callable[[], object]) -> tuple[object, float, float]:
    """Run ``func`` once: its result, CPU seconds and wall seconds."""
    cpu, wall = time.process_time(), time.perf_counter()
    result = func()
    return result, time.process_time() - cpu, time.perf_counter() - wall


def study_parser(description: str) -> argparse.ArgumentParser:
    """A parser for a study of the collections that ``../shared/data/unpack`` puts under
    ``--data-root``: with ``--jobs``, ``--doc`` and ``--every``, for a script to extend."""
    parser = argparse.ArgumentParser(description=description)
    parser.add_argument("--data-root", type=Path, default=DEFAULT_DATA.parent)
    parser.add_argument("--jobs", type=int, default=2, help="worker processes")
    parser.add_argument("--doc", type=Path, help="write the results into this Markdown file")
    parser.add_argument("--every", type=int, default=1, help="every k-th mesh (a quick look)")
    return parser


def head_commit() -> str:
    """The short hash of the checkout's HEAD: the commit a doc's figures were measured on."""
    root = Path(__file__).resolve().parents[1]
    git = ["git", "rev-parse", "--short", "HEAD"]
    return subprocess.run(git, cwd=root, capture_output=True, text=True).stdout.strip()


def report_measured(args: argparse.Namespace, script: str, marker: str, lines: list[str]) -> None:
    """Print ``lines`` under a line naming the commit and the command (``script`` with the
    `study_parser` options ``args``) that measured them, and write them into ``args.doc``, if
    given, in place of what follows ``marker``: the prose before it is kept (all of a file that
    holds no marker yet)."""
    every = f" --every {args.every}" if args.every > 1 else ""
    doc = f" --doc {args.doc}" if args.doc else ""
    command = f"python benchmarks/{script} --data-root {args.data_root}{every}{doc}"
    text = "\n".join([f"Measured on commit {head_commit()} by `{command}`.", "", *lines])
    print(text)
    if args.doc:
        head = args.doc.read_text().split(marker)[0] if args.doc.exists() else ""
        args.doc.write_text(f"{head}{marker}\n\n{text}\n")
