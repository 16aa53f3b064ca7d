"""The index: a folder of immutable segment files behind a small manifest replaced atomically.

Layout (format version 5, docs/index-format.md): ``INDEX/manifest.h5`` holds the header
(``format`` "cfsig-index", ``format_version``, ``params`` and ``layout`` as JSON,
``cfsig_version``, the time of the commit, the count of rows of each class) and the
list of segments with their row counts and file checksums; each ``INDEX/seg-NNNNNNNN.h5``
(`cfsig.index.segments`) holds the rows of one commit, or of several merged by compaction. A commit
writes one new segment, syncs it to disk and renames a new manifest over the old one: it costs
the rows it adds, whatever the size of the index. A name added again supersedes its older row,
which readers skip until compaction drops it; a removal is a commit of a segment without rows
that drops the rows removed. Segments pile up and are merged eight at a time
(`MERGE_FANOUT`), so a row is copied a few times in its life, not at every commit.

A process killed at any moment leaves the manifest of the previous or of the new commit; files
it left that no manifest names are removed by the next writer. One writer at a time holds an
exclusive lock on ``INDEX/lock``. An index of an older format is refused with the command that
rebuilds it.

cfsig runs on POSIX systems (Linux, macOS): the lock is ``flock`` and queries read with
``preadv``. ``fcntl`` is imported by the writer only, so that this module imports anywhere.
"""

from __future__ import annotations

import hashlib
import json
import math
import os
import shutil
import zlib
from collections import Counter
from collections.abc import Iterable
from dataclasses import dataclass, replace
from datetime import datetime, timezone
from pathlib import Path
from typing import IO, NoReturn, Protocol

import h5py
import numpy as np

from cfsig import __version__
from cfsig.errors import IndexFileError, UnknownNameError
from cfsig.index.blocks import BLOCK_ROWS, map_file, plan_blocks, read_rows
from cfsig.index.segments import (
    CELLS,
    COLUMNS,
    GROUP_COLUMNS,
    META,
    SEGMENT_FORMAT,
    SKETCH_EXTRA,
    STRING,
    TEXT,
    Piece,
    name_keys,
    scan_segment,
    write_segment,
)
from cfsig.index.sketch import Sketch
from cfsig.params import Layout, Params

FORMAT = "cfsig-index"
FORMAT_VERSION = 6
MANIFEST = "manifest.h5"
LOCK = "lock"
REBUILD = "rebuild it: cfsig index FOLDER -o NEW_INDEX"
MERGE_FANOUT = 8  # segments of one size class merged into one: each row is copied log8(N) times
_OPEN_ATTEMPTS = 5  # a reader retries when a compaction removed a segment it was about to open
_CRC_BLOCK = 1 << 24


@dataclass(frozen=True)
class Entry:
    """One indexed mesh.

    Attributes
    ----------
    name : str
        Path relative to the folder that was indexed (the file name for a file given alone).
    label : str
        Class label: the name of the mesh file's folder.
    path : str
        Absolute path of the mesh file when it was indexed.
    """

    name: str
    label: str
    path: str


class Signature(Protocol):
    """What the index stores of a mesh's signature (`cfsig.descriptors.signature.Signature`)."""

    @property
    def vector(self) -> np.ndarray: ...  # (layout.length,) float
    @property
    def cells(self) -> tuple[np.ndarray, np.ndarray] | None: ...  # (layout.cells,) each
    @property
    def sha256(self) -> str: ...
    @property
    def n_vertices(self) -> int: ...
    @property
    def n_faces(self) -> int: ...
    @property
    def n_components(self) -> int: ...
    @property
    def phi_range(self) -> tuple[float, float]: ...
    @property
    def curvature_error(self) -> float: ...


@dataclass(frozen=True)
class SegmentInfo:
    """A segment as the manifest lists it.

    Attributes
    ----------
    id : int
        Its number, never reused; the file is ``seg-<id, 8 digits>.h5``.
    rows : int
        Rows in the file.
    live : int
        Rows not superseded by a later segment.
    crc32 : int
        CRC-32 of the whole file.
    """

    id: int
    rows: int
    live: int
    crc32: int

    @property
    def file(self) -> str:
        """The segment's file name in the index folder."""
        return f"seg-{self.id:08d}.h5"


@dataclass(frozen=True)
class Manifest:
    """The committed state of an index.

    Attributes
    ----------
    params : Params
        Parameters of every signature in it.
    layout : Layout
        What it keeps per row.
    segments : tuple of SegmentInfo
        Oldest first; rows are numbered segment after segment.
    next_id : int
        Number of the next segment to write.
    classes : tuple of (str, int)
        Each label of the rows not superseded and its count, sorted by label.
    committed : str
        When this manifest was written: ISO 8601, UTC, to the second.
    version : str
        The cfsig version that wrote it.
    """

    params: Params
    layout: Layout
    segments: tuple[SegmentInfo, ...]
    next_id: int
    classes: tuple[tuple[str, int], ...] = ()
    committed: str = ""
    version: str = __version__


@dataclass(frozen=True)
class SegmentView:
    """An open segment as a reader scans it.

    Attributes
    ----------
    signatures : h5py.Dataset
        (rows, length) float32.
    start : int
        Number of rows, superseded ones included, in the segments before this one.
    dead : (d,) int64
        Sorted rows of this segment superseded by later ones.
    sketch : Sketch or None
        Its rows' sketches, the lower bounds a search prunes by; None: scanned in full.
    copies : tuple of ColumnCopy
        The layout's column groups stored on their own, which a search of those columns reads
        instead of the signatures.
    cells : (h5py.Dataset, h5py.Dataset) or None
        The fine curvature cells of its rows, (rows, slots) uint16, and their shares of the
        area, (rows, slots) uint16 in units of ``1 / UNIT``
        (`cfsig.descriptors.cells.packed_cells`); None for a layout that keeps none.
    """

    signatures: h5py.Dataset
    start: int
    dead: np.ndarray
    sketch: Sketch | None = None
    copies: tuple[ColumnCopy, ...] = ()
    cells: tuple[h5py.Dataset, h5py.Dataset] | None = None


@dataclass(frozen=True)
class ColumnCopy:
    """Some adjacent columns of a segment's signatures, stored again as a dataset of their own.

    Attributes
    ----------
    rows : h5py.Dataset
        (rows, columns.stop - columns.start) float32: ``signatures[:, columns]``.
    columns : slice
        Where they lie in the signatures, with a step of 1.
    """

    rows: h5py.Dataset
    columns: slice


class IndexReader:
    """Read access to an index folder; use as a context manager.

    Rows are numbered from 0 over the rows that are not superseded, segment after segment.

    Parameters
    ----------
    path : str or path-like
        The index.

    Raises
    ------
    IndexFileError
        Missing, not HDF5, corrupt, not a cfsig index, or of another format version.
    """

    def __init__(self, path: str | os.PathLike) -> None:
        self.path = Path(path)
        self._files: list[h5py.File] = []
        try:
            manifest, self.segments = self._open()
        except BaseException:
            self.close()
            raise
        self._dead = np.concatenate(
            [np.zeros(0, np.int64), *(s.start + s.dead for s in self.segments)]
        )
        rows = [s.signatures.shape[0] for s in self.segments]
        self.physical_rows = int(sum(rows))
        self._live_starts = np.cumsum(
            [0] + [r - len(s.dead) for r, s in zip(rows, self.segments, strict=True)]
        )
        self.params, self.layout = manifest.params, manifest.layout
        self.signatures = Signatures(self)
        self._keys: list[_Keys] | None = None

    def _open(self) -> tuple[Manifest, list[SegmentView]]:
        """Open the manifest and its segments."""
        for attempt in range(_OPEN_ATTEMPTS):
            manifest = read_manifest(self.path)
            try:
                files = _open_segments(self.path, manifest.segments)
            except IndexFileError:
                missing = [s for s in manifest.segments if not (self.path / s.file).is_file()]
                if not missing:
                    raise
                if attempt + 1 < _OPEN_ATTEMPTS:
                    continue  # a compaction replaced them after we read the manifest
                raise IndexFileError(f"{self.path}: segment {missing[0].file} is missing") from None
            self._files += files
            dead = _dead_rows(manifest.segments, files, self.path)
            views, start = [], 0
            for info, f in zip(manifest.segments, files, strict=True):
                where = self.path / info.file
                sketch, copies = _read_sketch(f, where), _read_copies(f, where, manifest.layout)
                cells = _read_cells(f, where, manifest.layout.cells)
                view = SegmentView(f["signatures"], start, dead[info.id], sketch, copies, cells)
                views.append(view)
                start += info.rows
            return manifest, views
        raise AssertionError("unreachable")  # pragma: no cover

    def __enter__(self) -> IndexReader:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    def __len__(self) -> int:
        return int(self._live_starts[-1])

    def close(self) -> None:
        """Close the files."""
        for f in self._files:
            f.close()
        self._files = []

    def logical_rows(self, physical: np.ndarray) -> np.ndarray:
        """Row numbers of rows given by their position among all rows, superseded ones included.

        Parameters
        ----------
        physical : (k,) int
            ``SegmentView.start`` plus the row in the segment, of rows not superseded.

        Returns
        -------
        rows : (k,) int64
        """
        physical = np.asarray(physical, np.int64)
        return physical - np.searchsorted(self._dead, physical)

    def _locate(self, rows: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """The segment and the row in it of some row numbers."""
        rows = np.asarray(rows, np.int64)
        if rows.size and (rows.min() < 0 or rows.max() >= len(self)):
            raise IndexError(f"row out of range for an index of {len(self)}")
        seg = np.searchsorted(self._live_starts, rows, side="right") - 1
        local = rows - self._live_starts[seg]
        for i, view in enumerate(self.segments):
            if len(view.dead) and (mine := seg == i).any():
                skips = view.dead - np.arange(len(view.dead))
                local[mine] += np.searchsorted(skips, local[mine], side="right")
        return seg, local

    def _gather(self, key: str, rows: np.ndarray) -> np.ndarray:
        """Values of one dataset at some row numbers, reading only those rows."""
        seg, local = self._locate(rows)
        parts = []
        for i in np.unique(seg):
            data = self.segments[i].signatures.file[key]
            want = local[seg == i]
            order = np.unique(want)
            parts.append(
                (np.flatnonzero(seg == i), _read(data, order)[np.searchsorted(order, want)])
            )
        width = parts[0][1].shape[1:] if parts else ()
        out = np.empty((len(rows), *width), object if not parts else parts[0][1].dtype)
        for where, values in parts:
            out[where] = values
        return out

    def find(self, names: list[str]) -> np.ndarray:
        """Row numbers of some entries, by name (reading 12 bytes a row once, then the names
        whose keys match).

        Parameters
        ----------
        names : list of str
            Entry names.

        Returns
        -------
        rows : (len(names),) int64

        Raises
        ------
        UnknownNameError
            A name is not in the index.
        """
        if self._keys is None:
            self._keys = [_Keys.read(v.signatures.file, v.dead) for v in self.segments]
        views = self.segments
        tables = [
            (i, v.signatures.file, keys)
            for i, (v, keys) in enumerate(zip(views, self._keys, strict=True))
        ]
        found = find_names(names, tables)
        missing = [n for n, at in zip(names, found, strict=True) if at is None]
        if missing:
            raise UnknownNameError(_unknown(self.path, missing))
        physical = [views[i].start + row for i, row in found]  # type: ignore[misc]
        return self.logical_rows(np.array(physical, np.int64))

    def entries(self, rows: np.ndarray) -> list[Entry]:
        """Names, labels and paths of some rows, reading only those rows.

        Parameters
        ----------
        rows : (k,) int
            Row numbers, in any order.

        Returns
        -------
        entries : list of Entry
            In the order of ``rows``.
        """
        rows = np.asarray(rows, dtype=np.int64)
        columns = [self._gather(key, rows) for key in TEXT]
        return [Entry(*map(str, values)) for values in zip(*columns, strict=True)]

    def column(self, key: str) -> np.ndarray:
        """A whole column: ``"names"``, ``"labels"``, ``"paths"``, ``"sha256"`` or a metadata key.

        Parameters
        ----------
        key : str
            Dataset name.

        Returns
        -------
        values : (N,) ndarray
            Strings as Python ``str`` objects.
        """
        parts = []
        for view in self.segments:
            data = view.signatures.file[key]
            values = data.asstr()[:] if data.dtype.kind in "OS" else data[:]
            parts.append(np.delete(values, view.dead))
        return np.concatenate(parts) if parts else np.zeros(0, META.get(key, object))

    def cells(self) -> tuple[np.ndarray, np.ndarray] | None:
        """Every row's fine curvature cells and their shares of the area, read into memory.

        Returns
        -------
        cells : ((N, slots) uint16, (N, slots) uint16) or None
            `cfsig.descriptors.cells.packed_cells` of each row; None when the index keeps none.
        """
        slots = self.layout.cells
        if not slots:
            return None
        stored = [(view.cells, view.dead) for view in self.segments if view.cells is not None]
        cells, units = (
            np.concatenate(
                [np.zeros((0, slots), dtype), *(np.delete(c[i][:], d, axis=0) for c, d in stored)]
            )
            for i, dtype in enumerate(CELLS.values())
        )
        return cells, units

    def cells_at(self, rows: np.ndarray) -> tuple[np.ndarray, np.ndarray] | None:
        """The fine curvature cells and shares of some rows, reading only those rows.

        Parameters
        ----------
        rows : (k,) int
            Row numbers, in any order.

        Returns
        -------
        cells : ((k, slots) uint16, (k, slots) uint16) or None
            As `cells`, in the order of ``rows``; None when the index keeps none.
        """
        if not self.layout.cells:
            return None
        rows = np.asarray(rows, dtype=np.int64)
        return self._gather("cells", rows), self._gather("cell_units", rows)


def _read(data: h5py.Dataset, rows: np.ndarray) -> np.ndarray:
    """Some rows of a column of a segment, distinct and ascending.

    A 2-D column is read by `cfsig.index.blocks.read_rows`, from a memory map of its file:
    HDF5 would read a whole chunk (4,096 rows) for each row that lies in another one.
    """
    if data.ndim == 2 and data.shape[0]:
        out = np.empty((len(rows), data.shape[1]), data.dtype)
        return read_rows(data, plan_blocks(data, BLOCK_ROWS), rows, out, map_file(data))
    run = rows[-1] - rows[0] + 1 == len(rows)  # one slice reads faster than a list
    picked = slice(int(rows[0]), int(rows[-1]) + 1) if run else rows
    return data.asstr()[picked] if data.dtype.kind == "O" else data[picked]


class Signatures:
    """The signatures of an `IndexReader`, indexed like an array of shape (N, length).

    Parameters
    ----------
    reader : IndexReader
        The open index.
    """

    def __init__(self, reader: IndexReader) -> None:
        self._reader = reader
        self.shape = (len(reader), reader.layout.length)
        self.dtype = np.dtype(np.float32)

    def __len__(self) -> int:
        return self.shape[0]

    def __getitem__(self, key: int | slice | np.ndarray) -> np.ndarray:
        """Rows by number, slice or array of numbers: (length,) or (k, length) float32."""
        if isinstance(key, (int, np.integer)):
            return self[np.array([key])][0]
        rows = np.arange(len(self))[key] if isinstance(key, slice) else np.asarray(key)
        return (
            self._reader._gather("signatures", rows).astype(np.float32).reshape(-1, self.shape[1])
        )

    def __array__(self, dtype: None = None, copy: object = None) -> np.ndarray:
        return self[:]


class IndexWriter:
    """Add signatures to an index, creating it if needed; use as a context manager.

    Records are buffered and written by `commit`, atomically. Leaving the ``with`` block
    commits what is left, also on an exception. Opening reads only the manifest; the keys of
    the names (12 bytes a row) are read when a name is first looked up.

    Parameters
    ----------
    path : str or path-like
        The index folder.
    params : Params
        Parameters of the signatures to add; an existing index must have been built with equal
        parameters.
    layout : Layout, optional
        What the index keeps per row, as the descriptor declares it
        (`cfsig.descriptors.layout`); needed to create an index, else the index's own.
    merge : bool
        Merge segments automatically after commits (`MERGE_FANOUT`).

    Raises
    ------
    IndexFileError
        Another process is writing the index, or the existing index is corrupt, foreign, of
        another format, or built with other parameters or layout.
    ValueError
        A new index and no ``layout``.
    """

    def __init__(
        self,
        path: str | os.PathLike,
        params: Params,
        layout: Layout | None = None,
        merge: bool = True,
    ) -> None:
        self.path = Path(path)
        self.params = params
        self.merge = merge
        if layout is not None and not self.path.exists():
            _create(self.path, Manifest(params, layout, (), 1, committed=_now()))
        self._lock = _acquire_lock(self.path)
        try:
            if (self.path / MANIFEST).exists():
                self._manifest = read_manifest(self.path)
                if self._manifest.params != params:
                    raise IndexFileError(
                        f"{self.path}: built with other parameters "
                        f"({self._manifest.params.to_json()})"
                    )
                if layout is not None and layout != self._manifest.layout:
                    raise IndexFileError(f"{self.path}: built with another layout; {REBUILD}")
                self._remove_orphans()
            elif layout is None:
                raise ValueError(f"{self.path}: a new index needs its descriptor's layout")
            else:  # an empty folder made an index
                self._manifest = Manifest(params, layout, (), 1, committed=_now())
                self._remove_orphans()  # of a writer killed before its first manifest
                write_manifest(self.path, self._manifest)
        except BaseException:
            self._lock.close()
            raise
        self._pending: list[tuple[Entry, Signature]] = []
        self._removals: dict[str, tuple[int, int]] = {}  # name -> its committed (segment, row)
        self._keys: dict[int, _Keys] | None = None
        self._files: dict[int, h5py.File] = {}

    def __enter__(self) -> IndexWriter:
        return self

    def __exit__(self, *exc: object) -> None:
        try:
            self.commit()
        finally:
            self.close()

    def __len__(self) -> int:
        return sum(s.live for s in self._manifest.segments)

    def close(self) -> None:
        """Release the lock and close the segment files (without committing)."""
        for f in self._files.values():
            f.close()
        self._files.clear()
        self._lock.close()

    @property
    def layout(self) -> Layout:
        """What the index keeps per row."""
        return self._manifest.layout

    @property
    def segments(self) -> tuple[SegmentInfo, ...]:
        """The committed segments, oldest first."""
        return self._manifest.segments

    def is_current(self, name: str, path: str | os.PathLike) -> bool:
        """Whether ``name`` is already indexed with the current contents of ``path``.

        Parameters
        ----------
        name : str
            Entry name.
        path : str or path-like
            The mesh file, hashed only when ``name`` is known.

        Returns
        -------
        current : bool
        """
        (found,) = self._find([name])
        if found is None:
            return False
        try:
            digest = hashlib.sha256(Path(path).read_bytes()).hexdigest()
        except OSError:
            return False
        return bytes(self._file(found[0])["sha256"][found[1]]).decode() == digest

    def add(self, entry: Entry, signature: Signature) -> None:
        """Queue one mesh for the next commit; an existing entry of that name is replaced.

        Parameters
        ----------
        entry : Entry
            Name, label and path.
        signature : Signature
            Its signature, made with this writer's parameters.

        Raises
        ------
        ValueError
            The layout keeps fine cells and the signature has none, or of another width; or
            its vector is not of the layout's length.
        """
        slots = self.layout.cells
        if slots and (signature.cells is None or len(signature.cells[0]) != slots):
            raise ValueError(f"{entry.name}: no fine cells, which this index keeps")
        if len(signature.vector) != self.layout.length:
            raise ValueError(f"{entry.name}: a vector of {len(signature.vector)} entries")
        self._pending.append((entry, signature))
        self._removals.pop(entry.name, None)

    def remove(self, names: Iterable[str]) -> None:
        """Queue the removal of some entries for the next commit, which drops their rows.

        A removal is committed like an addition: atomically, by a segment without rows that
        drops them. Queries stop seeing the rows at once; `compact` deletes them from disk.

        Parameters
        ----------
        names : iterable of str
            Entry names, committed or queued.

        Raises
        ------
        UnknownNameError
            A name is not in the index: nothing is queued.
        """
        names = list(dict.fromkeys(names))
        queued = {entry.name for entry, _ in self._pending}
        found = self._find(names)
        missing = [n for n, at in zip(names, found, strict=True) if at is None and n not in queued]
        if missing:
            raise UnknownNameError(_unknown(self.path, missing))
        gone = set(names)
        self._pending = [(e, s) for e, s in self._pending if e.name not in gone]
        self._removals.update((n, at) for n, at in zip(names, found, strict=True) if at is not None)

    def update(self, entries: Iterable[Entry]) -> int:
        """Queue new labels or paths for committed entries, their signatures copied as stored.

        Parameters
        ----------
        entries : iterable of Entry
            Each names a committed entry and gives its label and path.

        Returns
        -------
        changed : int
            Entries whose label or path differed, queued for the next commit; the others are
            left as they are.

        Raises
        ------
        UnknownNameError
            A name is not committed in the index: nothing is queued.
        """
        entries = list(entries)
        found = self._find([e.name for e in entries])
        missing = [e.name for e, at in zip(entries, found, strict=True) if at is None]
        if missing:
            raise UnknownNameError(_unknown(self.path, missing))
        changed = 0
        for entry, (segment, row) in zip(entries, found, strict=True):  # type: ignore[misc]
            f = self._file(segment)
            if (f["labels"].asstr()[row], f["paths"].asstr()[row]) != (entry.label, entry.path):
                self.add(entry, _Stored.read(f, row, self.layout.cells))
                changed += 1
        return changed

    @property
    def pending(self) -> int:
        """Number of records waiting for `commit`."""
        return len(self._pending)

    def commit(self) -> None:
        """Write the queued records and removals as one new segment and publish it (fsync,
        rename).

        Then merges segments if enough of one size class have piled up (see `merge`).
        """
        latest = {entry.name: (entry, sig) for entry, sig in self._pending}
        if not latest and not self._removals:
            return
        found = [*self._find(list(latest)), *self._removals.values()]
        drops = np.array([loc for loc in found if loc is not None], np.int64).reshape(-1, 2)
        classes = Counter(dict(self._manifest.classes))
        classes.update(entry.label for entry, _ in latest.values())
        classes.subtract(self._labels(drops))
        counts = tuple(sorted((k, v) for k, v in classes.items() if v > 0))
        piece = _piece(list(latest.values()), self.layout)
        self._write([piece], len(latest), drops, len(self.segments), counts)
        self._pending.clear()
        self._removals.clear()
        if self.merge:
            while (start := _merge_start(self.segments)) is not None:
                self._merge(start)

    def compact(self) -> None:
        """Merge every segment into one, leaving out superseded rows; commits pending records.

        Raises
        ------
        IndexFileError
            A segment is damaged (its checksums do not match): nothing is changed.
        """
        self.commit()
        if len(self.segments) > 1 or any(s.live < s.rows for s in self.segments):
            self._merge(0)

    def _merge(self, start: int) -> None:
        """Replace the segments from ``start`` on by one holding their live rows."""
        run = self.segments[start:]
        inside = {s.id for s in run}
        # The run ends the list: the rows of it that are superseded are named by its own drops.
        dead = _dead_rows(run, [self._file(s.id) for s in run], self.path)
        kept = [self._file(s.id)["drops"][:] for s in run]
        drops = np.concatenate([np.zeros((0, 2), np.int64), *kept])
        drops = drops[~np.isin(drops[:, 0], list(inside))]  # rows of older segments stay dropped
        pieces = (p for s in run for p in scan_segment(self._file(s.id), dead[s.id]))
        self._write(pieces, sum(s.live for s in run), drops, start)

    def _labels(self, drops: np.ndarray) -> list[str]:
        """The labels of some committed rows, (d, 2) (segment, row), each named once."""
        labels: list[str] = []
        for segment in np.unique(drops[:, 0]):
            rows = np.sort(drops[drops[:, 0] == segment, 1])
            data = self._file(int(segment))["labels"].asstr()
            dense = len(rows) * 8 > data.shape[0]  # one read of the column beats many rows
            labels += list(data[:][rows] if dense else data[rows])
        return labels

    def _write(
        self,
        pieces: Iterable[Piece],
        rows: int,
        drops: np.ndarray,
        start: int,
        classes: tuple[tuple[str, int], ...] | None = None,
    ) -> None:
        """Write a segment and publish a manifest where it replaces the segments from ``start``.

        ``drops`` are the rows of older segments it supersedes: newly (a commit, which gives
        the ``classes`` they leave), or already (a merge, which carries them over).
        """
        new = classes is not None
        old = self._manifest
        info = SegmentInfo(old.next_id, rows, rows, 0)
        path = self.path / info.file
        try:
            write_segment(path, info.id, old.layout, rows, pieces, drops)
            _fsync(path)
            info = replace(info, crc32=file_crc(path))
            ids, dropped = np.unique(drops[:, 0] if new else [], return_counts=True)
            counts = {int(s): int(n) for s, n in zip(ids, dropped, strict=True)}
            older = [replace(s, live=s.live - counts.get(s.id, 0)) for s in old.segments[:start]]
            manifest = replace(
                old, segments=(*older, info), next_id=info.id + 1, committed=_now(),
                classes=old.classes if classes is None else classes, version=__version__,
            )  # fmt: skip
            write_manifest(self.path, manifest)
        except BaseException:
            path.unlink(missing_ok=True)
            raise
        self._manifest = manifest
        for s in old.segments[start:]:
            if (f := self._files.pop(s.id, None)) is not None:
                f.close()
            (self.path / s.file).unlink(missing_ok=True)
        if self._keys is not None:  # the keys of the segments kept stay as they are
            for s in old.segments[start:]:
                del self._keys[s.id]
            for seg, row in drops if new else ():
                self._keys[int(seg)].dead.add(int(row))
            self._keys[info.id] = _Keys.read(self._file(info.id))

    def _find(self, names: list[str]) -> list[tuple[int, int] | None]:
        """The committed (segment, row) of each name, or None for a new name."""
        if not names or not self.segments:
            return [None] * len(names)
        if self._keys is None:
            files = [self._file(s.id) for s in self.segments]
            dead = _dead_rows(self.segments, files, self.path)
            self._keys = {
                s.id: _Keys.read(f, dead[s.id]) for s, f in zip(self.segments, files, strict=True)
            }
        keys = self._keys
        return find_names(names, [(s.id, self._file(s.id), keys[s.id]) for s in self.segments])

    def _file(self, segment: int) -> h5py.File:
        """An open segment, kept open while the writer lives."""
        if segment not in self._files:
            info = next(s for s in self.segments if s.id == segment)
            self._files[segment] = _open_segment(self.path, info)
        return self._files[segment]

    def _remove_orphans(self) -> None:
        """Delete what killed writers left: files no manifest names (only the lock holder may)."""
        named = {s.file for s in self.segments}
        for stale in [*self.path.glob("seg-*.h5"), *self.path.glob("*.tmp")]:
            if stale.name not in named:
                stale.unlink()


@dataclass
class _Keys:
    """The sorted name keys of one segment, the row of each, and its superseded rows."""

    sorted: np.ndarray
    rows: np.ndarray
    dead: set[int]

    @classmethod
    def read(cls, f: h5py.File, dead: Iterable[int] = ()) -> _Keys:
        return cls(f["key_sorted"][:], f["key_rows"][:], set(map(int, dead)))


def find_names(
    names: list[str], tables: list[tuple[int, h5py.File, _Keys]]
) -> list[tuple[int, int] | None]:
    """Where some names are among segments: by their keys, then their stored names.

    Parameters
    ----------
    names : list of str
        Entry names.
    tables : list of (int, h5py.File, _Keys)
        Each segment's number, open file and keys, oldest first.

    Returns
    -------
    found : list of (int, int) or None
        The segment number and row of each name's row not superseded, or None.
    """
    keys = name_keys(names)
    found: list[tuple[int, int] | None] = [None] * len(names)
    for segment, f, table in reversed(tables):
        low = np.searchsorted(table.sorted, keys, "left")
        high = np.searchsorted(table.sorted, keys, "right")
        pairs = [
            (int(i), int(row))
            for i in np.flatnonzero(high > low)
            if found[i] is None
            for row in table.rows[low[i] : high[i]]
            if row not in table.dead
        ]
        if not pairs:
            continue
        rows = np.unique([row for _, row in pairs])  # read at once, in order
        stored = dict(zip(rows.tolist(), f["names"].asstr()[rows], strict=True))
        for i, row in pairs:
            if stored[row] == names[i]:
                found[i] = (segment, row)
    return found


@dataclass(frozen=True)
class _Stored:
    """A committed row's signature as `Signature` gives it, to copy it under a new label."""

    vector: np.ndarray
    cells: tuple[np.ndarray, np.ndarray] | None
    sha256: str
    n_vertices: int
    n_faces: int
    n_components: int
    phi_range: tuple[float, float]
    curvature_error: float

    @classmethod
    def read(cls, f: h5py.File, row: int, slots: int) -> _Stored:
        cells = (f["cells"][row], f["cell_units"][row]) if slots else None
        return cls(
            f["signatures"][row], cells, bytes(f["sha256"][row]).decode(),
            int(f["n_vertices"][row]), int(f["n_faces"][row]), int(f["n_components"][row]),
            (float(f["phi_min"][row]), float(f["phi_max"][row])), float(f["curvature_error"][row]),
        )  # fmt: skip


def _unknown(path: Path, names: list[str]) -> str:
    """The one line refusing names an index lacks."""
    more = f" (and {len(names) - 1} more)" if len(names) > 1 else ""
    return f"{path}: no entry named {names[0]!r}{more}"


def _now() -> str:
    """The time now, UTC, ISO 8601 to the second."""
    return datetime.now(timezone.utc).replace(microsecond=0).isoformat()


def read_manifest(path: Path) -> Manifest:
    """Read and check an index folder's manifest.

    Parameters
    ----------
    path : Path
        The index folder.

    Returns
    -------
    manifest : Manifest

    Raises
    ------
    IndexFileError
        No manifest, not HDF5, not a cfsig index, newer, or its checksum does not match.
    """
    file = path / MANIFEST
    if path.is_file():
        _not_a_folder(path)
    if not path.is_dir():
        raise IndexFileError(f"{path}: no such index")
    if not file.is_file():
        raise IndexFileError(f"{path}: not a cfsig index (no {MANIFEST})")
    with _open_h5(file, path) as f:
        params, layout = _check_header(f, path)
        try:
            columns = [
                f[k][:] for k in ("segment_ids", "segment_rows", "segment_live", "segment_crc32")
            ]
            manifest = Manifest(
                params,
                layout,
                tuple(SegmentInfo(*map(int, row)) for row in zip(*columns, strict=True)),
                int(f.attrs["next_segment"]),
                tuple(sorted(json.loads(f.attrs["classes"]).items())),
                str(f.attrs["committed"]),
                str(f.attrs["cfsig_version"]),
            )
            crc = int(f.attrs["crc32"])
        except (KeyError, ValueError, OSError, AttributeError) as exc:
            raise IndexFileError(f"{path}: unreadable manifest ({exc})") from None
    if crc != _manifest_crc(manifest):
        raise IndexFileError(f"{path}: the manifest is damaged (checksum mismatch)")
    return manifest


def existing_params(path: str | os.PathLike) -> Params | None:
    """The parameters of the index at ``path``, or None when none has been committed there.

    Parameters
    ----------
    path : str or path-like
        A folder, an index or not.

    Returns
    -------
    params : Params or None

    Raises
    ------
    IndexFileError
        As `read_manifest`, for an index there that this cfsig does not read.
    """
    path = Path(path)
    if path.is_dir() and not (path / MANIFEST).exists():
        return None
    return read_manifest(path).params if path.exists() else None


def write_manifest(path: Path, manifest: Manifest) -> None:
    """Publish a manifest atomically: write a temporary file, sync it, rename it, sync the folder.

    Parameters
    ----------
    path : Path
        The index folder.
    manifest : Manifest
        What to publish.
    """
    tmp = path / (MANIFEST + ".tmp")
    segments = manifest.segments
    with h5py.File(tmp, "w") as f:
        f.attrs.update(
            format=FORMAT,
            format_version=FORMAT_VERSION,
            params=manifest.params.to_json(),
            layout=manifest.layout.to_json(),
            cfsig_version=manifest.version,
            committed=manifest.committed,
            classes=json.dumps(dict(manifest.classes)),
            next_segment=manifest.next_id,
            crc32=np.uint32(_manifest_crc(manifest)),
        )
        f.create_dataset("segment_files", data=[s.file for s in segments], dtype=STRING)
        for name, key in (
            ("segment_ids", "id"),
            ("segment_rows", "rows"),
            ("segment_live", "live"),
        ):
            f.create_dataset(name, data=np.array([getattr(s, key) for s in segments], np.int64))
        f.create_dataset("segment_crc32", data=np.array([s.crc32 for s in segments], np.uint32))
    _fsync(tmp)
    os.replace(tmp, path / MANIFEST)
    _fsync(path)


def _manifest_crc(manifest: Manifest) -> int:
    """CRC-32 of what a manifest says, as canonical JSON."""
    text = json.dumps(
        [
            manifest.params.to_json(),
            manifest.layout.to_json(),
            manifest.next_id,
            [list(vars(s).values()) for s in manifest.segments],
            manifest.classes,
            manifest.committed,
            manifest.version,
        ]
    )
    return zlib.crc32(text.encode())


def _merge_start(segments: tuple[SegmentInfo, ...]) -> int | None:
    """Where the trailing run of small segments to merge starts, if one has piled up.

    The run is the segments at the end no larger, in size class (log base `MERGE_FANOUT` of
    the live rows), than the last one; it is merged once it has `MERGE_FANOUT` segments.
    """

    def size_class(s: SegmentInfo) -> int:
        return int(math.log(max(s.live, 1), MERGE_FANOUT))

    last = size_class(segments[-1]) if segments else 0
    start = len(segments)
    while start and size_class(segments[start - 1]) <= last:
        start -= 1
    return start if len(segments) - start >= MERGE_FANOUT else None


def _dead_rows(
    segments: Iterable[SegmentInfo], files: Iterable[h5py.File], path: Path
) -> dict[int, np.ndarray]:
    """The superseded rows of each segment (sorted), from the drops of all; checks the counts."""
    infos, files = list(segments), list(files)
    found: dict[int, list[np.ndarray]] = {s.id: [] for s in infos}
    for f in files:
        drops = f["drops"][:]
        for seg in np.unique(drops[:, 0]):
            if int(seg) in found:
                found[int(seg)].append(drops[drops[:, 0] == seg, 1])
    dead = {
        s: np.unique(np.concatenate([np.zeros(0, np.int64), *rows])) for s, rows in found.items()
    }
    for s in infos:
        if s.rows - len(dead[s.id]) != s.live:
            raise IndexFileError(f"{path}: segment {s.file} does not match the manifest")
    return dead


def _piece(records: list[tuple[Entry, Signature]], layout: Layout) -> Piece:
    """The rows of some records, as `write_segment` takes them for ``layout``."""
    sigs = [s for _, s in records]
    width, slots = layout.length, layout.cells
    phi = np.array([s.phi_range for s in sigs], np.float64).reshape(-1, 2)
    held = [s.cells for s in sigs if s.cells is not None]  # all of them or none (`add`)
    cells = {}
    if slots:
        for i, (key, dtype) in enumerate(CELLS.items()):
            cells[key] = np.array([c[i] for c in held], dtype).reshape(-1, slots)
    return {
        **cells,
        "signatures": np.array([s.vector for s in sigs], np.float32).reshape(-1, width),
        "names": np.array([e.name for e, _ in records], object),
        "labels": np.array([e.label for e, _ in records], object),
        "paths": np.array([e.path for e, _ in records], object),
        "sha256": np.array([s.sha256.encode() for s in sigs], "S64"),
        "n_vertices": np.array([s.n_vertices for s in sigs], np.int64),
        "n_faces": np.array([s.n_faces for s in sigs], np.int64),
        "n_components": np.array([s.n_components for s in sigs], np.int64),
        "phi_min": phi[:, 0],
        "phi_max": phi[:, 1],
        "curvature_error": np.array([s.curvature_error for s in sigs], np.float64),
    }


def check_index(path: str | os.PathLike) -> list[str]:
    """Verify every checksum of an index: the manifest, each segment file, chunk and column.

    Parameters
    ----------
    path : str or path-like
        The index folder.

    Returns
    -------
    problems : list of str
        One line per damaged part, naming the file and the part; empty for a healthy index.

    Raises
    ------
    IndexFileError
        Not an index this cfsig reads, or a damaged manifest.
    """
    path = Path(path)
    manifest = read_manifest(path)
    problems = []
    for info in manifest.segments:
        file = path / info.file
        if not file.is_file():
            problems.append(f"{file}: missing")
            continue
        found: list[str] = []
        try:
            with _open_segment(path, info) as f:
                for _ in scan_segment(f, np.zeros(0, np.int64), found):
                    pass
        except (OSError, KeyError, ValueError, IndexFileError) as exc:
            found.append(f"unreadable ({exc})")
        if not found and file_crc(file) != info.crc32:
            found.append("file checksum mismatch outside the rows (HDF5 structure)")
        problems += [f"{file}: {p}" for p in found]
    if not problems:
        files = _open_segments(path, manifest.segments)
        try:
            problems += _check_drops(manifest.segments, files, path)
            dead = _dead_rows(manifest.segments, files, path)
            if not problems:  # every drop names a row: the live rows are known
                labels = [
                    np.delete(f["labels"].asstr()[:], dead[s.id])
                    for s, f in zip(manifest.segments, files, strict=True)
                ]
                counted = Counter(str(label) for part in labels for label in part)
                if tuple(sorted(counted.items())) != manifest.classes:
                    problems.append(f"{path / MANIFEST}: its class counts do not match the rows")
        except IndexFileError as exc:
            problems.append(str(exc))
        finally:
            for f in files:
                f.close()
    return problems


def _check_drops(
    segments: tuple[SegmentInfo, ...], files: list[h5py.File], path: Path
) -> list[str]:
    """Problems of the drops: each must name a row of an older segment, and once in all."""
    problems: list[str] = []
    held: dict[int, int] = {}
    seen: set[tuple[int, int]] = set()
    for info, f in zip(segments, files, strict=True):
        for segment, row in f["drops"][:].tolist():
            if segment not in held or not 0 <= row < held[segment]:
                problems.append(f"{path / info.file}: drops a row that is not in an older segment")
                break
            if (segment, row) in seen:
                problems.append(f"{path / info.file}: drops a row already dropped")
                break
            seen.add((segment, row))
        held[info.id] = info.rows
    return problems


@dataclass(frozen=True)
class IndexInfo:
    """What an index holds, as its manifest says.

    Attributes
    ----------
    path : Path
        The index folder.
    params : Params
        The parameters of its signatures, the descriptor among them.
    layout : Layout
        What it keeps per row; ``layout.cells`` > 0: fine curvature cells for partial queries.
    rows : int
        Entries.
    classes : dict of str to int
        Each label and its number of entries, sorted by label.
    segments : int
        Segment files.
    bytes : int
        Size of its files on disk, the manifest's and the segments'.
    version : str
        The cfsig version that wrote its manifest.
    committed : str
        When its manifest was written: ISO 8601, UTC.
    """

    path: Path
    params: Params
    layout: Layout
    rows: int
    classes: dict[str, int]
    segments: int
    bytes: int
    version: str
    committed: str

    def to_dict(self) -> dict:
        """The facts as JSON-ready values (what ``cfsig info --json`` prints)."""
        return {
            "index": str(self.path),
            "descriptor": self.params.descriptor,
            "params": json.loads(self.params.to_json()),
            "rows": self.rows,
            "classes": self.classes,
            "segments": self.segments,
            "bytes": self.bytes,
            "cfsig_version": self.version,
            "committed": self.committed,
            "partial_cells": self.layout.cells > 0,
        }


def index_info(path: str | os.PathLike) -> IndexInfo:
    """What an index holds, from its manifest and the sizes of its files: no row is read.

    Parameters
    ----------
    path : str or path-like
        The index folder.

    Returns
    -------
    info : IndexInfo

    Raises
    ------
    IndexFileError
        Not an index this cfsig reads, a damaged manifest, or a segment file missing.
    """
    path = Path(path)
    manifest = read_manifest(path)
    size = (path / MANIFEST).stat().st_size
    for info in manifest.segments:
        try:
            size += (path / info.file).stat().st_size
        except OSError:
            raise IndexFileError(f"{path}: segment {info.file} is missing") from None
    return IndexInfo(
        path, manifest.params, manifest.layout, sum(s.live for s in manifest.segments),
        dict(manifest.classes), len(manifest.segments), size, manifest.version,
        manifest.committed,
    )  # fmt: skip


def compact_index(path: str | os.PathLike) -> tuple[int, int]:
    """Merge every segment of an index into one (`IndexWriter.compact`).

    Parameters
    ----------
    path : str or path-like
        The index folder.

    Returns
    -------
    segments : int
        Segments before.
    rows : int
        Entries in the index.

    Raises
    ------
    IndexFileError
        The index is unusable, damaged, or another process is writing it.
    """
    path = Path(path)
    with IndexWriter(path, read_manifest(path).params) as writer:
        before = len(writer.segments)
        writer.compact()
        return before, len(writer)


def file_crc(path: Path) -> int:
    """CRC-32 of a whole file, read in blocks of 16 MiB.

    Parameters
    ----------
    path : Path
        The file.

    Returns
    -------
    crc : int
    """
    crc = 0
    with open(path, "rb") as f:
        while block := f.read(_CRC_BLOCK):
            crc = zlib.crc32(block, crc)
    return crc


def _open_segments(folder: Path, segments: tuple[SegmentInfo, ...]) -> list[h5py.File]:
    """Open every segment a manifest lists, closing those already open if one fails."""
    files: list[h5py.File] = []
    try:
        for info in segments:
            files.append(_open_segment(folder, info))
    except BaseException:
        for f in files:
            f.close()
        raise
    return files


def _open_segment(folder: Path, info: SegmentInfo) -> h5py.File:
    """Open a segment read-only and check that it is the one the manifest lists."""
    f = _open_h5(folder / info.file, folder)
    ok = (
        f.attrs.get("format") == SEGMENT_FORMAT
        and int(f.attrs.get("segment", -1)) == info.id
        and all(k in f for k in ("signatures", "drops", *COLUMNS))
        and f["signatures"].shape[0] == info.rows
    )
    if not ok:
        f.close()
        raise IndexFileError(f"{folder}: segment {info.file} does not match the manifest")
    return f


def _read_sketch(f: h5py.File, path: Path) -> Sketch | None:
    """A segment's sketches and what goes with them, or None if it has none; checks shapes."""
    if "sketch" not in f:
        return None
    try:
        groups, center, error = (f[k][:] for k in SKETCH_EXTRA)
    except KeyError:
        raise IndexFileError(f"{path}: its sketches are incomplete") from None
    rows, width = f["signatures"].shape
    ok = (
        f["sketch"].shape == (rows, len(groups)) == (rows, len(center))
        and error.shape == (1,)
        and (not len(groups) or (groups[0] == 0 and (np.diff(groups) > 0).all()))
        and (not len(groups) or groups[-1] < width)
    )
    if not ok:
        raise IndexFileError(f"{path}: its sketches do not match its signatures")
    return Sketch(f["sketch"], groups.astype(np.int64), center.astype(np.float64), float(error[0]))


def _read_cells(f: h5py.File, path: Path, slots: int) -> tuple[h5py.Dataset, h5py.Dataset] | None:
    """A segment's fine curvature cells and their shares, for a layout that keeps ``slots`` of
    them a row (0: none); checks that they are there, in shapes that fit its signatures."""
    if not slots:
        return None
    shape = (f["signatures"].shape[0], slots)
    if any(key not in f or f[key].shape != shape for key in CELLS):
        raise IndexFileError(f"{path}: its fine curvature cells are missing or do not fit")
    return f["cells"], f["cell_units"]


def _read_copies(f: h5py.File, path: Path, layout: Layout) -> tuple[ColumnCopy, ...]:
    """A segment's copies of the layout's column groups; checks that they are there and fit."""
    copies = []
    rows = f["signatures"].shape[0]
    for name, first, last in layout.groups:
        where = GROUP_COLUMNS.format(name)
        if name not in f or where not in f:
            raise IndexFileError(f"{path}: its copy of the columns {name!r} is incomplete")
        columns = f[where][:]
        if list(columns) != [first, last] or f[name].shape != (rows, last - first):
            raise IndexFileError(
                f"{path}: its copy of the columns {name!r} does not match its signatures"
            )
        copies.append(ColumnCopy(f[name], slice(first, last)))
    return tuple(copies)


def _open_h5(path: Path, index: Path | None = None) -> h5py.File:
    """Open an HDF5 file read-only, turning failures into `IndexFileError` naming the index."""
    name = index or path
    if not path.is_file():
        raise IndexFileError(f"{name}: no such index file")
    try:
        return h5py.File(path, "r", locking=False)
    except OSError as exc:
        where = "" if index is None else f" ({path.name})"
        raise IndexFileError(f"{name}: not a readable HDF5 file{where} ({exc})") from None


def _check_header(f: h5py.File, path: Path) -> tuple[Params, Layout]:
    """Check the format attributes and return the stored parameters and layout."""
    if f.attrs.get("format") != FORMAT:
        raise IndexFileError(f"{path}: not a cfsig index")
    version = int(f.attrs.get("format_version", -1))
    if version > FORMAT_VERSION:
        raise IndexFileError(
            f"{path}: index format {version} is newer than this cfsig reads ({FORMAT_VERSION})"
        )
    if version < FORMAT_VERSION:
        raise IndexFileError(f"{path}: {_made_by(f.attrs.get('params'), version)}; {REBUILD}")
    try:
        return Params.from_json(f.attrs["params"]), Layout.from_json(f.attrs["layout"])
    except (KeyError, TypeError, ValueError) as exc:
        raise IndexFileError(f"{path}: unreadable parameters ({exc})") from None


def _not_a_folder(path: Path) -> NoReturn:
    """Refuse a file given as an index: an index of the older one-file format names its
    rebuild, a manifest its folder."""
    with _open_h5(path) as f:
        _check_header(f, path)
    raise IndexFileError(f"{path}: the manifest of an index: name its folder")


def _made_by(params: object, version: int) -> str:
    """What an index of an older format was made with, in words, from its stored parameters."""
    if version >= 3:  # formats 3 to 5 name today's descriptors, computed or stored otherwise
        return f"made by an older cfsig, in index format {version}"
    try:
        data = json.loads(str(params))
        descriptor = str(data.get("descriptor", "cf"))
        version = data.get("version")
    except (ValueError, AttributeError):
        return "made by an older cfsig"
    named = descriptor if version is None else f"{descriptor} version {version}"
    return f"made by an older cfsig, with the descriptor {named} that this one no longer computes"


def _acquire_lock(path: Path) -> IO[str]:
    """Take the writer's lock file, failing at once if another process holds it."""
    try:
        import fcntl
    except ImportError:  # not POSIX: the module docstring says why
        raise IndexFileError(f"{path}: writing an index needs a POSIX system (flock)") from None
    if path.is_file():
        _not_a_folder(path)
    if (path / MANIFEST).exists():
        read_manifest(path)  # refuses an index of another format before writing into it
    elif path.is_dir() and any(not _ours(p.name) for p in path.iterdir()):
        raise IndexFileError(f"{path}: a folder that is not a cfsig index")
    path.mkdir(parents=True, exist_ok=True)
    lock = open(path / LOCK, "a+")  # noqa: SIM115
    try:
        fcntl.flock(lock, fcntl.LOCK_EX | fcntl.LOCK_NB)
    except BlockingIOError:
        lock.close()
        raise IndexFileError(f"{path}: another process is writing this index") from None
    return lock


def _create(path: Path, manifest: Manifest) -> None:
    """Create an empty index atomically: made aside with its manifest, then renamed into place,
    so that a reader never finds the folder without one. Another writer's folder that won the
    rename is left as it is."""
    tmp = path.with_name(f".{path.name}.{os.getpid()}.new")
    shutil.rmtree(tmp, ignore_errors=True)  # left by a process of that number killed here
    tmp.mkdir(parents=True)
    write_manifest(tmp, manifest)
    try:
        os.rename(tmp, path)
    except OSError:  # created meanwhile
        shutil.rmtree(tmp, ignore_errors=True)
    else:
        _fsync(path.parent)


def _ours(name: str) -> bool:
    """Whether a file in an index folder is one a writer makes: its lock, a segment, a
    temporary file (left by a writer killed before its first manifest)."""
    return (
        name == LOCK or name.endswith(".tmp") or (name.startswith("seg-") and name.endswith(".h5"))
    )


def _fsync(path: Path) -> None:
    """Flush a file or directory to disk."""
    fd = os.open(path, os.O_RDONLY)
    try:
        os.fsync(fd)
    finally:
        os.close(fd)
