"""What a user waits for at the shell: ``cfsig query INDEX PART.off --partial`` over many rows.

    python benchmarks/partial_speed.py --index-dir DIR --rows 1000000 [--real INDEX] [--repeat 5]

Builds ``DIR/rows-N``, an index of N rows with fine curvature cells
(``Params(partial_cells=True)``), unless it is already there, from some wholes: those of the
index ``--real`` (``cfsig index DATA/shrec07 -o INDEX --partial-cells``), whose cells are as
many as real meshes have (about 700 a row on SHREC 2007); without it, the demo collection
(`cfsig.files.demo.make_demo_collection`, one mesh a class: 6, about 240 cells a row), computed
once. Each row holds the fine cells of one whole, their shares jittered by a unit, and a vector
mixed from two of them plus noise (`build`), a commit every 100,000 rows.

Then times the whole command ``python -m cfsig query DIR/rows-N PART.off --partial`` in a fresh
interpreter (its start, imports, the part's measurement and the search of every row included),
with cfsig's modules compiled to bytecode first, as an installed package has them, PART half of
the first whole cut by a plane and re-tessellated (`world.query_mesh`), ``--repeat`` times after
one warm-up, and prints the median and the range in seconds.
"""

from __future__ import annotations

import argparse
import compileall
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
PARAMS = cfsig.Params(partial_cells=True)
NOISE = 0.05  # of each coordinate's spread over the demo meshes


def wholes(real: Path | None, folder: Path) -> tuple[list[Path], list[cfsig.Signature]]:
    """The wholes the rows are made from: their files and signatures with fine cells, those of
    the index ``real`` or else of the demo collection, made in ``folder``."""
    if real is None:
        demo = make_demo_collection(folder / "demo", per_class=1)
        return demo, [cfsig.signature_file(path, PARAMS) for path in demo]
    with cfsig.IndexReader(real) as reader:
        if reader.params != PARAMS:
            sys.exit(f"{real}: not an index of the default parameters with --partial-cells")
        vectors, (cells, units) = reader.signatures[:], reader.cells()
        paths = [Path(p) for p in reader.column("paths")]
    stored = cfsig.Signature(
        vector=vectors[0], phi=None, n_vertices=0, n_faces=0, n_components=1,
        curvature_error=0.0, repairs=(), route="clean", seconds=0.0,
    )  # fmt: skip
    made = [
        replace(stored, vector=v.astype(np.float64), cells=(c, u))
        for v, c, u in zip(vectors, cells, units, strict=True)
    ]
    return paths, made


def jittered(
    cells: tuple[np.ndarray, np.ndarray], rng: np.random.Generator
) -> tuple[np.ndarray, np.ndarray]:
    """A whole's fine cells with each share lowered by 0 or 1 unit (of 65,000), kept at least
    1 (never raised: a row's units must still sum below 2^16): the rows of one whole score
    apart, as rows of distinct wholes do."""
    held, units = cells
    lowered = units.astype(np.int64) - rng.integers(0, 2, units.shape)
    return held, np.maximum(lowered, units > 0).astype(np.uint16)


def build(index: Path, rows: int, signatures: list[cfsig.Signature]) -> float:
    """Write ``rows`` rows with fine cells; the seconds taken. Each row holds the cells of one
    whole, their shares `jittered`, and, as its vector, a random mix of two wholes' vectors plus
    noise of `NOISE` times each coordinate's spread over them: rows that look like real ones,
    not copies, which would tie at distance 0, defeat the whole-shape search's pruning and put
    a query's nearest rows all among the first copies."""
    start = time.perf_counter()
    vectors = np.array([s.vector for s in signatures])
    cells = [s.cells for s in signatures]
    spread = vectors.std(axis=0)
    rng = np.random.default_rng(0)
    with cfsig.IndexWriter(index, PARAMS, cfsig.layout(PARAMS)) as writer:
        for first in range(0, rows, COMMIT_ROWS):
            count = min(COMMIT_ROWS, rows - first)
            a, b = rng.integers(0, len(vectors), (2, count))
            t = rng.random((count, 1))
            mixed = t * vectors[a] + (1 - t) * vectors[b]
            mixed += NOISE * spread * rng.standard_normal(mixed.shape)
            for j in range(count):
                label = f"class{a[j]}"
                name = f"{label}/{first + j}.off"
                row = replace(signatures[a[j]], vector=mixed[j], cells=jittered(cells[a[j]], rng))
                writer.add(cfsig.Entry(name, label, f"/rows/{name}"), row)
            writer.commit()
    return time.perf_counter() - start


def main() -> None:
    """Build or reuse the index, make the part, time the command."""
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--index-dir", type=Path, required=True, help="folder of the index")
    parser.add_argument("--rows", type=int, default=1_000_000, help="rows of the index")
    parser.add_argument("--real", type=Path, help="an index with fine cells to make rows from")
    parser.add_argument("--repeat", type=int, default=5, help="timed commands")
    args = parser.parse_args()
    index = args.index_dir / f"rows-{args.rows}"
    paths, signatures = wholes(args.real, args.index_dir)
    if (index / "manifest.h5").exists():
        with cfsig.IndexReader(index) as reader:
            print(f"reusing {index}: {len(reader):,} rows")
    else:
        seconds = build(index, args.rows, signatures)
        print(f"built {index}: {args.rows:,} rows in {seconds:.1f} s")
    part = query_mesh(cfsig.read_mesh(paths[0]), "cut", 0.5, np.random.default_rng(0))
    path = args.index_dir / "part.off"
    write_off(path, part.vertices, part.faces)
    # Bytecode, as pip leaves an installed package: an interpreter that may not write it
    # (PYTHONDONTWRITEBYTECODE) would otherwise compile cfsig's modules at every start.
    compileall.compile_dir(Path(cfsig.__file__).parent, quiet=1)
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
