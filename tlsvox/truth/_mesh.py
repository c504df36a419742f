"""The meshes the truth world is built of: cylinders (bark, targets) and flat
polygonal leaves, with the vector geometry they share."""

from __future__ import annotations

import numpy as np

__all__ = ["LEAF_POLYGON_SIDES", "cylinders_mesh", "leaf_mesh", "orthonormal", "polygon_area_factor",
           "segment_distance"]

#: corners of a leaf polygon (an 8-gon inscribed in the leaf's ellipse)
LEAF_POLYGON_SIDES = 8


def orthonormal(d: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Two unit vectors perpendicular to each row of unit vectors ``d`` (N, 3)."""
    helper = np.where(np.abs(d[:, 2:3]) < 0.9, [[0.0, 0.0, 1.0]], [[1.0, 0.0, 0.0]])
    u = np.cross(d, helper)
    u /= np.linalg.norm(u, axis=1, keepdims=True)
    return u, np.cross(d, u)


def segment_distance(x, a, b) -> np.ndarray:
    """Distance from points ``x`` (..., 3) to the segments ``a``-``b`` (broadcast against ``x``)."""
    ab = b - a
    t = np.clip(np.sum((x - a) * ab, axis=-1) / np.maximum(np.sum(ab * ab, axis=-1), 1e-300), 0.0, 1.0)
    return np.linalg.norm(a + t[..., None] * ab - x, axis=-1)


def cylinders_mesh(cyl: np.ndarray, sides: int = 8, *, caps: bool = False) -> tuple[np.ndarray, np.ndarray]:
    """Cylinders (C, 7) -> vertices (C*2*sides, 3), triangles (C*2*sides [+ C*2*(sides-2)], 3).

    Open tubes, or with ``caps`` closed by a fan of ``sides - 2`` triangles at
    each end (solid wood: a beam down a tube's axis cannot reach the ground).
    """
    a, b, r = cyl[:, :3], cyl[:, 3:6], cyl[:, 6]
    d = b - a
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    u, v = orthonormal(d)
    ang = 2 * np.pi * np.arange(sides) / sides
    ring = np.cos(ang)[None, :, None] * u[:, None, :] + np.sin(ang)[None, :, None] * v[:, None, :]
    ring *= r[:, None, None]
    verts = np.concatenate([a[:, None, :] + ring, b[:, None, :] + ring], axis=1)  # (C, 2s, 3)
    i = np.arange(sides)
    j = (i + 1) % sides
    quad = np.concatenate([np.stack([i, j, sides + i], 1), np.stack([j, sides + j, sides + i], 1)])
    if caps:
        k = np.arange(1, sides - 1)
        fan = np.stack([np.zeros_like(k), k + 1, k], 1)  # facing -d at the start ring
        quad = np.concatenate([quad, fan, sides + fan[:, [0, 2, 1]]])
    base = (np.arange(len(cyl)) * 2 * sides)[:, None, None]
    tris = (quad[None] + base).reshape(-1, 3)
    return verts.reshape(-1, 3), tris


def leaf_mesh(centers, normals, length, width, rng) -> tuple[np.ndarray, np.ndarray]:
    """Flat elliptical leaves: 8-gon fans, long axis at a random angle in the leaf plane."""
    n = len(centers)
    k = LEAF_POLYGON_SIDES
    u, v = orthonormal(normals)
    spin = rng.uniform(0, 2 * np.pi, n)
    major = np.cos(spin)[:, None] * u + np.sin(spin)[:, None] * v
    minor = np.cross(normals, major)
    ang = 2 * np.pi * np.arange(k) / k
    verts = (centers[:, None, :]
             + 0.5 * length * np.cos(ang)[None, :, None] * major[:, None, :]
             + 0.5 * width * np.sin(ang)[None, :, None] * minor[:, None, :])
    fan = np.stack([np.zeros(k - 2, int), np.arange(1, k - 1), np.arange(2, k)], 1)
    tris = (fan[None] + (np.arange(n) * k)[:, None, None]).reshape(-1, 3)
    return verts.reshape(-1, 3), tris


def polygon_area_factor(k: int = LEAF_POLYGON_SIDES) -> float:
    """Area of a k-gon inscribed in an ellipse of semi-axes (1/2, 1/2)... per unit a*b."""
    return 0.5 * k * np.sin(2 * np.pi / k)
