"""The index at scale: commit time against index size, query time and memory, a Dask run.

Usage: python benchmarks/index_scale.py [--sizes 10000 100000 1000000 10000000] [--dir DIR]
       [--dask-tasks 20000] [--workers 4] [--keep]

Builds synthetic indexes of random `cfhks`-length rows through `IndexWriter` (commits of
1,000,000 rows, no merging while building) in DIR (default: a temporary folder under /work),
then measures, each in a fresh process:

- commit: open a writer, add 200 new rows, commit (median and max of 5, and the seconds to open);
- a run of 100 such commits in one process, merges included (median, 95th percentile, max);
- query: open, one query, names of the top 20 (median of 3 after one warm-up) and peak memory;
- writer alone: rows per second added and committed in commits of 200 into the largest index;
- Dask: a local cluster (one thread per worker) computing a stand-in signature per task through
  `cfsig.batch.compute_many`, its outcomes added to the largest index and committed every 200,
  as `cfsig index --scheduler` does: signatures per second, and the writer's busy fraction.

Prints Markdown for docs/index-scale.md. Needs about 15 GB of disk per 10M rows; the indexes
are deleted afterwards unless --keep.
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import shutil
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from cfsig.index import Entry, IndexWriter  # noqa: E402
from cfsig.params import Params, signature_length  # noqa: E402

PARAMS = Params(descriptor="cfhks")
WIDTH = signature_length(PARAMS)
BUILD_ROWS = 1_000_000
COMMIT = 200
COMMITS = 100  # in the run of consecutive commits


def fake_signature(i: int, rng: np.random.Generator | None = None):
    """A signature of random values for row ``i`` (the Signature class loads scipy: lazily)."""
    from cfsig.signature import Signature

    vector = (rng or np.random.default_rng(i)).random(WIDTH, dtype=np.float32)
    return Signature(vector, np.zeros(1), 1, 1, 1, 0.0, (), "clean", 0.0, f"{i:064x}")


def stand_in(path: Path, params: Params, solver: str):
    """The Dask run's cheap computation: a random signature seeded by the file's number."""
    return fake_signature(int(Path(path).stem))


def entry(i: int) -> Entry:
    label = f"class{i % 50}"
    return Entry(f"{label}/{i}.off", label, f"/data/{label}/{i}.off")


def build(path: Path, n: int) -> float:
    """Write n random rows in commits of BUILD_ROWS; return the seconds taken."""
    from cfsig.signature import Signature

    rng = np.random.default_rng(0)
    phi = np.zeros(1)
    start = time.perf_counter()
    with IndexWriter(path, PARAMS, merge=False) as writer:
        for first in range(0, n, BUILD_ROWS):
            rows = rng.random((min(BUILD_ROWS, n - first), WIDTH), dtype=np.float32)
            for i, vector in enumerate(rows, first):
                writer.add(entry(i), Signature(vector, phi, 1, 1, 1, 0.0, (), "clean", 0.0, ""))
            writer.commit()
    seconds = time.perf_counter() - start
    os.sync()  # so that writing back the build does not slow the fsyncs of the commits timed
    return seconds


def in_child(code: str) -> dict:
    """Run code in a fresh interpreter; it prints one JSON object, returned with peak memory."""
    prelude = f"import sys, json, time; sys.path.insert(0, {str(ROOT)!r})\n"
    epilogue = (  # VmHWM: getrusage's maxrss would count the parent's memory before exec
        "\nhwm = [l for l in open('/proc/self/status') if l.startswith('VmHWM')][0]"
        "\nout['peak_mb'] = int(hwm.split()[1]) / 1024\n"
    )
    done = subprocess.run(
        [sys.executable, "-c", prelude + code + epilogue + "print(json.dumps(out))"],
        capture_output=True, text=True, check=True, cwd=ROOT,
    )  # fmt: skip
    return json.loads(done.stdout.strip().splitlines()[-1])


def commit_times(path: Path, first: int, repeat: int) -> dict:
    """Open a writer, add 200 new rows, commit: seconds (open, total) of each of ``repeat``."""
    code = f"""
from benchmarks.index_scale import IndexWriter, PARAMS, entry, fake_signature
import numpy as np
rng = np.random.default_rng(1)
opens, totals = [], []
for r in range({repeat}):
    rows = range({first} + r * {COMMIT}, {first} + (r + 1) * {COMMIT})
    sigs = [(entry(i), fake_signature(i, rng)) for i in rows]
    t0 = time.perf_counter()
    with IndexWriter({str(path)!r}, PARAMS) as w:
        t1 = time.perf_counter()
        for e, sig in sigs:
            w.add(e, sig)
    totals.append(time.perf_counter() - t0)
    opens.append(t1 - t0)
out = {{'open': opens, 'total': totals}}
"""
    return in_child(code)


def commit_run(path: Path, first: int, commits: int) -> dict:
    """``commits`` consecutive commits of 200 rows in one writer (merges included): seconds."""
    code = f"""
from benchmarks.index_scale import IndexWriter, PARAMS, entry, fake_signature
import numpy as np
rng = np.random.default_rng(2)
times = []
sigs = [(entry(i), fake_signature(i, rng)) for i in range({first}, {first} + {commits * COMMIT})]
t0 = time.perf_counter()
with IndexWriter({str(path)!r}, PARAMS) as w:
    for c in range({commits}):
        t = time.perf_counter()
        for e, sig in sigs[c * {COMMIT} : (c + 1) * {COMMIT}]:
            w.add(e, sig)
        w.commit()
        times.append(time.perf_counter() - t)
    segments = len(w.segments)
out = {{'times': times, 'wall': time.perf_counter() - t0, 'segments': segments}}
"""
    return in_child(code)


def query_times(path: Path) -> dict:
    """Open + one query + names of the top 20, median of 3 after a warm-up, in a fresh process."""
    code = f"""
import numpy as np
from cfsig.index import IndexReader
from cfsig.nearest import search
query = np.random.default_rng(5).random((1, {WIDTH}), dtype=np.float32)
def once():
    t = time.perf_counter()
    with IndexReader({str(path)!r}) as r:
        hits = search(r, query, 20)[0]
    return time.perf_counter() - t, len(r)
once()
runs = [once() for _ in range(3)]
out = {{'times': [t for t, _ in runs], 'rows': runs[0][1]}}
"""
    return in_child(code)


def writer_alone(path: Path, first: int, rows: int) -> float:
    """Rows per second through add + commit every 200, fed as fast as the writer takes them."""
    code = f"""
from benchmarks.index_scale import IndexWriter, PARAMS, entry, fake_signature
import numpy as np
rng = np.random.default_rng(3)
sigs = [fake_signature(i, rng) for i in range({rows})]
t = time.perf_counter()
with IndexWriter({str(path)!r}, PARAMS) as w:
    for k, sig in enumerate(sigs):
        w.add(entry({first} + k), sig)
        if w.pending >= {COMMIT}:
            w.commit()
out = {{'seconds': time.perf_counter() - t}}
"""
    return rows / in_child(code)["seconds"]


def dask_run(path: Path, first: int, tasks: int, workers: int) -> dict:
    """The stand-in computation on a local Dask cluster, its outcomes written to the index."""
    from distributed import LocalCluster

    from cfsig.batch import compute_many

    with LocalCluster(
        n_workers=workers, threads_per_worker=1, dashboard_address=None, host="127.0.0.1"
    ) as cluster:
        paths = [Path(f"/data/dask/{first + i}.off") for i in range(tasks)]
        busy, count = 0.0, 0
        start = time.perf_counter()
        with IndexWriter(path, PARAMS) as writer:
            for outcome in compute_many(paths, PARAMS, scheduler=cluster.scheduler_address,
                                        compute=stand_in):  # fmt: skip
                t = time.perf_counter()
                i = int(outcome.path.stem)
                writer.add(Entry(f"dask/{i}.off", "dask", str(outcome.path)), outcome.signature)
                count += 1
                if writer.pending >= COMMIT:
                    writer.commit()
                busy += time.perf_counter() - t
        wall = time.perf_counter() - start
    return {"rate": count / wall, "busy": busy / wall, "count": count, "wall": wall}


def sad_uint8(block: np.ndarray, query: np.ndarray) -> np.ndarray:
    """Sums of absolute differences of uint8 rows (m, w) and a query (w,) or (m, w), w = 8k.

    What an 8-bit layout with one scale for all rows and the query would scan with numpy, no
    decoding: |a - b| as max - min in uint8, then the bytes of each row summed eight at a time
    in the 16-bit lanes of uint64 words (exact for w up to 1024). A tiled query (m, w) avoids
    numpy's slower broadcasting.
    """
    diff = np.maximum(block, query)
    diff -= np.minimum(block, query)
    words = diff.view(np.uint64)
    mask = np.uint64(0x00FF00FF00FF00FF)
    lanes = (words & mask) + ((words >> np.uint64(8)) & mask)
    total = lanes.sum(axis=1)
    return sum((total >> np.uint64(s)) & np.uint64(0xFFFF) for s in (0, 16, 32, 48))


def storage_scan(rows: int = 1_000_000) -> dict[str, float]:
    """Seconds to scan ``rows`` in-memory rows with one query, per storage, on one thread.

    float32 through cfsig's L1 kernel (faiss when installed); float16 and 8-bit rows with a
    per-row scale and offset decoded to float32 piece by piece, then the same kernel (the kernels
    available from wheels, numpy and faiss, take float32 only); and 8-bit rows summed as bytes
    by `sad_uint8`, without decoding.
    """
    from cfsig.l1 import choose_kernel

    kernel = choose_kernel(rows)
    rng = np.random.default_rng(7)
    data = rng.random((rows, WIDTH), dtype=np.float32)
    query = data[:1].copy()
    low, high = data.min(axis=1, keepdims=True), data.max(axis=1, keepdims=True)
    scale = (high - low) / 255
    codes = np.round((data - low) / scale).astype(np.uint8)
    stores = {"float32": data, "float16": data.astype(np.float16), "uint8 + scale": codes}
    piece = 4096
    out = np.empty((1, piece), np.float32)
    buffer = np.empty((piece, WIDTH), np.float32)
    seconds = {}
    for name, store in stores.items():
        best = float("inf")
        for _ in range(3):
            t = time.perf_counter()
            for start in range(0, rows, piece):
                block = store[start : start + piece]
                if name == "float32":
                    rows_f = block
                else:
                    rows_f = buffer[: len(block)]
                    np.copyto(rows_f, block, casting="unsafe")
                    if name != "float16":
                        rows_f *= scale[start : start + piece]
                        rows_f += low[start : start + piece]
                kernel(query, rows_f, out[:, : len(block)])
            best = min(best, time.perf_counter() - t)
        seconds[name] = best
    padded = np.zeros((rows, -(-WIDTH // 8) * 8), np.uint8)
    padded[:, :WIDTH] = codes
    best = float("inf")
    tiled = np.tile(padded[0], (1024, 1))
    for _ in range(3):
        t = time.perf_counter()
        for start in range(0, rows, 1024):
            block = padded[start : start + 1024]
            sad_uint8(block, tiled[: len(block)])
        best = min(best, time.perf_counter() - t)
    seconds["uint8, bytes summed (numpy)"] = best
    return seconds


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument(
        "--sizes", type=int, nargs="+", default=[10_000, 100_000, 1_000_000, 10_000_000]
    )
    parser.add_argument("--dir", type=Path, default=None)
    parser.add_argument("--dask-tasks", type=int, default=20_000)
    parser.add_argument("--workers", type=int, default=4)
    parser.add_argument("--keep", action="store_true")
    args = parser.parse_args()
    folder = Path(tempfile.mkdtemp(prefix="index-scale-", dir=args.dir or "/work"))
    started = time.time()
    load = os.getloadavg()[0]
    lines = [
        "Command: `python benchmarks/index_scale.py "
        + " ".join(f"--sizes {' '.join(map(str, args.sizes))}".split())
        + f" --dask-tasks {args.dask_tasks} --workers {args.workers}`",
        "",
        f"Machine: {os.cpu_count()} cores, Python {platform.python_version()}, numpy "
        f"{np.__version__}; rows of {WIDTH} float32 (`cfhks`); load average {load:.1f} at the "
        "start.",
        "",
        "| rows | build s | index size | open writer s (median) | open + add 200 + commit s "
        "(median of 5) | (max) | writer peak MB | query s (median of 3) | query peak MB |",
        "|---|---|---|---|---|---|---|---|---|",
    ]
    results = {}
    try:
        for n in args.sizes:
            path = folder / f"i{n}"
            built = build(path, n)
            size = sum(f.stat().st_size for f in path.iterdir())
            commits = commit_times(path, 10**9, 5)
            query = query_times(path)
            results[n] = {"commits": commits, "query": query, "build": built}
            print(n, json.dumps(results[n]), flush=True)
            lines.append(
                f"| {n:,} | {built:.0f} | {size / 1e9:.2f} GB | "
                f"{statistics.median(commits['open']):.3f} | "
                f"{statistics.median(commits['total']):.3f} | {max(commits['total']):.3f} | "
                f"{commits['peak_mb']:.0f} | {statistics.median(query['times']):.3f} | "
                f"{query['peak_mb']:.0f} |"
            )
        largest = folder / f"i{max(args.sizes)}"
        run = commit_run(largest, 2 * 10**9, COMMITS)
        times = sorted(run["times"])
        alone = writer_alone(largest, 3 * 10**9, 20_000)
        dask = dask_run(largest, 4 * 10**9, args.dask_tasks, args.workers)
        scan = storage_scan()
        print(json.dumps({"run": run, "alone": alone, "dask": dask, "scan": scan}), flush=True)
        lines += [
            "",
            f"{COMMITS} consecutive commits of 200 rows into the {max(args.sizes):,}-row index, "
            f"one writer (automatic merges included): median {statistics.median(times):.3f} s, "
            f"95th percentile {times[int(0.95 * len(times))]:.3f} s, max {times[-1]:.3f} s; "
            f"{run['segments']} segments at the end.",
            "",
            f"Writer alone, add + commit every 200 rows into the {max(args.sizes):,}-row index: "
            f"{alone:,.0f} rows per second.",
            "",
            f"Dask, local cluster of {args.workers} one-thread workers, stand-in computation, "
            f"{dask['count']:,} tasks through `compute_many`, written to the "
            f"{max(args.sizes):,}-row index with a commit every 200: {dask['rate']:,.0f} "
            f"signatures per second; the writer was busy {100 * dask['busy']:.0f}% of the "
            f"time ({dask['wall']:.1f} s in all).",
            "",
            "One query over 1,000,000 rows in memory, one thread, best of 3 (the L1 kernel "
            "takes float32: compact rows are decoded piece by piece first): "
            + ", ".join(f"{k} {v:.3f} s" for k, v in scan.items())
            + ".",
            "",
            f"The run took {time.time() - started:.0f} s; load average {os.getloadavg()[0]:.1f} "
            "at the end.",
        ]
    finally:
        if not args.keep:
            shutil.rmtree(folder, ignore_errors=True)
    print("\n".join(lines))


if __name__ == "__main__":
    main()
