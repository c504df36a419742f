"""tlsvox: terrestrial laser scans -> voxel model of leaf area density, wood and ground.

The public API is re-exported here; Open3D is imported only by the modules
that use it, so ``import tlsvox`` stays light.
"""

from .errors import InputError, TlsvoxError
from .estimators import Estimator
from .grid import VoxelGrid
from .leafangle import LeafAngle, LeafAngleKind
from .materials import Material, Optics
from .scene import Scene
from .versions import show_versions
from .voxelize import voxelize

__version__ = "0.1.0"

__all__ = [
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
