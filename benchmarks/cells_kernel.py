"""The fine-cell kernel of this checkout against that of an earlier commit (docs/partial.md).

    python benchmarks/cells_kernel.py --against REV --real INDEX --dir DIR

The host's speed drifts by a tenth or more between runs, so a change to `cfsig.search.cells_llvm` is
judged here by a ratio in one process: the kernel's module as it was at commit REV (read with
``git show``: ``cfsig/cells_llvm.py``, or numba's ``cells_numba.py`` before it) and as it is
now, loaded side by side, take turns at the same
``cfsig query --partial`` searches (`cfsig.search.partial.query_part`), round after round, over the
synthetic index of ``benchmarks/partial.py --scale`` in DIR (``partial-fine-ROWS``, built from
INDEX, an index of SHREC 2007 of version 10: run that first). The queries are those of
``partial.py --scale``: the synthetic query, then its real parts (`partial.real_parts`). Each
kernel's first search of each query compiles or loads its code and is not counted; reported,
the median over the rounds and the median over the real parts of theirs.

    python benchmarks/cells_kernel.py --bounds --real INDEX --dir DIR

What bounds this checkout's kernel: its time per slot, one thread per core each on rows of its
own, on rows that stay in the cache (150 synthetic rows per thread, scored over and over) for
the synthetic query, for the first real part, and for a part that holds none of the rows' cells
(every slot finds the table's row 0: the arithmetic alone); then inside the kernel during the
synthetic query's search of the 1M rows, read from the page cache. The median of five rounds.
"""

from __future__ import annotations

import argparse
import importlib.util
import os
import pickle
import statistics
import subprocess
import sys
import tempfile
import threading
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(ROOT / "benchmarks"))


def load_kernel(rev: str | None, folder: Path):
    """The fine-cell kernel's module at commit ``rev`` (None: this checkout's), as a module of
    its own, written to ``folder``: ``cfsig/cells_llvm.py``, or before it ``cells_numba.py``
    (numba's, which caches its compiled code in ``folder``; the extra ``bench``)."""
    name = "kernel_before" if rev else "kernel_now"
    for stem in ("cells_llvm", "cells_numba"):
        if rev is None:
            path = ROOT / "cfsig" / f"{stem}.py"
            source = path.read_text() if path.exists() else None
        else:
            show = ["git", "-C", str(ROOT), "show", f"{rev}:cfsig/{stem}.py"]
            done = subprocess.run(show, capture_output=True, text=True)
            source = done.stdout if done.returncode == 0 else None
        if source is not None:
            break
    else:
        sys.exit(f"{rev or 'this checkout'}: no cfsig/cells_llvm.py nor cells_numba.py")
    path = folder / f"{name}.py"
    path.write_text(source)
    # A module of the package cfsig, so that its relative imports resolve: to this checkout's
    # modules (`cfsig.descriptors.cells.part_table` since commit 1270ec4), whatever REV is.
    spec = importlib.util.spec_from_file_location(f"cfsig.{name}", path)
    assert spec is not None and spec.loader is not None
    module = importlib.util.module_from_spec(spec)
    sys.modules[spec.name] = module
    spec.loader.exec_module(module)
    return module


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--against", help="a commit: its kernel's module")
    parser.add_argument("--bounds", action="store_true", help="time per slot, in and out of cache")
    parser.add_argument("--real", required=True, help="the index of SHREC 2007, version 10")
    parser.add_argument("--dir", type=Path, required=True, help="partial.py --scale's folder")
    parser.add_argument("--rows", type=int, default=1_000_000)
    parser.add_argument("--rounds", type=int, default=5)
    args = parser.parse_args()
    if args.against is None and not args.bounds:
        parser.error("--against REV, or --bounds")

    import cfsig.descriptors.cells
    import cfsig.search.cells_llvm
    from benchmarks.index_scale import synthetic_query
    from benchmarks.partial import real_parts
    from cfsig.index.store import IndexReader
    from cfsig.search.partial import Part, query_part

    index = args.dir / f"partial-fine-{args.rows}"
    if not (index / "manifest.h5").exists():
        sys.exit(f"{index}: no synthetic index; build it with benchmarks/partial.py --scale")
    with IndexReader(args.real) as reader:
        cells = reader.cells()
    if cells is None:
        sys.exit(f"{args.real}: not an index of version 10")
    synthetic = Part(cells=synthetic_query(cells))
    with tempfile.TemporaryDirectory() as scratch:
        parts_file = Path(scratch) / "parts.pickle"
        real_parts(args.real, parts_file)
        queries = [
            ("synthetic query", synthetic),
            *enumerate(pickle.loads(parts_file.read_bytes())),
        ]
        if args.bounds:
            bounds(cells, [part for _, part in queries[:2]], index, args.rounds)
            return
        kernels = {
            f"at {args.against}": load_kernel(args.against, Path(scratch)),
            "now": load_kernel(None, Path(scratch)),
        }
        times = {(k, i): [] for k in kernels for i, _ in enumerate(queries)}

        cfsig.descriptors.cells.FAST_MIN_ROWS = 0  # the compiled kernel at any size

        def search(kernel, part) -> float:
            cfsig.search.cells_llvm.part_scorer = kernel.part_scorer
            start = time.perf_counter()
            with IndexReader(index) as reader:
                query_part(reader, part, 20)
            return time.perf_counter() - start

        for round_ in range(args.rounds + 1):
            for i, (_, part) in enumerate(queries):
                for name, kernel in kernels.items():
                    took = search(kernel, part)
                    if round_:
                        times[(name, i)].append(took)
    print(f"{args.rows:,} rows, {args.rounds} rounds, load average {os.getloadavg()[0]:.1f}:")
    for name in kernels:
        synthetic_time = statistics.median(times[(name, 0)])
        real = [statistics.median(times[(name, i)]) for i in range(1, len(queries))]
        print(
            f"- kernel {name}: synthetic query {synthetic_time:.3f} s; real parts "
            f"{statistics.median(real):.3f} s ({min(real):.3f} to {max(real):.3f})"
        )
    before, now = kernels
    for label, picked in (("synthetic query", [0]), ("real parts", range(1, len(queries)))):
        ratios = [
            statistics.median(times[(now, i)]) / statistics.median(times[(before, i)])
            for i in picked
        ]
        print(f"- now / {before}, {label}: {statistics.median(ratios):.3f}")


def bounds(real, queries, index: Path, rounds: int) -> None:
    """Print the kernel's time per slot in the cache and from ``index`` (module docstring);
    ``queries``: the synthetic query and a real part."""
    import numpy as np

    from benchmarks.index_scale import synthetic_cells
    from cfsig.search.partial import FINE_SHARES

    threads, rows = len(os.sched_getaffinity(0)), 150
    held = synthetic_cells(np.random.default_rng(1), threads * rows, real)
    stacked = np.stack([c for c, _ in held]), np.stack([f for _, f in held])
    blocks = [tuple(a[t * rows : (t + 1) * rows] for a in stacked) for t in range(threads)]
    nothing = tuple((np.array([65_535]), np.array([1.0])) for _ in FINE_SHARES)
    cases = {
        f"in the cache, {name} ({len(np.unique(np.concatenate([c for c, _ in part])))} cells)": part
        for name, part in (("synthetic query", queries[0].cells), ("a real part", queries[1].cells))
    }
    cases["in the cache, a part holding none of the rows' cells"] = nothing
    per_slot: dict[str, list[float]] = {name: [] for name in [*cases, "from the 1M rows"]}
    for _ in range(rounds + 1):  # the first round compiles or loads the kernel
        for name, part in cases.items():
            per_slot[name].append(_in_cache(part, blocks))
        per_slot["from the 1M rows"].append(_from_index(queries[0].cells, index))
    print(f"{threads} threads, {rounds} rounds, load average {os.getloadavg()[0]:.1f}:")
    for name, values in per_slot.items():
        print(f"- {name}: {statistics.median(values[1:]) * 1e9:.3f} ns a slot")


def _in_cache(part, blocks, repeats: int = 1000) -> float:
    """Seconds a slot of the kernel for ``part``, one thread per block, each scoring its block
    ``repeats`` times: the median over the threads."""
    from cfsig.search import cells_llvm
    from cfsig.search.nearest import parallel
    from cfsig.search.partial import FINE_SHARES

    score = cells_llvm.part_scorer(part, FINE_SHARES)
    took: list[float] = []

    def work(block, _buffer, lock) -> None:
        start = time.perf_counter()
        for _ in range(repeats):
            score(*block)
        with lock:
            took.append((time.perf_counter() - start) / (repeats * block[0].size))

    parallel(blocks, work, lambda: None)
    return statistics.median(took)


def _from_index(part, index: Path) -> float:
    """Seconds a slot spent in the kernel during ``cfsig query --partial``'s search of
    ``index``: the median over the threads."""
    from cfsig.index.store import IndexReader
    from cfsig.search import cells_llvm
    from cfsig.search.partial import Part, query_part

    spent: dict[int, list[float]] = {}
    made = cells_llvm.part_scorer

    def timed(part, shares):
        score = made(part, shares)

        def scorer(cells, fractions):
            start = time.perf_counter()
            out = score(cells, fractions)
            mine = spent.setdefault(threading.get_ident(), [0.0, 0])
            mine[0] += time.perf_counter() - start
            mine[1] += cells.size
            return out

        return scorer

    cells_llvm.part_scorer = timed
    try:
        with IndexReader(index) as reader:
            query_part(reader, Part(cells=part), 20)
    finally:
        cells_llvm.part_scorer = made
    return statistics.median(seconds / slots for seconds, slots in spent.values())


if __name__ == "__main__":
    main()
