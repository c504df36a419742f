"""clsim: OpenCL Monte Carlo simulation of airborne full-waveform LiDAR over a voxel scene.

Also reads real full-waveform data (LAS 1.3/1.4 waveform packets, PulseWaves),
decomposes waveforms into Gaussian echoes, and compares waveforms.  Heavy
modules (PyOpenCL, Open3D) are imported only when used.
"""

from .decompose import Components, decompose
from .errors import ClsimError, DeviceError, InputError
from .metrics import compare_waveforms, relative_heights
from . import testscenes
from .pointing import fit_pulse_directions, pointing_from_xyzt
from .sensor import Sensor, list_presets
from .simulator import Detect, Mode, SimulationResult, Simulator, list_devices
from .transport_ref import ReferenceSimulator
from .waveio import read_las_waveforms, read_pulsewaves, write_las_waveforms

__version__ = "0.1.0"

__all__ = [
    "Detect",
    "Mode",
    "ReferenceSimulator",
    "Sensor",
    "SimulationResult",
    "Simulator",
    "list_devices",
    "list_presets",
    "testscenes",
    "ClsimError",
    "Components",
    "DeviceError",
    "InputError",
    "__version__",
    "compare_waveforms",
    "decompose",
    "fit_pulse_directions",
    "pointing_from_xyzt",
    "read_las_waveforms",
    "read_pulsewaves",
    "relative_heights",
    "write_las_waveforms",
]
