"""The brute-force tracer reference against lengths worked out by hand."""

from __future__ import annotations

import numpy as np
import pytest

from tlsvox.errors import InputError
from tlsvox.voxel.beams import Beams, EchoKind
from tlsvox.voxel.grid import VoxelGrid
from tlsvox.voxel.trace_reference import trace_reference


def test_one_beam_with_a_leaf_echo_in_the_middle_voxel():
    grid = VoxelGrid((0, 0, 0), 1.0, (3, 1, 1))
    s = trace_reference(grid, Beams.from_rays([[-1, 0.5, 0.5]], [[1, 0, 0]], hit_range=[2.5]))
    assert s.field("count")[:, 0, 0].tolist() == [1.0, 1.0, 0.0]
    assert s.field("path_w")[:, 0, 0].tolist() == [1.0, 0.5, 0.0]    # the whole chord, then to the echo
    assert s.field("leaf_w")[:, 0, 0].tolist() == [0.0, 1.0, 0.0]
    assert s.field("leaf_zw")[:, 0, 0].tolist() == [0.0, 0.5, 0.0]   # echo range - entry
    assert s.field("chord_w")[:, 0, 0].tolist() == [1.0, 1.0, 0.0]   # the potential chord
    assert s.n_steps == 2


def test_a_gap_beam_across_the_diagonal_crosses_the_whole_grid():
    """A beam through the corners of a 2 x 2 x 2 grid: its chords add up to the diagonal, 2 sqrt(3)."""
    grid = VoxelGrid((0, 0, 0), 1.0, (2, 2, 2))
    d = np.array([[1.0, 1.0, 1.0]]) / np.sqrt(3)
    s = trace_reference(grid, Beams.from_rays([[-1, -1, -1]], d, kind=EchoKind.LEAF))
    assert s.field("path_w").sum() == pytest.approx(2 * np.sqrt(3), rel=1e-12)
    assert s.field("leaf_w").sum() == 0.0


def test_refuses_a_case_too_large_for_brute_force():
    grid = VoxelGrid((0, 0, 0), 0.01, (500, 500, 10))
    with pytest.raises(InputError, match="brute force"):
        trace_reference(grid, Beams.from_rays([0, 0, 0], [[1, 0, 0]] * 40))
