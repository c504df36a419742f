"""VoxelStats: its fields, and adding the sums of two traces."""

from __future__ import annotations

import numpy as np
import pytest

from tlsvox.errors import InputError
from tlsvox.voxel.grid import VoxelGrid
from tlsvox.voxel.stats import FIELDS, NF, VoxelStats


def test_fields_are_columns_in_grid_shape_and_sums_add():
    grid = VoxelGrid((0, 0, 0), 1.0, (2, 3, 1))
    acc = np.arange(grid.n_voxels * NF, dtype=np.float64).reshape(grid.n_voxels, NF)
    a = VoxelStats(grid, acc, n_beams=2, n_steps=5, seconds=1.0)
    b = VoxelStats(grid, 2 * acc, n_beams=3, n_steps=1, seconds=0.5)
    col = FIELDS.index("path_w")
    assert a.field("path_w").shape == (2, 3, 1)
    assert a.field("path_w").ravel().tolist() == acc[:, col].tolist()  # flat C order
    ab = a + b
    assert ab.field("path_w").ravel().tolist() == (3 * acc[:, col]).tolist()
    assert (ab.n_beams, ab.n_steps, ab.seconds, ab.beams_per_second) == (5, 6, 1.5, 5 / 1.5)


def test_unknown_field_and_other_grid_rejected():
    grid = VoxelGrid((0, 0, 0), 1.0, (1, 1, 1))
    s = VoxelStats(grid, np.zeros((1, NF)))
    with pytest.raises(InputError, match="field="):
        s.field("lad")
    with pytest.raises(InputError, match="dense"):
        s.brick_field("n_w")
    with pytest.raises(InputError, match="different grids"):
        s + VoxelStats(VoxelGrid((0, 0, 0), 0.5, (1, 1, 1)), np.zeros((1, NF)))
