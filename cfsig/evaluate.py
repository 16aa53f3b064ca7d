"""Retrieval measures of the Princeton Shape Benchmark and SHREC.

Every model is used as a query against all the other models (leave-one-out), which are ranked
by ascending distance. For a query whose class has ``C`` members, the ``C - 1`` other members
are relevant and the measures are (Shilane, Min, Kazhdan and Funkhouser, "The Princeton Shape
Benchmark", Shape Modeling International 2004):

- ``NN`` (nearest neighbour): 1 if the top result is relevant, else 0.
- ``FT`` (first tier): fraction of the relevant models found in the top ``C - 1`` results.
- ``ST`` (second tier): fraction of the relevant models found in the top ``2 (C - 1)``.
- ``E`` (E-measure): ``2 / (1/P + 1/R)`` with precision ``P`` and recall ``R`` in the top 32
  results (all results if there are fewer; 0 when none of them is relevant).
- ``DCG`` (discounted cumulative gain): ``G_1 + sum_{i>=2} G_i / log2(i)`` over the whole
  ranking, where ``G_i`` is 1 for a relevant result, normalised by its ideal value
  ``1 + sum_{j=2}^{C-1} 1 / log2(j)``.
- ``mAP``: average precision (mean precision at the rank of each relevant result).
- Precision/recall curve: interpolated precision at recall 0.05, 0.10, ..., 1.00, i.e. the
  maximum precision over ranks whose recall is at least that level.

Overall measures are micro averages (mean over all queries, as in PSB); per-class measures
average over the queries of one class.

A `Collection` holds the signatures of labelled meshes for one descriptor, computed from a
folder (`compute_collection`) or read from an index (`collection_from_index`);
`evaluate_collections` evaluates one or several of them side by side on the same meshes.
"""

from __future__ import annotations

import os
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field, replace
from pathlib import Path

import numpy as np

from .batch import Progress, compute_many
from .errors import MeshError
from .index import IndexReader
from .mesh import find_meshes
from .params import Params, signature_length
from .search import l1_distances

MEASURES = ("NN", "FT", "ST", "E", "DCG", "mAP")
RECALL_LEVELS = np.arange(1, 21) / 20.0
_E_DEPTH = 32


@dataclass(frozen=True)
class RetrievalReport:
    """Retrieval measures of a leave-one-out evaluation.

    Attributes
    ----------
    measures : dict[str, float]
        Mean over all evaluated queries of ``NN``, ``FT``, ``ST``, ``E``, ``DCG`` and ``mAP``.
    per_class : dict[str, dict[str, float]]
        Class name -> the same six measures averaged over that class's queries (only classes
        with at least two members).
    precision_recall : np.ndarray
        Shape (20, 2): rows ``[recall, precision]`` at recall 0.05, 0.10, ..., 1.00, the
        interpolated precision averaged over all evaluated queries.
    count : int
        Number of queries evaluated.
    class_precision_recall : dict[str, np.ndarray]
        Class name -> shape (20,): interpolated precision at recall 0.05, ..., 1.00 averaged
        over that class's queries (the classes of ``per_class``).
    """

    measures: dict[str, float]
    per_class: dict[str, dict[str, float]]
    precision_recall: np.ndarray
    count: int
    class_precision_recall: dict[str, np.ndarray] = field(default_factory=dict)

    def to_dict(self) -> dict:
        """Return the report as plain JSON-serialisable Python.

        Returns
        -------
        dict
            Keys ``measures`` (dict of float), ``per_class`` (dict of dict of float),
            ``precision_recall`` (list of 20 ``[recall, precision]`` pairs) and ``count``.
        """
        return {
            "measures": {k: float(v) for k, v in self.measures.items()},
            "per_class": {
                c: {k: float(v) for k, v in m.items()} for c, m in self.per_class.items()
            },
            "precision_recall": [[float(r), float(p)] for r, p in self.precision_recall],
            "count": int(self.count),
        }


def _stable_argsort(rows: np.ndarray) -> np.ndarray:
    """Row-wise argsort with ties broken by index, using the faster quicksort on tie-free rows."""
    order = np.argsort(rows, axis=1)
    ordered = np.take_along_axis(rows, order, axis=1)
    tied = (ordered[:, 1:] == ordered[:, :-1]).any(axis=1)
    if tied.any():
        order[tied] = np.argsort(rows[tied], axis=1, kind="stable")
    return order


def _class_scores(
    distances: np.ndarray, codes: np.ndarray, queries: np.ndarray, code: int
) -> tuple[np.ndarray, np.ndarray]:
    """Per-query measures (q, 6) and interpolated precision (q, 20) for one class's queries."""
    n = distances.shape[0]
    q = queries.size
    nrel = q - 1
    order = _stable_argsort(distances[queries])
    order = order[order != queries[:, None]].reshape(q, n - 1)  # leave the query out
    pos = np.nonzero((codes == code)[order])[1].reshape(q, nrel)  # 0-based ranks of relevant
    gain = 1.0 / np.log2(np.maximum(np.arange(1, n), 2))  # rank 1 -> 1, rank i >= 2 -> 1/log2 i
    precision = np.arange(1, nrel + 1) / (pos + 1.0)
    scores = np.column_stack(
        [
            pos[:, 0] == 0,
            np.mean(pos < nrel, axis=1),
            np.mean(pos < 2 * nrel, axis=1),
            2.0 * np.sum(pos < _E_DEPTH, axis=1) / (min(_E_DEPTH, n - 1) + nrel),
            gain[pos].sum(axis=1) / gain[:nrel].sum(),
            precision.mean(axis=1),
        ]
    ).astype(float)
    # Precision only rises at relevant ranks, so the maximum over ranks with recall >= j/20 is
    # the maximum over the k-th relevant ranks with k >= ceil(j * nrel / 20).
    best = np.maximum.accumulate(precision[:, ::-1], axis=1)[:, ::-1]
    first = -(-np.arange(1, 21) * nrel // 20) - 1
    return scores, best[:, first]


def evaluate_distances(distances: np.ndarray, labels: Sequence[str]) -> RetrievalReport:
    """Evaluate a distance matrix with the PSB/SHREC retrieval measures.

    Each model is a query against all the other models (leave-one-out: the query itself is
    removed from its own ranking). Results are ranked by ascending distance, ties broken by
    model index (stable sort), so the ranking does not depend on the diagonal. Queries whose
    class has a single member have no relevant model: they are excluded from every average and
    from ``count`` and their class is absent from ``per_class``; they still take part as
    (irrelevant) results of the other queries.

    Parameters
    ----------
    distances : np.ndarray
        Shape (n, n), float: ``distances[i, j]`` is the distance from query ``i`` to model
        ``j``. It need not be symmetric.
    labels : Sequence[str]
        Length n: class name of each model.

    Returns
    -------
    RetrievalReport
        Overall (micro-averaged) and per-class measures, the 20-point precision/recall curve and
        the number of queries evaluated.

    Raises
    ------
    ValueError
        If ``distances`` is not a square 2-D matrix, its size differs from ``len(labels)``,
        it contains NaN, or no class has at least two members.
    """
    distances = np.asarray(distances, dtype=float)
    if distances.ndim != 2 or distances.shape[0] != distances.shape[1]:
        raise ValueError(f"distances must be a square (n, n) matrix, got shape {distances.shape}")
    if len(labels) != distances.shape[0]:
        raise ValueError(
            f"distances is {distances.shape[0]}x{distances.shape[0]} but there are "
            f"{len(labels)} labels"
        )
    if np.isnan(distances).any():
        raise ValueError("distances contains NaN")
    names, codes, sizes = np.unique(
        np.asarray([str(label) for label in labels]), return_inverse=True, return_counts=True
    )
    if not (sizes >= 2).any():
        raise ValueError("no class has at least two members: nothing to retrieve")
    scores, curves, per_class, class_curves = [], [], {}, {}
    for code in np.flatnonzero(sizes >= 2):
        s, c = _class_scores(distances, codes, np.flatnonzero(codes == code), int(code))
        scores.append(s)
        curves.append(c)
        per_class[str(names[code])] = dict(zip(MEASURES, map(float, s.mean(axis=0)), strict=True))
        class_curves[str(names[code])] = c.mean(axis=0)
    scores = np.concatenate(scores)
    precision = np.concatenate(curves).mean(axis=0)
    return RetrievalReport(
        measures=dict(zip(MEASURES, map(float, scores.mean(axis=0)), strict=True)),
        per_class=per_class,
        precision_recall=np.column_stack([RECALL_LEVELS, precision]),
        count=len(scores),
        class_precision_recall=class_curves,
    )


def _int(token: str, where: str) -> int:
    """Parse a non-negative integer count or raise a ValueError naming its location."""
    try:
        value = int(token)
    except ValueError:
        raise ValueError(f"{where}: expected an integer, got {token!r}") from None
    if value < 0:
        raise ValueError(f"{where}: expected a non-negative integer, got {value}")
    return value


def read_cla(path: str | os.PathLike) -> dict[str, str]:
    """Read a Princeton Shape Benchmark classification (``.cla``) file.

    The format is a ``PSB 1`` header line, a ``numClasses numModels`` line, then for each class
    a ``name parentName count`` line followed by ``count`` lines of model ids. Blank lines are
    ignored.

    Parameters
    ----------
    path : str or os.PathLike
        The ``.cla`` file.

    Returns
    -------
    dict[str, str]
        Model id (as written in the file) -> class name, ``numModels`` entries.

    Raises
    ------
    ValueError
        If the header is not ``PSB 1``, a count is not a non-negative integer, a line has the
        wrong number of fields, a model id appears twice, the file ends early or has extra
        lines, or the counts do not add up to the declared numbers.
    """
    with open(path, encoding="utf-8") as f:
        lines = [(i, line.split()) for i, line in enumerate(f, 1) if line.strip()]
    if not lines or lines[0][1] != ["PSB", "1"]:
        raise ValueError(f"{path}: not a PSB classification file (first line must be 'PSB 1')")
    if len(lines) < 2 or len(lines[1][1]) != 2:
        raise ValueError(f"{path}: second line must be 'numClasses numModels'")
    where = f"{path}:{lines[1][0]}"
    num_classes, num_models = (_int(t, where) for t in lines[1][1])
    classes: dict[str, str] = {}
    k = 2
    for _ in range(num_classes):
        if k >= len(lines):
            raise ValueError(f"{path}: file ends before the {num_classes} declared classes")
        lineno, fields = lines[k]
        if len(fields) != 3:
            raise ValueError(f"{path}:{lineno}: expected 'name parentName count', got {fields}")
        name, count = fields[0], _int(fields[2], f"{path}:{lineno}")
        members = lines[k + 1 : k + 1 + count]
        if len(members) < count or any(len(m) != 1 for _, m in members):
            raise ValueError(f"{path}:{lineno}: class {name!r} should list {count} model ids")
        for mline, (model,) in members:
            if model in classes:
                raise ValueError(f"{path}:{mline}: duplicate model id {model!r}")
            classes[model] = name
        k += 1 + count
    if k != len(lines):
        raise ValueError(f"{path}:{lines[k][0]}: extra lines after the {num_classes} classes")
    if len(classes) != num_models:
        raise ValueError(
            f"{path}: header declares {num_models} models, classes list {len(classes)}"
        )
    return classes


def labels_from_cla(names: Sequence[str], classes: Mapping[str, str]) -> list[str | None]:
    """Look up the class of mesh files in a `read_cla` mapping by their numeric id.

    A file's id is its stem (``17`` for ``human/17.off``), or the stem without a leading
    ``m`` as the Princeton Shape Benchmark names its files (``m17.off``).

    Parameters
    ----------
    names : sequence of str
        Mesh file names or paths.
    classes : mapping of str to str
        Model id -> class name.

    Returns
    -------
    labels : list of str or None
        None where the id is not in ``classes``.
    """
    stems = [Path(name).stem for name in names]
    return [classes.get(stem, classes.get(stem.removeprefix("m"))) for stem in stems]


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
        return Collection(
            *(tuple(column[i] for i in rows) for column in (self.names, self.labels, self.paths)),
            self.signatures[rows],
            None if self.seconds is None else self.seconds[rows],
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
        Shape (m, m), float64: L1 distances between their signatures.
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
) -> tuple[Collection, list[str]]:
    """Compute the signatures of all mesh files in a folder, each subfolder a class.

    Files are found by `cfsig.mesh.find_meshes` and computed in spawned worker processes by
    `cfsig.batch.compute_many` (in a script, call it under ``if __name__ == "__main__":``); a
    file that fails is left out and reported.

    Parameters
    ----------
    folder : str or os.PathLike
        Walked recursively for OFF, OBJ, PLY and STL files. A mesh's label is the name of the
        folder holding it (``folder``'s own name for files directly in it).
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
    outcomes = compute_many(found, params, solver, jobs)
    signatures, failures = {}, []
    for outcome in progress(outcomes, len(found)) if progress else outcomes:
        if outcome.error:
            failures.append(outcome.error)
            if strict:
                break
        else:
            signatures[outcome.path] = outcome.signature
    order = [path for path in found if path in signatures]
    names = tuple(found[path] for path in order)
    rows = np.array([signatures[path].vector for path in order])
    collection = Collection(
        names,
        tuple(Path(name).parent.name or folder.name for name in names),
        tuple(str(folder / name) for name in names),
        rows.reshape(len(order), signature_length(params)),  # (0, length) if every file failed
        np.array([signatures[path].seconds for path in order], dtype=float),
    )
    return collection, failures


def collection_from_index(path: str | os.PathLike) -> tuple[str, Collection]:
    """Read the signatures of an index as a collection.

    Parameters
    ----------
    path : str or os.PathLike
        The HDF5 index file.

    Returns
    -------
    descriptor : str
        The index's descriptor (``cf`` or ``cfhks``).
    collection : Collection
        All its meshes in index order, labelled as indexed, untimed (``seconds`` None).

    Raises
    ------
    IndexFileError
        If the index is missing, not HDF5, corrupt, not a cfsig index, or of a newer version.
    """
    with IndexReader(path) as reader:
        columns = (tuple(reader.column(key)) for key in ("names", "labels", "paths"))
        return reader.params.descriptor, Collection(*columns, reader.signatures[:])


def evaluate_collections(
    collections: Mapping[str, Collection], classes: Mapping[str, str] | None = None
) -> dict[str, Evaluation]:
    """Evaluate one or several collections side by side on the same meshes (leave-one-out, L1).

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
    evaluated = replace(collection.subset(keep), labels=tuple(labels[i] for i in keep))
    distances = l1_distances(evaluated.signatures, evaluated.signatures)
    report = evaluate_distances(distances, evaluated.labels)
    seconds = None if collection.seconds is None else float(np.median(collection.seconds))
    return Evaluation(report, evaluated, distances, seconds)
