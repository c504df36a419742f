"""clsim: OpenCL Monte Carlo simulation of airborne full-waveform LiDAR over a voxel scene."""

from .errors import ClsimError, DeviceError, InputError

__version__ = "0.1.0"

__all__ = ["ClsimError", "DeviceError", "InputError", "__version__"]
