"""Blocks: stream the rows of a 2-D float32 HDF5 dataset without holding it in memory.

Where HDF5 stores rows as plain bytes (contiguous, or chunked by whole rows with no filter, in a
file without a user block, read by the default driver), a block is memory-mapped from the file:
the page cache is read once, by the code that uses the rows, with no copy through HDF5. Any other
layout (compressed, compact, external, non-native byte order, chunks not yet allocated) is read
through h5py into a buffer. Mapping is safe because an index file is never modified in place:
a commit renames a new file over it, and the mapping keeps the file that was opened.
"""

from __future__ import annotations

import mmap
from dataclasses import dataclass

import h5py
import numpy as np

_FLOAT32 = np.dtype(np.float32)


@dataclass(frozen=True)
class Block:
    """A run of rows read as one array.

    Attributes
    ----------
    start, stop : int
        Row range ``[start, stop)``.
    offset : int or None
        Byte offset of row ``start`` in the file when the rows can be mapped, else None.
    """

    start: int
    stop: int
    offset: int | None


def plan_blocks(dataset: h5py.Dataset, rows_per_block: int) -> list[Block]:
    """Split a dataset's rows into blocks: one per chunk where chunks can be mapped.

    Parameters
    ----------
    dataset : h5py.Dataset
        A 2-D dataset of shape (N, bins).
    rows_per_block : int
        Rows per block when the rows cannot be mapped chunk by chunk (rounded up to whole
        chunks) or the dataset is contiguous.

    Returns
    -------
    blocks : list of Block
        Covering rows 0 to N in order.
    """
    n, mappable = dataset.shape[0], _mappable(dataset)
    if dataset.chunks is not None and mappable:
        step, offsets = dataset.chunks[0], _chunk_offsets(dataset)
        return [Block(s, min(s + step, n), offsets.get(s)) for s in range(0, n, step)]
    base = dataset.id.get_offset() if mappable else None
    if dataset.chunks is not None:
        rows_per_block = -(-rows_per_block // dataset.chunks[0]) * dataset.chunks[0]
    row_bytes = dataset.shape[1] * _FLOAT32.itemsize
    return [
        Block(s, min(s + rows_per_block, n), None if base is None else base + s * row_bytes)
        for s in range(0, n, rows_per_block)
    ]  # fmt: skip


def read_block(dataset: h5py.Dataset, block: Block, buffer: np.ndarray) -> np.ndarray:
    """The rows of one block, mapped from the file or read into ``buffer``.

    A mapped block stays mapped while the returned array (or a view of it) is referenced: drop
    it before reading many more.

    Parameters
    ----------
    dataset : h5py.Dataset
        The dataset the block was planned on, still open.
    block : Block
        From `plan_blocks`.
    buffer : (rows, bins) float32
        Scratch space with at least ``block.stop - block.start`` rows, used when the block cannot
        be mapped.

    Returns
    -------
    rows : (block.stop - block.start, bins) float32, read-only when mapped
    """
    count = block.stop - block.start
    if block.offset is None:
        out = buffer[:count]
        dataset.read_direct(out, np.s_[block.start : block.stop])
        return out
    bins = dataset.shape[1]
    aligned = block.offset - block.offset % mmap.ALLOCATIONGRANULARITY
    skip = block.offset - aligned
    # MAP_POPULATE (Linux) maps the pages in one call instead of one page fault per 4 KiB.
    view = mmap.mmap(
        dataset.file.id.get_vfd_handle(), skip + count * bins * _FLOAT32.itemsize,
        flags=mmap.MAP_SHARED | getattr(mmap, "MAP_POPULATE", 0), prot=mmap.PROT_READ,
        offset=aligned,
    )  # fmt: skip
    return np.frombuffer(view, _FLOAT32, count * bins, skip).reshape(count, bins)


def _mappable(dataset: h5py.Dataset) -> bool:
    """Whether the dataset's rows are plain native float32 bytes at known file offsets."""
    dcpl = dataset.id.get_create_plist()
    layout = dcpl.get_layout()
    chunked_by_rows = layout == h5py.h5d.CHUNKED and dataset.chunks[1] == dataset.shape[1]
    return (
        dataset.file.driver == "sec2"
        and dataset.file.id.get_create_plist().get_userblock() == 0
        and dataset.dtype == _FLOAT32
        and dataset.ndim == 2
        and (layout == h5py.h5d.CONTIGUOUS or chunked_by_rows)
        and dcpl.get_nfilters() == 0
        and dcpl.get_external_count() == 0
    )


def _chunk_offsets(dataset: h5py.Dataset) -> dict[int, int]:
    """File offsets of a chunked dataset's allocated, unfiltered chunks, by first row."""
    full = dataset.chunks[0] * dataset.shape[1] * _FLOAT32.itemsize
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
