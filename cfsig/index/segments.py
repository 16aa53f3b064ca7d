"""Segments: the immutable HDF5 files an index is made of, written once with their checksums.

A segment holds the rows of one commit (or of several merged by compaction), with the columns
of the format-1 index file, the sorted 64-bit keys of its names (so that a writer finds a name
without reading the names), the rows of older segments it supersedes, the sketch of each row
(`cfsig.index.sketch`, the lower bounds a search prunes by), the curvature channel's columns of the
signatures stored again on their own (so that a partial query, `cfsig.search.partial`, reads only
them),
and a CRC-32 per chunk of signatures and per column. Layout: docs/index-format.md.
"""

from __future__ import annotations

import hashlib
import zlib
from collections.abc import Iterable, Iterator
from pathlib import Path

import h5py
import numpy as np

from cfsig.errors import IndexFileError
from cfsig.index.sketch import sketch_center, sketch_groups, sketch_rows
from cfsig.params import Layout

SEGMENT_FORMAT = "cfsig-segment"
STRING = h5py.string_dtype("utf-8")
META = {
    "n_vertices": np.int64,
    "n_faces": np.int64,
    "n_components": np.int64,
    "phi_min": np.float64,
    "phi_max": np.float64,
    "curvature_error": np.float64,
}
TEXT = ("names", "labels", "paths")
COLUMNS = (*TEXT, "sha256", *META)  # the columns of a row besides its signature
# The fine curvature cells of a row and their shares (`cfsig.descriptors.cells.packed_cells`),
# (rows, slots) each, in the segments of an index whose layout keeps them (`Layout.cells`).
CELLS = {"cells": np.uint16, "cell_units": np.uint16}
_DTYPES = {**{k: STRING for k in TEXT}, "sha256": "S64", **META}
_CHUNK_ROWS = 4096  # rows per chunk of signatures, each with its CRC-32
_PIECE_CHUNKS = 16  # chunks copied at a time by a merge: bounds its memory
_SKETCH_CHUNK_ROWS = 65536  # rows per chunk of sketches (8.9 MB at 34 float32): few reads a scan
_EXTRA = ("key_sorted", "key_rows", "drops", "signature_crc32")
SKETCH_EXTRA = ("sketch_groups", "sketch_center", "sketch_error")  # with the dataset `sketch`
GROUP_COLUMNS = "{}_columns"  # where a column group's copy (the dataset of its name) lies
# "signatures" (m, length) float32, every column (m,), and the CELLS (m, slots) if kept
Piece = dict[str, np.ndarray]


def name_keys(names: Iterable[str]) -> np.ndarray:
    """The 64-bit keys of some names: the first 8 bytes of BLAKE2b, little-endian.

    Parameters
    ----------
    names : iterable of str
        Entry names.

    Returns
    -------
    keys : (n,) uint64
    """
    digests = b"".join(hashlib.blake2b(n.encode(), digest_size=8).digest() for n in names)
    return np.frombuffer(digests, dtype="<u8").astype(np.uint64)


def column_crc(values: np.ndarray, crc: int = 0) -> int:
    """CRC-32 of a column's values, continuing ``crc``: strings as UTF-8, each ended by NUL.

    Parameters
    ----------
    values : (m,) ndarray
        Strings (object or bytes) or numbers, as h5py reads them.
    crc : int
        CRC of the values before these.

    Returns
    -------
    crc : int
    """
    if values.dtype.kind == "O":
        data = b"".join(v.encode() + b"\0" if isinstance(v, str) else v + b"\0" for v in values)
    else:
        data = np.ascontiguousarray(values, values.dtype.newbyteorder("<")).tobytes()
    return zlib.crc32(data, crc)


def chunk_crcs(signatures: np.ndarray, chunk_rows: int) -> np.ndarray:
    """CRC-32 of each run of ``chunk_rows`` rows of signatures (float32, little-endian bytes).

    Parameters
    ----------
    signatures : (m, length) float32
        Rows.
    chunk_rows : int
        Rows per chunk.

    Returns
    -------
    crcs : (ceil(m / chunk_rows),) uint32
    """
    data = np.ascontiguousarray(signatures, "<f4")
    crcs = [zlib.crc32(data[s : s + chunk_rows].data) for s in range(0, len(data), chunk_rows)]
    return np.array(crcs, dtype=np.uint32)


def write_segment(
    path: Path,
    segment_id: int,
    layout: Layout,
    rows: int,
    pieces: Iterable[Piece],
    drops: np.ndarray,
) -> None:
    """Write a segment file from pieces of rows, with the keys of its names, sketches, checksums.

    The sketches are computed from the signatures (`cfsig.index.sketch`), on a centre taken from the
    first piece (`sketch_center`).

    Parameters
    ----------
    path : Path
        The new file.
    segment_id : int
        Its number in the index.
    layout : Layout
        The signature length, the column groups stored again on their own (each as the dataset
        of its name, (rows, its columns) float32, in chunks of the signatures' rows), and the
        fine cells per row (the pieces then hold `CELLS`, stored as (rows, cells) datasets).
    rows : int
        Number of rows the pieces hold in all.
    pieces : iterable of dict
        Consecutive rows, of any sizes: ``"signatures"`` (m, width) float32 and every column of
        `COLUMNS` (m,).
    drops : (d, 2) int64
        (segment, row) of the rows of older segments that rows of this one replace.

    Raises
    ------
    ValueError
        The pieces do not hold ``rows`` rows.
    """
    chunk = max(1, min(_CHUNK_ROWS, rows))
    width, cells = layout.length, layout.cells
    groups = sketch_groups(width)
    center, error = np.zeros(len(groups)), 0.0
    with h5py.File(path, "w", libver="latest") as f:
        f.attrs.update(format=SEGMENT_FORMAT, segment=segment_id)
        sigs = f.create_dataset(
            "signatures", (rows, width), np.float32, chunks=(chunk, width) if rows else None
        )
        sketch_chunk = (min(_SKETCH_CHUNK_ROWS, rows), len(groups)) if rows else None
        sketches = f.create_dataset("sketch", (rows, len(groups)), np.float32, chunks=sketch_chunk)
        columns = {k: f.create_dataset(k, (rows,), _DTYPES[k]) for k in COLUMNS}
        if cells:
            for key, dtype in CELLS.items():
                columns[key] = f.create_dataset(
                    key, (rows, cells), dtype, chunks=(chunk, cells) if rows else None
                )
        copies = {
            name: f.create_dataset(
                name,
                (rows, last - first),
                np.float32,
                chunks=(chunk, last - first) if rows else None,
            )
            for name, first, last in layout.groups
        }
        crcs = dict.fromkeys((*columns, "sketch", *copies), 0)
        sig_crcs, keys, start = [], [], 0
        for piece in _regroup(pieces, chunk * _PIECE_CHUNKS):
            rows32 = np.asarray(piece["signatures"], np.float32)  # the sketch of what is stored
            stop = start + len(rows32)
            sigs[start:stop] = rows32
            sig_crcs.append(chunk_crcs(rows32, chunk))
            if start == 0:
                center = sketch_center(rows32, groups)
            sketch, piece_error = sketch_rows(rows32, groups, center)
            sketches[start:stop] = sketch
            crcs["sketch"] = column_crc(sketch, crcs["sketch"])
            error = max(error, piece_error)
            for name, first, last in layout.groups:
                values32 = rows32[:, first:last]
                copies[name][start:stop] = values32
                crcs[name] = column_crc(values32, crcs[name])
            for key in columns:
                values = np.asarray(piece[key], dtype=columns[key].dtype)
                columns[key][start:stop] = values
                crcs[key] = column_crc(values, crcs[key])
            keys.append(name_keys(piece["names"]))
            start = stop
        if start != rows:
            raise ValueError(f"{rows} rows announced, {start} given")
        every = np.concatenate([np.zeros(0, np.uint64), *keys])
        order = np.argsort(every, kind="stable")
        extra = {
            "key_sorted": every[order],
            "key_rows": order.astype(np.uint32),
            "drops": np.asarray(drops, np.int64).reshape(-1, 2),
            "signature_crc32": np.concatenate([np.zeros(0, np.uint32), *sig_crcs]),
            "sketch_groups": groups,
            "sketch_center": center,
            "sketch_error": np.array([error]),
        }
        for name, first, last in layout.groups:
            extra[GROUP_COLUMNS.format(name)] = np.array([first, last], np.int64)
        for key, values in extra.items():
            f.create_dataset(key, data=values)
        f.attrs.update({f"crc32_{k}": np.uint32(v) for k, v in crcs.items()})
        f.attrs.update({f"crc32_{k}": np.uint32(column_crc(v)) for k, v in extra.items()})


def scan_segment(
    f: h5py.File, dead: np.ndarray, problems: list[str] | None = None
) -> Iterator[Piece]:
    """The live rows of an open segment in pieces, checking every checksum on the way.

    Parameters
    ----------
    f : h5py.File
        Open segment.
    dead : (d,) int64
        Sorted rows of this segment that later ones supersede: left out.
    problems : list of str, optional
        Given: each damaged part is appended to it (a run of signature rows, a column) and the
        scan goes on. Not given: the first damage raises.

    Yields
    ------
    piece : dict
        As `write_segment` takes it, strings as ``str``. A segment's sketches and column group
        copies are checked, not yielded.

    Raises
    ------
    IndexFileError
        Without ``problems``: a checksum does not match (columns are checked after their last
        piece).
    """
    sigs = f["signatures"]
    n = sigs.shape[0]
    chunk = sigs.chunks[0] if sigs.chunks else _CHUNK_ROWS
    step = chunk * _PIECE_CHUNKS
    want = f["signature_crc32"][:]
    copies = [k for k in f if GROUP_COLUMNS.format(k) in f]
    derived = [k for k in ("sketch", *copies) if k in f]
    stored = (*COLUMNS, *(k for k in CELLS if k in f))
    crcs = dict.fromkeys((*stored, *derived), 0)
    for start in range(0, n, step):
        stop = min(start + step, n)
        for key in derived:  # checked, not yielded: a new segment computes its own
            crcs[key] = column_crc(f[key][start:stop], crcs[key])
        piece = {"signatures": sigs[start:stop]}
        for key in stored:
            piece[key] = f[key][start:stop]  # strings as bytes: checked before they are decoded
            crcs[key] = column_crc(piece[key], crcs[key])
            if piece[key].dtype.kind == "O":  # a damaged one is reported by its checksum below
                piece[key] = np.array([v.decode(errors="replace") for v in piece[key]], object)
        got = chunk_crcs(piece["signatures"], chunk)
        for i in np.flatnonzero(got != want[start // chunk : start // chunk + len(got)]):
            first = start + int(i) * chunk
            last = min(first + chunk, n) - 1
            _damage(problems, f, f"signatures rows {first}-{last}")
        keep = np.setdiff1d(np.arange(start, stop), dead, assume_unique=True) - start
        yield {key: values[keep] for key, values in piece.items()}
    extras = {"sketch": SKETCH_EXTRA, **{k: (GROUP_COLUMNS.format(k),) for k in copies}}
    for key in (*_EXTRA, *(e for k in derived for e in extras[k])):
        crcs[key] = column_crc(f[key][:])
    for key, crc in crcs.items():
        if crc != int(f.attrs.get(f"crc32_{key}", -1)):
            _damage(problems, f, f"column {key}")


def _damage(problems: list[str] | None, f: h5py.File, part: str) -> None:
    """Record a checksum mismatch, or raise it when no list collects them."""
    if problems is None:
        raise IndexFileError(f"{f.filename}: {part} damaged (checksum mismatch)")
    problems.append(f"{part}: checksum mismatch")


def _regroup(pieces: Iterable[Piece], size: int) -> Iterator[Piece]:
    """The same rows in pieces of exactly ``size`` rows, the last one possibly shorter."""
    held: list[Piece] = []
    count = 0
    for piece in pieces:
        held.append(piece)
        count += len(piece["signatures"])
        while count >= size:
            joined = {k: np.concatenate([p[k] for p in held]) for k in held[0]}
            yield {k: v[:size] for k, v in joined.items()}
            held, count = [{k: v[size:] for k, v in joined.items()}], count - size
    if count:
        yield {k: np.concatenate([p[k] for p in held]) for k in held[0]}
