"""The survey tests' shared scene: a 6 m homogeneous leaf layer over the ground, 0.5 m voxels."""

import pytest

from clsim.validation import testscenes


@pytest.fixture(scope="module")
def scene_file(tmp_path_factory):
    s = testscenes.homogeneous_layer(width=6.0, thickness=1.5, lad=1.0, voxel_size=0.5, base_height=3.0)
    return str(s.save(tmp_path_factory.mktemp("scene") / "layer.npz"))
