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
Solid voxels (``scene.wood_solid``) are opaque (``sigma_wood`` at the cap
``p = WOOD_P_MAX``) and carry ``(axis, -1 - cap share)`` in ``wdir``.
Scenes without directional wood have no ``wdir`` and are traced exactly as
before.

Uniform boxes (:func:`uniform_boxes`, computed from the pool when the scene is
uploaded): a brick whose non-empty voxels fill one axis-aligned box and all
hold the same values (and bark direction) is crossed by the kernel as one
segment of constant extinction instead of voxel by voxel (docs/method.md,
"Uniform bricks").  Per pool slot the box is packed into one int32:
``lo_x | lo_y << s | lo_z << 2s | hi_x << 3s | hi_y << 4s | hi_z << 5s`` with
``s = log2(brick)`` and ``hi`` inclusive, or -1 when the brick is not uniform.
The record depends only on a slot's contents, so a plot's shared bricks and its
copied bricks get the same one.

Examples
--------
>>> from clsim.validation.testscenes import homogeneous_layer
>>> g = build_bricks(homogeneous_layer(width=5.0, thickness=1.0, voxel_size=0.5))
>>> g.brick_shape.tolist(), g.n_bricks, g.pool.shape
([2, 2, 1], 4, (2048, 2))
"""

from __future__ import annotations

import zlib
from dataclasses import dataclass, field

import numpy as np

from voxlidar.scene import Scene

__all__ = ["BrickGrid", "build_bricks", "bricks_key", "extinction", "uniform_boxes", "uniform_records", "wood_direction",
           "BRICK", "WOOD_P_MAX"]

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
    # solid wood stops a beam from every direction, whatever its wood value says
    sw = np.where(scene.wood_solid, -np.log1p(-WOOD_P_MAX) / scene.voxel_size, sw)
    return lad, sw, flags


def wood_direction(scene: Scene) -> np.ndarray | None:
    """Per stored voxel ``(axis x, y, z, w)`` float64, or None when no bark has a direction.

    ``w`` is ``beta`` in [0, 1] for bark as a turbid medium, and ``-1 - cap`` in
    [-2, -1] for a solid voxel (``Scene.wood_solid``, cap share ``Scene.wood_cap``):
    the kernel tells the two apart by the sign (kernels/transport.cl ``wood_parts``).
    """
    if not scene.wood_directional:
        return None
    w = np.where(scene.wood_solid, -1.0 - scene.wood_cap, scene.wood_beta)
    return np.column_stack([scene.wood_axis, w]).astype(np.float64)


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
    _boxes: tuple | None = field(default=None, init=False, repr=False, compare=False)

    @property
    def boxes(self) -> np.ndarray:
        """(n_bricks,) int32: each slot's uniform box or -1 (:func:`uniform_boxes`), computed
        once per ``pool`` and ``wdir`` array (assigning another array to either recomputes it)."""
        c = self._boxes
        if c is None or c[0] is not self.pool or c[1] is not self.wdir:
            self._boxes = c = (self.pool, self.wdir, uniform_boxes(self.pool, self.wdir, brick=self.brick))
        return c[2]

    @property
    def n_bricks(self) -> int:
        return len(self.pool) // self.brick**3

    @property
    def nbytes(self) -> int:
        return self.index.nbytes + self.pool.nbytes + (0 if self.wdir is None else self.wdir.nbytes)


def bricks_key(scene: Scene, *, leaf_off: bool = False) -> tuple:
    """A fingerprint of everything :func:`build_bricks` reads from ``scene``: equal keys, equal bricks.

    The grid, ``wood_kind``, ``leaf_off`` and a CRC-32 of each of the voxel
    index, LAD and wood columns (with the bark directions and solid wood) (about 25 ms for a million voxels on one core,
    against hundreds for the build), so a cache keyed on it also notices a
    scene changed in place."""
    key = [tuple(scene.shape), float(scene.voxel_size), scene.wood_kind, bool(leaf_off)]
    for a in (scene.ijk, scene.lad, scene.wood, scene.wood_axis, scene.wood_beta, scene.wood_solid, scene.wood_cap):
        if a is None:
            key.append(None)
            continue
        a = np.ascontiguousarray(a)
        key.append((a.dtype.str, a.shape, zlib.crc32(a.view(np.uint8).reshape(-1))))
    return tuple(key)


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


def uniform_boxes(pool: np.ndarray, wdir: np.ndarray | None = None, *, brick: int = BRICK,
                  chunk: int = 4096) -> np.ndarray:
    """Per pool slot, the box of its non-empty voxels when they fill it with one value, else -1.

    Parameters
    ----------
    pool : (n_bricks * brick**3, 2) float32
        :attr:`BrickGrid.pool`.
    wdir : (n_bricks * brick**3, 4) float32 or None
        :attr:`BrickGrid.wdir`; when given, the bark directions must agree too.
    brick : int
        Voxels per brick edge (a power of two up to 32).
    chunk : int
        Slots examined at a time (bounds the temporary memory).

    Returns
    -------
    (n_bricks,) int32
        ``lo_x | lo_y << s | lo_z << 2s | hi_x << 3s | hi_y << 4s | hi_z << 5s``
        (local voxel indices, ``hi`` inclusive, ``s = log2(brick)``) for a
        uniform brick, -1 otherwise.

    Examples
    --------
    >>> from clsim.validation.testscenes import homogeneous_layer
    >>> g = build_bricks(homogeneous_layer(width=2.0, thickness=1.0, base_height=0.5, voxel_size=0.25))
    >>> [[int(b >> (3 * k)) & 7 for k in range(6)] for b in uniform_boxes(g.pool)]   # lo xyz, hi xyz
    [[0, 0, 2, 7, 7, 5]]
    """
    s = brick.bit_length() - 1
    if brick != 1 << s or s * 6 > 31:
        raise ValueError(f"brick must be a power of two up to 32, got {brick}")
    b3 = brick**3
    n = len(pool) // b3
    out = np.full(n, -1, dtype=np.int32)
    for a in range(0, n, chunk):
        z = min(n, a + chunk)
        p = pool[a * b3:z * b3].reshape(z - a, brick, brick, brick, 2)  # [slot, lz, ly, lx]
        nz = (p != 0).any(axis=-1)
        count = nz.sum(axis=(1, 2, 3))
        lo, hi = [], []
        for axes in ((1, 2), (1, 3), (2, 3)):  # x, y, z occupancy profiles
            prof = nz.any(axis=axes)
            lo.append(np.argmax(prof, axis=1))
            hi.append(brick - 1 - np.argmax(prof[:, ::-1], axis=1))
        lo, hi = np.stack(lo, axis=1), np.stack(hi, axis=1)  # (slots, 3) as x, y, z
        full = (count > 0) & (np.prod(hi - lo + 1, axis=1) == count)
        k = np.arange(z - a)
        ref = p[k, lo[:, 2], lo[:, 1], lo[:, 0]]
        same = ((p == ref[:, None, None, None, :]).all(axis=-1) | ~nz).all(axis=(1, 2, 3))
        ok = full & same & (ref.sum(axis=1) > 0)
        if wdir is not None:
            q = wdir[a * b3:z * b3].reshape(z - a, brick, brick, brick, 4)
            qref = q[k, lo[:, 2], lo[:, 1], lo[:, 0]]
            ok &= ((q == qref[:, None, None, None, :]).all(axis=-1) | ~nz).all(axis=(1, 2, 3))
        packed = (lo[:, 0] | lo[:, 1] << s | lo[:, 2] << 2 * s | hi[:, 0] << 3 * s | hi[:, 1] << 4 * s
                  | hi[:, 2] << 5 * s)
        out[a:z] = np.where(ok, packed, -1).astype(np.int32)
    return out


def uniform_records(pool: np.ndarray, boxes: np.ndarray, *, brick: int = BRICK) -> np.ndarray:
    """Per pool slot the kernel's record ``(box, LAD bits, sigma_wood bits, 0)`` (int32).

    ``box`` is :func:`uniform_boxes`'s; for a uniform brick the box's value follows as the
    bits of its two float32s (0 otherwise), so that the walker reads the box and its value
    in one 16-byte load from a small array instead of a pool row, one per 4 KiB slot.

    Examples
    --------
    >>> from clsim.validation.testscenes import homogeneous_layer
    >>> g = build_bricks(homogeneous_layer(width=2.0, thickness=1.0, base_height=0.5, voxel_size=0.25))
    >>> r = uniform_records(g.pool, g.boxes)
    >>> r[:, 1:3].copy().view(np.float32).tolist(), bool(r[0, 0] == g.boxes[0])
    ([[1.0, 0.0]], True)
    """
    s = brick.bit_length() - 1
    b = np.asarray(boxes, dtype=np.int32)
    rec = np.zeros((len(b), 4), dtype=np.int32)
    rec[:, 0] = b
    u = np.nonzero(b >= 0)[0]
    m = brick - 1
    lo = [(b[u] >> (k * s)) & m for k in range(3)]
    rows = u * brick**3 + lo[0] + brick * (lo[1] + brick * lo[2])
    rec[u, 1:3] = np.ascontiguousarray(pool[rows], dtype=np.float32).view(np.int32)
    return rec
