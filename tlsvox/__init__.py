"""tlsvox: terrestrial laser scans -> voxel model of leaf area density, wood and ground.

The public API is re-exported here; Open3D is imported only by the modules
that use it, so ``import tlsvox`` stays light.
"""

from .errors import InputError, TlsvoxError
from .estimators import Estimator
from .classify import PointClass, classify_scan
from .grid import VoxelGrid
from .io import read_any
from .register import RegistrationError, register_pair, register_scans
from .leafangle import LeafAngle, LeafAngleKind
from .materials import Material, Optics
from .scene import Scene
from .versions import show_versions
from .voxelize import voxelize

__version__ = "0.1.0"

__all__ = [
    "PointClass",
    "RegistrationError",
    "classify_scan",
    "read_any",
    "register_pair",
    "register_scans",
    "Estimator",
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
