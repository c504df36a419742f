"""The LAD profile (tlsvox.voxel.profile) against a scene built with a known profile."""

from __future__ import annotations

import numpy as np
import pytest

from tlsvox.errors import InputError
from tlsvox.voxel.profile import lad_profile, lad_profile_figure
from voxlidar.scene import Scene


def _scene():
    """10 x 10 x 5 voxels of 0.5 m, ground at z = 0: layer k holds LAD k + 1 in every voxel, except that a
    quarter of layer 2's voxels are occluded (and hold 0)."""
    ijk = np.argwhere(np.ones((10, 10, 5), bool))
    lad = ijk[:, 2] + 1.0
    occluded = (ijk[:, 2] == 2) & (ijk[:, 0] < 5) & (ijk[:, 1] < 5)
    lad[occluded] = 0.0
    return Scene(origin=(0.0, 0.0, 0.0), voxel_size=0.5, shape=(10, 10, 5), ijk=ijk, lad=lad, occluded=occluded,
                 crown_center=(2.5, 2.5), ground_z=0.0)


def test_profile_is_the_mean_of_the_seen_voxels(tmp_path):
    p = lad_profile(_scene())
    assert p.height.tolist() == [0.25, 0.75, 1.25, 1.75, 2.25] and p.above_ground
    assert p.lad.tolist() == [1, 2, 3, 4, 5]  # the occluded quarter of layer 2 does not pull its mean down
    assert p.occluded.tolist() == [0, 0, 0.25, 0, 0]
    assert p.leaf_area_index == pytest.approx(0.5 * 15)
    near = lad_profile(_scene(), radius=1.0, center=(1.25, 1.25))  # columns all in the occluded quarter
    assert near.occluded[2] == 1.0 and near.lad[2] == 0.0
    out = lad_profile_figure({"known": p, "within 1 m": near}, tmp_path / "profile.png", title="known")
    assert out.stat().st_size > 10_000
    with pytest.raises(InputError, match="positive distance"):
        lad_profile(_scene(), radius=0)
    with pytest.raises(InputError, match="no voxel column"):
        lad_profile(_scene(), radius=0.1, center=(50, 50))
