"""Beams: their checks, joining scans, and where their echoes lie."""

from __future__ import annotations

import numpy as np
import pytest

from tlsvox.errors import InputError
from tlsvox.voxel.beams import Beams, EchoKind, echo_voxels
from tlsvox.voxel.grid import VoxelGrid


def test_bad_beams_rejected():
    with pytest.raises(InputError, match="unit vector"):
        Beams(origin=[0, 0, 0], direction=[[1, 1, 0]], echo_start=[0, 0], echo_range=[],
              echo_weight=[], echo_kind=[], tail=1.0, max_range=np.inf)
    with pytest.raises(InputError, match="echo_start"):
        Beams(origin=[0, 0, 0], direction=[[1, 0, 0]], echo_start=[1, 2], echo_range=[1.0],
              echo_weight=[1.0], echo_kind=[1], tail=0.0, max_range=np.inf)


def test_concat_keeps_each_scans_echoes_and_numbers_the_scans():
    a = Beams.from_rays([0, 0, 0], [[1, 0, 0], [0, 1, 0]], hit_range=[2.0, np.inf])
    b = Beams.from_rays([5, 0, 0], [[0, 0, 1]], hit_range=[3.0], kind=EchoKind.WOOD)
    ab = Beams.concat([a, b])
    assert len(ab) == 3 and ab.n_echoes == 2
    assert ab.echo_start.tolist() == [0, 1, 1, 2]
    assert ab.scan_index.tolist() == [0, 0, 1]
    assert ab.echo_kind.tolist() == [EchoKind.LEAF, EchoKind.WOOD]
    assert ab.echo_points().tolist() == [[2.0, 0.0, 0.0], [5.0, 0.0, 3.0]]
    assert ab.tail.tolist() == [0.0, 1.0, 0.0]


def test_an_echo_on_a_voxel_face_marks_both_voxels():
    grid = VoxelGrid((0, 0, 0), 1.0, (4, 1, 1))
    on_face = Beams.from_rays([[-1, 0.5, 0.5]], [[1, 0, 0]], hit_range=[3.0])  # x = 2: voxels 1 and 2
    inside = Beams.from_rays([[-1, 0.5, 0.5]], [[1, 0, 0]], hit_range=[2.5])   # x = 1.5: voxel 1
    assert echo_voxels(grid, on_face).tolist() == [[1, 0, 0], [2, 0, 0]]
    assert echo_voxels(grid, inside).tolist() == [[1, 0, 0]]
