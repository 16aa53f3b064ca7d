"""What a user waits for at the shell: ``cfsig query INDEX PART.off --partial`` over many rows.

    python benchmarks/partial_speed.py --index-dir DIR --rows 1000000 [--repeat 5]

Builds ``DIR/rows-N``, an index of N rows with fine curvature cells
(``Params(partial_cells=True)``), unless it is already there: the demo collection
(`cfsig.files.demo.make_demo_collection`, one mesh a class: 6) is computed once; each row
holds the fine cells of one of them and a vector mixed from two of them plus noise (`build`),
a commit every 100,000 rows.

Then times the whole command ``python -m cfsig query DIR/rows-N PART.off --partial`` in a fresh
interpreter (its start, imports, the part's measurement and the search of every row included),
PART half of one demo mesh cut by a plane and re-tessellated (`world.query_mesh`),
``--repeat`` times after one warm-up, and prints the median and the range in seconds.
"""

from __future__ import annotations

import argparse
import statistics
import subprocess
import sys
import time
from dataclasses import replace
from pathlib import Path

import numpy as np
from world import query_mesh

import cfsig
from cfsig.files.demo import make_demo_collection, write_off

COMMIT_ROWS = 100_000
NOISE = 0.05  # of each coordinate's spread over the demo meshes


def build(index: Path, rows: int, demo: list[Path]) -> float:
    """Write ``rows`` rows with fine cells; the seconds taken. Each row holds the cells of one
    demo mesh and, as its vector, a random mix of two demo meshes' vectors plus noise of
    `NOISE` times each coordinate's spread over them: rows that look like real ones, not
    copies, which would tie at distance 0 and defeat the whole-shape search's pruning."""
    start = time.perf_counter()
    params = cfsig.Params(partial_cells=True)
    signatures = [cfsig.signature_file(path, params) for path in demo]
    vectors = np.array([s.vector for s in signatures])
    spread = vectors.std(axis=0)
    rng = np.random.default_rng(0)
    with cfsig.IndexWriter(index, params, cfsig.layout(params)) as writer:
        for first in range(0, rows, COMMIT_ROWS):
            count = min(COMMIT_ROWS, rows - first)
            a, b = rng.integers(0, len(vectors), (2, count))
            t = rng.random((count, 1))
            mixed = t * vectors[a] + (1 - t) * vectors[b]
            mixed += NOISE * spread * rng.standard_normal(mixed.shape)
            for j in range(count):
                label = f"class{a[j]}"
                name = f"{label}/{first + j}.off"
                row = replace(signatures[a[j]], vector=mixed[j])
                writer.add(cfsig.Entry(name, label, f"/rows/{name}"), row)
            writer.commit()
    return time.perf_counter() - start


def main() -> None:
    """Build or reuse the index, make the part, time the command."""
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--index-dir", type=Path, required=True, help="folder of the index")
    parser.add_argument("--rows", type=int, default=1_000_000, help="rows of the index")
    parser.add_argument("--repeat", type=int, default=5, help="timed commands")
    args = parser.parse_args()
    index = args.index_dir / f"rows-{args.rows}"
    demo = make_demo_collection(args.index_dir / "demo", per_class=1)
    if (index / "manifest.h5").exists():
        with cfsig.IndexReader(index) as reader:
            print(f"reusing {index}: {len(reader):,} rows")
    else:
        print(f"built {index}: {args.rows:,} rows in {build(index, args.rows, demo):.1f} s")
    part = query_mesh(cfsig.read_mesh(demo[0]), "cut", 0.5, np.random.default_rng(0))
    path = args.index_dir / "part.off"
    write_off(path, part.vertices, part.faces)
    command = [sys.executable, "-m", "cfsig", "query", str(index), str(path), "--partial"]
    times = []
    for _ in range(args.repeat + 1):  # the first is a warm-up
        start = time.perf_counter()
        subprocess.run(command, check=True, capture_output=True)
        times.append(time.perf_counter() - start)
    times = times[1:]
    print(
        f"`cfsig query INDEX PART.off --partial`, {args.rows:,} rows with fine cells, "
        f"{len(part.faces)} faces in the part: median {statistics.median(times):.3f} s "
        f"over {args.repeat} (range {min(times):.3f} to {max(times):.3f} s)"
    )


if __name__ == "__main__":
    main()
