"""Blocks: stream the rows of a 2-D float32 or uint16 HDF5 dataset without holding it in memory.

Where HDF5 stores rows as plain bytes (contiguous, or chunked by whole rows with no filter, in a
file without a user block, read by the default driver), they are read at the offset HDF5
reports, with no HDF5 in between. A scan views each block in place in one read-only memory map
of the file (`map_file`, `load_block`), its page table filled a block at a time: no copy at
all. Some columns of a block (`read_columns`) are copied from a memory map, which reads only
those; rows scattered over a block (`read_rows`) are copied from the map where the block gives
64 or more, else read run by run with ``preadv`` (docs/performance.md). Where the file cannot
be mapped, a block is read with one ``preadv`` into a reused buffer (`read_block`). Any other
layout (compressed, compact, external, non-native byte order, chunks not yet allocated) is read
through h5py into the same buffer. Reading at fixed offsets is safe because the files of an
index are never modified: a commit adds a segment file and renames a new manifest into place,
and a merge deletes the files it replaced, which stay readable through the open file.
"""

from __future__ import annotations

import ctypes
import functools
import mmap
import os
import sys
from dataclasses import dataclass

import h5py
import numpy as np

from cfsig.errors import IndexFileError

BLOCK_ROWS = 16384  # rows per block of a dataset that is not chunked
_PLAIN_TYPES = (np.dtype(np.float32), np.dtype(np.uint16))  # native: the bytes are the values
# MADV_POPULATE_READ (Linux 5.14, not in Python's mmap module): a block's page table filled in
# one call, not a fault per 64 KB (docs/method.md).
_POPULATE_READ = 22
_DENSE = 4  # `read_rows` reads a whole block when it wants a quarter of its rows or more
# `read_rows` copies a block's rows from a memory map from this many on: filling the block's page
# table costs about what as many reads of runs do (measured on a million rows).
_MAPPED_ROWS = 64


@dataclass(frozen=True)
class Block:
    """A run of rows read as one array.

    Attributes
    ----------
    start, stop : int
        Row range ``[start, stop)``.
    offset : int or None
        Byte offset of row ``start`` in the file when the rows are plain bytes there, else None.
    """

    start: int
    stop: int
    offset: int | None


def plan_blocks(dataset: h5py.Dataset, rows_per_block: int) -> list[Block]:
    """Split a dataset's rows into blocks: one per chunk where chunks can be read directly.

    Parameters
    ----------
    dataset : h5py.Dataset
        A 2-D dataset of shape (N, bins).
    rows_per_block : int
        Rows per block when the rows cannot be read chunk by chunk (rounded up to whole
        chunks) or the dataset is contiguous.

    Returns
    -------
    blocks : list of Block
        Covering rows 0 to N in order.
    """
    n, plain = dataset.shape[0], _plain(dataset)
    if dataset.chunks is not None and plain:
        step, offsets = dataset.chunks[0], _chunk_offsets(dataset)
        return [Block(s, min(s + step, n), offsets.get(s)) for s in range(0, n, step)]
    base = dataset.id.get_offset() if plain else None
    if dataset.chunks is not None:
        rows_per_block = -(-rows_per_block // dataset.chunks[0]) * dataset.chunks[0]
    row_bytes = dataset.shape[1] * dataset.dtype.itemsize
    return [
        Block(s, min(s + rows_per_block, n), None if base is None else base + s * row_bytes)
        for s in range(0, n, rows_per_block)
    ]  # fmt: skip


def read_block(dataset: h5py.Dataset, block: Block, buffer: np.ndarray) -> np.ndarray:
    """The rows of one block, read into ``buffer``.

    Parameters
    ----------
    dataset : h5py.Dataset
        The dataset the block was planned on, still open.
    block : Block
        From `plan_blocks`.
    buffer : (rows, bins) of the dataset's dtype, C-contiguous
        Space for at least ``block.stop - block.start`` rows, reused from block to block.

    Returns
    -------
    rows : (block.stop - block.start, bins)
        A view of ``buffer``.

    Raises
    ------
    IndexFileError
        The file ends before the block does.
    """
    out = buffer[: block.stop - block.start]
    if block.offset is None:
        dataset.read_direct(out, np.s_[block.start : block.stop])
        return out
    handle = dataset.file.id.get_vfd_handle()
    if os.preadv(handle, [out.data.cast("B")], block.offset) != out.nbytes:
        raise _cut_short(dataset)
    return out


@functools.cache
def _libc() -> ctypes.CDLL:
    """The C library, for `madvise` on a memory map."""
    return ctypes.CDLL(None)


def map_file(dataset: h5py.Dataset) -> mmap.mmap | None:
    """A read-only memory map of the whole file that holds ``dataset``.

    Parameters
    ----------
    dataset : h5py.Dataset
        A dataset of an open file; only its blocks of plain bytes (with offsets) are read
        through the map (`load_block`, `read_rows`), the others through a buffer.

    Returns
    -------
    mapped : mmap.mmap or None
        Unmapped once it and every array that views it (`mapped_block`) are gone; None where
        the file cannot be mapped (a file system without memory maps): read its blocks instead.
    """
    try:
        return mmap.mmap(dataset.file.id.get_vfd_handle(), 0, prot=mmap.PROT_READ)
    except (OSError, ValueError):
        return None


def mapped_block(dataset: h5py.Dataset, block: Block, mapped: mmap.mmap) -> np.ndarray:
    """The rows of one block, read in place from a memory map of their file: no copy.

    Parameters
    ----------
    dataset : h5py.Dataset
        The dataset the block was planned on.
    block : Block
        From `plan_blocks`, with an offset (plain rows).
    mapped : mmap.mmap
        `map_file` of the dataset.

    Returns
    -------
    rows : (block.stop - block.start, bins) of the dataset's dtype, read-only
        A view of ``mapped``.

    Raises
    ------
    IndexFileError
        The file ended before the block's end when it was mapped.
    """
    assert block.offset is not None  # plain rows
    count = (block.stop - block.start) * dataset.shape[1]
    end = block.offset + count * dataset.dtype.itemsize
    if end > len(mapped):  # a page touched past the end of the map would kill the process
        raise _cut_short(dataset)
    rows = np.frombuffer(mapped, dataset.dtype, count, block.offset)
    if sys.platform == "linux":
        start = block.offset - block.offset % mmap.PAGESIZE
        address = rows.ctypes.data - (block.offset - start)
        # Through ctypes, which lets other threads run meanwhile; mmap.madvise holds the GIL.
        # Before Linux 5.14 it fails: a fault per 64 KB then, as without.
        _libc().madvise(ctypes.c_void_p(address), ctypes.c_size_t(end - start), _POPULATE_READ)
    return rows.reshape(-1, dataset.shape[1])


def load_block(
    dataset: h5py.Dataset, block: Block, buffer: np.ndarray, mapped: mmap.mmap | None
) -> np.ndarray:
    """The rows of one block: viewed in place where they are plain bytes of a mapped file,
    else read into ``buffer``.

    Parameters
    ----------
    dataset : h5py.Dataset
        The dataset the block was planned on, still open.
    block : Block
        From `plan_blocks`.
    buffer : (rows, bins) of the dataset's dtype, C-contiguous
        As `read_block`; unused when the block is viewed.
    mapped : mmap.mmap or None
        `map_file` of the dataset, or None: read.

    Returns
    -------
    rows : (block.stop - block.start, bins)
        `mapped_block` or `read_block`.

    Raises
    ------
    IndexFileError
        The file ends before the block does.
    """
    if mapped is not None and block.offset is not None:
        return mapped_block(dataset, block, mapped)
    return read_block(dataset, block, buffer)


def read_columns(
    dataset: h5py.Dataset, block: Block, columns: slice, buffer: np.ndarray
) -> np.ndarray:
    """Some columns of the rows of one block.

    Plain rows are copied from a memory map of the block, which touches only those columns'
    bytes instead of copying whole rows out of the page cache; other layouts are read whole
    (`read_block`) and sliced.

    Parameters
    ----------
    dataset : h5py.Dataset
        The dataset the block was planned on, still open.
    block : Block
        From `plan_blocks`.
    columns : slice
        The columns wanted.
    buffer : (rows, bins) of the dataset's dtype, C-contiguous
        Space for at least ``block.stop - block.start`` whole rows, used for other layouts.

    Returns
    -------
    values : (block.stop - block.start, len(columns)) of the dataset's dtype, C-contiguous

    Raises
    ------
    IndexFileError
        The file ends before the block does.
    """
    if block.offset is None:
        return np.ascontiguousarray(read_block(dataset, block, buffer)[:, columns])
    shape = (block.stop - block.start, dataset.shape[1])
    count, dtype = shape[0] * shape[1], dataset.dtype
    handle = dataset.file.id.get_vfd_handle()
    # A map reaching past the end of the file would kill the process when touched there.
    if os.fstat(handle).st_size < block.offset + count * dtype.itemsize:
        raise _cut_short(dataset)
    start = block.offset - block.offset % mmap.ALLOCATIONGRANULARITY
    skip = block.offset - start
    length = skip + count * dtype.itemsize
    with mmap.mmap(handle, length, prot=mmap.PROT_READ, offset=start) as mapped:
        rows = np.frombuffer(mapped, dtype, count, skip).reshape(shape)
        values = np.ascontiguousarray(rows[:, columns])
        del rows  # the map closes only once no array views it
    return values


def read_rows(
    dataset: h5py.Dataset,
    blocks: list[Block],
    rows: np.ndarray,
    out: np.ndarray,
    mapped: mmap.mmap | None = None,
) -> np.ndarray:
    """Some rows of a dataset: copied from a memory map of its file where they are plain
    bytes there, else read by runs of adjacent rows, or by whole blocks where dense.

    Parameters
    ----------
    dataset : h5py.Dataset
        A 2-D dataset of shape (N, bins), still open.
    blocks : list of Block
        From `plan_blocks` on it.
    rows : (m,) int64
        Distinct row numbers, ascending.
    out : (m', bins) of the dataset's dtype, C-contiguous
        Space for at least m rows.
    mapped : mmap.mmap, optional
        `map_file` of the dataset: rows scattered over many blocks cost a copy each from it,
        not a system call per run.

    Returns
    -------
    rows : (m, bins)
        A view of ``out``, in the order of ``rows``.

    Raises
    ------
    IndexFileError
        The file ends before a row does.
    """
    got = out[: len(rows)]
    starts = np.array([b.start for b in blocks], np.int64)
    which = np.searchsorted(starts, rows, side="right") - 1
    row_bytes = dataset.shape[1] * dataset.dtype.itemsize
    handle = dataset.file.id.get_vfd_handle() if any(b.offset is not None for b in blocks) else -1
    bounds = np.flatnonzero(np.diff(which, prepend=-1, append=len(blocks))).tolist()
    for first, last in zip(bounds[:-1], bounds[1:], strict=True):
        block = blocks[which[first]]
        local = rows[first:last] - block.start
        if mapped is not None and block.offset is not None and len(local) >= _MAPPED_ROWS:
            got[first:last] = mapped_block(dataset, block, mapped)[local]
            continue
        if block.offset is None or _DENSE * len(local) >= block.stop - block.start:
            whole = np.empty((block.stop - block.start, dataset.shape[1]), dataset.dtype)
            got[first:last] = read_block(dataset, block, whole)[local]
            continue
        breaks = (np.flatnonzero(np.diff(local) != 1) + 1).tolist()
        offsets = (block.offset + local * row_bytes).tolist()
        for a, b in zip([0, *breaks], [*breaks, len(local)], strict=True):
            space = got[first + a : first + b]
            if os.preadv(handle, [space.data.cast("B")], offsets[a]) != space.nbytes:
                raise _cut_short(dataset)
    return got


def _plain(dataset: h5py.Dataset) -> bool:
    """Whether the dataset's rows are plain native float32 or uint16 bytes at known offsets."""
    dcpl = dataset.id.get_create_plist()
    layout = dcpl.get_layout()
    chunked_by_rows = layout == h5py.h5d.CHUNKED and dataset.chunks[1] == dataset.shape[1]
    return (
        hasattr(os, "preadv")  # not on Windows: read through h5py there
        and dataset.file.driver == "sec2"
        and dataset.file.id.get_create_plist().get_userblock() == 0
        and dataset.dtype in _PLAIN_TYPES
        and dataset.ndim == 2
        and (layout == h5py.h5d.CONTIGUOUS or chunked_by_rows)
        and dcpl.get_nfilters() == 0
        and dcpl.get_external_count() == 0
    )


def _chunk_offsets(dataset: h5py.Dataset) -> dict[int, int]:
    """File offsets of a chunked dataset's allocated, unfiltered chunks, by first row."""
    full = dataset.chunks[0] * dataset.shape[1] * dataset.dtype.itemsize
    infos: list = []
    try:
        dataset.id.chunk_iter(infos.append)
    except (AttributeError, NotImplementedError):  # HDF5 older than 1.14
        infos = [dataset.id.get_chunk_info(i) for i in range(dataset.id.get_num_chunks())]
    return {
        info.chunk_offset[0]: info.byte_offset
        for info in infos
        if info.filter_mask == 0 and info.size == full and info.byte_offset is not None
    }


def _cut_short(dataset: h5py.Dataset) -> IndexFileError:
    """The error for a file that ends before the rows of ``dataset`` do."""
    return IndexFileError(f"{dataset.file.filename}: the file ends inside {dataset.name}")
