"""Batches: signatures of many mesh files in worker processes, one bad file costing only itself."""

from __future__ import annotations

import multiprocessing
import os
import threading
import time
from collections.abc import Callable, Iterable, Iterator, Mapping
from concurrent.futures import FIRST_COMPLETED, Future, ProcessPoolExecutor, wait
from concurrent.futures.process import BrokenProcessPool
from dataclasses import dataclass
from functools import partial
from itertools import islice
from pathlib import Path
from typing import TYPE_CHECKING, Any, Generic, TypeVar

from cfsig.errors import (
    CfsigError,
    ClusterError,
    EmptyPathError,
    MissingDependencyError,
    UnknownNameError,
)
from cfsig.files.cla import labels_from_cla
from cfsig.files.folders import find_meshes, mesh_label
from cfsig.params import Params

if TYPE_CHECKING:  # neither HDF5 in the workers, nor SciPy in the process that writes the index
    from cfsig.descriptors.signature import Signature
    from cfsig.index.store import IndexWriter
    from cfsig.isolate import Limits

_CONNECT_TIMEOUT = "20s"
_COMMIT_SECONDS = 30.0
_TASK_SECONDS = 0.5  # work per Dask task that batches aim at: docs/performance.md
_MAX_BATCH = 1000  # files per Dask task at most
Compute = Callable[[Path, Params, str], Any]  # returns a Signature, or another measure of a file
Result = TypeVar("Result")


@dataclass(frozen=True)
class Outcome(Generic[Result]):
    """The result for one file: its signature (or what else was computed), or why there is none.

    Attributes
    ----------
    path : Path
        The mesh file.
    signature : Signature or None
        What the computation returned: a `cfsig.descriptors.signature.Signature` unless the
        caller computed something else (`cfsig.evaluation.collections.evaluate_partial`
        measures parts); None when the file failed.
    error : str
        One line naming the file and the reason; empty on success.
    """

    path: Path
    signature: Result | None
    error: str = ""


@dataclass(frozen=True)
class Indexed:
    """What `index_meshes` did to an index.

    Attributes
    ----------
    added : int
        Meshes added or updated.
    updated : int
        Entries indexed already given a new label (by the classes) or path (a file moved with
        its folder), their signatures kept.
    pruned : int
        Entries dropped because their file no longer exists.
    failures : list of str
        One line per file that failed or whose name another file already took,
        ``<file>: <reason>``.
    """

    added: int
    updated: int
    pruned: int
    failures: list[str]


# progress(outcomes, total): wraps the outcomes; total() is the number expected so far, which
# grows while a folder is still being scanned.
Progress = Callable[[Iterator[Outcome], Callable[[], int]], Iterable[Outcome]]


def compute_many(
    paths: Iterable[Path],
    params: Params,
    solver: str = "auto",
    jobs: int | None = None,
    scheduler: str | None = None,
    compute: Compute | None = None,
    limits: Limits | None = None,
) -> Iterator[Outcome]:
    """Signatures of many files in worker processes, yielded as they finish.

    Files are taken from ``paths`` lazily, with a bounded number in flight, so memory does not
    grow with the number of files. Workers run with one BLAS/OpenMP thread each. Locally, a
    worker that dies (a crash in native code, the out-of-memory killer) fails only its own
    file: after a pool breaks, the files that were in flight are retried one at a time. On a
    Dask cluster, files go in batches, as many per task as fit in about half a second of work
    (one per task while the first results are awaited, at most 1,000): Dask's cost per task is
    paid once per batch. A task whose worker dies is retried by Dask on another worker a few
    times; if it still fails, its files are sent again one per task, and the bad one fails alone.

    Parameters
    ----------
    paths : iterable of Path
        Mesh files. With ``scheduler``, each must be readable under its absolute path on every
        Dask worker (a shared file system).
    params : Params
        Signature parameters.
    solver : {"auto", "cholmod", "eigen", "scipy"}
        Sparse solver backend.
    jobs : int, optional
        Local worker processes; default: the number of CPU cores. Ignored with ``scheduler``.
    scheduler : str, optional
        Address of a running Dask scheduler (``tcp://host:port``): compute on its workers
        instead of local processes. Needs the ``dask`` extra, and cfsig installed on the workers.
    compute : callable, optional
        ``compute(path, params, solver)``, a module-level function (it is pickled by name)
        whose return value each outcome carries; default:
        `cfsig.descriptors.signature.signature_file`.
    limits : Limits, optional
        Wall time and memory allowed to each file's proxy remesh, when ``compute`` is the
        default (`cfsig.descriptors.signature.signature_file`).

    Yields
    ------
    outcome : Outcome
        One per path, in completion order; those that complete together, in the order of
        ``paths``.

    Raises
    ------
    MissingDependencyError
        ``scheduler`` given and Dask's distributed package not installed.
    ClusterError
        The scheduler cannot be reached.
    """
    compute = compute or _signature_file(limits)
    if scheduler is not None:
        yield from _compute_on_cluster(paths, params, solver, scheduler, compute)
        return
    jobs = max(1, jobs or os.cpu_count() or 1)
    pending = iter(paths)
    suspects: list[Path] = []
    with _pool(jobs) as pool:
        running: dict[Future, Path] = {}
        while True:
            while len(running) < 2 * jobs and (path := next(pending, None)) is not None:
                running[pool.submit(_work, path, params, solver, compute)] = path
            if not running:
                break
            done, _ = wait(running, return_when=FIRST_COMPLETED)
            # Those done together in the order they were sent: with one job, the order of the files.
            for future in [f for f in running if f in done]:
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
            yield _isolated(path, params, solver, compute)
        yield from compute_many(pending, params, solver, jobs, compute=compute)


def index_meshes(
    writer: IndexWriter,
    paths: Iterable[str | os.PathLike],
    solver: str = "auto",
    jobs: int | None = None,
    scheduler: str | None = None,
    strict: bool = False,
    commit_every: int = 200,
    progress: Progress | None = None,
    limits: Limits | None = None,
    classes: Mapping[str, str] | None = None,
    prune: bool = False,
) -> Indexed:
    """Compute the new and changed meshes under some files and folders and add them to an index.

    Files are found by `cfsig.files.folders.find_meshes` as the computation goes: the first is
    computed
    as soon as it is found, not after the whole folder has been scanned. A file whose name is
    indexed with the same contents (SHA-256) is skipped, and only those files are hashed; the
    others are computed by `compute_many` and added as `Entry` (name, the name of the folder
    holding the file as label, absolute path as given, links not resolved). The writer commits
    every ``commit_every`` meshes and every 30 s, so a killed job keeps what it committed;
    the caller's ``with writer`` commits the rest, with the relabelling and pruning queued
    last, together. Memory holds the files in flight, not the folder (and, when several paths
    are given, the names seen, to refuse a name taken twice; with ``classes``, the names under
    the paths; with ``classes`` or ``prune``, the index's names).

    Parameters
    ----------
    writer : IndexWriter
        The open index; its ``params`` are those computed.
    paths : iterable of str or os.PathLike
        Mesh files and folders.
    solver : {"auto", "cholmod", "eigen", "scipy"}
        Sparse solver backend.
    jobs, scheduler
        As `compute_many`.
    strict : bool
        Stop at the first file that fails.
    commit_every : int
        Meshes between commits.
    progress : callable, optional
        ``progress(outcomes, total)`` wraps the iterator of `Outcome` (in completion order) and
        yields the same outcomes, e.g. to show a progress bar; ``total()`` is the number of
        files to compute found so far.
    limits : Limits, optional
        As `compute_many`.
    classes : mapping of str to str, optional
        Model id -> class (`cfsig.files.cla.read_cla`): the label of every mesh, added or
        already indexed, whose id it lists (`cfsig.files.cla.labels_from_cla`); the others
        keep their folder's name. Relabelling recomputes nothing.
    prune : bool
        Drop the entries whose file, under one of the folders given, no longer exists.

    Returns
    -------
    indexed : Indexed

    Raises
    ------
    MissingDependencyError, ClusterError
        As `compute_many`.
    EmptyPathError
        A folder given holds no mesh file: nothing is changed.
    UnknownNameError
        ``classes`` lists ids that no mesh indexed or under the paths has: nothing is changed.
    IndexFileError
        A commit failed.
    """
    from cfsig.index.store import Entry

    roots = list(paths)
    check_inputs(writer.path, roots, classes)
    names: dict[Path, str] = {}  # the files found to compute (those in flight), and their names
    taken: set[str] | None = set() if len(roots) > 1 else None  # one folder has unique names
    failures: list[str] = []
    kept: list[Entry] = []  # files indexed already, whose label or path may have changed
    found = updated = 0

    def label(path: Path) -> str:
        return (labels_from_cla([path.name], classes)[0] if classes else None) or mesh_label(path)

    def todo() -> Iterator[Path]:
        nonlocal found, updated
        for path, name in find_meshes(roots):
            if taken is not None and name in taken:
                failures.append(f"{path}: its name {name!r} is already taken by another file")
                continue
            if taken is not None:
                taken.add(name)
            if not writer.is_current(name, path):
                names[path] = name
                found += 1
                yield path
            else:
                kept.append(Entry(name, label(path), os.path.abspath(path)))
                if len(kept) >= commit_every:
                    updated += writer.update(kept)
                    kept.clear()

    added, last_commit = 0, time.monotonic()
    outcomes = compute_many(todo(), writer.params, solver, jobs, scheduler, limits=limits)
    for path, signature in successes(outcomes, lambda: found, failures, strict, progress):
        writer.add(Entry(names.pop(path), label(path), os.path.abspath(path)), signature)
        added += 1
        if writer.pending >= commit_every or time.monotonic() - last_commit > _COMMIT_SECONDS:
            writer.commit()
            last_commit = time.monotonic()
    updated += writer.update(kept)
    writer.commit()
    updated += _relabel(writer, classes) if classes else 0
    pruned = _prune(writer, roots) if prune else 0
    return Indexed(added, updated, pruned, failures)


def _committed(writer: IndexWriter, *columns: str) -> list:
    """Some columns of the rows an index has committed."""
    from cfsig.index.store import IndexReader

    with IndexReader(writer.path) as reader:
        return [reader.column(key) for key in columns]


def check_inputs(
    index: str | os.PathLike,
    paths: Iterable[str | os.PathLike],
    classes: Mapping[str, str] | None = None,
) -> None:
    """Refuse what `index_meshes` refuses before it changes anything.

    Parameters
    ----------
    index : str or path-like
        The index, existing or not.
    paths : iterable of str or path-like
        Mesh files and folders.
    classes : mapping of str to str, optional
        As `index_meshes` takes them.

    Raises
    ------
    EmptyPathError
        A folder holds no mesh file.
    UnknownNameError
        ``classes`` lists an id that no mesh indexed or under ``paths`` has.
    IndexFileError
        With ``classes``: the index is unusable.
    """
    from cfsig.index.store import IndexReader, existing_params

    roots = list(paths)
    for root in roots:
        if Path(root).is_dir() and next(find_meshes([root]), None) is None:
            raise EmptyPathError(f"{root}: no mesh file under it")
    if classes is None:
        return
    names = [name for _, name in find_meshes(roots)]
    if existing_params(index) is not None:
        with IndexReader(index) as reader:
            names += list(reader.column("names"))
    stems = [Path(name).stem for name in names]
    lacking = sorted(set(classes) - set(stems) - {s.removeprefix("m") for s in stems})
    if lacking:
        more = f" (and {len(lacking) - 1} more)" if len(lacking) > 1 else ""
        raise UnknownNameError(f"lists model {lacking[0]!r}{more}, which no mesh has")


def _relabel(writer: IndexWriter, classes: Mapping[str, str]) -> int:
    """Queue the classes' labels for the committed entries whose label differs."""
    from cfsig.index.store import Entry

    names, labels, paths = _committed(writer, "names", "labels", "paths")
    wanted = labels_from_cla(names, classes)
    rows = zip(names, labels, paths, wanted, strict=True)
    return writer.update(Entry(n, w, p) for n, old, p, w in rows if w and w != old)


def _prune(writer: IndexWriter, roots: list[str | os.PathLike]) -> int:
    """Queue the removal of the committed entries whose file under a folder of ``roots`` is
    gone; return their number."""
    folders = tuple(os.path.join(os.path.abspath(r), "") for r in roots if Path(r).is_dir())
    names, paths = _committed(writer, "names", "paths")
    gone = [
        name
        for name, path in zip(names, paths, strict=True)
        if path.startswith(folders) and not os.path.exists(path)
    ]
    writer.remove(gone)
    return len(gone)


def successes(
    outcomes: Iterator[Outcome],
    total: Callable[[], int],
    failures: list[str],
    strict: bool = False,
    progress: Progress | None = None,
) -> Iterator[tuple[Path, Signature]]:
    """The signatures among some outcomes, as they come; the errors go to ``failures``.

    Parameters
    ----------
    outcomes : iterator of Outcome
        As `compute_many` yields them.
    total : callable
        ``total()`` is the number of outcomes expected so far, for ``progress``.
    failures : list of str
        Appended with the error line of each outcome that failed.
    strict : bool
        Stop at the first outcome that failed.
    progress : callable, optional
        ``progress(outcomes, total)`` wraps the iterator and yields the same outcomes, e.g. to
        show a progress bar whose total may grow.

    Yields
    ------
    path : Path
        A mesh file that gave a signature.
    signature : Signature
        Its signature.
    """
    for outcome in progress(outcomes, total) if progress else outcomes:
        if outcome.signature is None:
            failures.append(outcome.error)
            if strict:
                return
            continue
        yield outcome.path, outcome.signature


def _compute_on_cluster(
    paths: Iterable[Path], params: Params, solver: str, address: str, compute: Compute
) -> Iterator[Outcome]:
    """`compute_many` on the workers of a Dask cluster, a sliding window of tasks in flight.

    Each task computes a batch of files, as many as the workers' reported seconds per file fit
    in `_TASK_SECONDS` (at most `_MAX_BATCH`, one until a first batch is back): Dask's cost per
    task is then paid once per batch, not per file (docs/performance.md). A batch whose task
    fails as a whole (its worker died, and Dask's retries too) is sent again file by file, so
    that a bad file fails alone, as it would in a task of its own. A worker's death also fails
    the tasks queued behind on it, so a file whose own task failed is sent once more with
    nothing else in flight, and reported as failed only if it fails then.
    """
    try:
        from distributed import Client, as_completed
    except ImportError:
        raise MissingDependencyError(
            "--scheduler needs Dask's distributed package: pip install 'cfsig[dask]'"
        ) from None
    try:
        client = Client(address, timeout=_CONNECT_TIMEOUT, set_as_default=False)
    except (OSError, TimeoutError, ValueError) as exc:
        raise ClusterError(f"cannot connect to the Dask scheduler at {address}: {exc}") from None
    with client:
        window = 2 * max(1, sum(client.nthreads().values()))
        pending = iter(paths)
        running: dict = {}
        alone: list[Path] = []  # the files of batches that failed as a whole, to send one by one
        suspects: list[Path] = []  # files whose own task failed, to send with nothing beside
        solo: set = set()  # the future of the suspect in flight
        seconds, done = 0.0, 0  # work reported by the workers, and the files it took

        def submit(count: int) -> list:
            """Send up to ``count`` more batches to the cluster; return their futures."""
            futures = []
            for _ in range(count):
                if solo or (suspects and running):
                    break  # a suspect runs with nothing beside it
                suspect = bool(suspects)
                if suspects or alone:
                    batch = [(suspects or alone).pop(0)]
                else:
                    fit = int(_TASK_SECONDS * done / seconds) if done else 1
                    batch = list(islice(pending, max(1, min(_MAX_BATCH, fit))))
                if not batch:
                    break
                absolute = [str(Path(path).resolve()) for path in batch]
                future = client.submit(_work_batch, absolute, params, solver, compute, pure=False)
                futures.append(future)
                running[future] = batch
                if suspect:
                    solo.add(future)
            return futures

        tasks = as_completed(submit(window), loop=client.loop)
        for future in tasks:
            batch = running.pop(future)
            try:
                results, took = future.result()
            except Exception as exc:  # Dask re-raises what failed remotely, or KilledWorker
                if future in solo:
                    yield Outcome(batch[0], None, f"{batch[0]}: failed on the cluster: {exc}")
                elif len(batch) == 1:
                    suspects.append(batch[0])
                else:
                    alone.extend(batch)
                results, took = [], 0.0
            solo.discard(future)
            seconds, done = seconds + took, done + len(results)
            for path, result in zip(batch, results, strict=False):
                if isinstance(result, str):
                    yield Outcome(path, None, f"{path}: failed on the cluster: {result}")
                else:
                    yield Outcome(path, result.signature, result.error)
            future.release()
            tasks.update(submit(window - len(running)))


def _signature_file(limits: Limits | None) -> Compute:
    """`cfsig.descriptors.signature.signature_file` with ``limits``, imported when first needed:
    the process
    that hands out the files and writes the index computes nothing, and so starts without
    loading SciPy (docs/performance.md, "Start-up")."""
    from cfsig.descriptors.signature import signature_file

    return signature_file if limits is None else partial(signature_file, limits=limits)


def _work_batch(
    paths: list[str], params: Params, solver: str, compute: Compute
) -> tuple[list[Outcome | str], float]:
    """Compute a batch of files on a Dask worker, each failure costing only its own file.

    Returns the outcome of each file, or the text of the exception it raised, and the seconds
    the batch took.
    """
    start = time.perf_counter()
    results: list[Outcome | str] = []
    for path in paths:
        try:
            results.append(_work(Path(path), params, solver, compute))
        except Exception as exc:  # what a task of its own would have raised to the client
            results.append(str(exc))
    return results, time.perf_counter() - start


def _work(path: Path, params: Params, solver: str, compute: Compute) -> Outcome:
    """Compute one file's signature in a worker, turning library errors into an outcome."""
    try:
        return Outcome(path, compute(path, params, solver))
    except CfsigError as exc:
        return Outcome(path, None, str(exc))
    except MemoryError:
        return Outcome(path, None, f"{path}: out of memory")


def _isolated(path: Path, params: Params, solver: str, compute: Compute) -> Outcome:
    """Compute one file alone in a fresh worker, reporting a crash of that worker."""
    with _pool(1) as pool:
        try:
            return pool.submit(_work, path, params, solver, compute).result()
        except BrokenProcessPool:
            return Outcome(path, None, f"{path}: the worker process crashed on this file")


def _pool(jobs: int) -> ProcessPoolExecutor:
    """A process pool of fresh interpreters with one BLAS/OpenMP thread each."""
    ctx = multiprocessing.get_context("spawn")
    return ProcessPoolExecutor(
        jobs, mp_context=ctx, initializer=_start_worker, initargs=(os.getpid(),)
    )


def _start_worker(parent: int) -> None:
    """In a new worker: one thread per native thread pool, and exit when the parent dies."""
    from threadpoolctl import threadpool_limits

    from cfsig.operators.conformal import available_solvers

    available_solvers()  # loads the solver libraries, so that the limit reaches their pools too
    threadpool_limits(1)  # stays in force for the life of the worker
    _exit_with_parent(parent)


def _exit_with_parent(parent: int) -> None:
    """In a worker: exit as soon as the parent dies (killed batch jobs leave no orphans)."""

    def watch() -> None:
        while os.getppid() == parent:
            time.sleep(0.5)
        os._exit(1)

    threading.Thread(target=watch, daemon=True).start()
