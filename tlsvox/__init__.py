"""tlsvox: terrestrial laser scans -> voxel model of leaf area density, wood and ground.

The public API is re-exported here; Open3D is imported only by the modules
that use it, so ``import tlsvox`` stays light.
"""

from tlsvox.errors import InputError, TlsvoxError
from tlsvox.voxel.estimators import Estimator
from tlsvox.classify import PointClass, classify_scan
from tlsvox.voxel.grid import VoxelGrid
from tlsvox.io import read_any
from tlsvox.leafangles import measure_leaf_angles
from tlsvox.register import RegistrationError, register_pair, register_scans
from voxlidar.leafangle import LeafAngle, LeafAngleKind
from voxlidar.materials import Material, Optics
from voxlidar.scene import Scene
from voxlidar.versions import show_versions
from tlsvox.voxel.voxlad import voxelize
from tlsvox.voxel.weights import EchoWeights

__version__ = "0.1.0"

__all__ = [
    "PointClass",
    "RegistrationError",
    "classify_scan",
    "read_any",
    "measure_leaf_angles",
    "register_pair",
    "register_scans",
    "Estimator",
    "EchoWeights",
    "VoxelGrid",
    "voxelize",
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
