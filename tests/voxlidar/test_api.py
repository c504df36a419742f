"""The public API: every exported name resolves, the version is one, and the packages stay light to import."""

from __future__ import annotations

import subprocess
import sys

import pytest


@pytest.mark.parametrize("package", ["voxlidar", "tlsvox", "clsim"])
def test_every_exported_name_resolves(package):
    import importlib

    mod = importlib.import_module(package)
    missing = [name for name in mod.__all__ if getattr(mod, name, None) is None]
    assert not missing, missing


def test_one_version_from_the_installed_distribution():
    from importlib.metadata import version

    import clsim
    import tlsvox
    import voxlidar

    assert voxlidar.__version__ == tlsvox.__version__ == clsim.__version__ == version("voxlidar")


def test_the_user_verbs_are_at_the_top_of_tlsvox():
    import tlsvox
    from tlsvox.pipeline import scene_from_scans
    from tlsvox.scan import Scan
    from tlsvox.truth.scanner import simulate_scan
    from tlsvox.truth.synthetic import make_tree

    assert (tlsvox.Scan, tlsvox.scene_from_scans, tlsvox.make_tree, tlsvox.simulate_scan) == (
        Scan, scene_from_scans, make_tree, simulate_scan)


def test_import_tlsvox_loads_neither_open3d_nor_clsim():
    code = "import sys, tlsvox; print(sorted(m for m in ('open3d', 'clsim') if m in sys.modules))"
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True).stdout
    assert out.strip() == "[]"
