"""Solid wood voxels from cylinders: the cells inside them, their surface and cap share.

Shared by the truth's twin (:meth:`tlsvox.truth.synthetic.SyntheticTree.truth_scene`,
from the tree's own cylinders) and the TLS pipeline (:mod:`tlsvox.voxel.wood.qsm`, from
cylinders fitted to the wood echoes), so both fill solid wood the same way: a
voxel is solid when its centre lies inside a cylinder with flat ends; its
surface is the cylinder's side and end caps, the caps' share of the bark
around the voxel taken from the area-weighted normals of that bark
(docs/method.md, solid wood).

Examples
--------
>>> import numpy as np
>>> cyl = np.array([[0.5, 0.5, 0.0, 0.5, 0.5, 1.0, 0.3]])   # upright, r 0.3 m, centred in a 1 m box
>>> flat, axis, owner = cylinder_cells(cyl, origin=(0, 0, 0), voxel_size=0.1, shape=(10, 10, 10))
>>> len(flat) // 10, axis[0].tolist(), int(owner.max())    # 32 columns of centres inside the circle
(32, [0.0, 0.0, 1.0], 0)
"""

from __future__ import annotations

import numpy as np

from tlsvox.errors import InputError

__all__ = ["cylinder_cells", "dilate", "cap_share", "cylinder_surface"]


def cylinder_cells(cylinders, *, origin, voxel_size, shape) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Voxels whose centre lies inside a cylinder (flat ends), with that cylinder's axis and row.

    Parameters
    ----------
    cylinders : (C, 7) float
        Start (3), end (3), radius, metres.
    origin, voxel_size, shape
        The grid (lower corner, edge in metres, (nx, ny, nz)).

    Returns
    -------
    flat : (K,) int64
        Sorted flat (C-order) indices of the voxels.
    axis : (K, 3) float64
        Unit axis (z >= 0) of the cylinder holding each centre (the last
        one listed where cylinders overlap).
    owner : (K,) int64
        That cylinder's row in ``cylinders``.
    """
    cylinders = np.asarray(cylinders, dtype=np.float64).reshape(-1, 7)
    origin = np.asarray(origin, dtype=np.float64).reshape(3)
    if not (np.isfinite(voxel_size) and voxel_size > 0):
        raise InputError(f"voxel_size must be > 0 metres, got {voxel_size!r}")
    shape = tuple(int(v) for v in shape)
    a, b, r = cylinders[:, :3], cylinders[:, 3:6], cylinders[:, 6]
    length = np.linalg.norm(b - a, axis=1)
    axes = (b - a) / np.where(length > 0, length, 1.0)[:, None]
    axes *= np.where(axes[:, 2] < 0, -1.0, 1.0)[:, None]
    flats, owner = [], []
    for i in np.flatnonzero((length > 0) & (r > 0)):
        lo = np.maximum(np.floor((np.minimum(a[i], b[i]) - r[i] - origin) / voxel_size).astype(int), 0)
        hi = np.minimum(np.floor((np.maximum(a[i], b[i]) + r[i] - origin) / voxel_size).astype(int),
                        np.array(shape) - 1)
        if np.any(hi < lo):
            continue
        g = np.stack(np.meshgrid(*[np.arange(lo[k], hi[k] + 1) for k in range(3)], indexing="ij"),
                     -1).reshape(-1, 3)
        x = origin + (g + 0.5) * voxel_size - a[i]
        u = (b[i] - a[i]) / length[i]
        t = x @ u  # along the axis from a, m
        radial = np.linalg.norm(x - t[:, None] * u, axis=1)
        inside = (t >= 0) & (t <= length[i]) & (radial < r[i])  # flat ends
        flats.append(np.ravel_multi_index(g[inside].T, shape))
        owner.append(np.full(int(inside.sum()), i))
    if not flats:
        return np.zeros(0, np.int64), np.zeros((0, 3)), np.zeros(0, np.int64)
    # np.unique keeps each voxel's first occurrence: reversed, that is the last cylinder listed
    flat, first = np.unique(np.concatenate(flats)[::-1], return_index=True)
    own = np.concatenate(owner)[::-1][first]
    return flat.astype(np.int64), axes[own], own.astype(np.int64)


def dilate(cells, shape) -> np.ndarray:
    """Dense (nx, ny, nz) bool mask of ``cells`` (flat indices) and their 26 neighbours."""
    mask = np.zeros(tuple(shape), bool)
    if not len(cells):
        return mask
    ijk = np.stack(np.unravel_index(cells, tuple(shape)), axis=1)
    for off in np.stack(np.meshgrid(*[np.arange(-1, 2)] * 3, indexing="ij"), -1).reshape(-1, 3):
        nb = ijk + off
        nb = nb[np.all((nb >= 0) & (nb < np.asarray(shape)), axis=1)]
        mask[tuple(nb.T)] = True
    return mask


def cap_share(cells, axis, flat, area, moment, shape) -> np.ndarray:
    """Share of the bark around each of ``cells`` on end caps of a cylinder about ``axis``.

    The bark of the cell and its 26 neighbours (``flat``, ``area``, ``moment``
    from :func:`tlsvox.truth.meshtruth.normal_moments_per_voxel`): ``a^T M a / A``,
    the area-weighted mean of ``(n . a)^2``, which is 1 on an end cap and 0 on
    the side.  A cell with no bark around it (deep inside a thick trunk) gets 0.
    """
    shape = np.asarray(shape, dtype=np.int64)
    ijk = np.stack(np.unravel_index(cells, tuple(shape)), axis=1)
    tot_a = np.zeros(len(cells))
    tot_m = np.zeros((len(cells), 3, 3))
    for off in np.stack(np.meshgrid(*[np.arange(-1, 2)] * 3, indexing="ij"), -1).reshape(-1, 3):
        nb = ijk + off
        inside = np.all((nb >= 0) & (nb < shape), axis=1)
        keys = np.ravel_multi_index(nb[inside].T, tuple(shape))
        pos = np.minimum(np.searchsorted(flat, keys), max(len(flat) - 1, 0))
        hit = np.zeros(len(cells), bool)
        if len(flat):
            hit[inside] = flat[pos] == keys
        rows = pos[hit[inside]]
        tot_a[hit] += area[rows]
        tot_m[hit] += moment[rows]
    share = np.einsum("ki,kij,kj->k", axis, tot_m, axis) / np.maximum(tot_a, 1e-300)
    return np.clip(np.where(tot_a > 0, share, 0.0), 0.0, 1.0)


def cylinder_surface(cylinders, *, caps_start=None, caps_end=None, sides: int = 16) -> np.ndarray:
    """(T, 3, 3) triangles of the cylinders' sides, and of the end caps asked for.

    ``caps_start`` / ``caps_end`` (C,) bool (default all True) choose which
    ends are closed: where stacked cylinders meet, the joint is no surface.
    """
    from tlsvox.truth._mesh import orthonormal

    cyl = np.asarray(cylinders, dtype=np.float64).reshape(-1, 7)
    n = len(cyl)
    if not n:
        return np.zeros((0, 3, 3))
    caps_start = np.ones(n, bool) if caps_start is None else np.asarray(caps_start, bool)
    caps_end = np.ones(n, bool) if caps_end is None else np.asarray(caps_end, bool)
    a, b, r = cyl[:, :3], cyl[:, 3:6], cyl[:, 6]
    d = (b - a) / np.linalg.norm(b - a, axis=1, keepdims=True)
    u, v = orthonormal(d)
    ang = 2 * np.pi * np.arange(sides) / sides
    ring = (np.cos(ang)[None, :, None] * u[:, None] + np.sin(ang)[None, :, None] * v[:, None]) * r[:, None, None]
    ra, rb = a[:, None] + ring, b[:, None] + ring  # (C, s, 3)
    nxt = np.roll(np.arange(sides), -1)
    side = np.concatenate([np.stack([ra, ra[:, nxt], rb], 2), np.stack([ra[:, nxt], rb[:, nxt], rb], 2)], 1)
    parts = [side.reshape(-1, 3, 3)]
    for ends, rr, centre in ((caps_start, ra, a), (caps_end, rb, b)):
        if ends.any():
            fan = np.stack([np.repeat(centre[ends][:, None], sides, 1), rr[ends], rr[ends][:, nxt]], 2)
            parts.append(fan.reshape(-1, 3, 3))
    return np.concatenate(parts)
