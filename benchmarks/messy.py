"""Messy copies of clean closed meshes, and retrieval on them: what cfsig's repair must undo.

Real models from the web are triangle soups, cut into parts, holed, doubled, finned and full of
hidden inner parts. This script writes, for every clean mesh of a labelled collection
(``<class>/<file>``) and every kind of mess, one messy copy ``OUT/<kind>/<class>/<file>``, then
measures how well each copy's signature finds its own clean original:

    python benchmarks/messy.py write --data FOLDER --out DIR    # the copies, check figures
    python benchmarks/messy.py measure --data FOLDER --out DIR  # signatures and retrieval
    python benchmarks/messy.py run --data FOLDER                # both, in a temporary folder

``FOLDER`` holds the clean meshes ``<class>/<file>`` (e.g. ``DATA/shrec07``); ``--every K``
takes every k-th in sorted order.

Kinds (`KINDS`; each at several amounts, named ``<kind>-<amount>``; ``--kinds fins`` names
every amount of a kind; each copy is seeded by its file's name and the kind, so reruns are
identical):

- ``fins-0.1%``, ``-1%``, ``-5%``: a fin (a third triangle on an edge, its tip 1% of the
  bounding box diagonal off the edge's midpoint) on that share of the edges.
- ``flips-5%``, ``-30%``: that share of the faces reversed.
- ``holes-1``, ``-10``, ``-50``: that many holes of radius 1.5-3% of the diagonal, at most 5% of
  the faces in all.
- ``gaps-2``, ``-10``, ``-30``: cut by planes into that many pieces (a cut may leave more
  parts), each with its own vertices, moved 0.5% of the diagonal away from its cuts.
- ``inner-1``, ``-5``: closed spheres or boxes (radius 2-5% of the diagonal) hidden anywhere
  inside the shape.
- ``walls-1``, ``-5``: flat open disks (radius 5-15% of the diagonal) through points inside
  the shape, turned at random, cut to their faces inside it: hidden inner walls.
- ``outside-1``, ``-5``: small closed spheres or boxes (radius 1-2%) beside the surface, apart
  from it (buttons, eyes): parts of the object, which the repair keeps.
- ``intersecting-1``, ``-5``: small closed spheres or boxes (radius 1-2%) centred on the
  surface, crossing it.
- ``mixture-2%``, ``-5%``: that share of the faces duplicated (half of the copies reversed),
  2.5 times as many reversed, and fins on half as many edges.
- ``overlap``: cut by a plane into two parts that overlap in a band of 3% of the diagonal, one
  moved by 0.1% of the diagonal so the bands interpenetrate.
- ``seams``: cut by a plane into two parts, the second's faces on the cut each split at that
  edge's midpoint: T-junctions all along the seam.
- ``soup``: every face has its own three vertices, faces shuffled, binary STL.
- ``collapsed-1%``, ``-5%``: that share of the faces each with its first corner moved onto its
  second: needles and faces without area, as exporters leave them.
- ``everything-1``, ``-2``: six kinds at once, as in a file off the web: ``holes-10k``,
  ``gaps-10k``, ``inner-5k``, ``outside-5k``, ``fins-k%`` and ``flips-30%`` (k the amount),
  then a soup.
- ``proxy`` (`PROXY_KINDS`): the clean mesh with a tiny closed sphere (radius 0.2%) just inside
  its surface, measured with the repair mode ``proxy``: the proxy forced while the shape is
  intact.

Three more kinds (`SCAN_KINDS`, only when ``--kinds`` names them) are not mess for the repair
stage to undo but the ways a scan of a shape differs from its model:

- ``remesh``: simplified to half its faces by quadric edge collapses
  (`cfsig.repair.simplify.decimate`), so that no vertex or triangle is the model's.
- ``noise-3%``, ``-10%``, ``-50%``: every vertex moved by Gaussian noise whose standard
  deviation per coordinate is that share of the mesh's mean edge length.
- ``shot-0.1%``, ``-1%``: that share of the vertices each moved by 5% of the bounding box
  diagonal in a random direction (spikes, a scanner's outliers).

``measure`` computes the clean signatures (the clean index) and the messy ones with
`cfsig.batch.compute_many`; each messy copy queries the clean index by distance and its original's
rank is counted (ties pessimistically), and the share of copies that took the proxy. The
messy collection (file i replaced by its copy of kind i mod K, files in sorted order, the proxy
kinds left out) and each single-kind collection are evaluated leave-one-out
like the clean one. Files that fail are listed; they rank after every mesh (n + 1) and are left
out of the collections they belong to.

``--doc FILE`` writes a summary (each kind's rank 1, proxy share and FT, and the clean and
messy collections' FT) between the lines ``<!-- benchmarks/messy.py NAME -->`` and
``<!-- /benchmarks/messy.py NAME -->`` of FILE, NAME the data folder's name (docs/results.md
holds such sections); a FILE without them gets the full results instead.
"""

from __future__ import annotations

import argparse
import hashlib
import io
import shlex
import sys
import tempfile
from collections.abc import Callable, Sequence
from dataclasses import replace
from functools import partial
from pathlib import Path

import common
import igl
import numpy as np

from cfsig import Params, compute_many, evaluate_distances
from cfsig.descriptors import NAMES as DESCRIPTORS
from cfsig.params import REPAIR_MODES
from cfsig.repair.simplify import decimate
from cfsig.search.nearest import distances

Mesh = tuple[np.ndarray, np.ndarray]  # vertices (n, 3) float64, faces (m, 3) int64
SUFFIXES = (".off", ".obj", ".ply", ".stl")
MARGIN = 1.25  # an inner part's centre is at least MARGIN times its radius from the surface
MEASURES = ("NN", "FT", "ST", "mAP")
# Clean meshes closer than this (L1 of their signatures) are one shape saved twice: SHREC07 holds
# 7 such pairs, against a median distance of 0.38 from a mesh to its nearest other mesh.
DUPLICATE = 1e-3


def vector(signature) -> np.ndarray:
    """The signature's vector (the one place that names the attribute)."""
    return signature.vector


# --- small geometry -----------------------------------------------------------------------


def diagonal(vertices: np.ndarray) -> float:
    """The length of the bounding box diagonal."""
    return float(np.linalg.norm(vertices.max(axis=0) - vertices.min(axis=0)))


def centroids(mesh: Mesh) -> np.ndarray:
    """Face centroids (m, 3)."""
    vertices, faces = mesh
    return vertices[faces].mean(axis=1)


def face_normals(mesh: Mesh) -> np.ndarray:
    """Unit face normals (m, 3); zero for degenerate faces."""
    vertices, faces = mesh
    tri = vertices[faces]
    cross = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])
    length = np.linalg.norm(cross, axis=1, keepdims=True)
    return np.divide(cross, length, out=np.zeros_like(cross), where=length > 0)


def unit_vector(rng: np.random.Generator) -> np.ndarray:
    """A random direction, uniform on the sphere."""
    v = rng.normal(size=3)
    return v / np.linalg.norm(v)


def rotation(rng: np.random.Generator) -> np.ndarray:
    """A random rotation matrix (QR of a Gaussian matrix, determinant +1)."""
    q, r = np.linalg.qr(rng.normal(size=(3, 3)))
    q = q * np.sign(np.diag(r))
    return q if np.linalg.det(q) > 0 else -q


def submesh(mesh: Mesh, keep: np.ndarray, shift: np.ndarray | None = None) -> Mesh:
    """The faces ``keep`` (mask or indices) with their own copies of their vertices, shifted."""
    vertices, faces = mesh
    chosen = faces[keep]
    used, inverse = np.unique(chosen, return_inverse=True)
    moved = vertices[used] + (0.0 if shift is None else shift)
    return moved, inverse.reshape(chosen.shape).astype(np.int64)


def concatenate(meshes: Sequence[Mesh]) -> Mesh:
    """One mesh made of several, vertex indices offset."""
    offsets = np.cumsum([0] + [len(v) for v, _ in meshes[:-1]])
    vertices = np.vstack([v for v, _ in meshes])
    faces = np.vstack([f + o for (_, f), o in zip(meshes, offsets, strict=True)])
    return vertices, faces.astype(np.int64)


def icosphere(center: np.ndarray, radius: float, subdivisions: int = 2) -> Mesh:
    """A closed, outward-oriented icosphere."""
    t = (1.0 + 5.0**0.5) / 2.0
    v = np.array(
        [[-1, t, 0], [1, t, 0], [-1, -t, 0], [1, -t, 0], [0, -1, t], [0, 1, t]]
        + [[0, -1, -t], [0, 1, -t], [t, 0, -1], [t, 0, 1], [-t, 0, -1], [-t, 0, 1]],
        dtype=np.float64,
    )
    f = np.array(
        [[0, 11, 5], [0, 5, 1], [0, 1, 7], [0, 7, 10], [0, 10, 11], [1, 5, 9], [5, 11, 4]]
        + [[11, 10, 2], [10, 7, 6], [7, 1, 8], [3, 9, 4], [3, 4, 2], [3, 2, 6], [3, 6, 8]]
        + [[3, 8, 9], [4, 9, 5], [2, 4, 11], [6, 2, 10], [8, 6, 7], [9, 8, 1]],
        dtype=np.int64,
    )
    v, f = igl.upsample(v, f, subdivisions)
    v = v / np.linalg.norm(v, axis=1, keepdims=True)
    return center + radius * v, f.astype(np.int64)


def box(center: np.ndarray, radius: float, rng: np.random.Generator) -> Mesh:
    """A closed, outward-oriented cube of circumradius ``radius``, randomly rotated."""
    corners = np.array([[x, y, z] for x in (-1, 1) for y in (-1, 1) for z in (-1, 1)], float)
    f = np.array(
        [[0, 1, 3], [0, 3, 2], [4, 6, 7], [4, 7, 5], [0, 4, 5], [0, 5, 1]]
        + [[2, 3, 7], [2, 7, 6], [0, 2, 6], [0, 6, 4], [1, 5, 7], [1, 7, 3]],
        dtype=np.int64,
    )
    v, f = igl.upsample(corners, f, 1)
    return center + (radius / 3**0.5) * v @ rotation(rng).T, f.astype(np.int64)


def inner_centers(
    mesh: Mesh, radii: Sequence[float], rng: np.random.Generator
) -> tuple[list[np.ndarray], list[float]]:
    """Centres strictly inside the shape for parts of the given radii, apart from each other.

    Candidates are random points of the bounding box and points moved off random faces along
    their normals, both ways; a candidate is inside when its generalised winding number exceeds
    0.5 in absolute value (whatever the orientation), and it fits a part when its distance to
    the surface is at least `MARGIN` radii and it does not touch the parts already placed. A
    shape too thin for a radius gets the largest part that fits at its deepest free candidate
    (the radii returned are those used); a part with no free candidate at all is left out.
    """
    vertices, faces = mesh
    diag = diagonal(vertices)
    lo, hi = vertices.min(axis=0), vertices.max(axis=0)
    picks = rng.integers(len(faces), size=4000)
    depth = rng.uniform(0.002, 0.1, size=(4000, 1)) * diag
    points = np.vstack(
        [
            rng.uniform(lo, hi, size=(4000, 3)),
            centroids(mesh)[picks] - depth * face_normals(mesh)[picks],
            centroids(mesh)[picks] + depth * face_normals(mesh)[picks],
        ]
    )
    inside = np.abs(igl.fast_winding_number(vertices, faces, points)) > 0.5
    points = points[inside]
    dist = np.sqrt(igl.point_mesh_squared_distance(points, vertices, faces)[0])
    placed, used = [], []
    for radius in radii:
        free = dist.copy()
        for c, r in zip(placed, used, strict=True):
            free = np.minimum(free, np.linalg.norm(points - c, axis=1) - r)
        if len(free) == 0 or free.max() <= 0:
            continue
        fits = np.flatnonzero(free >= MARGIN * radius)
        if len(fits):
            i = int(rng.choice(fits))
        else:
            i = int(np.argmax(free))
            radius = float(free[i] / MARGIN)
        placed.append(points[i])
        used.append(radius)
    return placed, used


# --- the kinds of mess ----------------------------------------------------------------------


def soup(mesh: Mesh, rng: np.random.Generator) -> Mesh:
    """Every face with its own three vertices, faces in random order."""
    vertices, faces = mesh
    shuffled = faces[rng.permutation(len(faces))]
    return vertices[shuffled].reshape(-1, 3), np.arange(3 * len(faces)).reshape(-1, 3)


def _split(mesh: Mesh, part: np.ndarray, rng: np.random.Generator) -> tuple:
    """Cut faces by a random plane through one's centroid: (below, above, normal, offset).

    A face is above when its centroid is (``centroid @ normal > offset``).

    The plane is retried until each side holds at least a tenth of the part's faces.
    """
    c = centroids(mesh)[part]
    best = None
    for _ in range(100):
        normal = unit_vector(rng)
        offset = float(c[rng.integers(len(c))] @ normal)
        side = c @ normal > offset
        balance = min(side.sum(), (~side).sum())
        if best is None or balance > best[0]:
            best = (balance, side, normal, offset)
        if balance >= 0.1 * len(part):
            break
    _, side, normal, offset = best
    return part[~side], part[side], normal, offset


def gaps(mesh: Mesh, rng: np.random.Generator, count: int) -> Mesh:
    """``count`` parts cut by planes, each with its own vertices, moved apart by small gaps.

    The largest part is cut again until there are enough; each part then moves by 0.5% of the
    diagonal in a random direction on the far side of its cuts.
    """
    diag = diagonal(mesh[0])
    parts = [(np.arange(len(mesh[1])), np.zeros(3))]  # faces, sum of outward cut normals
    for _ in range(count - 1):
        faces, away = parts.pop(int(np.argmax([len(p) for p, _ in parts])))
        below, above, normal, _ = _split(mesh, faces, rng)
        parts += [(below, away - normal), (above, away + normal)]
    pieces = []
    for faces, away in parts:
        if len(faces) == 0:
            continue
        direction = away / max(np.linalg.norm(away), 1e-12) + 0.5 * unit_vector(rng)
        shift = 0.005 * diag * direction / np.linalg.norm(direction)
        pieces.append(submesh(mesh, faces, shift))
    return concatenate(pieces)


def holes(mesh: Mesh, rng: np.random.Generator, count: int) -> Mesh:
    """``count`` holes: the faces whose centroids are near a random seed face's, at most 5%
    of the faces overall.

    A hole that would pass the budget takes only the faces nearest its seed. A hole that would
    cut the surface in two (around a thin part) is drawn again elsewhere, its radius halved
    after every 10 such draws; a hole that still cuts after 30 draws is not made.
    """
    vertices, faces = mesh
    diag, c = diagonal(vertices), centroids(mesh)
    removed = np.zeros(len(faces), dtype=bool)
    budget, parts = int(0.05 * len(faces)), components(faces)
    for _ in range(count):
        radius = rng.uniform(0.015, 0.03) * diag
        for attempt in range(30):
            seed = int(rng.choice(np.flatnonzero(~removed)))
            dist = np.linalg.norm(c - c[seed], axis=1)
            near = np.flatnonzero((dist < radius * 0.5 ** (attempt // 10)) & ~removed)
            near = near[np.argsort(dist[near])][: max(budget - int(removed.sum()), 1)]
            trial = removed.copy()
            trial[near] = True
            if components(faces[~trial]) == parts:
                removed = trial
                break
    return submesh(mesh, ~removed)


def _fin_faces(mesh: Mesh, rng: np.random.Generator, share: float) -> tuple[np.ndarray, Mesh]:
    """Fins on ``share`` of the edges (at least one): the new tip vertices and fin faces.

    Each fin is a new triangle on an edge whose third vertex sits 1% of the diagonal off the
    edge's midpoint, along the normal of one of the edge's faces.
    """
    vertices, faces = mesh
    half = np.column_stack([faces.ravel(), faces[:, [1, 2, 0]].ravel()])
    _, first = np.unique(np.sort(half, axis=1), axis=0, return_index=True)
    count = max(1, round(share * len(first)))
    picked = rng.choice(first, size=count, replace=False)
    host, (a, b) = picked // 3, half[picked].T
    tips = (vertices[a] + vertices[b]) / 2 + 0.01 * diagonal(vertices) * face_normals(mesh)[host]
    return tips, np.column_stack([b, a, len(vertices) + np.arange(count)])


def fins(mesh: Mesh, rng: np.random.Generator, share: float) -> Mesh:
    """Fins (a third triangle on an edge, its tip off the surface) on ``share`` of the edges."""
    tips, fin = _fin_faces(mesh, rng, share)
    return np.vstack([mesh[0], tips]), np.vstack([mesh[1], fin])


def flips(mesh: Mesh, rng: np.random.Generator, share: float) -> Mesh:
    """``share`` of the faces reversed."""
    vertices, faces = mesh
    out = faces.copy()
    picked = rng.choice(len(faces), size=round(share * len(faces)), replace=False)
    out[picked] = out[picked, ::-1]
    return vertices, out


def mixture(mesh: Mesh, rng: np.random.Generator, share: float) -> Mesh:
    """Duplicated, flipped and finned faces at once: ``share`` of the faces repeated (half of
    the copies reversed), 2.5 times as many reversed, and fins on half as many edges."""
    vertices, faces = flips(mesh, rng, 2.5 * share)
    dup = faces[rng.choice(len(faces), size=round(share * len(faces)), replace=False)]
    reverse = rng.random(len(dup)) < 0.5
    dup[reverse] = dup[reverse, ::-1]
    tips, fin = _fin_faces(mesh, rng, share / 2)
    return np.vstack([vertices, tips]), np.vstack([faces, dup, fin])


def collapsed(mesh: Mesh, rng: np.random.Generator, share: float) -> Mesh:
    """``share`` of the faces each with its first corner moved onto its second."""
    vertices, faces = mesh
    moved = vertices.copy()
    picked = faces[rng.choice(len(faces), size=round(share * len(faces)), replace=False)]
    moved[picked[:, 0]] = moved[picked[:, 1]]
    return moved, faces


def everything(mesh: Mesh, rng: np.random.Generator, amount: int) -> Mesh:
    """Holes, gaps, inner and outside parts, fins and flips at once, as a soup."""
    mesh = holes(mesh, rng, 10 * amount)
    mesh = gaps(mesh, rng, 10 * amount)
    mesh = inner(mesh, rng, 5 * amount)
    mesh = outside(mesh, rng, 5 * amount)
    mesh = fins(mesh, rng, amount / 100)
    return soup(flips(mesh, rng, 0.3), rng)


def _closed_part(center: np.ndarray, radius: float, rng: np.random.Generator) -> Mesh:
    """A sphere or a box, at random."""
    return icosphere(center, radius) if rng.random() < 0.5 else box(center, radius, rng)


def inner(mesh: Mesh, rng: np.random.Generator, count: int) -> Mesh:
    """``count`` closed spheres or boxes (radius 2-5% of the diagonal) hidden inside the shape."""
    diag = diagonal(mesh[0])
    radii = rng.uniform(0.02, 0.05, size=count) * diag
    centers, used = inner_centers(mesh, radii, rng)
    parts = [_closed_part(x, r, rng) for x, r in zip(centers, used, strict=True)]
    return concatenate([mesh, *parts])


def _disk(center: np.ndarray, radius: float, rng: np.random.Generator) -> Mesh:
    """A flat open disk of 8 rings of 32 points around a centre point, turned at random."""
    rings, around = 8, 32
    r = np.repeat(np.arange(1, rings + 1) / rings, around)
    t = np.tile(2 * np.pi * np.arange(around) / around, rings)
    flat = np.vstack(
        [np.zeros(3), np.column_stack([r * np.cos(t), r * np.sin(t), np.zeros_like(r)])]
    )
    k = np.arange(around)
    k1 = (k + 1) % around
    faces = [np.column_stack([np.zeros_like(k), 1 + k, 1 + k1])]
    for ring in range(rings - 1):
        a, b = 1 + ring * around, 1 + (ring + 1) * around
        faces += [np.column_stack([a + k, b + k, b + k1]), np.column_stack([a + k, b + k1, a + k1])]
    return center + radius * flat @ rotation(rng).T, np.vstack(faces)


def walls(mesh: Mesh, rng: np.random.Generator, count: int) -> Mesh:
    """``count`` flat open disks (radius 5-15% of the diagonal) through points inside the shape,
    cut to their faces whose centroids are inside it: hidden inner walls."""
    vertices, faces = mesh
    diag = diagonal(vertices)
    centers, _ = inner_centers(mesh, [0.005 * diag] * count, rng)
    parts = []
    for center in centers:
        disk = _disk(center, rng.uniform(0.05, 0.15) * diag, rng)
        inside = np.abs(igl.fast_winding_number(vertices, faces, centroids(disk))) > 0.5
        parts.append(submesh(disk, inside))
    return concatenate([mesh, *parts])


def _surface_points(mesh: Mesh, rng: np.random.Generator, count: int) -> tuple:
    """Centroids of ``count`` random faces and their unit normals, faces drawn by area."""
    vertices, faces = mesh
    tri = vertices[faces]
    area = np.linalg.norm(np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0]), axis=1)
    picked = rng.choice(len(faces), size=count, p=area / area.sum())
    return centroids(mesh)[picked], face_normals(mesh)[picked]


def outside(mesh: Mesh, rng: np.random.Generator, count: int) -> Mesh:
    """``count`` small closed spheres or boxes (radius 1-2% of the diagonal) beside the shape:
    each off a random point of the surface, along its normal, by twice its radius (buttons,
    eyes, bolts), apart from the body and from each other."""
    vertices, faces = mesh
    diag, parts = diagonal(vertices), []
    points, normals = _surface_points(mesh, rng, 20 * count)
    radii = rng.uniform(0.01, 0.02, size=len(points)) * diag
    centers = points + 2 * radii[:, None] * normals
    clear = igl.point_mesh_squared_distance(centers, vertices, faces)[0] > (1.5 * radii) ** 2
    clear &= np.abs(igl.fast_winding_number(vertices, faces, centers)) <= 0.5
    placed: list[tuple[np.ndarray, float]] = []
    for center, radius in zip(centers[clear], radii[clear], strict=True):
        if all(np.linalg.norm(center - c) > 1.5 * (radius + r) for c, r in placed):
            placed.append((center, radius))
            parts.append(_closed_part(center, radius, rng))
        if len(parts) == count:
            break
    return concatenate([mesh, *parts])


def intersecting(mesh: Mesh, rng: np.random.Generator, count: int) -> Mesh:
    """``count`` closed spheres or boxes (radius 1-2% of the diagonal) centred on random points
    of the surface: each half inside the shape, half out, their surfaces crossing its."""
    diag = diagonal(mesh[0])
    points, _ = _surface_points(mesh, rng, count)
    radii = rng.uniform(0.01, 0.02, size=count) * diag
    return concatenate(
        [mesh, *(_closed_part(x, r, rng) for x, r in zip(points, radii, strict=True))]
    )


def speck(mesh: Mesh, rng: np.random.Generator) -> Mesh:
    """A tiny closed sphere (radius 0.2% of the diagonal) just inside the surface, so that the
    mesh is not clean and a forced proxy runs while the shape itself is intact."""
    diag = diagonal(mesh[0])
    points, normals = _surface_points(mesh, rng, 20)
    centers = np.vstack([points - 0.004 * diag * normals, points + 0.004 * diag * normals])
    winding = np.abs(igl.fast_winding_number(*mesh, centers))
    center = centers[int(np.argmax(winding > 0.5))]
    return concatenate([mesh, icosphere(center, 0.002 * diag, 1)])


def seams(mesh: Mesh, rng: np.random.Generator) -> Mesh:
    """Two parts cut by a plane, the second meshed anew along the cut: each of its faces on
    the cut is split at that edge's midpoint, a vertex inside the first part's edge
    (T-junctions, as where two sides of a seam were meshed independently)."""
    vertices, faces = mesh
    below, above, _, _ = _split(mesh, np.arange(len(faces)), rng)
    first = faces[below]
    half = np.sort(np.column_stack([first.ravel(), first[:, [1, 2, 0]].ravel()]), axis=1)
    keys, counts = np.unique(half, axis=0, return_counts=True)
    cut = {(int(i), int(j)) for i, j in keys[counts == 1]}
    new_vertices, new_faces = [vertices], [first]
    count = len(vertices)
    for face in faces[above]:
        for j in range(3):
            a, b, c = face[j], face[(j + 1) % 3], face[(j + 2) % 3]
            if (min(a, b), max(a, b)) in cut:
                new_vertices.append(((vertices[a] + vertices[b]) / 2)[None])
                new_faces.append(np.array([[a, count, c], [count, b, c]]))
                count += 1
                break
        else:
            new_faces.append(face[None])
    return np.vstack(new_vertices), np.vstack(new_faces).astype(np.int64)


def overlap(mesh: Mesh, rng: np.random.Generator) -> Mesh:
    """Two parts cut by a plane, each also keeping a band of 3% of the diagonal past the cut.

    The second part moves by 0.1% of the diagonal in a random direction, so the two bands
    interpenetrate instead of coinciding.
    """
    diag, c = diagonal(mesh[0]), centroids(mesh)
    _, _, normal, offset = _split(mesh, np.arange(len(mesh[1])), rng)
    height = c @ normal - offset
    first = submesh(mesh, height < 0.03 * diag)
    second = submesh(mesh, height > -0.03 * diag, 0.001 * diag * unit_vector(rng))
    return concatenate([first, second])


def remesh(mesh: Mesh, rng: np.random.Generator) -> Mesh:
    """Simplified to half its faces by quadric edge collapses (``rng`` unused: deterministic)."""
    vertices, faces = mesh
    return decimate(vertices, faces, len(faces) // 2)


def noise(mesh: Mesh, rng: np.random.Generator, share: float) -> Mesh:
    """Every vertex moved by Gaussian noise of ``share`` times the mean edge length."""
    vertices, faces = mesh
    edges = vertices[faces] - vertices[np.roll(faces, 1, axis=1)]
    sigma = share * float(np.linalg.norm(edges, axis=2).mean())
    return vertices + rng.normal(scale=sigma, size=vertices.shape), faces


def shot(mesh: Mesh, rng: np.random.Generator, share: float) -> Mesh:
    """``share`` of the vertices each moved by 5% of the diagonal in a random direction."""
    vertices, faces = mesh
    moved = vertices.copy()
    picked = rng.choice(len(vertices), size=max(1, int(share * len(vertices))), replace=False)
    moved[picked] += 0.05 * diagonal(vertices) * np.array([unit_vector(rng) for _ in picked])
    return moved, faces


Kind = Callable[[Mesh, np.random.Generator], Mesh]
# Each kind of mess at each amount: the amounts run from light to heavy.
MESS_KINDS: dict[str, Kind] = {
    **{f"fins-{p:g}%": partial(fins, share=p / 100) for p in (0.1, 1, 5)},
    **{f"flips-{p:g}%": partial(flips, share=p / 100) for p in (5, 30)},
    **{f"holes-{n}": partial(holes, count=n) for n in (1, 10, 50)},
    **{f"gaps-{n}": partial(gaps, count=n) for n in (2, 10, 30)},
    **{f"inner-{n}": partial(inner, count=n) for n in (1, 5)},
    **{f"walls-{n}": partial(walls, count=n) for n in (1, 5)},
    **{f"outside-{n}": partial(outside, count=n) for n in (1, 5)},
    **{f"intersecting-{n}": partial(intersecting, count=n) for n in (1, 5)},
    **{f"mixture-{p:g}%": partial(mixture, share=p / 100) for p in (2, 5)},
    "overlap": overlap,
    "seams": seams,
    "soup": soup,
    **{f"collapsed-{p:g}%": partial(collapsed, share=p / 100) for p in (1, 5)},
    **{f"everything-{k}": partial(everything, amount=k) for k in (1, 2)},
}
# The proxy forced on clean meshes: measured with the repair mode "proxy".
PROXY_KINDS: dict[str, Kind] = {"proxy": speck}
SCAN_KINDS: dict[str, Kind] = {
    **{f"noise-{p:g}%": partial(noise, share=p / 100) for p in (3, 10, 50)},
    **{f"shot-{p:g}%": partial(shot, share=p / 100) for p in (0.1, 1)},
    "remesh": remesh,
}
KINDS = {**MESS_KINDS, **PROXY_KINDS, **SCAN_KINDS}
# The soups are written as binary STL, the other kinds as OFF.
SUFFIX = {kind: ".stl" for kind in MESS_KINDS if kind.split("-")[0] in ("soup", "everything")}


# --- files ----------------------------------------------------------------------------------


def clean_files(data: Path, every: int) -> list[Path]:
    """The meshes ``<class>/<file>`` of a folder, by class then file (numbers in order)."""

    def key(path: Path) -> tuple:
        stem = path.stem
        return (path.parent.name, not stem.isdigit(), int(stem) if stem.isdigit() else 0, stem)

    files = sorted(
        (p for p in data.glob("*/*") if p.suffix.lower() in SUFFIXES and p.is_file()), key=key
    )
    if not files:
        raise SystemExit(f"no meshes under {data} (pass --data FOLDER of <class>/<file> meshes)")
    return files[::every]


def messy_path(out: Path, kind: str, clean: Path) -> Path:
    """Where the copy of one kind of a clean mesh goes."""
    return out / kind / clean.parent.name / (clean.stem + SUFFIX.get(kind, ".off"))


def generator(clean: Path, kind: str) -> np.random.Generator:
    """A random generator seeded by the file's ``<class>/<name>`` and the kind."""
    digest = hashlib.sha256(f"{clean.parent.name}/{clean.name}:{kind}".encode()).digest()
    return np.random.default_rng(int.from_bytes(digest[:8], "little"))


def read(path: Path) -> Mesh:
    """A mesh file as float64 vertices and int64 faces."""
    vertices, faces = igl.read_triangle_mesh(str(path))
    return np.asarray(vertices, np.float64), np.asarray(faces, np.int64)


def write_off(path: Path, mesh: Mesh) -> None:
    """Write OFF with every coordinate at full precision (17 significant digits)."""
    vertices, faces = mesh
    buffer = io.StringIO()
    buffer.write(f"OFF\n{len(vertices)} {len(faces)} 0\n")
    np.savetxt(buffer, vertices, fmt="%.17g")
    np.savetxt(buffer, np.column_stack([np.full(len(faces), 3), faces]), fmt="%d")
    path.write_text(buffer.getvalue())


def write_stl(path: Path, mesh: Mesh) -> None:
    """Write binary STL: an 80-byte header, the count, then per face normal, corners, 0."""
    tri = mesh[0][mesh[1]]
    record = np.dtype([("normal", "<f4", 3), ("corners", "<f4", (3, 3)), ("attribute", "<u2")])
    rows = np.zeros(len(tri), dtype=record)
    rows["normal"], rows["corners"] = face_normals(mesh), tri
    with path.open("wb") as f:
        f.write(b"cfsig messy benchmark: triangle soup".ljust(80, b" "))
        f.write(np.uint32(len(tri)).tobytes())
        f.write(rows.tobytes())


def write_copy(out: Path, kind: str, clean: Path) -> tuple[Path, Mesh]:
    """Make and write one messy copy; return its path and the mesh written."""
    mesh = KINDS[kind](read(clean), generator(clean, kind))
    path = messy_path(out, kind, clean)
    path.parent.mkdir(parents=True, exist_ok=True)
    (write_stl if path.suffix == ".stl" else write_off)(path, mesh)
    return path, mesh


# --- checks ---------------------------------------------------------------------------------


def components(faces: np.ndarray) -> int:
    """Connected components of faces sharing vertices (unreferenced vertices ignored)."""
    return len(np.unique(igl.vertex_components(faces)[faces.ravel()]))


def check(mesh: Mesh) -> dict[str, int]:
    """Topology figures: as written, and after merging exactly coincident vertices (as readers do).

    ``boundary`` edges have one face, ``nonmanifold`` edges three or more, ``misoriented``
    edges two faces that run along them the same way.
    """
    vertices, faces = mesh
    _, inverse = np.unique(vertices, axis=0, return_inverse=True)
    welded = inverse.reshape(-1)[faces]
    half = welded[:, [0, 1, 1, 2, 2, 0]].reshape(-1, 2)
    half = half[half[:, 0] != half[:, 1]]
    edges, which, counts = np.unique(
        np.sort(half, axis=1), axis=0, return_inverse=True, return_counts=True
    )
    forward = np.bincount(which.reshape(-1), half[:, 0] < half[:, 1], minlength=len(edges))
    pairs = counts == 2
    return {
        "vertices": len(vertices),
        "faces": len(faces),
        "parts": components(faces),
        "welded parts": components(welded),
        "boundary": int((counts == 1).sum()),
        "nonmanifold": int((counts > 2).sum()),
        "misoriented": int((pairs & (forward != 1)).sum()),
    }


def write_all(out: Path, files: Sequence[Path], kinds: Sequence[str], checked: int) -> list[dict]:
    """Write every messy copy; print and return the check figures of ``checked`` meshes.

    The checked meshes are spread evenly over the sorted files (so over the classes).
    """
    rows, chosen = [], set(np.linspace(0, len(files) - 1, checked).round().astype(int))
    for i, clean in enumerate(files):
        if i in chosen:
            rows.append({"kind": "(clean)", "mesh": _name(clean), **check(read(clean))})
        for kind in kinds:
            _, mesh = write_copy(out, kind, clean)
            if i in chosen:
                rows.append({"kind": kind, "mesh": _name(clean), **check(mesh)})
    print(f"{len(files)} meshes x {len(kinds)} kinds -> {out}")
    if rows:
        rows.sort(key=lambda r: (r["mesh"], r["kind"] != "(clean)", r["kind"]))
        print("\nChecks (welded: exactly coincident vertices merged; edges counted after welding):")
        print("\n" + common.table(list(rows[0]), [list(r.values()) for r in rows]))
    return rows


def _name(path: Path) -> str:
    """``<class>/<file>`` of a mesh."""
    return f"{path.parent.name}/{path.name}"


# --- measurement ----------------------------------------------------------------------------


def signatures(paths: Sequence[Path], params: Params, jobs: int) -> tuple[dict, list[str]]:
    """Signatures of files by `compute_many`: {path: signature} and the failures' messages."""
    found, failures = {}, []
    for outcome in compute_many(paths, params, jobs=jobs):
        if outcome.error:
            failures.append(outcome.error)
        else:
            found[outcome.path] = outcome.signature
    return found, sorted(failures)


def own_ranks(
    descriptor: str,
    queries: np.ndarray,
    index: np.ndarray,
    own: np.ndarray,
    same: np.ndarray | None = None,
) -> np.ndarray:
    """Rank of row ``own[i]`` of ``index`` by the descriptor's distance to query i (1 = nearest;
    ties pessimistic).

    ``same[j, k]``, when given, marks clean meshes k that are duplicates of j (`duplicates`):
    they do not rank ahead of their original.
    """
    d = distances(descriptor, queries, index)
    rows = np.arange(len(own))
    ahead = d <= d[rows, own][:, None]
    if same is not None:
        ahead &= ~same[own]
    ahead[rows, own] = True
    return ahead.sum(axis=1)


def duplicates(descriptor: str, index: np.ndarray) -> np.ndarray:
    """Pairs of clean meshes whose signatures are within `DUPLICATE` of each other."""
    same = distances(descriptor, index, index) < DUPLICATE
    np.fill_diagonal(same, False)
    return same


def collection(
    descriptor: str,
    vectors: Sequence[np.ndarray | None],
    labels: Sequence[str],
    models: np.ndarray | None = None,
) -> dict:
    """Leave-one-out measures of a collection, files without a signature left out.

    With ``models`` (one row per file, in the same order), each vector queries the models
    instead of the other vectors, its own file's model left out. The measures are NaN when no
    class keeps two members (nothing to retrieve).
    """
    kept = [i for i, v in enumerate(vectors) if v is not None]
    names = [labels[i] for i in kept]
    found = {"meshes": len(kept), "left out": len(vectors) - len(kept)}
    if len(set(names)) == len(names):
        return {**found, **dict.fromkeys(MEASURES, float("nan"))}
    matrix = np.array([vectors[i] for i in kept])
    against = matrix if models is None else models[kept]
    return {**found, **evaluate_distances(distances(descriptor, matrix, against), names).measures}


def measure(
    out: Path, files: Sequence[Path], kinds: Sequence[str], args: argparse.Namespace
) -> dict:
    """Signatures of the clean and messy files, ranks of the originals, collections' measures."""
    params = Params(descriptor=args.descriptor, **({"repair": args.repair} if args.repair else {}))
    clean, clean_failures = signatures(files, params, args.jobs)
    files = [f for f in files if f in clean]
    labels = [f.parent.name for f in files]
    paths = {kind: [messy_path(out, kind, f) for f in files] for kind in kinds}
    messy: dict = {}
    failures: list[str] = []
    for forced in (False, True):  # the proxy kinds with the repair mode "proxy"
        chosen = [p for kind in kinds if (kind in PROXY_KINDS) == forced for p in paths[kind]]
        found, failed = signatures(
            chosen, replace(params, repair="proxy") if forced else params, args.jobs
        )
        messy.update(found)
        failures += failed
    index = np.array([vector(clean[f]) for f in files])
    n, copies = len(files), []
    collections = {"clean": collection(params.descriptor, list(index), labels)}
    mess = [kind for kind in kinds if kind not in PROXY_KINDS] or kinds
    mixed = [paths[mess[i % len(mess)]][i] for i in range(n)]
    collections["messy (kinds round-robin)"] = collection(
        params.descriptor, [vector(messy[p]) if p in messy else None for p in mixed], labels
    )
    ranks, ranks_as_one, same = {}, {}, duplicates(params.descriptor, index)
    for kind in kinds:
        ok = np.array([i for i, p in enumerate(paths[kind]) if p in messy], dtype=np.int64)
        ranks[kind] = np.full(n, n + 1)  # a failed copy ranks after every mesh
        ranks_as_one[kind] = ranks[kind].copy()
        if len(ok):
            queries = np.array([vector(messy[paths[kind][i]]) for i in ok])
            ranks[kind][ok] = own_ranks(params.descriptor, queries, index, ok)
            ranks_as_one[kind][ok] = own_ranks(params.descriptor, queries, index, ok, same)
        seconds = [messy[p].seconds for p in paths[kind] if p in messy]
        copies.append(
            {
                "kind": kind,
                "copies": n,
                "failed": n - len(ok),
                "rank 1 %": 100.0 * float(np.mean(ranks[kind] == 1)),
                "rank 1 %, duplicates as one": 100.0 * float(np.mean(ranks_as_one[kind] == 1)),
                "top 5 %": 100.0 * float(np.mean(ranks[kind] <= 5)),
                "proxy %": 100.0
                * float(
                    np.mean([messy[p].route == "proxy" for p in paths[kind] if p in messy] or [0.0])
                ),
                "median rank": float(np.median(ranks[kind])),
                "median s": common.median(seconds) if seconds else float("nan"),
            }
        )
        vectors = [vector(messy[p]) if p in messy else None for p in paths[kind]]
        collections[f"all {kind}"] = collection(params.descriptor, vectors, labels)
        collections[f"each {kind} against the clean others"] = collection(
            params.descriptor, vectors, labels, index
        )
    return {
        "command": command(),
        "params": params.to_json(),
        "meshes": n,
        "copies": copies,
        "rank 1 % overall": 100.0 * float(np.mean(np.concatenate(list(ranks.values())) == 1)),
        "rank 1 % overall, duplicates as one": 100.0
        * float(np.mean(np.concatenate(list(ranks_as_one.values())) == 1)),
        "duplicate pairs": int(same.sum()) // 2,
        "clean median s": common.median([clean[f].seconds for f in files]),
        "collections": collections,
        "ranks": {kind: [int(r) for r in ranks[kind]] for kind in kinds},
        "files": [_name(f) for f in files],
        "failures": clean_failures + failures,
    }


def command() -> str:
    """The command line that is running, as one could type it again from the project folder."""
    return shlex.join(["python", "benchmarks/messy.py", *sys.argv[1:]])


def markdown(results: dict, checks: list[dict]) -> str:
    """The results as Markdown: the command, the copies' ranks, the collections, the checks."""
    copies, collections = results["copies"], results["collections"]
    lines = [
        "# Retrieval on "
        + ("scan-like" if set(results["ranks"]) <= set(SCAN_KINDS) else "messy")
        + " copies of clean meshes",
        "",
        f"Measured with `{results['command']}`: {results['meshes']} clean meshes, parameters "
        f"`{results['params']}`; kinds of mess as in the docstring of benchmarks/messy.py.",
        "",
        "Each messy copy queries the index of the clean meshes by distance; the rank is its own "
        "original's (1 = nearest, ties counted against it, a failed file after every mesh):",
        "",
        common.table(list(copies[0]), [list(r.values()) for r in copies]),
        "",
        f"Rank 1 over all kinds: {results['rank 1 % overall']:.1f}%; "
        f"{results['rank 1 % overall, duplicates as one']:.1f}% when the "
        f"{results['duplicate pairs']} pairs of clean meshes whose signatures are within "
        f"{DUPLICATE:g} of each other (one shape saved twice) count as one shape. Median seconds "
        f"per clean file: {results['clean median s']:.3f}.",
        "",
        "Leave-one-out retrieval of each collection: the clean one; the messy one, file i "
        "replaced by its copy of kind i mod K (files sorted); one per kind, every file replaced "
        "by its copy of that kind; and each copy of a kind as a query against the clean "
        "collection, its own original left out (a scan against an index of models). Failed "
        "files are left out:",
        "",
        common.table(
            ["collection", "meshes", "left out", *MEASURES],
            [
                [name, c["meshes"], c["left out"], *(c[m] for m in MEASURES)]
                for name, c in collections.items()
            ],
        ),
        "",
        f"Failures ({len(results['failures'])}):",
        "",
        *(f"- {line}" for line in results["failures"] or ["none"]),
    ]
    if checks:
        lines += [
            "",
            "Checks of the copies of a few meshes (parts: connected components as written; "
            "welded: after merging exactly coincident vertices, by which the edges are counted; "
            "nonmanifold: edges of three or more faces; misoriented: edges of two faces running "
            "along them the same way):",
            "",
            common.table(list(checks[0]), [list(r.values()) for r in checks]),
        ]
    return "\n".join(lines) + "\n"


def summary(results: dict, name: str) -> str:
    """The results in short, for a section of docs/results.md: one row per kind."""
    collections = results["collections"]
    rows = [
        [
            c["kind"],
            c["rank 1 %"],
            c["rank 1 %, duplicates as one"],
            c["proxy %"],
            collections[f"all {c['kind']}"]["FT"],
        ]
        for c in results["copies"]
    ]
    headers = ["kind", "rank 1 %", "duplicates as one", "proxy %", "FT"]
    clean, messy = collections["clean"], collections["messy (kinds round-robin)"]
    return "\n".join(
        [
            f"Measured by `{results['command']}` on {results['meshes']} meshes of {name}, a "
            "copy of each per kind, near-duplicate search. Rank 1: the copies whose own original "
            "is the nearest clean mesh (duplicates as one: the clean meshes saved twice count as "
            "one shape); FT: the copies of a kind as a collection, leave-one-out.",
            "",
            common.table(headers, rows),
            "",
            f"FT of the clean collection {clean['FT']:.3f}; of the messy one (file i replaced "
            f"by its copy of kind i mod K) {messy['FT']:.3f}. Failures: "
            + ("; ".join(results["failures"]) or "none")
            + ".",
        ]
    )


def write_doc(path: Path, results: dict, checks: list[dict], name: str) -> None:
    """Write `summary` into the section of ``path`` named by ``name``, else the full results."""
    begin, end = f"<!-- benchmarks/messy.py {name} -->", f"<!-- /benchmarks/messy.py {name} -->"
    text = path.read_text() if path.exists() else ""
    if begin not in text or end not in text:
        path.write_text(markdown(results, checks))
        return
    head, rest = text.split(begin, 1)
    tail = rest.split(end, 1)[1]
    path.write_text(f"{head}{begin}\n\n{summary(results, name)}\n\n{end}{tail}")


def main() -> None:
    """Parse the command line and run a stage."""
    parser = common.arguments(__doc__.splitlines()[0])
    parser.add_argument("stage", choices=("write", "measure", "run"))
    parser.add_argument("--out", type=Path, help="folder of the messy copies (default: temporary)")
    parser.add_argument(
        "--kinds", nargs="+", default=[*MESS_KINDS, *PROXY_KINDS], metavar="KIND",
        help="kinds of copy, each a name of KINDS or a family (\"fins\": every amount) "
        "[every kind of mess, and the forced proxy]",
    )  # fmt: skip
    parser.add_argument("--jobs", type=int, default=2, help="worker processes for signatures")
    parser.add_argument("--descriptor", choices=DESCRIPTORS, default="intrinsic")
    parser.add_argument("--repair", choices=REPAIR_MODES, help="default: the library's")
    parser.add_argument("--check", type=int, default=3, help="meshes whose copies are checked")
    parser.add_argument(
        "--doc", type=Path, help="write the results as Markdown here (or into its section)"
    )
    args = parser.parse_args()
    if args.stage == "measure" and args.out is None:
        parser.error("measure reads the copies that write made: pass --out")
    if args.out is not None or args.stage == "write":
        stage(args, args.out or Path(tempfile.mkdtemp(prefix="cfsig-messy-")))
    else:
        with tempfile.TemporaryDirectory(prefix="cfsig-messy-") as tmp:
            stage(args, Path(tmp))


def chosen_kinds(names: Sequence[str]) -> list[str]:
    """The kinds named, a family standing for its every amount, in the order of `KINDS`."""
    unknown = [
        name
        for name in names
        if name not in KINDS and not any(k.startswith(f"{name}-") for k in KINDS)
    ]
    if unknown:
        raise SystemExit(f"unknown kinds {unknown}; choose from {', '.join(KINDS)} or a family")
    return [k for k in KINDS if any(k == name or k.startswith(f"{name}-") for name in names)]


def stage(args: argparse.Namespace, out: Path) -> None:
    """Write the copies into ``out`` and/or measure them; print, and save as asked."""
    files, kinds = clean_files(args.data, args.every), chosen_kinds(args.kinds)
    checks = write_all(out, files, kinds, args.check) if args.stage != "measure" else []
    if args.stage == "write":
        return
    results = measure(out, files, kinds, args)
    text = markdown(results, checks)
    print("\n" + text)
    common.save_rows(args.json, [{**results, "checks": checks}])
    if args.doc is not None:
        write_doc(args.doc, results, checks, args.data.resolve().name)


if __name__ == "__main__":
    main()
