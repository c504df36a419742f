"""Exact surface area of a triangle mesh per voxel.

Triangles are cut by the grid planes until each piece lies inside one voxel;
each cut splits a triangle into three (one on one side of the plane, a
quadrilateral as two triangles on the other), so areas add up exactly (to
float rounding).  Fully vectorised: one NumPy pass per plane crossing.

Examples
--------
>>> import numpy as np
>>> tri = np.array([[[0.0, 0.0, 0.5], [2.0, 0.0, 0.5], [0.0, 2.0, 0.5]]])
>>> a = area_per_voxel(tri, origin=(0, 0, 0), voxel_size=1.0, shape=(2, 2, 1))
>>> float(a.sum()), float(a[0, 0, 0]), float(a[1, 1, 0])
(2.0, 1.0, 0.0)
"""

from __future__ import annotations

import numpy as np

from tlsvox.errors import InputError

__all__ = ["area_per_voxel", "normal_moments_per_voxel", "bark_direction", "triangle_areas",
           "split_triangles_on_grid"]


def triangle_areas(tris: np.ndarray) -> np.ndarray:
    """Areas (T,) of triangles given as (T, 3, 3) vertex coordinates."""
    return 0.5 * np.linalg.norm(np.cross(tris[:, 1] - tris[:, 0], tris[:, 2] - tris[:, 0]), axis=1)


def _split_axis(tris: np.ndarray, axis: int, origin: float, h: float) -> np.ndarray:
    """Cut triangles on the planes ``origin + k h`` of one axis, until none straddles."""
    done = []
    work = tris
    while len(work):
        c = work[:, :, axis]
        lo, hi = c.min(axis=1), c.max(axis=1)
        # lowest grid plane strictly above the minimum
        k = np.floor((lo - origin) / h) + 1.0
        plane = origin + k * h
        k = np.where(plane <= lo, k + 1.0, k)  # lo sits on a plane up to rounding
        plane = origin + k * h
        cross = hi > plane
        done.append(work[~cross])
        work, plane = work[cross], plane[cross]
        if not len(work):
            break
        c = work[:, :, axis]
        below = c < plane[:, None]  # (T, 3)
        # the vertex alone on its side: index where `below` differs from the other two
        n_below = below.sum(axis=1)
        lone_is_below = n_below == 1
        lone = np.where(lone_is_below, np.argmax(below, axis=1), np.argmin(below, axis=1))
        idx = np.arange(len(work))
        a = work[idx, lone]
        b = work[idx, (lone + 1) % 3]
        cc = work[idx, (lone + 2) % 3]
        ta = (plane - a[:, axis]) / (b[:, axis] - a[:, axis])
        tc = (plane - a[:, axis]) / (cc[:, axis] - a[:, axis])
        p = a + ta[:, None] * (b - a)
        q = a + tc[:, None] * (cc - a)
        p[:, axis] = plane
        q[:, axis] = plane
        # keep the winding: (a, p, q), (p, b, cc), (p, cc, q)
        work = np.concatenate(
            [np.stack([a, p, q], axis=1), np.stack([p, b, cc], axis=1), np.stack([p, cc, q], axis=1)]
        )
    return np.concatenate(done) if done else tris[:0]


def split_triangles_on_grid(tris, origin, voxel_size) -> np.ndarray:
    """Cut (T, 3, 3) triangles so that every piece lies in a single voxel."""
    tris = np.asarray(tris, dtype=np.float64).reshape(-1, 3, 3)
    origin = np.asarray(origin, dtype=np.float64).reshape(3)
    for axis in range(3):
        tris = _split_axis(tris, axis, origin[axis], float(voxel_size))
    return tris


def area_per_voxel(tris, *, origin, voxel_size, shape, chunk: int = 200_000) -> np.ndarray:
    """Surface area (m2) of triangles inside each voxel of a regular grid.

    Parameters
    ----------
    tris : (T, 3, 3) float, metres
        Triangle vertex coordinates.
    origin : (3,) float, metres
        Lower corner of the grid.
    voxel_size : float, metres
    shape : (3,) int
        Grid dimensions.
    chunk : int
        Triangles processed per pass (bounds memory).

    Returns
    -------
    (nx, ny, nz) float64
        Area per voxel; area outside the grid is dropped.
    """
    if not (np.isfinite(voxel_size) and voxel_size > 0):
        raise InputError(f"voxel_size must be > 0 metres, got {voxel_size!r}")
    shape = tuple(int(s) for s in shape)
    tris = np.asarray(tris, dtype=np.float64).reshape(-1, 3, 3)
    origin = np.asarray(origin, dtype=np.float64).reshape(3)
    out = np.zeros(int(np.prod(shape)), dtype=np.float64)
    for start in range(0, len(tris), chunk):
        pieces = split_triangles_on_grid(tris[start : start + chunk], origin, voxel_size)
        area = triangle_areas(pieces)
        ijk = np.floor((pieces.mean(axis=1) - origin) / voxel_size).astype(np.int64)
        inside = np.all((ijk >= 0) & (ijk < np.array(shape)), axis=1)
        flat = np.ravel_multi_index(ijk[inside].T, shape)
        out += np.bincount(flat, weights=area[inside], minlength=out.size)
    return out.reshape(shape)


def normal_moments_per_voxel(tris, *, origin, voxel_size, shape, chunk: int = 200_000):
    """Area and area-weighted second moment of the unit normals per occupied voxel.

    Parameters
    ----------
    tris, origin, voxel_size, shape, chunk
        As :func:`area_per_voxel`.

    Returns
    -------
    flat : (K,) int64
        Flat (C-order) indices of the voxels holding area.
    area : (K,) float64, m2
    moment : (K, 3, 3) float64, m2
        ``sum A n n^T`` over the pieces in each voxel (n the unit normal;
        its sign does not matter).
    """
    if not (np.isfinite(voxel_size) and voxel_size > 0):
        raise InputError(f"voxel_size must be > 0 metres, got {voxel_size!r}")
    shape = tuple(int(s) for s in shape)
    tris = np.asarray(tris, dtype=np.float64).reshape(-1, 3, 3)
    origin = np.asarray(origin, dtype=np.float64).reshape(3)
    keys, areas, moms = [], [], []
    for start in range(0, len(tris), chunk):
        pieces = split_triangles_on_grid(tris[start : start + chunk], origin, voxel_size)
        cr = np.cross(pieces[:, 1] - pieces[:, 0], pieces[:, 2] - pieces[:, 0])
        two_a = np.linalg.norm(cr, axis=1)
        ok = two_a > 0
        n = cr[ok] / two_a[ok, None]
        area = 0.5 * two_a[ok]
        ijk = np.floor((pieces[ok].mean(axis=1) - origin) / voxel_size).astype(np.int64)
        inside = np.all((ijk >= 0) & (ijk < np.array(shape)), axis=1)
        flat = np.ravel_multi_index(ijk[inside].T, shape)
        u, inv = np.unique(flat, return_inverse=True)
        a = area[inside]
        nn = (n[inside, :, None] * n[inside, None, :]).reshape(-1, 9) * a[:, None]
        keys.append(u)
        areas.append(np.bincount(inv, weights=a, minlength=len(u)))
        moms.append(np.stack([np.bincount(inv, weights=nn[:, c], minlength=len(u)) for c in range(9)], axis=1))
    if not keys:
        return np.zeros(0, np.int64), np.zeros(0), np.zeros((0, 3, 3))
    u, inv = np.unique(np.concatenate(keys), return_inverse=True)
    area = np.bincount(inv, weights=np.concatenate(areas), minlength=len(u))
    m9 = np.concatenate(moms)
    mom = np.stack([np.bincount(inv, weights=m9[:, c], minlength=len(u)) for c in range(9)], axis=1)
    return u, area, mom.reshape(-1, 3, 3)


def bark_direction(area, moment) -> tuple[np.ndarray, np.ndarray]:
    """Bark axis and anisotropy from the normals' second moment (docs/method.md, directional wood).

    ``M = moment / area`` has eigenvalues l1 >= l2 >= l3 (sum 1).  The axis is
    the eigenvector of l3 (the direction the normals avoid) and
    ``beta = 1 - 3 l3``: 1 for a cylinder side (normals all perpendicular to
    its axis, l3 = 0), 0 for isotropic facets (l = 1/3 each).  The model
    ``M = beta (I - a a^T) / 2 + (1 - beta) I / 3`` has the same l3.

    Returns
    -------
    axis : (K, 3) float64, unit, z >= 0
    beta : (K,) float64 in [0, 1]
    """
    area = np.asarray(area, dtype=np.float64)
    m = np.asarray(moment, dtype=np.float64).reshape(-1, 3, 3) / np.maximum(area, 1e-300)[:, None, None]
    w, v = np.linalg.eigh(0.5 * (m + m.transpose(0, 2, 1)))  # ascending eigenvalues
    axis = v[:, :, 0]
    axis = np.where(axis[:, 2:3] < 0, -axis, axis)
    beta = np.clip(1.0 - 3.0 * w[:, 0] / np.maximum(w.sum(axis=1), 1e-300), 0.0, 1.0)
    return axis, np.where(area > 0, beta, 0.0)
