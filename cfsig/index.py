"""The index: signatures and their metadata in one HDF5 file that is never left half-written.

Layout (format version 1): datasets of one row per mesh, ``signatures`` (N, length) float32,
``names``, ``labels``, ``paths`` (UTF-8 strings), ``sha256`` (64 ASCII bytes), ``n_vertices``,
``n_faces``, ``n_components`` (int64), ``phi_min``, ``phi_max``, ``curvature_error`` (float64);
file attributes ``format`` ("cfsig-index"), ``format_version``, ``params`` (`Params` as JSON)
and ``cfsig_version``.

Writes are copy-on-write: a commit copies the file, appends to the copy, syncs it to disk and
renames it over the original, so a reader, or a process killed at any moment, only ever sees a
complete committed state. One writer at a time holds an exclusive lock on ``INDEX.lock``.

cfsig runs on POSIX systems (Linux, macOS): the lock is ``flock`` and queries read with
``preadv``. ``fcntl`` is imported by the writer only, so that this module imports anywhere.
"""

from __future__ import annotations

import hashlib
import os
import shutil
from dataclasses import dataclass
from pathlib import Path
from typing import IO, TYPE_CHECKING

import h5py
import numpy as np

from . import __version__
from .errors import IndexFileError
from .params import Params, signature_length

if TYPE_CHECKING:  # importing the signature code would load scipy on the query path
    from .signature import Signature

FORMAT = "cfsig-index"
FORMAT_VERSION = 1
_STRING = h5py.string_dtype("utf-8")
_META = {
    "n_vertices": np.int64,
    "n_faces": np.int64,
    "n_components": np.int64,
    "phi_min": np.float64,
    "phi_max": np.float64,
    "curvature_error": np.float64,
}
_TEXT = ("names", "labels", "paths")
_CHUNK_ROWS = 4096


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


class IndexReader:
    """Read access to an index file; use as a context manager.

    Parameters
    ----------
    path : str or path-like
        The index file.

    Raises
    ------
    IndexFileError
        Missing, not HDF5, corrupt, not a cfsig index, or of a newer format version.
    """

    def __init__(self, path: str | os.PathLike) -> None:
        self.path = Path(path)
        self._file = _open_h5(self.path)
        try:
            self.params = _check_header(self._file, self.path)
        except IndexFileError:
            self._file.close()
            raise
        self.signatures: h5py.Dataset = self._file["signatures"]

    def __enter__(self) -> IndexReader:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    def __len__(self) -> int:
        return int(self.signatures.shape[0])

    def close(self) -> None:
        """Close the file."""
        self._file.close()

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
        order = np.unique(rows)
        columns = [self._file[key].asstr()[order] if len(order) else [] for key in _TEXT]
        found = {int(r): Entry(*map(str, vals)) for r, *vals in zip(order, *columns, strict=True)}
        return [found[int(r)] for r in rows]

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
        data = self._file[key]
        return data.asstr()[:] if data.dtype.kind in "OS" else data[:]


class IndexWriter:
    """Add signatures to an index, creating it if needed; use as a context manager.

    Records are buffered and written by `commit`, atomically. Leaving the ``with`` block
    commits what is left, also on an exception.

    Parameters
    ----------
    path : str or path-like
        The index file.
    params : Params
        Parameters of the signatures to add; an existing index must have been built with equal
        parameters.

    Raises
    ------
    IndexFileError
        Another process is writing the index, or the existing file is corrupt, foreign, of a
        newer format or built with other parameters.
    """

    def __init__(self, path: str | os.PathLike, params: Params) -> None:
        self.path = Path(path)
        self.params = params
        self._lock = _acquire_lock(self.path)
        for stale in self.path.parent.glob(f".{self.path.name}.*.tmp"):
            stale.unlink()  # left by a writer that was killed: only the lock holder makes these
        self._pending: list[tuple[Entry, Signature]] = []
        self.known: dict[str, tuple[int, str]] = {}
        if self.path.exists():
            with IndexReader(self.path) as reader:
                if reader.params != params:
                    self._lock.close()
                    raise IndexFileError(
                        f"{self.path}: built with other parameters ({reader.params.to_json()})"
                    )
                names, hashes = reader.column("names"), reader.column("sha256")
            self.known = {n: (i, h) for i, (n, h) in enumerate(zip(names, hashes, strict=True))}

    def __enter__(self) -> IndexWriter:
        return self

    def __exit__(self, *exc: object) -> None:
        try:
            self.commit()
        finally:
            self._lock.close()

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
        if name not in self.known:
            return False
        try:
            digest = hashlib.sha256(Path(path).read_bytes()).hexdigest()
        except OSError:
            return False
        return self.known[name][1] == digest

    def add(self, entry: Entry, signature: Signature) -> None:
        """Queue one mesh for the next commit; an existing entry of that name is replaced.

        Parameters
        ----------
        entry : Entry
            Name, label and path.
        signature : Signature
            Its signature, made with this writer's parameters.
        """
        self._pending.append((entry, signature))

    @property
    def pending(self) -> int:
        """Number of records waiting for `commit`."""
        return len(self._pending)

    def commit(self) -> None:
        """Write the queued records atomically (copy, append, fsync, rename)."""
        if not self._pending and self.path.exists():
            return
        tmp = self.path.with_name(f".{self.path.name}.{os.getpid()}.tmp")
        try:
            if self.path.exists():
                shutil.copyfile(self.path, tmp)
            with h5py.File(tmp, "a") as f:
                if "signatures" not in f:
                    _create_layout(f, self.params)
                self._write_rows(f)
            _fsync(tmp)
            os.replace(tmp, self.path)
            _fsync(self.path.parent)
        except BaseException:
            tmp.unlink(missing_ok=True)
            raise
        self._pending.clear()

    def _write_rows(self, f: h5py.File) -> None:
        """Append new names and overwrite changed ones in an open file."""
        latest = {entry.name: (entry, sig) for entry, sig in self._pending}
        if not latest:
            return
        rows = []
        for name, (_, sig) in latest.items():
            row = self.known.get(name, (len(self.known), ""))[0]
            self.known[name] = (row, sig.sha256)
            rows.append(row)
        for key in f:
            f[key].resize(len(self.known), axis=0)
        order = np.argsort(rows)
        records = list(latest.values())
        picks = [records[i] for i in order]
        columns = {
            "signatures": np.array([s.vector for _, s in picks], dtype=np.float32),
            "names": [e.name for e, _ in picks],
            "labels": [e.label for e, _ in picks],
            "paths": [e.path for e, _ in picks],
            "sha256": np.array([s.sha256.encode() for _, s in picks], dtype="S64"),
            "n_vertices": [s.n_vertices for _, s in picks],
            "n_faces": [s.n_faces for _, s in picks],
            "n_components": [s.n_components for _, s in picks],
            "phi_min": [s.phi_range[0] for _, s in picks],
            "phi_max": [s.phi_range[1] for _, s in picks],
            "curvature_error": [s.curvature_error for _, s in picks],
        }
        for key, values in columns.items():
            f[key][np.asarray(rows)[order]] = np.asarray(values, dtype=f[key].dtype)


def _create_layout(f: h5py.File, params: Params) -> None:
    """Create the empty datasets and the header attributes."""
    f.attrs.update(
        format=FORMAT,
        format_version=FORMAT_VERSION,
        params=params.to_json(),
        cfsig_version=__version__,
    )
    width = signature_length(params)
    f.create_dataset(
        "signatures", (0, width), np.float32, maxshape=(None, width), chunks=(_CHUNK_ROWS, width)
    )
    dtypes = {**{k: _STRING for k in _TEXT}, "sha256": "S64", **_META}
    for key, dtype in dtypes.items():
        f.create_dataset(key, (0,), dtype, maxshape=(None,), chunks=(_CHUNK_ROWS,))


def _open_h5(path: Path) -> h5py.File:
    """Open an HDF5 file read-only, turning failures into `IndexFileError`."""
    if not path.is_file():
        raise IndexFileError(f"{path}: no such index file")
    try:
        return h5py.File(path, "r", locking=False)
    except OSError as exc:
        raise IndexFileError(f"{path}: not a readable HDF5 file ({exc})") from None


def _check_header(f: h5py.File, path: Path) -> Params:
    """Check the format attributes and datasets and return the stored parameters."""
    if f.attrs.get("format") != FORMAT or "signatures" not in f:
        raise IndexFileError(f"{path}: not a cfsig index")
    version = int(f.attrs.get("format_version", -1))
    if version > FORMAT_VERSION:
        raise IndexFileError(
            f"{path}: index format {version} is newer than this cfsig reads ({FORMAT_VERSION})"
        )
    try:
        return Params.from_json(f.attrs["params"])
    except (KeyError, TypeError, ValueError) as exc:
        raise IndexFileError(f"{path}: unreadable parameters ({exc})") from None


def _acquire_lock(path: Path) -> IO[str]:
    """Take the writer's lock file, failing at once if another process holds it."""
    try:
        import fcntl
    except ImportError:  # not POSIX: the module docstring says why
        raise IndexFileError(f"{path}: writing an index needs a POSIX system (flock)") from None
    path.parent.mkdir(parents=True, exist_ok=True)
    lock = open(path.with_name(path.name + ".lock"), "a+")  # noqa: SIM115
    try:
        fcntl.flock(lock, fcntl.LOCK_EX | fcntl.LOCK_NB)
    except BlockingIOError:
        lock.close()
        raise IndexFileError(f"{path}: another process is writing this index") from None
    return lock


def _fsync(path: Path) -> None:
    """Flush a file or directory to disk."""
    fd = os.open(path, os.O_RDONLY)
    try:
        os.fsync(fd)
    finally:
        os.close(fd)
