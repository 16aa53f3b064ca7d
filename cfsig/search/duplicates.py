"""Questions of a whole collection: each entry's nearest others, and groups of near-duplicates.

Every entry is a query against the index, a batch at a time, by the search `cfsig.query` makes
(`cfsig.search.nearest.search`: pruned by sketches, equal to a full scan), in batches as large
as the search takes at once (`cfsig.search.nearest.group_size`): memory holds one batch of
queries and the search's own bounded buffers, whatever the index's size, and the results
stream out as they come.
"""

from __future__ import annotations

from collections.abc import Callable, Iterator
from dataclasses import dataclass

import numpy as np

from cfsig.index.store import Entry, IndexReader
from cfsig.search.nearest import Hit, group_size, hits, search, without_self

BATCH = 4096  # entries searched at a time at most
_FIRST_K = 8  # neighbours asked per entry by `duplicate_groups`, then more where all are close
BELOW = 0.2  # the default threshold, for the default descriptor: docs/guide.md says why

Progress = Callable[[int], None]  # called with the number of entries done since the last call


@dataclass(frozen=True)
class Group:
    """Entries joined by distances below a threshold, directly or through others.

    Attributes
    ----------
    entries : list of Entry
        In row order.
    distance : float
        The largest of the distances that join them.
    """

    entries: list[Entry]
    distance: float


def nearest_all(
    reader: IndexReader, k: int, progress: Progress | None = None
) -> Iterator[tuple[Entry, list[Hit]]]:
    """Every entry's k nearest other entries, in row order.

    Parameters
    ----------
    reader : IndexReader
        An open index.
    k : int
        Neighbours per entry.
    progress : callable, optional
        Called with the number of entries done after each batch.

    Yields
    ------
    entry : Entry
        An entry of the index.
    hits : list of Hit
        Its k nearest others, as `cfsig.query` ranks them, itself left out.
    """
    for rows in _batches(reader):
        found, dists = search(reader, reader.signatures[rows], k + 1)
        found, dists = without_self(rows, found, dists, k)
        yield from zip(reader.entries(rows), hits(reader, found, dists), strict=True)
        if progress:
            progress(len(rows))


def duplicate_groups(
    reader: IndexReader, below: float = BELOW, progress: Progress | None = None
) -> list[Group]:
    """The groups of entries closer than ``below`` to one another, directly or through others.

    Each entry's neighbours closer than ``below`` are found exactly: `_FIRST_K` are asked
    first, then four times as many for the entries whose neighbours are all that close. Memory
    holds a batch of queries and the entries that have a near neighbour.

    Parameters
    ----------
    reader : IndexReader
        An open index.
    below : float
        Distances below this join two entries (the descriptor's distance: L1 for most).
    progress : callable, optional
        Called with the number of entries done after each batch.

    Returns
    -------
    groups : list of Group
        Of two entries or more, ordered by their first row.
    """
    parent: dict[int, int] = {}
    widest: dict[int, float] = {}
    for rows in _batches(reader):
        todo, k = rows, _FIRST_K
        while len(todo):
            found, dists = without_self(todo, *search(reader, reader.signatures[todo], k + 1), k)
            for row, others, d in zip(todo, found, dists, strict=True):
                for other, distance in zip(others[d < below], d[d < below], strict=True):
                    _join(parent, widest, int(row), int(other), float(distance))
            full = (dists < below).all(axis=1) & (found.shape[1] == k)
            todo, k = todo[full], 4 * k
        if progress:
            progress(len(rows))
    members: dict[int, list[int]] = {}
    for row in sorted(parent):
        members.setdefault(_root(parent, row), []).append(row)
    return [
        Group(reader.entries(np.array(group)), widest[root])
        for root, group in sorted(members.items(), key=lambda item: item[1][0])
    ]


def _batches(reader: IndexReader) -> Iterator[np.ndarray]:
    """The row numbers of an index, in runs of as many queries as its search takes at once
    (at most `BATCH`)."""
    n, size = len(reader), min(BATCH, group_size(reader))
    for first in range(0, n, size):
        yield np.arange(first, min(first + size, n))


def _root(parent: dict[int, int], row: int) -> int:
    """The representative of a row's group, halving the path on the way."""
    while parent[row] != row:
        parent[row] = parent[parent[row]]
        row = parent[row]
    return row


def _join(
    parent: dict[int, int], widest: dict[int, float], a: int, b: int, distance: float
) -> None:
    """Join the groups of rows a and b, keeping the largest distance that joins each group."""
    for row in (a, b):
        if row not in parent:
            parent[row], widest[row] = row, 0.0
    ra, rb = _root(parent, a), _root(parent, b)
    top = max(widest[ra], widest[rb], distance)
    if ra != rb:
        parent[rb] = ra
    widest[ra] = top
