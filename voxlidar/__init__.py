"""voxlidar: the floor shared by both stages (:mod:`tlsvox` and :mod:`clsim`).

It imports neither stage.  Today it holds the exception root and the OpenCL
device layer (:mod:`voxlidar.devices`); see docs/devices.md.
"""

from ._preload import preload_tbb
from .errors import DeviceError, VoxlidarError

preload_tbb()  # before Open3D can load its older oneTBB (see voxlidar/_preload.py)

__version__ = "0.1.0"

__all__ = ["DeviceError", "VoxlidarError", "__version__"]
