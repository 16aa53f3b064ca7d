"""The index at scale: the time of a commit, a query, `info` and a removal against its rows.

    python benchmarks/index_scale.py --dir DIR --sizes 1000000 [--real INDEX] [--repeat 5]
        [--duplicates]

For each size N, builds ``DIR/scale-N`` (or reuses it) with `cfsig.IndexWriter`: N rows of the
default parameters, each a random mix of two signatures of the index ``--real`` (``cfsig index
DATA/shrec07 -o INDEX``) plus Gaussian noise of `NOISE` times each coordinate's standard
deviation over them, rows that look like real signatures; without ``--real``, of the six demo
meshes (`cfsig.files.demo.make_demo_collection`), too few for rows as varied as real ones, on
which the search prunes little. Written in commits of 1,000,000 rows, no merging while
building. Then measures, in this process:

- commit: open a writer, add 1,000 new rows, commit (median of ``--repeat``, merges included);
- query: open a reader, the 20 nearest rows of one new row with their names (`cfsig.query`),
  median of 3 after one warm-up;
- info: the whole command ``cfsig info INDEX``, interpreter start included (median of 5);
- remove: open a writer, remove 1,000 rows, commit (`cfsig.IndexWriter.remove`; median of
  ``--repeat``, other rows each time);
- with ``--duplicates``: the whole command ``cfsig duplicates INDEX --top 10``, once: wall
  seconds, and CPU seconds of all its threads (what a machine shared with other work inflates
  the least).
"""

from __future__ import annotations

import argparse
import resource
import statistics
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
from common import table

import cfsig
from cfsig.files.demo import make_demo_collection

PARAMS = cfsig.Params()
NOISE = 0.02
BUILD_ROWS = 1_000_000
COMMIT_ROWS = 1_000
REMOVE_ROWS = 1_000
K = 20
TOP = 10


class Rows:
    """Synthetic rows: two real signatures mixed, plus noise."""

    def __init__(self, folder: Path, real: Path | None = None) -> None:
        if real is not None:  # an index of a collection: rows as varied as real ones
            with cfsig.IndexReader(real) as reader:
                if reader.params != PARAMS:
                    sys.exit(f"{real}: not an index of the default parameters")
                self.real = reader.signatures[:].astype(np.float64)
        else:  # the six demo meshes: too few to be varied, and the search prunes little
            demo = make_demo_collection(folder, per_class=1)
            self.real = np.array([cfsig.signature_file(p, PARAMS).vector for p in demo])
        self.scale = NOISE * self.real.std(axis=0)

    def make(self, rng: np.random.Generator, n: int) -> np.ndarray:
        """n rows."""
        i, j = rng.integers(0, len(self.real), (2, n))
        t = rng.random((n, 1))
        mixed = t * self.real[i] + (1 - t) * self.real[j]
        return mixed + rng.standard_normal(mixed.shape) * self.scale

    def add(self, writer: cfsig.IndexWriter, vectors: np.ndarray, first: int) -> None:
        """Add rows numbered from ``first``."""
        for i, vector in enumerate(vectors, first):
            label = f"class{i % 50}"
            entry = cfsig.Entry(f"{label}/{i}.off", label, f"/rows/{label}/{i}.off")
            writer.add(entry, cfsig.Signature(vector, None, 1, 1, 1, 0.0, (), "clean", 0.0))


def build(path: Path, n: int, rows: Rows) -> float:
    """Write n rows in commits of `BUILD_ROWS`; the seconds taken."""
    rng, start = np.random.default_rng(0), time.perf_counter()
    with cfsig.IndexWriter(path, PARAMS, cfsig.layout(PARAMS), merge=False) as writer:
        for first in range(0, n, BUILD_ROWS):
            rows.add(writer, rows.make(rng, min(BUILD_ROWS, n - first)), first)
            writer.commit()
    return time.perf_counter() - start


def commit_seconds(path: Path, rows: Rows, repeat: int) -> list[float]:
    """Open a writer, add `COMMIT_ROWS` new rows, commit: seconds of each of ``repeat``."""
    rng, times = np.random.default_rng(1), []
    with cfsig.IndexReader(path) as reader:
        first = 10**9 + len(reader)  # names no row has
    for r in range(repeat):
        vectors = rows.make(rng, COMMIT_ROWS)
        start = time.perf_counter()
        with cfsig.IndexWriter(path, PARAMS) as writer:
            rows.add(writer, vectors, first + r * COMMIT_ROWS)
        times.append(time.perf_counter() - start)
    return times


def query_seconds(path: Path, rows: Rows) -> list[float]:
    """Open, the `K` nearest rows of a new row and their names: one warm-up, then 3."""
    query, times = rows.make(np.random.default_rng(2), 1), []
    for _ in range(4):
        start = time.perf_counter()
        with cfsig.IndexReader(path) as reader:
            hits = cfsig.query(reader, query, K)[0]
            [hit.entry.name for hit in hits]
        times.append(time.perf_counter() - start)
    return times[1:]


def command_seconds(*args: object) -> tuple[float, float]:
    """Wall and CPU seconds of the command ``python -m cfsig ARGS``, its output discarded."""
    cpu = resource.getrusage(resource.RUSAGE_CHILDREN)
    start = time.perf_counter()
    command = [sys.executable, "-m", "cfsig", *map(str, args)]
    subprocess.run(command, check=True, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    wall, after = time.perf_counter() - start, resource.getrusage(resource.RUSAGE_CHILDREN)
    return wall, after.ru_utime + after.ru_stime - cpu.ru_utime - cpu.ru_stime


def remove_seconds(path: Path, repeat: int) -> list[float]:
    """Open a writer, remove `REMOVE_ROWS` rows, commit: seconds of each of ``repeat``."""
    times = []
    with cfsig.IndexReader(path) as reader:
        names = reader.entries(
            np.arange(repeat * REMOVE_ROWS) * (len(reader) // (repeat * REMOVE_ROWS))
        )
    for r in range(repeat):
        gone = [e.name for e in names[r * REMOVE_ROWS : (r + 1) * REMOVE_ROWS]]
        start = time.perf_counter()
        with cfsig.IndexWriter(path, PARAMS) as writer:
            writer.remove(gone)
        times.append(time.perf_counter() - start)
    return times


def main() -> None:
    """Build or reuse each index, measure it, print a table."""
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--dir", type=Path, required=True, help="folder of the indexes")
    parser.add_argument("--sizes", type=int, nargs="+", default=[1_000_000], help="rows")
    parser.add_argument("--repeat", type=int, default=5, help="commits timed per index")
    parser.add_argument("--real", type=Path, help="an index of a collection to mix rows from")
    parser.add_argument("--duplicates", action="store_true", help=f"time duplicates --top {TOP}")
    args = parser.parse_args()
    rows = Rows(args.dir / "demo", args.real)
    lines = []
    for n in args.sizes:
        path = args.dir / f"scale-{n}"
        built = "reused" if (path / "manifest.h5").exists() else f"{build(path, n, rows):.0f} s"
        commits, queries = commit_seconds(path, rows, args.repeat), query_seconds(path, rows)
        infos = [command_seconds("info", path)[0] for _ in range(5)]
        removals = remove_seconds(path, args.repeat)
        top = ""
        if args.duplicates:
            wall, cpu = command_seconds("duplicates", path, "--top", TOP)
            top = f"{wall:.0f} ({cpu:.0f} CPU)"
        with cfsig.IndexReader(path) as reader:
            count = len(reader)
        lines.append(
            [f"{n:,}", f"{count:,}", built, f"{statistics.median(commits):.3f}",
             f"{max(commits):.3f}", f"{statistics.median(queries):.3f}",
             f"{statistics.median(infos):.3f}", f"{statistics.median(removals):.3f}",
             f"{max(removals):.3f}", top]
        )  # fmt: skip
        print(f"scale-{n}: done", flush=True)
    heads = ["rows", "rows now", "build", "commit of 1,000 rows s (median)", "max", "query s",
             "`cfsig info` s", "removal of 1,000 rows s (median)", "max",
             f"`duplicates --top {TOP}` s"]  # fmt: skip
    print(table(heads, lines))


if __name__ == "__main__":
    main()
