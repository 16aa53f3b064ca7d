"""Batches: signatures of many mesh files in worker processes, one bad file costing only itself."""

from __future__ import annotations

import multiprocessing
import os
from collections.abc import Iterable, Iterator
from concurrent.futures import FIRST_COMPLETED, Future, ProcessPoolExecutor, wait
from concurrent.futures.process import BrokenProcessPool
from dataclasses import dataclass
from pathlib import Path

from .errors import CfsigError
from .params import Params
from .signature import Signature, signature_file

_THREAD_VARS = ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS")


@dataclass(frozen=True)
class Outcome:
    """The result for one file: a signature, or the reason there is none.

    Attributes
    ----------
    path : Path
        The mesh file.
    signature : Signature or None
        None when the file failed.
    error : str
        One line naming the file and the reason; empty on success.
    """

    path: Path
    signature: Signature | None
    error: str = ""


def compute_many(
    paths: Iterable[Path], params: Params, solver: str = "auto", jobs: int | None = None
) -> Iterator[Outcome]:
    """Signatures of many files in a pool of worker processes, yielded as they finish.

    Files are taken from ``paths`` lazily, with a bounded number in flight, so memory does not
    grow with the number of files. Workers run with one BLAS/OpenMP thread each. A worker that
    dies (a crash in native code, the out-of-memory killer) fails only its own file: after a
    pool breaks, the files that were in flight are retried one at a time.

    Parameters
    ----------
    paths : iterable of Path
        Mesh files.
    params : Params
        Signature parameters.
    solver : {"auto", "scipy", "cholmod"}
        Sparse solver backend.
    jobs : int, optional
        Worker processes; default: the number of CPU cores.

    Yields
    ------
    outcome : Outcome
        One per path, in completion order.
    """
    jobs = max(1, jobs or os.cpu_count() or 1)
    pending = iter(paths)
    suspects: list[Path] = []
    with _pool(jobs) as pool:
        running: dict[Future, Path] = {}
        while True:
            while len(running) < 2 * jobs and (path := next(pending, None)) is not None:
                running[pool.submit(_work, path, params, solver)] = path
            if not running:
                break
            done, _ = wait(running, return_when=FIRST_COMPLETED)
            for future in done:
                path = running.pop(future)
                try:
                    yield future.result()
                except BrokenProcessPool:
                    suspects = [path, *running.values()]
                    break
            if suspects:
                break
    if suspects:
        for path in suspects:
            yield _isolated(path, params, solver)
        yield from compute_many(pending, params, solver, jobs)


def _work(path: Path, params: Params, solver: str) -> Outcome:
    """Compute one file's signature in a worker, turning library errors into an outcome."""
    try:
        return Outcome(path, signature_file(path, params, solver))
    except CfsigError as exc:
        return Outcome(path, None, str(exc))
    except MemoryError:
        return Outcome(path, None, f"{path}: out of memory")


def _isolated(path: Path, params: Params, solver: str) -> Outcome:
    """Compute one file alone in a fresh worker, reporting a crash of that worker."""
    with _pool(1) as pool:
        try:
            return pool.submit(_work, path, params, solver).result()
        except BrokenProcessPool:
            return Outcome(path, None, f"{path}: the worker process crashed on this file")


def _pool(jobs: int) -> ProcessPoolExecutor:
    """A process pool of fresh interpreters with one BLAS/OpenMP thread each."""
    saved = {var: os.environ.get(var) for var in _THREAD_VARS}
    os.environ.update(dict.fromkeys(_THREAD_VARS, "1"))
    try:
        ctx = multiprocessing.get_context("spawn")
        pool = ProcessPoolExecutor(jobs, mp_context=ctx)
        # Each submit while no task has finished spawns a worker: all start with the variables.
        for future in [pool.submit(int) for _ in range(jobs)]:
            future.result()
    finally:
        for var, value in saved.items():
            if value is None:
                os.environ.pop(var, None)
            else:
                os.environ[var] = value
    return pool
