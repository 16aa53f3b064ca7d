"""The index at scale: commit time against index size, query time and memory, a Dask run.

Usage: python benchmarks/index_scale.py --real INDEX [--sizes 1000000 10000000]
       [--random-sizes 1000000] [--dir DIR] [--dask-files 100000] [--workers 4] [--keep]

Builds synthetic indexes through `IndexWriter` (commits of 1,000,000 rows, no merging while
building) in DIR (default: a temporary folder under /work), of two kinds of `cfhks`-length rows:

- "mixed" (``--sizes``): each row a random convex combination of two rows of a real index
  (``--real``, e.g. `cfsig index` over SHREC07) plus Gaussian noise of `NOISE` times each
  coordinate's standard deviation over the real rows: rows that look like real signatures;
- "random" (``--random-sizes``): uniform random values, the worst case of any pruning.

Then measures, each in a fresh process:

- commit (mixed only): open a writer, add 200 new rows, commit (median and max of 5, and the
  seconds to open);
- query: open, one query (a new row of the same kind), names of the top 20, median of 3 after
  one warm-up, peak memory, and the rows whose exact distance was computed; then the same with
  pruning off (the full scan), in another process;
- on the largest mixed index: a run of 100 commits (median, 95th percentile, max); the writer
  alone (rows per second added and committed every 200); Dask: a local cluster (one thread per
  worker) computing a stand-in signature per file through `cfsig.batch.compute_many`, its
  outcomes added to the index and committed every 200, as `cfsig index --scheduler` does
  (signatures per second, the writer's busy fraction), with batches as `compute_many` makes them
  and with one file per task (the batch size forced to 1) for comparison;
- in memory: the sketch group size (rows left to compute exactly, and the sketch scan's time).

Prints Markdown for docs/index-scale.md. An index already in DIR (from --keep) is reused; each is
deleted once measured unless --keep.
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

from cfsig.index.store import Entry, IndexWriter  # noqa: E402
from cfsig.params import Params, signature_length  # noqa: E402

PARAMS = Params(descriptor="cfhks")
WIDTH = signature_length(PARAMS)
BUILD_ROWS = 1_000_000
PIECE_ROWS = 100_000  # synthetic rows generated at a time
COMMIT = 200
COMMITS = 100  # in the run of consecutive commits
BATCH_STUDY = (100, 5000)  # largest batches measured besides compute_many's own
NOISE = 0.02  # noise of a mixed row, in standard deviations of each coordinate over real rows
K = 20


def real_rows(index: str | None, params: Params = PARAMS) -> np.ndarray | None:
    """The signatures of a real index of ``params``, or None for random rows."""
    if index is None:
        return None
    from cfsig.index.store import IndexReader

    with IndexReader(index) as reader:
        if reader.params != params:
            raise SystemExit(f"{index}: not an index of {params.to_json()}")
        return reader.signatures[:]


def synthetic_cells(
    rng: np.random.Generator, n: int, real: tuple[np.ndarray, np.ndarray], fill: str = "full"
) -> list[tuple[np.ndarray, np.ndarray]]:
    """n rows of fine cells (`cfsig.descriptors.cells.packed_cells`) from the cells ``real`` of the rows of a
    real index (`IndexReader.cells`): two real rows' cells, their fractions mixed as
    `synthetic_rows` mixes vectors, the largest kept: as many as fit (``fill="full"``: the two
    rows together nearly always fill every slot), or as many as a third real row, drawn at
    random, occupies (``fill="real"``: rows fill their slots as the real index's do)."""
    cells, fractions = real
    slots = cells.shape[1]
    i, j = rng.integers(0, len(cells), (2, n))
    t = rng.random(n)
    counts = np.full(n, slots)
    if fill == "real":
        counts = (fractions > 0).sum(axis=1)[rng.integers(0, len(cells), n)]
    out = []
    for a, b, share, count in zip(i, j, t, counts, strict=True):
        both = np.concatenate([cells[a], cells[b]])
        mixed = np.concatenate([share * fractions[a], (1 - share) * fractions[b]])
        held, where = np.unique(both, return_inverse=True)
        summed = np.bincount(where, weights=mixed)
        keep = np.sort(np.argsort(-summed, kind="stable")[:count])
        keep = keep[summed[keep] > 0]
        row_cells, row_fractions = np.zeros(slots, np.uint16), np.zeros(slots, np.float32)
        row_cells[: len(keep)], row_fractions[: len(keep)] = held[keep], summed[keep]
        out.append((row_cells, row_fractions))
    return out


def synthetic_query(
    real: tuple[np.ndarray, np.ndarray],
) -> tuple[tuple[np.ndarray, np.ndarray], ...]:
    """The synthetic partial query of version 10: its cells at each of the 13 shares
    (`cfsig.search.partial.FINE_SHARES`) are those of one more `synthetic_cells` row, seeded: 13
    unrelated histograms, each of mass 1."""
    from cfsig.search.partial import FINE_SHARES

    held = synthetic_cells(np.random.default_rng(6), len(FINE_SHARES), real)
    return tuple((c[f > 0].astype(np.int64), f[f > 0] / f.sum()) for c, f in held)


def synthetic_rows(rng: np.random.Generator, n: int, real: np.ndarray | None) -> np.ndarray:
    """n rows: mixtures of two real rows plus noise, or uniform random values without ``real``."""
    if real is None:
        return rng.random((n, WIDTH), dtype=np.float32)
    i, j = rng.integers(0, len(real), (2, n))
    t = rng.random((n, 1), dtype=np.float32)
    noise = rng.standard_normal((n, WIDTH), dtype=np.float32) * (NOISE * real.std(axis=0))
    return (t * real[i] + (1 - t) * real[j] + noise).astype(np.float32)


def fake_signature(i: int, rng: np.random.Generator | None = None):
    """A signature of random values for row ``i`` (the Signature class loads scipy: lazily)."""
    from cfsig.descriptors.signature import Signature

    vector = (rng or np.random.default_rng(i)).random(WIDTH, dtype=np.float32)
    return Signature(vector, np.zeros(1), 1, 1, 1, 0.0, (), "clean", 0.0, f"{i:064x}")


def stand_in(path: Path, params: Params, solver: str):
    """The Dask run's cheap computation: a random signature seeded by the file's number."""
    return fake_signature(int(Path(path).stem))


def entry(i: int) -> Entry:
    label = f"class{i % 50}"
    return Entry(f"{label}/{i}.off", label, f"/data/{label}/{i}.off")


def build(
    path: Path,
    n: int,
    real: np.ndarray | None,
    params: Params = PARAMS,
    cells: tuple[np.ndarray, np.ndarray] | None = None,
    fill: str = "full",
) -> float:
    """Write n synthetic rows of ``params`` in commits of BUILD_ROWS, with `synthetic_cells` of
    the real ``cells`` (and ``fill``) when the parameters keep fine cells, in commits of
    PIECE_ROWS then (a commit holds its rows in memory: 6 KB of cells a row); return the
    seconds taken."""
    from cfsig.descriptors.signature import Signature

    rng = np.random.default_rng(0)
    phi = np.zeros(1)
    start = time.perf_counter()
    with IndexWriter(path, params, merge=False) as writer:
        for first in range(0, n, PIECE_ROWS):
            rows = synthetic_rows(rng, min(PIECE_ROWS, n - first), real)
            count = len(rows)
            fine = [None] * count if cells is None else synthetic_cells(rng, count, cells, fill)
            for i, (vector, held) in enumerate(zip(rows, fine, strict=True), first):
                sig = Signature(vector, phi, 1, 1, 1, 0.0, (), "clean", 0.0, "", held)
                writer.add(entry(i), sig)
            if (
                writer.pending >= (BUILD_ROWS if cells is None else PIECE_ROWS)
                or first + PIECE_ROWS >= n
            ):
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


def query_times(path: Path, real: str | None, pruned: bool) -> dict:
    """Open + one query + names of the top 20, median of 3 after a warm-up, in a fresh process.

    Also counts the rows whose exact distance the query computed; ``pruned`` False forces the
    full scan.
    """
    code = f"""
import numpy as np
import cfsig.search.nearest
from cfsig.index.store import IndexReader
from cfsig.search.nearest import query
from benchmarks.index_scale import real_rows, synthetic_rows
real = real_rows({real!r})
query = synthetic_rows(np.random.default_rng(5), 1, real)
if not {pruned}:
    cfsig.search.nearest.PRUNE_MIN_ROWS = 10**15
exact = []
real_exact = cfsig.search.nearest._Pruned._exact
def counted(self, j, query, rows, *args):
    exact.append(len(rows))
    return real_exact(self, j, query, rows, *args)
cfsig.search.nearest._Pruned._exact = counted
def once():
    exact.clear()
    t = time.perf_counter()
    with IndexReader({str(path)!r}) as r:
        hits = query(r, query, {K})[0]
    return time.perf_counter() - t, len(r)
once()
runs = [once() for _ in range(3)]
out = {{'times': [t for t, _ in runs], 'rows': runs[0][1], 'exact': sum(exact)}}
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


def dask_run(path: Path, first: int, files: int, workers: int, batch: int) -> dict:
    """The stand-in computation on a local Dask cluster, its outcomes written to the index.

    ``batch`` is the largest number of files per task (1: a task per file, as before batches).
    """
    from distributed import LocalCluster

    import cfsig.batch
    from cfsig.batch import compute_many

    cfsig.batch._MAX_BATCH = batch
    with LocalCluster(
        n_workers=workers, threads_per_worker=1, dashboard_address=None, host="127.0.0.1"
    ) as cluster:
        paths = [Path(f"/data/dask/{first + i}.off") for i in range(files)]
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


def group_study(real: np.ndarray, rows: int = 1_000_000, queries: int = 5) -> list[dict]:
    """Sketch group sizes on ``rows`` mixed rows in memory, one thread: for each, the mean
    number of rows whose bound does not exceed the 20th distance (those a search computes
    exactly, at least), and the seconds to scan the sketches with one query (best of 3)."""
    from cfsig.index.sketch import group_sums
    from cfsig.search.l1 import choose_kernel

    rng = np.random.default_rng(11)
    data = np.concatenate(
        [synthetic_rows(rng, PIECE_ROWS, real) for _ in range(rows // PIECE_ROWS)]
    )
    probe = synthetic_rows(rng, queries, real)
    kernel = choose_kernel(rows)
    dist = np.empty((queries, rows), np.float32)
    kernel(probe, data, dist)
    kth = np.sort(dist, axis=1)[:, K - 1]
    study = []
    for size in (8, 16, 32, 64):
        groups = np.arange(0, WIDTH, size)
        sketches = np.concatenate(
            [group_sums(data[s : s + PIECE_ROWS], groups).astype(np.float32)
             for s in range(0, rows, PIECE_ROWS)]
        )  # fmt: skip
        probes = group_sums(probe, groups).astype(np.float32)
        bounds = np.empty((queries, rows), np.float32)
        kernel(probes, sketches, bounds)
        left = float((bounds <= kth[:, None]).sum(axis=1).mean())
        best = float("inf")
        out = np.empty((1, rows), np.float32)
        for _ in range(3):
            t = time.perf_counter()
            kernel(probes[:1], sketches, out)
            best = min(best, time.perf_counter() - t)
        study.append({"group": size, "entries": len(groups), "left": left, "scan": best})
    return study


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
    from cfsig.search.l1 import choose_kernel

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


def rankings_check(index: str) -> dict:
    """Every row of a real index as a query, its 2(C - 1) + 1 nearest (C its class size) pruned
    (forced, however few the rows) and by the full scan: whether rows and distances are equal,
    NN, FT and ST from each ranking (the query itself left out), and the rows each computed."""
    import cfsig.search.nearest
    from cfsig.index.store import IndexReader
    from cfsig.search.nearest import nearest

    settings = {"PRUNE_MIN_ROWS": 0, "_SCAN_RATIO": 0, "_FIRST": 1}
    saved = {key: getattr(cfsig.search.nearest, key) for key in settings}
    with IndexReader(index) as reader:
        labels = np.array(reader.column("labels"))
        sizes = {c: int((labels == c).sum()) for c in set(labels)}
        k = 2 * (max(sizes.values()) - 1) + 1
        queries = reader.signatures[:]
        full = nearest(reader, queries, k)
        vars(cfsig.search.nearest).update(settings)
        try:
            pruned = nearest(reader, queries, k)
        finally:
            vars(cfsig.search.nearest).update(saved)
    out: dict = {"identical": bool(np.array_equal(full[0], pruned[0]))}
    out["identical"] &= bool(np.array_equal(full[1], pruned[1]))
    for route, (rows, _) in (("full", full), ("pruned", pruned)):
        nn, ft, st = [], [], []
        for q, ranked in enumerate(rows):
            others = labels[ranked[ranked != q]]
            same, c = others == labels[q], sizes[labels[q]] - 1
            nn.append(same[0])
            ft.append(same[:c].sum() / c)
            st.append(same[: 2 * c].sum() / c)
        out[route] = {"NN": float(np.mean(nn)), "FT": float(np.mean(ft)), "ST": float(np.mean(st))}
    return out


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--real", default=None, help="an index of real cfhks signatures")
    parser.add_argument("--sizes", type=int, nargs="*", default=[1_000_000, 10_000_000])
    parser.add_argument("--random-sizes", type=int, nargs="*", default=[1_000_000])
    parser.add_argument("--dir", type=Path, default=None)
    parser.add_argument("--dask-files", type=int, default=100_000)
    parser.add_argument("--workers", type=int, default=4)
    parser.add_argument("--keep", action="store_true")
    parser.add_argument(
        "--writer-index", type=Path, default=None,
        help="measure the writer and Dask on this index instead of the largest mixed one",
    )  # fmt: skip
    args = parser.parse_args()
    if args.sizes and args.real is None:
        parser.error("mixed rows (--sizes) need --real INDEX")
    if args.dir is not None:
        args.dir.mkdir(parents=True, exist_ok=True)
    folder = args.dir or Path(tempfile.mkdtemp(prefix="index-scale-", dir="/work"))
    real = real_rows(args.real)
    started = time.time()
    load = os.getloadavg()[0]
    lines = [
        "Command: `python benchmarks/index_scale.py --real INDEX --sizes "
        + " ".join(map(str, args.sizes))
        + " --random-sizes "
        + " ".join(map(str, args.random_sizes))
        + f" --dask-files {args.dask_files} --workers {args.workers}"
        + ("" if args.writer_index is None else " --writer-index INDEX")
        + "`",
        "",
        f"Machine: {os.cpu_count()} cores, Python {platform.python_version()}, numpy "
        f"{np.__version__}; rows of {WIDTH} float32 (`cfhks`); real rows: "
        f"{0 if real is None else len(real)}; load average {load:.1f} at the start.",
        "",
        "| rows | kind | build s | index size | query s (median of 3) | rows computed exactly "
        "| query peak MB | full scan s (median of 3) | full scan peak MB | full scan / query |",
        "|---|---|---|---|---|---|---|---|---|---|",
    ]
    commit_lines = [
        "",
        "| rows | open writer s (median) | open + add 200 + commit s (median of 5) | (max) "
        "| writer peak MB |",
        "|---|---|---|---|---|",
    ]
    tail: list[str] = []
    for kind, sizes in (("mixed", args.sizes), ("random", args.random_sizes)):
        source = args.real if kind == "mixed" else None
        for n in sizes:
            path = folder / f"{kind}-{n}"
            built = (
                None
                if (path / "manifest.h5").exists()
                else build(path, n, real if source else None)
            )
            size = sum(f.stat().st_size for f in path.iterdir())
            query = query_times(path, source, True)
            full = query_times(path, source, False)
            print(n, kind, built, json.dumps({"query": query, "full": full}), flush=True)
            fast, slow = statistics.median(query["times"]), statistics.median(full["times"])
            lines.append(
                f"| {n:,} | {kind} | {'reused' if built is None else f'{built:.0f}'} | "
                f"{size / 1e9:.2f} GB | {fast:.3f} | {query['exact']:,} | {query['peak_mb']:.0f} "
                f"| {slow:.3f} | {full['peak_mb']:.0f} | {slow / fast:.1f} |"
            )
            if kind == "mixed":
                commits = commit_times(path, 10**9, 5)
                print(json.dumps(commits), flush=True)
                commit_lines.append(
                    f"| {n:,} | {statistics.median(commits['open']):.3f} | "
                    f"{statistics.median(commits['total']):.3f} | {max(commits['total']):.3f} | "
                    f"{commits['peak_mb']:.0f} |"
                )
            if kind == "mixed" and n == max(sizes) and args.writer_index is None:
                tail += writer_measures(path, n, args.dask_files, args.workers)
            if not args.keep:
                shutil.rmtree(path, ignore_errors=True)
    if args.writer_index is not None:
        from cfsig.index.store import IndexReader

        with IndexReader(args.writer_index) as reader:
            rows = len(reader)
        tail += writer_measures(args.writer_index, rows, args.dask_files, args.workers)
    if real is not None:
        check = rankings_check(args.real)
        print(json.dumps(check), flush=True)
        tail += [
            "",
            "Every row of the real index as a query, its nearest by the pruned search (forced) "
            f"and by the full scan: rows and distances identical: {check['identical']}; "
            + "; ".join(
                f"{route}: " + ", ".join(f"{m} {v:.3f}" for m, v in check[route].items())
                for route in ("full", "pruned")
            )
            + ".",
        ]
        study = group_study(real)
        print(json.dumps(study), flush=True)
        tail += [
            "",
            "Sketch group sizes, 1,000,000 mixed rows in memory, 5 queries, one thread: "
            + "; ".join(
                f"{g['group']} coordinates ({g['entries']} entries): {g['left']:,.0f} rows with "
                f"a bound at most the 20th distance, sketch scan {g['scan']:.4f} s"
                for g in study
            )
            + ".",
        ]
    scan = storage_scan()
    print(json.dumps(scan), flush=True)
    tail += [
        "",
        "One query over 1,000,000 rows in memory, one thread, best of 3 (the L1 kernel "
        "takes float32: compact rows are decoded piece by piece first): "
        + ", ".join(f"{k} {v:.3f} s" for k, v in scan.items())
        + ".",
        "",
        f"The run took {time.time() - started:.0f} s; load average {os.getloadavg()[0]:.1f} "
        "at the end.",
    ]
    print("\n".join(lines + commit_lines + tail))


def writer_measures(path: Path, n: int, files: int, workers: int) -> list[str]:
    """Consecutive commits, the writer alone and the Dask runs on the largest mixed index."""
    run = commit_run(path, 2 * 10**9, COMMITS)
    times = sorted(run["times"])
    alone = writer_alone(path, 3 * 10**9, 20_000)
    from cfsig.batch import _MAX_BATCH as default  # before dask_run changes it

    dask = dask_run(path, 4 * 10**9, files, workers, default)
    single = dask_run(path, 5 * 10**9, min(files, 5_000), workers, 1)
    others = {b: dask_run(path, (6 + i) * 10**9, files // 3, workers, b)
              for i, b in enumerate(BATCH_STUDY)}  # fmt: skip
    print(json.dumps({"run": run, "alone": alone, "dask": dask, "single": single,
                      "others": others}), flush=True)  # fmt: skip
    return [
        "",
        f"{COMMITS} consecutive commits of 200 rows into the {n:,}-row index, one writer "
        f"(automatic merges included): median {statistics.median(times):.3f} s, 95th percentile "
        f"{times[int(0.95 * len(times))]:.3f} s, max {times[-1]:.3f} s; {run['segments']} "
        "segments at the end.",
        "",
        f"Writer alone, add + commit every 200 rows into the {n:,}-row index: {alone:,.0f} rows "
        "per second.",
        "",
        f"Dask, local cluster of {workers} one-thread workers, stand-in computation, written to "
        f"the {n:,}-row index with a commit every 200, through `compute_many`: batched, "
        f"{dask['count']:,} files in {dask['wall']:.1f} s, **{dask['rate']:,.0f} signatures per "
        f"second**, the writer busy {100 * dask['busy']:.0f}% of the time; one file per task, "
        f"{single['count']:,} files in {single['wall']:.1f} s, {single['rate']:,.0f} per second, "
        f"the writer busy {100 * single['busy']:.0f}%. At most "
        + ", ".join(
            f"{b:,} files per task ({r['count']:,} files): {r['rate']:,.0f} per second"
            for b, r in others.items()
        )
        + f" (`compute_many`: at most {default:,}).",
    ]


if __name__ == "__main__":
    main()
