"""Exceptions raised by :mod:`clsim`.

Every error the package raises on purpose derives from :class:`ClsimError`.
"""

from __future__ import annotations


class ClsimError(Exception):
    """Base class of every error raised by clsim."""


class InputError(ClsimError, ValueError):
    """An argument or input file is not what was expected.

    The message names the parameter, what was expected, what came, and how to
    fix it.
    """


class DeviceError(ClsimError, RuntimeError):
    """No usable OpenCL device, or a kernel failed to build or run."""
