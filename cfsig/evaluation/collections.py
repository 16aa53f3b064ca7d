"""Evaluation of labelled collections: signatures of a folder or an index, ranked leave-one-out.

A `Collection` holds the signatures of labelled meshes for one descriptor, computed from a
folder (`compute_collection`) or read from an index (`collection_from_index`);
`evaluate_collections` evaluates one or several of them side by side on the same meshes with
the measures of `cfsig.evaluation.measures`, the classes taken from the folders or from a `.cla`
file
(`cfsig.files.cla`).
"""

from __future__ import annotations

import os
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, replace
from pathlib import Path

import numpy as np

from cfsig import descriptors
from cfsig.batch import Progress, compute_many, successes
from cfsig.descriptors.parts import Part, curvature_columns, partial_file
from cfsig.errors import MeshError
from cfsig.evaluation.measures import RetrievalReport, evaluate_distances, evaluate_queries
from cfsig.files.cla import labels_from_cla
from cfsig.files.folders import find_meshes, mesh_label
from cfsig.index.store import IndexReader
from cfsig.isolate import Limits
from cfsig.params import Params
from cfsig.search.nearest import check_layout
from cfsig.search.nearest import distances as descriptor_distances
from cfsig.search.partial import expanded_distances


@dataclass(frozen=True)
class Collection:
    """The signatures of a labelled collection of meshes for one descriptor, in file order.

    Attributes
    ----------
    names : tuple of str
        Length n: each mesh's name, its path relative to the collection's folder.
    labels : tuple of str
        Length n: each mesh's class, the name of the folder holding it.
    paths : tuple of str
        Length n: each mesh file.
    signatures : np.ndarray
        Shape (n, length), float: one signature per row.
    seconds : np.ndarray or None
        Shape (n,), seconds: wall time of each signature, reading included; None when the
        signatures were not timed (read from an index).
    descriptor : str
        The descriptor of the signatures (a name of `cfsig.descriptors.NAMES`), which decides
        how they compare (`cfsig.search.nearest.distances`).

    Raises
    ------
    ValueError
        If the attributes do not all hold one entry per mesh.
    """

    names: tuple[str, ...]
    labels: tuple[str, ...]
    paths: tuple[str, ...]
    signatures: np.ndarray
    seconds: np.ndarray | None = None
    descriptor: str = descriptors.NAMES[0]

    def __post_init__(self) -> None:
        """Check that every attribute has one entry per mesh."""
        n = len(self.names)
        timed = n if self.seconds is None else len(self.seconds)
        sizes = {len(self.labels), len(self.paths), len(self.signatures), timed}
        if sizes != {n} or self.signatures.ndim != 2:
            raise ValueError(
                f"a collection needs one name, label, path, signature row and time per mesh, "
                f"got {n} names, {len(self.labels)} labels, {len(self.paths)} paths, "
                f"signatures of shape {self.signatures.shape} and {timed} times"
            )

    def __len__(self) -> int:
        """The number of meshes."""
        return len(self.names)

    def subset(self, rows: Sequence[int]) -> Collection:
        """The meshes at some rows.

        Parameters
        ----------
        rows : sequence of int
            Length m: row numbers, in the order wanted.

        Returns
        -------
        Collection
            Of the m meshes.
        """
        rows = list(rows)
        names, labels, paths = (
            tuple(column[i] for i in rows) for column in (self.names, self.labels, self.paths)
        )
        return Collection(
            names,
            labels,
            paths,
            self.signatures[rows],
            None if self.seconds is None else self.seconds[rows],
            self.descriptor,
        )


@dataclass(frozen=True)
class Evaluation:
    """The retrieval measures of one collection and what they were computed from.

    Attributes
    ----------
    report : RetrievalReport
        The measures.
    collection : Collection
        The m meshes evaluated (those with a class, and common to all the collections evaluated
        together), in file order, labelled with the classes the measures used.
    distances : np.ndarray
        Shape (m, m), float64: the descriptor's distances between their signatures
        (`cfsig.search.nearest.distances`: L1 for most).
    seconds_per_mesh : float or None
        Median seconds per mesh over the whole collection given (not only the evaluated
        meshes); None when it was not timed.
    """

    report: RetrievalReport
    collection: Collection
    distances: np.ndarray
    seconds_per_mesh: float | None


def compute_collection(
    folder: str | os.PathLike,
    params: Params,
    solver: str = "auto",
    jobs: int | None = None,
    strict: bool = False,
    progress: Progress | None = None,
    limits: Limits | None = None,
) -> tuple[Collection, list[str]]:
    """Compute the signatures of all mesh files in a folder, each subfolder a class.

    Files are found by `cfsig.files.folders.find_meshes` and computed in spawned worker processes by
    `cfsig.batch.compute_many` (in a script, call it under ``if __name__ == "__main__":``); a
    file that fails is left out and reported.

    Parameters
    ----------
    folder : str or os.PathLike
        Walked recursively for mesh files (`cfsig.files.folders.MESH_SUFFIXES`). A mesh's
        label is the name of the folder holding it (``folder``'s own name for files directly
        in it).
    params : Params
        Signature parameters, the descriptor included.
    solver : {"auto", "cholmod", "eigen", "scipy"}
        Sparse solver backend.
    jobs : int, optional
        Worker processes; default: the number of CPU cores.
    strict : bool
        Stop at the first file that fails (the collection then holds the files finished
        before it).
    progress : callable, optional
        ``progress(outcomes, total)`` wraps the iterator of `cfsig.batch.Outcome` (``total``
        files, in completion order) and yields the same outcomes, e.g. to show a progress bar.
    limits : Limits, optional
        Wall time and memory allowed to each file's proxy remesh (`cfsig.batch.compute_many`).

    Returns
    -------
    collection : Collection
        The meshes computed, in file order, timed; empty (signatures of shape (0, length)) if
        every file failed.
    failures : list of str
        One line per file that failed, ``<file>: <reason>``.

    Raises
    ------
    MeshError
        If the folder holds no mesh file.
    """
    folder = Path(folder)
    found = dict(find_meshes([folder]))
    if not found:
        raise MeshError(f"{folder}: no mesh files")
    failures: list[str] = []
    outcomes = compute_many(found, params, solver, jobs, limits=limits)
    signatures = dict(successes(outcomes, lambda: len(found), failures, strict, progress))
    order = [path for path in found if path in signatures]
    names = tuple(found[path] for path in order)
    rows = np.array([signatures[path].vector for path in order])
    collection = Collection(
        names,
        tuple(mesh_label(path) for path in order),
        tuple(str(folder / name) for name in names),
        rows.reshape(
            len(order), descriptors.layout(params).length
        ),  # (0, length) if every file failed
        np.array([signatures[path].seconds for path in order], dtype=float),
        params.descriptor,
    )
    return collection, failures


def collection_from_index(path: str | os.PathLike) -> tuple[str, Collection]:
    """Read the signatures of an index as a collection.

    Parameters
    ----------
    path : str or os.PathLike
        The index (a folder, or a format-1 file).

    Returns
    -------
    descriptor : str
        The index's descriptor (a name of `cfsig.descriptors.NAMES`).
    collection : Collection
        All its meshes in index order, labelled as indexed, untimed (``seconds`` None).

    Raises
    ------
    IndexFileError
        If the index is missing, not HDF5, corrupt, not a cfsig index, of a newer version, or
        made by an earlier version of its descriptor (`check_layout`).
    """
    with IndexReader(path) as reader:
        check_layout(reader)
        names, labels, paths = (tuple(reader.column(key)) for key in ("names", "labels", "paths"))
        name = reader.params.descriptor
        return name, Collection(names, labels, paths, reader.signatures[:], descriptor=name)


def evaluate_partial(
    index: str | os.PathLike, folder: str | os.PathLike, jobs: int | None = None
) -> tuple[RetrievalReport, list[str]]:
    """Partial queries from a labelled folder against the whole shapes of an index.

    Each mesh of ``folder`` is a part (a cut, a scan, a shape with holes) whose class is the
    name of the folder holding it; it is ranked against every indexed mesh as
    `cfsig.search.partial.query_part` ranks them, and the relevant ones are the indexed meshes of
    its class (`evaluate_queries`).

    Parameters
    ----------
    index : str or os.PathLike
        An index of the ``intrinsic`` descriptor.
    folder : str or os.PathLike
        Walked recursively for mesh files.
    jobs : int, optional
        Worker processes measuring the parts (`cfsig.batch.compute_many`: a part that crashes
        its worker fails alone); default: the number of CPU cores.

    Returns
    -------
    report : RetrievalReport
        Over the parts whose class is indexed.
    failures : list of str
        One line per part that could not be read or solved, ``<file>: <reason>``.

    Raises
    ------
    IndexFileError
        As `collection_from_index`.
    PartialError
        The index's descriptor has no curvature channel.
    MeshError
        The folder holds no mesh file, or no part could be computed.
    ValueError
        No part's class is in the index.
    """
    with IndexReader(index) as reader:
        params = reader.params
        curvature_columns(params)
        labels, signatures, cells = reader.column("labels"), reader.signatures[:], reader.cells()
    found = dict(find_meshes([folder]))
    if not found:
        raise MeshError(f"{folder}: no mesh files")
    rows, asked, failures = [], [], []
    paths = list(found)
    parts = {o.path: o for o in compute_many(paths, params, jobs=jobs, compute=_part_file)}
    for path in paths:
        part = parts[path].signature
        if part is None:
            failures.append(parts[path].error)
        else:
            rows.append(expanded_distances(part, signatures, params, cells))
            asked.append(mesh_label(path))
    if not rows:
        raise MeshError(f"{folder}: no part could be computed")
    return evaluate_queries(np.array(rows), asked, [str(label) for label in labels]), failures


def _part_file(path: Path, params: Params, solver: str) -> Part:
    """`partial_file` as `compute_many` calls it: parts are solved by the default solver."""
    return partial_file(path, params)


def evaluate_collections(
    collections: Mapping[str, Collection], classes: Mapping[str, str] | None = None
) -> dict[str, Evaluation]:
    """Evaluate one or several collections side by side on the same meshes (leave-one-out, each
    by its descriptor's distance).

    The meshes evaluated are those whose names are in every collection and that have a class,
    so that the measures of several descriptors of one folder compare the same queries.

    Parameters
    ----------
    collections : mapping of str to Collection
        Descriptor (or any name) -> its collection.
    classes : mapping of str to str, optional
        Model id -> class name, as `read_cla` returns, replacing the collections' labels
        (`labels_from_cla`: meshes whose id is absent are left out).

    Returns
    -------
    dict of str to Evaluation
        The same keys, in the same order.

    Raises
    ------
    ValueError
        If there is no collection, or the meshes evaluated leave no class with at least two
        members (`evaluate_distances`).
    """
    if not collections:
        raise ValueError("no collection to evaluate")
    common = set.intersection(*(set(c.names) for c in collections.values()))
    return {name: _evaluate(c, common, classes) for name, c in collections.items()}


def _evaluate(
    collection: Collection, common: set[str], classes: Mapping[str, str] | None
) -> Evaluation:
    """Evaluate the meshes of ``collection`` that are in ``common`` and have a class."""
    labels = (
        labels_from_cla(collection.names, classes) if classes is not None else collection.labels
    )
    pairs = enumerate(zip(collection.names, labels, strict=True))
    keep = [i for i, (name, label) in pairs if name in common and label]
    evaluated = replace(collection.subset(keep), labels=tuple(str(labels[i]) for i in keep))
    signatures = evaluated.signatures
    distances = descriptor_distances(collection.descriptor, signatures, signatures)
    report = evaluate_distances(distances, evaluated.labels)
    seconds = None if collection.seconds is None else float(np.median(collection.seconds))
    return Evaluation(report, evaluated, distances, seconds)
