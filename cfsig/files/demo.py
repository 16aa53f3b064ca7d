"""Built-in labelled collection of synthetic shapes for trying out cfsig.

The demo collection lets a new user index, query and evaluate retrieval without data of their
own. It has six classes whose members are different *poses* of one shape, so that a pose-invariant
intrinsic descriptor such as the conformal-factor histogram retrieves them while the classes
themselves differ:

``limbs1``, ``limbs2``, ``limbs3``, ``limbs5``
    A round body with 1, 2, 3 or 5 tubular limbs. Each pose bends every limb at a shoulder and an
    elbow joint in a random plane (an arc-length preserving bend, hence near-isometric).
``torus``
    A torus with slightly varied tube radius whose core circle is warped out of its plane.
``capsule``
    A sphere-capped cylinder with slightly varied proportions, bent into a banana.

All meshes are closed, consistently outward-oriented, connected 2-manifolds without degenerate
triangles, with 1,000 to 4,000 vertices; tori have genus 1 and all other shapes genus 0. Limbed
bodies are built as a coarse control mesh (an icosphere with extruded pentagonal limbs) refined by
two steps of Loop subdivision, then posed. :func:`make_demo_collection` writes the collection as
ASCII OFF files ``<folder>/<class>/<class>-<i>.off``; it is bit-for-bit deterministic per seed.
"""

from __future__ import annotations

from functools import lru_cache
from pathlib import Path

import igl
import numpy as np
from numpy.typing import ArrayLike
from scipy.spatial import cKDTree

CLASSES = ("limbs1", "limbs2", "limbs3", "limbs5", "torus", "capsule")

# Icosahedron vertex indices used as limb roots (the top, two lower and two upper vertices).
_LIMB_SITES = (0, 7, 9, 1, 3)
_LIMB_SEGMENTS, _LIMB_STEP, _LIMB_RADIUS, _TIP_LENGTH = 6, 0.33, 0.36, 0.25
# (start, length) of the shoulder and elbow bends, measured along the limb from the body surface.
_JOINTS = ((0.2, 0.5), (1.1, 0.5))
_MIN_CLEARANCE = 0.15  # random poses bringing a limb closer than this to other parts are redrawn


def _icosahedron() -> tuple[np.ndarray, np.ndarray]:
    """Unit icosahedron with a vertex on +z: top, upper ring, lower ring, bottom."""
    k = np.arange(5)
    z, rho = 1 / np.sqrt(5), 2 / np.sqrt(5)
    az_up = np.deg2rad(72 * k)
    az_lo = az_up + np.deg2rad(36)
    V = np.vstack(
        [
            [0.0, 0.0, 1.0],
            np.column_stack([rho * np.cos(az_up), rho * np.sin(az_up), np.full(5, z)]),
            np.column_stack([rho * np.cos(az_lo), rho * np.sin(az_lo), np.full(5, -z)]),
            [0.0, 0.0, -1.0],
        ]
    )
    up0, up1, lo0, lo1 = 1 + k, 1 + (k + 1) % 5, 6 + k, 6 + (k + 1) % 5
    F = np.vstack(
        [
            np.column_stack([np.zeros(5, int), up0, up1]),
            np.column_stack([up0, lo0, up1]),
            np.column_stack([up1, lo0, lo1]),
            np.column_stack([np.full(5, 11), lo1, lo0]),
        ]
    )
    return V, F.astype(np.int64)


def _icosphere(level: int) -> tuple[np.ndarray, np.ndarray]:
    """Unit icosphere refined ``level`` times; the 12 icosahedron vertices come first."""
    V, F = _icosahedron()
    for _ in range(level):
        V, F = igl.upsample(V, F)
        V /= np.linalg.norm(V, axis=1, keepdims=True)
    return V, F


def _one_ring(F: np.ndarray, v: int) -> np.ndarray:
    """Neighbours of vertex ``v`` in counter-clockwise order seen from outside."""
    fan = F[(F == v).any(axis=1)]
    fan = np.array([np.roll(f, -int(np.flatnonzero(f == v)[0])) for f in fan])
    nxt = dict(zip(fan[:, 1], fan[:, 2], strict=True))
    ring = [int(fan[0, 1])]
    while len(ring) < len(fan):
        ring.append(int(nxt[ring[-1]]))
    return np.array(ring)


def _stitch(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Triangles joining closed vertex loop ``a`` to the loop ``b`` above it (same winding)."""
    a1, b1 = np.roll(a, -1), np.roll(b, -1)
    return np.vstack([np.column_stack([b, a, a1]), np.column_stack([b, a1, b1])])


@lru_cache(maxsize=8)
def _rest_limbed_body(n_limbs: int) -> tuple[np.ndarray, ...]:
    """Unposed limbed body (V, F, limb axes, per-vertex limb label or -1, distance along limb)."""
    V, F = _icosphere(1)
    axes = V[list(_LIMB_SITES[:n_limbs])].copy()
    verts, faces = [V], [F[~np.isin(F, _LIMB_SITES[:n_limbs]).any(axis=1)]]
    n = len(V)
    for site, axis in zip(_LIMB_SITES[:n_limbs], axes, strict=True):
        ring = _one_ring(F, site)
        e = V[ring] - axis
        e -= np.outer(e @ axis, axis)
        e /= np.linalg.norm(e, axis=1, keepdims=True)
        rings = [axis + 0.65 * (V[ring] - axis)]
        rings += [
            (1 + j * _LIMB_STEP) * axis + _LIMB_RADIUS * e for j in range(1, _LIMB_SEGMENTS + 1)
        ]
        loops = [ring] + [n + len(ring) * j + np.arange(len(ring)) for j in range(len(rings))]
        faces += [_stitch(lo, hi) for lo, hi in zip(loops[:-1], loops[1:], strict=True)]
        tip = loops[-1]  # the site vertex itself becomes the tip of the limb
        faces.append(np.column_stack([np.full(len(tip), site), tip, np.roll(tip, -1)]))
        V[site] = (1 + _LIMB_SEGMENTS * _LIMB_STEP + _TIP_LENGTH) * axis
        verts += rings
        n += len(ring) * len(rings)
    V, F = igl.loop(np.vstack(verts), np.vstack(faces).astype(np.int64), 2)
    proj = V @ axes.T
    inside = (proj > 1) & (np.linalg.norm(V[:, None] - proj[..., None] * axes, axis=2) < 0.6)
    label = np.where(inside.any(axis=1), inside.argmax(axis=1), -1)
    t = np.where(label >= 0, np.take_along_axis(proj, label.clip(0)[:, None], 1)[:, 0] - 1, 0.0)
    for a in (V, F, axes, label, t):
        a.flags.writeable = False
    return V, F, axes, label, t


def _perpendicular_basis(axis: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Two unit vectors completing unit ``axis`` to a right-handed orthonormal frame."""
    helper = np.array([1.0, 0.0, 0.0]) if abs(axis[0]) < 0.9 else np.array([0.0, 1.0, 0.0])
    e1 = np.cross(axis, helper)
    e1 /= np.linalg.norm(e1)
    return e1, np.cross(axis, e1)


def _bend(
    P: np.ndarray,
    origin: np.ndarray,
    axis: np.ndarray,
    direction: np.ndarray,
    angle: float,
    start: float,
    length: float,
) -> np.ndarray:
    """Barr bend of points ``P``: the axis segment [start, start+length] becomes a circular arc."""
    q = P - origin
    t, y = q @ axis, q @ direction
    rest = q - np.outer(t, axis) - np.outer(y, direction)
    u = np.clip(t - start, 0.0, length)
    phi = angle * u / length
    c, s = np.cos(phi), np.sin(phi)
    beyond = t - start - u
    ta = start + u * np.sinc(phi / np.pi) - y * s + beyond * c
    td = u * np.sin(phi / 2) * np.sinc(phi / (2 * np.pi)) + y * c + beyond * s
    return origin + rest + np.outer(ta, axis) + np.outer(td, direction)


def _pose_limbs(
    V0: np.ndarray, axes: np.ndarray, label: np.ndarray, angles: np.ndarray
) -> np.ndarray:
    """Bend each limb of the rest body at its elbow, then its shoulder, in its bending plane."""
    V = V0.copy()
    for k, (axis, (azimuth, *bends)) in enumerate(zip(axes, angles, strict=True)):
        e1, e2 = _perpendicular_basis(axis)
        direction = np.cos(azimuth) * e1 + np.sin(azimuth) * e2
        limb = label == k
        for (start, length), angle in reversed(list(zip(_JOINTS, bends, strict=True))):
            V[limb] = _bend(V[limb], axis, axis, direction, angle, start, length)
    return V


def _limb_clearance(V: np.ndarray, label: np.ndarray, t: np.ndarray) -> float:
    """Smallest distance from a vertex past a limb's shoulder to any vertex not on that limb."""
    distal = t > sum(_JOINTS[0])
    return min(
        cKDTree(V[label != k]).query(V[(label == k) & distal])[0].min()
        for k in range(label.max() + 1)
    )


def capsule(
    radius: float = 0.5, length: float = 1.2, bend: float = 0.0, bend_azimuth: float = 0.0
) -> tuple[np.ndarray, np.ndarray]:
    """Sphere-capped cylinder along z, optionally bent into an arc.

    The mesh is a level-4 icosphere whose meridians are mapped by arc length onto the capsule
    profile, so triangles stay well shaped for ``length`` up to about ``3 * radius``.

    Parameters
    ----------
    radius : float
        Radius of the cylinder and of the two hemispherical caps.
    length : float
        Length of the cylindrical part (0 gives a sphere).
    bend : float
        Angle in radians through which the cylindrical part is bent (arc-length preserving).
    bend_azimuth : float
        Azimuth in radians of the plane in which the capsule is bent.

    Returns
    -------
    V : (2562, 3) float64
        Vertex positions, centred at the origin.
    F : (5120, 3) int64
        Outward-oriented triangles.
    """
    V, F = _icosphere(4)
    theta = np.arccos(np.clip(V[:, 2], -1.0, 1.0))
    total = np.pi * radius + length
    s = theta / np.pi * total
    cap = np.pi * radius / 2
    top_phi = np.minimum(s, cap) / radius
    bot_phi = np.minimum(total - s, cap) / radius
    rho = np.where(s < cap, radius * np.sin(top_phi), radius * np.sin(bot_phi))
    z = np.where(
        s < cap,
        length / 2 + radius * np.cos(top_phi),
        np.where(s > total - cap, -length / 2 - radius * np.cos(bot_phi), length / 2 + cap - s),
    )
    sin_theta = np.linalg.norm(V[:, :2], axis=1)
    scale = np.divide(rho, sin_theta, out=np.full_like(rho, total / np.pi), where=sin_theta > 0)
    V = np.column_stack([V[:, :2] * scale[:, None], z])
    if bend:
        axis = np.array([0.0, 0.0, 1.0])
        direction = np.array([np.cos(bend_azimuth), np.sin(bend_azimuth), 0.0])
        V = _bend(V, np.zeros(3), axis, direction, bend, -length / 2, length)
        V -= V.mean(axis=0)
    return V, F


def torus(
    R: float = 1.0, r: float = 0.35, wave: float = 0.0, n_major: int = 72, n_minor: int = 24
) -> tuple[np.ndarray, np.ndarray]:
    """Torus around the z axis whose core circle may be warped out of its plane.

    Parameters
    ----------
    R : float
        Radius of the core circle.
    r : float
        Radius of the tube, ``0 < r < R``.
    wave : float
        Out-of-plane amplitude of the core circle relative to ``R``: the core curve is
        ``(R cos u, R sin u, wave * R sin 2u)`` (a saddle-shaped warp, 0 gives a flat torus).
    n_major, n_minor : int
        Number of vertices around the core circle and around the tube.

    Returns
    -------
    V : (n_major * n_minor, 3) float64
        Vertex positions.
    F : (2 * n_major * n_minor, 3) int64
        Outward-oriented triangles.
    """
    u = 2 * np.pi * np.arange(n_major) / n_major
    v = 2 * np.pi * np.arange(n_minor) / n_minor
    zeros = np.zeros_like(u)
    core = np.column_stack([R * np.cos(u), R * np.sin(u), wave * R * np.sin(2 * u)])
    tangent = np.column_stack([-np.sin(u), np.cos(u), 2 * wave * np.cos(2 * u)])
    tangent /= np.linalg.norm(tangent, axis=1, keepdims=True)
    n1 = np.column_stack([np.cos(u), np.sin(u), zeros])  # orthogonal to the tangent
    n2 = np.cross(n1, tangent)
    V = core[:, None] + r * (
        np.cos(v)[None, :, None] * n1[:, None] + np.sin(v)[None, :, None] * n2[:, None]
    )
    i, j = np.meshgrid(np.arange(n_major), np.arange(n_minor), indexing="ij")
    a = (i * n_minor + j).ravel()
    b = ((i + 1) % n_major * n_minor + j).ravel()
    c = ((i + 1) % n_major * n_minor + (j + 1) % n_minor).ravel()
    d = (i * n_minor + (j + 1) % n_minor).ravel()
    F = np.vstack([np.column_stack([a, b, c]), np.column_stack([a, c, d])])
    return V.reshape(-1, 3), F.astype(np.int64)


def limbed_body(
    n_limbs: int, pose: int | ArrayLike = 0, max_bend: float = 0.9
) -> tuple[np.ndarray, np.ndarray]:
    """Round body with 1 to 5 tubular limbs, each bent at a shoulder and an elbow joint.

    All poses of a body share the same connectivity. Bends preserve arc length along each limb,
    so different poses are near-isometric (total area changes by well under 5%).

    Parameters
    ----------
    n_limbs : int
        Number of limbs, 1 to 5.
    pose : int or (n_limbs, 3) array_like of float
        Either a random seed, or per limb ``(azimuth, shoulder, elbow)`` in radians: the azimuth of
        the bending plane around the limb axis and the signed bend angles of the two joints.
        An all-zero array gives straight limbs. Random poses in which a limb would come close to
        another part of the surface are redrawn; explicit angles are used as given.
    max_bend : float
        Largest absolute joint angle, in radians, drawn when ``pose`` is a seed.

    Returns
    -------
    V : (n, 3) float64
        Vertex positions (1,202 to 3,442 vertices depending on ``n_limbs``).
    F : (2n - 4, 3) int64
        Outward-oriented triangles.
    """
    if not 1 <= n_limbs <= len(_LIMB_SITES):
        raise ValueError(f"n_limbs must be between 1 and {len(_LIMB_SITES)}, got {n_limbs}")
    V0, F, axes, label, t = _rest_limbed_body(n_limbs)
    if not isinstance(pose, (int, np.integer)):
        angles = np.asarray(pose, dtype=np.float64).reshape(n_limbs, 3)
        return _pose_limbs(V0, axes, label, angles), F.copy()
    rng = np.random.default_rng(pose)
    for _ in range(1000):
        angles = np.column_stack(
            [rng.uniform(0, 2 * np.pi, n_limbs), rng.uniform(-max_bend, max_bend, (n_limbs, 2))]
        )
        V = _pose_limbs(V0, axes, label, angles)
        if _limb_clearance(V, label, t) > _MIN_CLEARANCE:
            return V, F.copy()
    raise RuntimeError(f"no collision-free pose found with max_bend={max_bend}")


def write_off(path: str | Path, V: np.ndarray, F: np.ndarray) -> None:
    """Write a triangle mesh as an ASCII OFF file.

    Parameters
    ----------
    path : str or Path
        Output file; its parent directory must exist.
    V : (n, 3) float64
        Vertex positions, written with 9 significant digits.
    F : (m, 3) int64
        Triangles as 0-based vertex indices.
    """
    V = np.asarray(V, dtype=np.float64) + 0.0  # turns -0.0 into 0.0
    lines = [f"OFF\n{len(V)} {len(F)} 0"]
    lines += [f"{x:.9g} {y:.9g} {z:.9g}" for x, y, z in V.tolist()]
    lines += [f"3 {i} {j} {k}" for i, j, k in np.asarray(F, dtype=np.int64).tolist()]
    Path(path).write_text("\n".join(lines) + "\n", encoding="ascii")


def make_demo_collection(folder: str | Path, per_class: int = 5, seed: int = 0) -> list[Path]:
    """Generate the labelled demo collection as OFF files.

    Parameters
    ----------
    folder : str or Path
        Output directory; created if needed. Shape ``i`` of class ``c`` is written to
        ``folder/c/c-i.off`` for each class in :data:`CLASSES`.
    per_class : int
        Number of shapes (poses) per class.
    seed : int
        Seed of the random poses and proportions; equal seeds give byte-identical files.

    Returns
    -------
    paths : list of Path
        The written files, grouped by class in the order of :data:`CLASSES`.
    """
    rng = np.random.default_rng(seed)
    paths = []
    for name in CLASSES:
        (Path(folder) / name).mkdir(parents=True, exist_ok=True)
        for i in range(per_class):
            if name == "torus":
                V, F = torus(r=0.35 * rng.uniform(0.95, 1.05), wave=rng.uniform(-0.15, 0.15))
            elif name == "capsule":
                V, F = capsule(
                    radius=0.5 * rng.uniform(0.95, 1.05),
                    length=1.2 * rng.uniform(0.95, 1.05),
                    bend=rng.uniform(-0.9, 0.9),
                    bend_azimuth=rng.uniform(0, 2 * np.pi),
                )
            else:
                V, F = limbed_body(int(name.removeprefix("limbs")), int(rng.integers(2**31)))
            path = Path(folder) / name / f"{name}-{i}.off"
            write_off(path, V, F)
            paths.append(path)
    return paths
