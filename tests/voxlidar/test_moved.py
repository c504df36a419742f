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


@pytest.mark.parametrize("package, old, new", [("clsim", "Mode", "InteractionModel"),
                                               ("clsim", "Detect", "PhotonTally"),
                                               ("clsim.transport", "Mode", "InteractionModel"),
                                               ("clsim.transport", "Detect", "PhotonTally")])
def test_renamed_names_give_the_new_object_with_a_warning(package, old, new):
    mod = importlib.import_module(package)
    with pytest.warns(DeprecationWarning, match=rf"{package}\.{old} is now {package}\.{new}"):
        obj = getattr(mod, old)
    assert obj is getattr(mod, new)
    assert old not in mod.__all__


def test_testscenes_left_the_top_level_with_a_warning():
    import clsim
    from clsim.validation import testscenes

    vars(clsim).pop("testscenes", None)  # an import of the old module path (test above) sets the attribute
    with pytest.warns(DeprecationWarning, match="clsim.testscenes is now clsim.validation.testscenes"):
        assert clsim.testscenes is testscenes
    assert "testscenes" not in clsim.__all__
