"""clsim: OpenCL Monte Carlo simulation of airborne full-waveform LiDAR over a voxel scene.

Also reads real full-waveform data (LAS 1.3/1.4 waveform packets, PulseWaves),
decomposes waveforms into Gaussian echoes, and compares waveforms.  Heavy
modules (PyOpenCL, Open3D) are imported only when used.
"""

from clsim.errors import ClsimError, DeviceError, InputError
from clsim.sensor import Sensor, list_presets
from clsim.transport.reference import ReferenceSimulator
from clsim.transport.simulator import InteractionModel, PhotonTally, SimulationResult, Simulator, list_devices
from clsim.waveforms.io import read_las_waveforms, read_pulsewaves, write_las_waveforms
from clsim.waveforms.metrics import compare_waveforms, relative_heights
from clsim.waveforms.pointing import fit_pulse_directions, pointing_from_xyzt
from voxlidar import __version__  # one version for the distribution (pyproject.toml)
from voxlidar._moved import renamed

#: names whose modules load on first use (the decomposition pulls in scipy.ndimage and scipy.optimize)
_LAZY = {"Components": "clsim.waveforms.decompose", "decompose": "clsim.waveforms.decompose"}


#: old names of 0.1, kept for one release: each access warns and names the new one
_RENAMED = {"Mode": ("clsim.transport.setup", "InteractionModel"), "Detect": ("clsim.transport.setup", "PhotonTally"),
            "testscenes": ("clsim.validation.testscenes", None)}


def __getattr__(name):
    import importlib

    if name in _LAZY:
        return getattr(importlib.import_module(_LAZY[name]), name)
    if name in _RENAMED:
        return renamed("clsim", name, *_RENAMED[name])
    raise AttributeError(f"module 'clsim' has no attribute {name!r}")

__all__ = [
    "InteractionModel",
    "PhotonTally",
    "ReferenceSimulator",
    "Sensor",
    "SimulationResult",
    "Simulator",
    "list_devices",
    "list_presets",
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
