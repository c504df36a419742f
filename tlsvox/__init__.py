"""tlsvox: terrestrial laser scans -> voxel model of leaf area density, wood and ground.

The public API is re-exported here; Open3D is imported only by the modules
that use it, so ``import tlsvox`` stays light.
"""

from tlsvox.classify import ClassifySettings, PointClass, classify_scan
from tlsvox.errors import InputError, TlsvoxError
from tlsvox.leafangles import LeafAngleSettings, measure_leaf_angles
from tlsvox.readers import read_any
from tlsvox.register import RegisterSettings, RegistrationError, register_pair, register_scans
from tlsvox.voxel.estimators import Estimator
from tlsvox.voxel.grid import VoxelGrid
from tlsvox.voxel.settings import VoxelizeSettings
from tlsvox.voxel.stages import voxelize
from tlsvox.voxel.weights import EchoWeights
from voxlidar import __version__  # one version for the distribution (pyproject.toml)
from voxlidar.leaf_orientation import LeafAngle, LeafAngleKind
from voxlidar.materials import Material, Optics
from voxlidar.scene import Scene
from voxlidar.versions import show_versions

#: the user's verbs whose modules load on first use (the synthetic tree and the scanner pull in Open3D)
_LAZY = {"Scan": "tlsvox.scan", "scene_from_scans": "tlsvox.pipeline", "TreeParams": "tlsvox.truth.synthetic",
         "make_tree": "tlsvox.truth.synthetic", "ScannerPreset": "tlsvox.truth.scanner",
         "paper_scan_poses": "tlsvox.truth.scanner", "simulate_scan": "tlsvox.truth.scanner",
         "voxelize_beams": "tlsvox.voxel.airborne"}


def __getattr__(name):
    if name in _LAZY:
        import importlib

        return getattr(importlib.import_module(_LAZY[name]), name)
    raise AttributeError(f"module 'tlsvox' has no attribute {name!r}")


__all__ = [
    "Scan",
    "ScannerPreset",
    "TreeParams",
    "make_tree",
    "paper_scan_poses",
    "scene_from_scans",
    "simulate_scan",
    "voxelize_beams",
    "PointClass",
    "RegistrationError",
    "classify_scan",
    "ClassifySettings",
    "read_any",
    "measure_leaf_angles",
    "LeafAngleSettings",
    "register_pair",
    "register_scans",
    "RegisterSettings",
    "Estimator",
    "EchoWeights",
    "VoxelGrid",
    "voxelize",
    "VoxelizeSettings",
    "InputError",
    "LeafAngle",
    "LeafAngleKind",
    "Material",
    "Optics",
    "Scene",
    "TlsvoxError",
    "show_versions",
    "__version__",
]
