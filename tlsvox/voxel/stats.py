"""The tracer's per-voxel sums (:class:`VoxelStats`) and their fields.

Per voxel the tracer (:mod:`tlsvox.voxel.trace`) accumulates
(:data:`FIELDS`, pooled over all beams given):

=============  ==============================================================
``count``      number of beams entering
``n_w``        beam weight entering, N
``leaf_w``     leaf echo weight inside, N_I
``wood_w``     wood echo weight inside
``other_w``    weight stopped by other surfaces (ground, targets)
``path_w``     free path: integral of the beam weight along its path inside
               (entry to echo, or the whole chord), m
``path_wg``    the same times G(theta) of each beam (its leaf projection), m
``leaf_zw``    sum over leaf echoes of weight x (echo range - entry), m
``leaf_zwg``   the same times G(theta)
``wood_zw``    sum over wood echoes of weight x (echo range - entry), m
``chord_w``    entering weight x potential chord delta (as if unobstructed), m
``chord2_w``   entering weight x delta^2, m2
``dir_x/y/z``  entering weight x beam direction (mean direction = dir / n_w)
``leaf_w_g``   leaf echo weight / G(theta)
=============  ==============================================================

A dense trace holds one row of sums per voxel; a sparse one
(:mod:`tlsvox.voxel.bricks`) one row per listed voxel plus coarse sums per
brick.

Examples
--------
>>> from tlsvox.voxel.grid import VoxelGrid
>>> stats = VoxelStats(VoxelGrid((0, 0, 0), 1.0, (2, 1, 1)), np.zeros((2, NF)))
>>> stats.field("n_w").shape
(2, 1, 1)
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from tlsvox.errors import InputError
from tlsvox.voxel.bricks import BRICK_FIELDS, Bricks
from tlsvox.voxel.grid import VoxelGrid

__all__ = ["TINY", "safe_divide", "FIELDS", "NF", "VoxelStats"]

#: sums at or below this count as zero (safe_divide)
TINY = 1e-12


def safe_divide(a, b):
    """a / b where b > tiny, else 0 (never NaN or inf)."""
    a = np.asarray(a, dtype=np.float64)
    b = np.asarray(b, dtype=np.float64)
    out = np.zeros(np.broadcast(a, b).shape)
    np.divide(a, b, out=out, where=b > TINY)
    return out

FIELDS = ("count", "n_w", "leaf_w", "wood_w", "other_w", "path_w", "path_wg", "leaf_zw",
          "leaf_zwg", "wood_zw", "chord_w", "chord2_w", "dir_x", "dir_y", "dir_z", "leaf_w_g")
NF = len(FIELDS)
_INDEX = {name: i for i, name in enumerate(FIELDS)}


@dataclass
class VoxelStats:
    """Accumulated beam statistics on a grid (see :data:`FIELDS`).

    Attributes
    ----------
    grid : VoxelGrid
    acc : (n_rows, NF) float64
        One row per voxel in flat C order (dense), or per row voxel of
        ``rows`` (sparse); one column per field.
    rows : Bricks or None
        The row voxels of a sparse trace (None: dense).
    bricks : (n_bricks, len(BRICK_FIELDS)) float64 or None
        Sparse: the coarse sums per brick (:data:`tlsvox.voxel.bricks.BRICK_FIELDS`).
    n_beams : int
    n_steps : int
        Voxel visits (segments of beams inside voxels).
    seconds : float
        Wall time of the trace.
    """

    grid: VoxelGrid
    acc: np.ndarray
    n_beams: int = 0
    n_steps: int = 0
    seconds: float = 0.0
    device: str = ""
    rows: Bricks | None = None
    bricks: np.ndarray | None = None

    @property
    def sparse(self) -> bool:
        return self.rows is not None

    def field(self, name: str) -> np.ndarray:
        """One field: an (nx, ny, nz) view (dense), or (n_rows,) in row order (sparse)."""
        if name not in _INDEX:
            raise InputError(f"field={name!r} is not a tracer field; choose one of {', '.join(FIELDS)}")
        column = self.acc[:, _INDEX[name]]
        return column if self.sparse else column.reshape(self.grid.shape)

    def brick_field(self, name: str) -> np.ndarray:
        """Sparse traces: one coarse field per brick, shape :attr:`Bricks.shape`."""
        if not self.sparse:
            raise InputError("brick_field: this trace is dense; every voxel has its own sums (field)")
        if name not in BRICK_FIELDS:
            raise InputError(f"field={name!r} is not a brick field; choose one of {', '.join(BRICK_FIELDS)}")
        return self.bricks[:, BRICK_FIELDS.index(name)].reshape(self.rows.shape)

    def __add__(self, other: VoxelStats) -> VoxelStats:
        if other.grid != self.grid or (self.rows is None) != (other.rows is None) or (
                self.sparse and not (np.array_equal(self.rows.start, other.rows.start)
                                     and np.array_equal(self.rows.key, other.rows.key))):
            raise InputError("cannot add VoxelStats of different grids or rows")
        return VoxelStats(self.grid, self.acc + other.acc, self.n_beams + other.n_beams,
                          self.n_steps + other.n_steps, self.seconds + other.seconds, self.device,
                          self.rows, None if self.bricks is None else self.bricks + other.bricks)

    @property
    def beams_per_second(self) -> float:
        return self.n_beams / self.seconds if self.seconds > 0 else float("nan")
