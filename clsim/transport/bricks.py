"""Sparse scene on the device: an occupancy grid of bricks plus a brick pool.

The grid is cut into bricks of ``B**3`` voxels (B = 8).  ``index`` holds, per
brick cell, the brick's slot in ``pool`` or -1 when every voxel in it is
empty; ``pool`` holds the extinction of every voxel of the occupied bricks.
Traversal (kernels/scene.cl) skips an empty brick in one step, so empty space
costs almost nothing and memory grows with the occupied volume only.

Per voxel the pool stores ``(LAD, sigma_wood)``:

- LAD, one-sided leaf area density, m2/m3 (leaf extinction is LAD x G);
- ``sigma_wood``, 1/m, wood as a turbid medium.  For ``wood_kind =
  "probability"`` the full-voxel crossing probability equals the wood value
  ``p``: ``sigma_wood = -ln(1 - p) / h`` (p is capped at ``1 - 1e-6``); for
  ``"area_density"`` randomly oriented bark gives ``sigma_wood = 0.5 WAD``.

Directional wood (``scene.wood_beta > 0`` somewhere; docs/method.md): a
second pool ``wdir`` of the same rows holds ``(axis x, y, z, beta)`` per
voxel, and ``sigma_wood`` above is the direction-averaged extinction, which
the kernel scales by ``1 + beta (4 sin(psi) / pi - 1)`` along a direction at
angle psi to the axis (largest across the axis, ``1 + beta (4 / pi - 1)``: the
tracking majorant; kernels/transport.cl ``wood_parts``, ``wood_majorant``).
Scenes without directional wood have no ``wdir`` and are traced exactly as
before.

Examples
--------
>>> from clsim.validation.testscenes import homogeneous_layer
>>> g = build_bricks(homogeneous_layer(width=5.0, thickness=1.0, voxel_size=0.5))
>>> g.brick_shape.tolist(), g.n_bricks, g.pool.shape
([2, 2, 1], 4, (2048, 2))
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from voxlidar.scene import Scene

__all__ = ["BrickGrid", "build_bricks", "extinction", "wood_direction", "BRICK", "WOOD_P_MAX"]

BRICK = 8
WOOD_P_MAX = 1.0 - 1e-6


def extinction(scene: Scene, *, leaf_off: bool = False) -> tuple[np.ndarray, np.ndarray, dict]:
    """Per stored voxel ``(lad, sigma_wood)`` float64 and flags.

    Returns
    -------
    lad : (M,) float64, m2/m3
    sigma_wood : (M,) float64, 1/m
    flags : dict
        ``wood_probability_capped``: number of voxels with p >= 1.
    """
    lad = np.zeros(scene.n_voxels) if leaf_off else scene.lad.astype(np.float64)
    flags = {}
    if scene.wood_kind == "probability":
        p = np.asarray(scene.wood, dtype=np.float64)
        capped = int(np.count_nonzero(p > WOOD_P_MAX))
        if capped:
            flags["wood_probability_capped"] = capped
        sw = -np.log1p(-np.minimum(p, WOOD_P_MAX)) / scene.voxel_size
    else:
        sw = 0.5 * np.asarray(scene.wood, dtype=np.float64)
    return lad, sw, flags


def wood_direction(scene: Scene) -> np.ndarray | None:
    """Per stored voxel ``(axis x, y, z, beta)`` float64, or None when no bark has a direction."""
    if not scene.wood_directional:
        return None
    return np.column_stack([scene.wood_axis, scene.wood_beta]).astype(np.float64)


@dataclass
class BrickGrid:
    """Brick occupancy grid and pool (see module docstring).

    Attributes
    ----------
    brick : int
        Voxels per brick edge.
    brick_shape : (3,) int
        Brick cells per axis, ``ceil(shape / brick)``.
    index : (nbx * nby * nbz,) int32
        Pool slot per brick cell, x fastest; -1 for empty bricks.
    pool : (n_bricks * brick**3, 2) float32
        ``(LAD, sigma_wood)`` per voxel; voxel (lx, ly, lz) of slot s is row
        ``s * brick**3 + lx + brick * (ly + brick * lz)``.
    wdir : (n_bricks * brick**3, 4) float32 or None
        ``(axis x, y, z, beta)`` per voxel, same rows as ``pool``; None when
        the scene's wood has no direction (every ``beta`` 0).
    """

    brick: int
    brick_shape: np.ndarray
    index: np.ndarray
    pool: np.ndarray
    flags: dict
    wdir: np.ndarray | None = None

    @property
    def n_bricks(self) -> int:
        return len(self.pool) // self.brick**3

    @property
    def nbytes(self) -> int:
        return self.index.nbytes + self.pool.nbytes + (0 if self.wdir is None else self.wdir.nbytes)


def build_bricks(scene: Scene, *, leaf_off: bool = False, brick: int = BRICK) -> BrickGrid:
    """Pack a scene's non-empty voxels into bricks."""
    lad, sw, flags = extinction(scene, leaf_off=leaf_off)
    keep = (lad > 0) | (sw > 0)
    ijk = scene.ijk[keep].astype(np.int64)
    vals = np.column_stack([lad[keep], sw[keep]]).astype(np.float32)
    bshape = -(-np.asarray(scene.shape, dtype=np.int64) // brick)
    bijk = ijk // brick
    bflat = bijk[:, 0] + bshape[0] * (bijk[:, 1] + bshape[1] * bijk[:, 2])
    used, slot = np.unique(bflat, return_inverse=True)
    index = np.full(int(np.prod(bshape)), -1, dtype=np.int32)
    index[used] = np.arange(len(used), dtype=np.int32)
    loc = ijk - bijk * brick
    row = slot * brick**3 + loc[:, 0] + brick * (loc[:, 1] + brick * loc[:, 2])
    pool = np.zeros((len(used) * brick**3, 2), dtype=np.float32)
    pool[row] = vals
    wdir = None
    wd = wood_direction(scene)
    if wd is not None:
        wdir = np.zeros((len(pool), 4), dtype=np.float32)
        wdir[:, 2] = 1.0
        wdir[row] = wd[keep]
    return BrickGrid(brick=brick, brick_shape=bshape.astype(np.int32), index=index, pool=pool,
                     flags=flags, wdir=wdir)
