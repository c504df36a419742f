"""Exceptions raised by :mod:`clsim`.

Every error the package raises on purpose derives from :class:`ClsimError`,
itself a :class:`voxlidar.errors.VoxlidarError` (the root both stages share).
"""

from __future__ import annotations

from voxlidar.errors import DeviceError as _DeviceError
from voxlidar.errors import VoxlidarError


class ClsimError(VoxlidarError):
    """Base class of every error raised by clsim."""


class InputError(ClsimError, ValueError):
    """An argument or input file is not what was expected.

    The message names the parameter, what was expected, what came, and how to
    fix it.
    """


class DeviceError(ClsimError, _DeviceError):
    """No usable OpenCL device, or a kernel failed to build or run."""
