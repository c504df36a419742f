"""The sparse voxel layout: full statistics only where the scans saw something.

A dense trace keeps 16 sums for every voxel of the bounding grid: 2 cm voxels
over an oak's crown are ~3e8 voxels, ~100 GB.  But a voxel that holds no leaf
or wood echo has LAD 0 and no wood whatever its sums say; all the estimators
need to know of it is whether beams saw it empty or never reached it
(occlusion).  So the sparse layout keeps

- a full row of the tracer's sums (:data:`tlsvox.voxel.trace.FIELDS`) for
  each *row voxel*: a voxel that holds at least one leaf or wood echo;
- seven coarse sums per *brick* of ``BRICK**3`` voxels (beams crossing it,
  voxels they entered in it, weight entering, free path, potential chord,
  free path times G, weight entering its voxels),
  from which the voxels of the brick that hold no echo are judged seen or
  occluded: by the mean beams per voxel (visits over the brick's voxels),
  with ``weighted_count`` also by the mean beam weight per voxel, and the
  explored share (free path over potential chord).

Memory then scales with the echoes (rows) and with the grid / 512 (bricks),
not with the grid.  Row voxels are found in the kernel through their brick:
``start[b]:start[b + 1]`` are the rows of brick ``b``, their in-brick indices
``key`` ascending (a binary search of at most 9 steps).

Examples
--------
>>> from tlsvox.voxel.grid import VoxelGrid
>>> g = VoxelGrid((0, 0, 0), 0.1, (20, 20, 20))
>>> rows = Bricks.from_points(g, [[0.05, 0.05, 0.05], [1.05, 1.05, 1.05], [0.06, 0.04, 0.05]])
>>> rows.n_rows, rows.shape, rows.ijk.tolist()
(2, (3, 3, 3), [[0, 0, 0], [10, 10, 10]])
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from tlsvox.errors import InputError
from tlsvox.voxel.grid import VoxelGrid

__all__ = ["BRICK", "BRICK_FIELDS", "Bricks"]

BRICK = 8  #: voxels per brick edge (trace.cl BRICK_BITS = 3)
#: coarse sums per brick (trace.cl NB); ``visits_w``: the weight entering its voxels (the dense ``n_w`` summed)
BRICK_FIELDS = ("count", "visits", "n_w", "path_w", "chord_w", "path_wg", "visits_w")


@dataclass(frozen=True, eq=False)
class Bricks:
    """The row voxels of a grid, grouped by brick.

    Attributes
    ----------
    grid : VoxelGrid
    start : (n_bricks + 1,) int32
        Rows of brick ``b`` are ``start[b]:start[b + 1]``.
    key : (n_rows,) uint16
        In-brick index ``(i % 8 * 8 + j % 8) * 8 + k % 8`` of each row, ascending within a brick.
    ijk : (n_rows, 3) int64
        Grid index of each row voxel, in row order.
    """

    grid: VoxelGrid
    start: np.ndarray
    key: np.ndarray
    ijk: np.ndarray

    @staticmethod
    def shape_of(grid: VoxelGrid) -> tuple:
        """Bricks along x, y, z (the last ones may stick out of the grid)."""
        return tuple(-(-int(n) // BRICK) for n in grid.shape)

    @property
    def shape(self) -> tuple:
        return self.shape_of(self.grid)

    @property
    def n_rows(self) -> int:
        return len(self.key)

    @property
    def n_bricks(self) -> int:
        return len(self.start) - 1

    @classmethod
    def from_points(cls, grid: VoxelGrid, points) -> Bricks:
        """Rows for the voxels holding ``points`` (N, 3), metres; points outside the grid are left out."""
        ijk = grid.index_of(points)
        return cls.from_ijk(grid, ijk[grid.contains_index(ijk)])

    @classmethod
    def from_ijk(cls, grid: VoxelGrid, ijk) -> Bricks:
        """Rows for the voxels ``ijk`` (N, 3), inside the grid; repeats are merged."""
        ijk = np.asarray(ijk, dtype=np.int64).reshape(-1, 3)
        if len(ijk) and not np.all(grid.contains_index(ijk)):
            raise InputError("Bricks.from_ijk: every voxel index must lie inside the grid")
        shape = cls.shape_of(grid)
        n_bricks = int(np.prod(shape))
        if n_bricks >= 2**31 - 1 or len(ijk) >= 2**31 - 1:
            raise InputError(f"the grid has {n_bricks:,} bricks of {BRICK}^3 voxels, more than the sparse "
                             "tracer indexes (2^31): use a larger voxel size or a smaller region (bounds)")
        brick = np.ravel_multi_index(tuple((ijk >> 3).T), shape) if len(ijk) else np.zeros(0, np.int64)
        local = ((ijk[:, 0] & 7) * BRICK + (ijk[:, 1] & 7)) * BRICK + (ijk[:, 2] & 7)
        code = np.unique(brick * BRICK**3 + local)
        brick, local = np.divmod(code, BRICK**3)
        start = np.zeros(n_bricks + 1, np.int32)
        np.cumsum(np.bincount(brick, minlength=n_bricks), out=start[1:])
        b = np.stack(np.unravel_index(brick, shape), axis=1) * BRICK
        li, rest = np.divmod(local, BRICK * BRICK)
        lj, lk = np.divmod(rest, BRICK)
        rows = b + np.stack([li, lj, lk], axis=1)
        return cls(grid, start, local.astype(np.uint16), rows.astype(np.int64))

    def brick_of_rows(self) -> np.ndarray:
        """(n_rows,) flat brick index of each row."""
        return np.repeat(np.arange(self.n_bricks), np.diff(self.start))

    def voxels_in_grid(self) -> np.ndarray:
        """(bx, by, bz) int: how many voxels of each brick lie inside the grid (edge bricks have fewer)."""
        per_axis = [np.minimum(BRICK, n - BRICK * np.arange(m)) for n, m in zip(self.grid.shape, self.shape)]
        return per_axis[0][:, None, None] * per_axis[1][None, :, None] * per_axis[2][None, None, :]

    def brick_voxels(self, bricks) -> np.ndarray:
        """(K, 3) grid indices of every voxel of the flat bricks ``bricks`` that lies inside the grid."""
        b = np.stack(np.unravel_index(np.asarray(bricks, dtype=np.int64), self.shape), axis=1) * BRICK
        offs = np.stack(np.unravel_index(np.arange(BRICK**3), (BRICK,) * 3), axis=1)
        ijk = (b[:, None, :] + offs[None]).reshape(-1, 3)
        return ijk[self.grid.contains_index(ijk)]

    @staticmethod
    def bytes_for(n_rows: int, n_bricks: int) -> int:
        """Bytes of a Bricks of this size, with the temporaries of building it."""
        return int(n_rows) * (2 + 24 + 16) + int(n_bricks) * (4 + 8)
