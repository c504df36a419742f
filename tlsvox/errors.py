"""Exceptions raised by :mod:`tlsvox`.

Every error the package raises on purpose derives from :class:`TlsvoxError`,
so a caller can catch them all with one ``except`` clause; it is itself a
:class:`voxlidar.errors.VoxlidarError`, the root both stages share.
"""

from __future__ import annotations

from voxlidar.errors import DeviceError as _DeviceError
from voxlidar.errors import VoxlidarError


class TlsvoxError(VoxlidarError):
    """Base class of every error raised by tlsvox."""


class InputError(TlsvoxError, ValueError):
    """An argument or input file is not what was expected.

    The message names the parameter, what was expected, what came, and how to
    fix it.
    """


class ScanFileError(TlsvoxError, OSError):
    """A scan file could not be read or written."""


class DeviceError(TlsvoxError, _DeviceError):
    """No usable OpenCL device, or the device failed."""


def parse_choice(enum_cls, value, label: str, what: str):
    """The member of ``enum_cls`` for ``value`` (case-insensitive), or an InputError
    that names the parameter and lists the valid choices.

    Examples
    --------
    >>> import enum
    >>> class Colour(enum.Enum):
    ...     RED = "red"
    >>> parse_choice(Colour, "RED", "colour", "colour").value
    'red'
    """
    if isinstance(value, enum_cls):
        return value
    try:
        return enum_cls(str(value).lower())
    except ValueError:
        choices = ", ".join(m.value for m in enum_cls)
        raise InputError(f"{label}={value!r} is not a {what}; choose one of: {choices}") from None
