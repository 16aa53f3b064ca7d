"""Ways to scan 1M stored signatures for the nearest ones, measured on this machine.

Usage: python benchmarks/query_options.py [--no-write]

Writes random normalised 200-bin float32 histograms into HDF5 files in a temporary folder: 1M rows
chunked by 4096 rows as `IndexWriter` makes them, 1M rows contiguous, and 100k rows chunked; then
runs each option in a fresh process (one untimed run, then the median of 3), in 3 interleaved
rounds, and writes the table to docs/query-options.md. Takes about 4 minutes on 2 cores.
"""

from __future__ import annotations

import argparse
import json
import mmap
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import h5py
import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

import cfsig.index.blocks  # noqa: E402
import cfsig.search.l1  # noqa: E402
import cfsig.search.nearest  # noqa: E402
from benchmarks.query import baseline_nearest, peak_mb, versions  # noqa: E402

DOC = ROOT / "docs" / "query-options.md"
BINS = 200
ROUNDS = 3


class Signatures:
    """The part of `IndexReader` that `nearest` uses, on a bare HDF5 file."""

    def __init__(self, path: str) -> None:
        self._file = h5py.File(path, "r", locking=False)
        self.signatures = self._file["signatures"]

    def __len__(self) -> int:
        return self.signatures.shape[0]


def write_file(path: Path, n: int, chunked: bool) -> None:
    """n random normalised histograms, chunked like the index writer's or contiguous."""
    rng = np.random.default_rng(0)
    layout = {"chunks": (4096, BINS), "maxshape": (None, BINS)} if chunked else {}
    with h5py.File(path, "w") as f:
        data = f.create_dataset("signatures", (n, BINS), np.float32, **layout)
        for start in range(0, n, 65536):
            block = rng.random((min(65536, n - start), BINS), dtype=np.float32)
            data[start : start + len(block)] = block / block.sum(axis=1, keepdims=True)


def read_only(reader: Signatures, how: str) -> None:
    """Read every row once and sum it, without any distance."""
    data, n = reader.signatures, len(reader)
    if how == "h5py slices of 16384 rows":
        for start in range(0, n, 16384):
            np.einsum("ij->", data[start : start + 16384])
        return
    if how == "read_direct into a reused buffer":
        step = data.chunks[0] if data.chunks else 16384
        buffer = np.empty((step, BINS), np.float32)
        for start in range(0, n, step):
            rows = buffer[: min(step, n - start)]
            data.read_direct(rows, np.s_[start : start + len(rows)])
            np.einsum("ij->", rows)
        return
    read = read_block_mapped if how.startswith("mapped") else cfsig.index.blocks.read_block
    buffer = np.empty((16384, BINS), np.float32)
    for block in cfsig.index.blocks.plan_blocks(data, 16384):
        np.einsum("ij->", read(data, block, buffer))


def read_block_mapped(dataset, block, buffer: np.ndarray) -> np.ndarray:
    """cfsig's `read_block` before preadv: each directly readable block memory-mapped."""
    if block.offset is None:
        return cfsig.index.blocks.read_block(dataset, block, buffer)
    count, bins = block.stop - block.start, dataset.shape[1]
    aligned = block.offset - block.offset % mmap.ALLOCATIONGRANULARITY
    view = mmap.mmap(
        dataset.file.id.get_vfd_handle(), block.offset - aligned + count * bins * 4,
        flags=mmap.MAP_SHARED | getattr(mmap, "MAP_POPULATE", 0), prot=mmap.PROT_READ,
        offset=aligned,
    )  # fmt: skip
    rows = np.frombuffer(view, np.float32, count * bins, block.offset - aligned)
    return rows.reshape(count, bins)


def l1_numpy_broadcast(queries: np.ndarray, rows: np.ndarray, out: np.ndarray) -> None:
    """cfsig's numpy kernel with the query broadcast over each piece instead of tiled."""
    diff = np.empty((min(256, len(rows)), rows.shape[1]), np.float32)
    for query, dist in zip(queries, out, strict=True):
        for start in range(0, len(rows), 256):
            piece = rows[start : start + 256]
            scratch = diff[: len(piece)]
            np.subtract(piece, query, out=scratch)
            np.abs(scratch, out=scratch)
            np.einsum("ij->i", scratch, out=dist[start : start + len(piece)])


def l1_cdist(queries: np.ndarray, rows: np.ndarray, out: np.ndarray) -> None:
    """scipy's cdist cityblock (converts to float64)."""
    from scipy.spatial.distance import cdist

    out[:] = cdist(queries, rows, "cityblock")


def l1_numba() -> cfsig.search.l1.Kernel:
    """The numba kernel cfsig used before faiss (one pass over the rows for all queries)."""
    import numba

    @numba.njit(nogil=True, fastmath=True, cache=True)
    def kernel(queries, rows, out):
        for i in range(rows.shape[0]):
            for j in range(queries.shape[0]):
                total = np.float32(0.0)
                for b in range(rows.shape[1]):
                    total += abs(rows[i, b] - queries[j, b])
                out[j, i] = total

    return kernel


def configure(option: str) -> None:
    """Set cfsig's search up for one option (kernel, threads, reading, piece size)."""
    threads = 1 if "1 thread" in option else 2
    cfsig.search.nearest._threads = lambda: threads
    kernel = cfsig.search.l1.l1_numpy
    if "numba" in option:
        kernel = l1_numba()
    elif "faiss" in option:
        kernel = cfsig.search.l1.fast_kernel()
    elif "broadcast" in option:
        kernel = l1_numpy_broadcast
    elif "cdist" in option:
        kernel = l1_cdist
    cfsig.search.nearest.choose_kernel = lambda work: kernel
    if "read_direct" in option:
        cfsig.index.blocks._plain = lambda dataset: False
    if "mapped blocks" in option:
        cfsig.search.nearest.read_block = read_block_mapped
    for piece in (64, 1024):
        if f"pieces of {piece}" in option:
            cfsig.search.l1._PIECE_ROWS = piece


def measure(path: str, option: str, n_queries: int) -> dict:
    """In this process: one untimed run of ``option``, then the median of 3."""
    import_start = time.perf_counter()
    configure(option)
    setup = time.perf_counter() - import_start
    reader = Signatures(path)
    queries = np.random.default_rng(1).random((n_queries, BINS)).astype(np.float32)
    queries /= queries.sum(axis=1, keepdims=True)
    wall, cpu = [], []
    for _ in range(4):
        t, c = time.perf_counter(), time.process_time()
        if option.startswith("read:"):
            read_only(reader, option.split(": ", 1)[1])
        elif option.startswith("baseline"):
            baseline_nearest(reader, queries, 20)
        else:
            cfsig.search.nearest.nearest(reader, queries, 20)
        wall.append(time.perf_counter() - t)
        cpu.append(time.process_time() - c)
    return {
        "wall": float(np.median(wall[1:])), "cpu": float(np.median(cpu[1:])),
        "first": wall[0], "setup": setup, "peak_mb": peak_mb(),
    }  # fmt: skip


OPTIONS_1M = [
    "read: h5py slices of 16384 rows",
    "read: read_direct into a reused buffer",
    "read: preadv blocks (cfsig.index.blocks)",
    "read: mapped blocks (cfsig before preadv)",
    "baseline: numpy over h5py slices (the code before)",
    "numpy, 2 threads",
    "numpy, 1 thread",
    "numpy, 2 threads, pieces of 64 rows",
    "numpy, 2 threads, pieces of 1024 rows",
    "numpy broadcast instead of tiled, 2 threads",
    "numpy, 2 threads, read_direct instead of preadv",
    "scipy cdist, 2 threads",
    "faiss, 2 threads",
    "faiss, 1 thread",
    "faiss, 2 threads, mapped blocks instead of preadv",
    "numba, 2 threads",
    "numba, 1 thread",
]
OPTIONS_CONTIGUOUS = [
    "read: read_direct into a reused buffer",
    "read: preadv blocks (cfsig.index.blocks)",
    "read: mapped blocks (cfsig before preadv)",
    "faiss, 2 threads",
]
OPTIONS_BATCH = ["numpy, 2 threads", "faiss, 2 threads", "numba, 2 threads"]


def load_cost(kernel: str) -> dict:
    """Seconds and peak memory to import a kernel's library and make a first call, fresh process."""
    make = {"faiss": "cfsig.search.l1.fast_kernel()", "numba": "query_options.l1_numba()"}[kernel]
    code = (
        "import time, json, numpy as np\n"
        "import cfsig.search.l1\n"
        "from benchmarks import query_options\n"
        "from benchmarks.query import peak_mb\n"
        "before = peak_mb(); t = time.perf_counter()\n"
        f"k = {make}; z = np.zeros((1, 200), np.float32)\n"
        "k(z, z, np.zeros((1, 1), np.float32))\n"
        "print(json.dumps([time.perf_counter() - t, peak_mb() - before]))\n"
    )
    runs = []
    for _ in range(4):  # the first may compile and fill numba's cache
        out = subprocess.run([sys.executable, "-c", code], check=True, capture_output=True,
                             text=True, cwd=ROOT).stdout  # fmt: skip
        runs.append(json.loads(out.splitlines()[-1]))
    return {"seconds": float(np.median([r[0] for r in runs[1:]])), "mb": runs[-1][1]}


def run(path: Path, option: str, n_queries: int) -> dict:
    """`measure` in a fresh process."""
    cmd = [sys.executable, __file__, "--measure", str(path), option, str(n_queries)]
    out = subprocess.run(cmd, check=True, capture_output=True, text=True, cwd=ROOT).stdout
    result = json.loads(out.splitlines()[-1])
    print(f"  {path.name} q={n_queries} {option}: {result}", flush=True)
    return result


def main() -> None:
    """Write the files, measure every option, and write the report."""
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--no-write", action="store_true", help="print, do not edit docs/")
    parser.add_argument("--measure", nargs=3, help=argparse.SUPPRESS)
    args = parser.parse_args()
    if args.measure:
        path, option, n_queries = args.measure
        print(json.dumps(measure(path, option, int(n_queries))))
        return

    started, load_start = time.perf_counter(), os.getloadavg()[0]
    results: dict = {}
    with tempfile.TemporaryDirectory() as tmp:
        files = {
            "1M, chunked": (Path(tmp) / "chunked.h5", 1_000_000, True, OPTIONS_1M, 1),
            "1M, contiguous": (Path(tmp) / "contiguous.h5", 1_000_000, False,
                               OPTIONS_CONTIGUOUS, 1),
            "100k, chunked": (Path(tmp) / "small.h5", 100_000, True, OPTIONS_BATCH, 100),
        }  # fmt: skip
        for path, n, chunked, *_ in files.values():
            write_file(path, n, chunked)
        for _ in range(ROUNDS):  # interleaved, so that a busy spell of the machine hits all
            for name, (path, _n, _c, options, n_queries) in files.items():
                for option in options:
                    results.setdefault((name, n_queries, option), []).append(
                        run(path, option, n_queries)
                    )
        cost = {kernel: load_cost(kernel) for kernel in ("faiss", "numba")}
    rows = [
        (*key, {m: float(np.median([r[m] for r in runs])) for m in ("wall", "cpu", "peak_mb")})
        for key, runs in results.items()
    ]
    load = (load_start, os.getloadavg()[0])
    text = report(rows, cost, load, time.perf_counter() - started)
    print(text)
    if not args.no_write:
        DOC.write_text(text)


def report(rows: list, cost: dict, load: tuple, seconds: float) -> str:
    """The markdown page."""
    lines = [
        "# Scanning stored signatures: options measured",
        "",
        "Command: `python benchmarks/query_options.py` (synthetic float32 histograms, 200 bins, "
        "top 20 per query; files in a temporary folder, page cache warm). Each option runs in a "
        f"fresh process: one untimed run, then the median of 3; {ROUNDS} rounds interleaved, and "
        "the table gives the median over rounds. Peak memory is the process's VmHWM, imports "
        "included.",
        "",
        f"Machine: {os.cpu_count()} cores, {versions()}. Load average {load[0]:.1f} at the start "
        f"and {load[1]:.1f} at the end (other jobs shared the cores: compare rows of one run, and "
        f"CPU time, more than absolute wall time). The run took {seconds:.0f} s.",
        "",
        "| file | queries | option | wall | CPU | peak memory |",
        "|---|---|---|---|---|---|",
    ]
    for name, n_queries, option, r in rows:
        lines.append(
            f"| {name} | {n_queries} | {option} | {r['wall'] * 1000:.0f} ms | "
            f"{r['cpu'] * 1000:.0f} ms | {r['peak_mb']:.0f} MB |"
        )
    lines += [""]
    lines += [
        f"Importing {name} and making a first call in a fresh process"
        f"{' (loading the cached kernel)' if name == 'numba' else ''}: "
        f"{c['seconds'] * 1000:.0f} ms and {c['mb']:.0f} MB more peak memory (median of 3, after "
        "one run that may compile)."
        for name, c in cost.items()
    ]
    lines += [""]
    return "\n".join(lines)


if __name__ == "__main__":
    main()
