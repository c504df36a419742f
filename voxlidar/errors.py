"""The exception root of voxlidar.

Every error that :mod:`tlsvox`, :mod:`clsim` or :mod:`voxlidar` raises on
purpose derives from :class:`VoxlidarError`, so one ``except`` clause catches
them all.
"""

from __future__ import annotations

import math

__all__ = ["DeviceError", "InputError", "VoxlidarError", "exit_code", "finite_number"]


class VoxlidarError(Exception):
    """Base class of every error raised on purpose by voxlidar's packages."""


class InputError(VoxlidarError, ValueError):
    """An argument or input file is not what was expected.

    The message names the parameter, what was expected, what came, and how to
    fix it.  Each stage's own ``InputError`` derives from this one.
    """


class DeviceError(VoxlidarError, RuntimeError):
    """No usable OpenCL device, or a kernel failed to build or run.

    The message names the device, the reason and the fix in one line.
    """


def exit_code(err: BaseException) -> int:
    """The command-line exit status of an error: 1 for a runtime failure (no
    working device, a kernel or a registration that failed: a ``RuntimeError``),
    2 for a usage or input error (everything else)."""
    return 1 if isinstance(err, RuntimeError) else 2


def finite_number(value, what: str) -> float:
    """``value`` as a finite float, or an :class:`InputError` that names ``what``.

    >>> finite_number("2.5", "sensor altitude_m")
    2.5
    >>> finite_number(float("nan"), "scan fov_deg")
    Traceback (most recent call last):
    ...
    voxlidar.errors.InputError: scan fov_deg must be finite, got nan
    """
    try:
        v = float(value)
    except (TypeError, ValueError) as err:
        raise InputError(f"{what} must be a number, got {value!r}") from err
    if not math.isfinite(v):
        raise InputError(f"{what} must be finite, got {value!r}")
    return v
