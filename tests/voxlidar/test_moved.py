"""Old import paths of moved modules: the very module at its new path, with a DeprecationWarning naming it."""

from __future__ import annotations

import importlib
import sys

import pytest

from voxlidar._moved import MOVED, new_name


@pytest.mark.parametrize("old", sorted(MOVED))
def test_old_path_gives_the_new_module_with_a_warning(old):
    new = importlib.import_module(MOVED[old])
    sys.modules.pop(old, None)
    with pytest.warns(DeprecationWarning, match=f"{old} moved to {MOVED[old]}"):
        module = importlib.import_module(old)
    assert module is new


def test_submodules_of_moved_packages_map_too():
    assert new_name("clsim.decompose._batch") == "clsim.waveforms.decompose._batch"
    assert new_name("tlsvox.voxel.voxlad") == "tlsvox.voxel.stages"
    assert new_name("tlsvox.voxel.stages") is None
