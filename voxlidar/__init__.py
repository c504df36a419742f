"""voxlidar: the floor shared by both stages (:mod:`tlsvox` and :mod:`clsim`).

It imports neither stage.  It holds the contract between them (the
:class:`~voxlidar.scene.Scene`, leaf angles, materials), one exception root,
one parser of string choices, the OpenCL device layer, safe file writing, the
command-line convention and the versions report; see docs/architecture.md.
"""

from voxlidar import _moved
from voxlidar._preload import preload_tbb
from voxlidar.errors import DeviceError, InputError, VoxlidarError
from voxlidar.leaf_orientation import LeafAngle, LeafAngleKind
from voxlidar.materials import Material, Optics
from voxlidar.scene import Scene

preload_tbb()  # before Open3D can load its older oneTBB (see voxlidar/_preload.py)
_moved.install()  # old module paths (tlsvox.trace, clsim.decompose, ...) for one release

try:  # the one version: pyproject.toml's, as installed
    from importlib.metadata import PackageNotFoundError as _NotFound
    from importlib.metadata import version as _version

    __version__ = _version("voxlidar")
except _NotFound:  # run from a source tree that was never installed
    __version__ = "0+unknown"

__all__ = ["DeviceError", "InputError", "LeafAngle", "LeafAngleKind", "Material", "Optics", "Scene",
           "VoxlidarError", "__version__"]
