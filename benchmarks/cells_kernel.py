"""The compiled fine-cell kernel's two loops, AVX2 and portable, on real rows held in memory.

    python benchmarks/cells_kernel.py --index INDEX --part PART.off [--rows 300000] [--repeat 5]

INDEX has fine cells (``cfsig index ... --partial-cells``, or ``partial_speed.py``'s rows);
PART is measured with its parameters. The first ``--rows`` rows' cells are read into memory and
scored by each loop (`cfsig.search.cells_compiled.part_scorer`), in blocks of 4,096 rows on one
thread and on two, the loops taking turns; prints each loop's median seconds per million rows,
after checking that both give the same scores.
"""

from __future__ import annotations

import argparse
import statistics
import sys
import time
from collections.abc import Callable
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path

import numpy as np

import cfsig
from cfsig.descriptors.parts import FINE_SHARES

BLOCK = 4096


def seconds_per_million(
    score: Callable[[np.ndarray, np.ndarray], np.ndarray],
    cells: np.ndarray,
    units: np.ndarray,
    threads: int,
) -> float:
    """Wall time of scoring every row, block by block on ``threads`` threads, per 1M rows."""
    starts = range(0, len(cells), BLOCK)
    start = time.perf_counter()
    with ThreadPoolExecutor(threads) as pool:
        list(pool.map(lambda i: score(cells[i : i + BLOCK], units[i : i + BLOCK]), starts))
    return (time.perf_counter() - start) * 1e6 / len(cells)


def main() -> None:
    """Read the rows, check the loops agree, time them."""
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--index", type=Path, required=True, help="an index with fine cells")
    parser.add_argument("--part", type=Path, required=True, help="a part's mesh file")
    parser.add_argument("--rows", type=int, default=300_000, help="rows scored")
    parser.add_argument("--repeat", type=int, default=5, help="timed passes")
    args = parser.parse_args()
    try:
        from cfsig.search import cells_compiled
    except ImportError:
        sys.exit("cfsig's kernel was not compiled: install cfsig with a C compiler")
    with cfsig.IndexReader(args.index) as reader:
        part = cfsig.partial_file(args.part, reader.params)
        if part.cells is None:
            sys.exit(f"{args.index}: not an index with fine cells (--partial-cells)")
        cells, units = (d[: args.rows] for d in reader.segments[0].cells or ())
    loops = {"portable": False, **({"AVX2": True} if cells_compiled.AVX2 else {})}
    scorers = {
        n: cells_compiled.part_scorer(part.cells, FINE_SHARES, avx2=a) for n, a in loops.items()
    }
    scores = [score(cells, units) for score in scorers.values()]
    if not all(np.array_equal(scores[0], s) for s in scores):
        sys.exit("the loops' scores differ")
    print(
        f"{len(cells):,} rows, {int(np.count_nonzero(cells[:, 1:]) / len(cells)) + 1} cells a row"
    )
    for threads in (1, 2):
        times: dict[str, list[float]] = {name: [] for name in scorers}
        for _ in range(args.repeat):  # the loops interleaved, against the machine's drift
            for name, score in scorers.items():
                times[name].append(seconds_per_million(score, cells, units, threads))
        for name, taken in times.items():
            print(f"{name} loop, {threads} thread(s): {statistics.median(taken):.3f} s per 1M rows")


if __name__ == "__main__":
    main()
