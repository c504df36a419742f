"""The photon transport: the OpenCL simulator and its float64 NumPy oracle.

- :mod:`clsim.transport.simulator`: :class:`Simulator` and :class:`SimulationResult`;
- :mod:`clsim.transport.bricks`: the sparse scene as the device holds it;
- :mod:`clsim.transport.rng`: Philox4x32-10, bit-identical to the kernels;
- :mod:`clsim.transport.reference`: :class:`ReferenceSimulator`, the oracle.

The kernels themselves are ``.cl`` files in ``clsim/kernels/``.
"""

from clsim.transport.reference import ReferenceSimulator
from clsim.transport.simulator import InteractionModel, PhotonTally, SimulationResult, Simulator, list_devices

__all__ = ["PhotonTally", "InteractionModel", "ReferenceSimulator", "SimulationResult", "Simulator", "list_devices"]


def __getattr__(name):
    if name in ("Mode", "Detect"):
        from voxlidar._moved import renamed

        return renamed("clsim.transport", name, "clsim.transport.setup",
                       {"Mode": "InteractionModel", "Detect": "PhotonTally"}[name])
    raise AttributeError(f"module 'clsim.transport' has no attribute {name!r}")
