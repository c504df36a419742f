"""Exceptions raised by :mod:`clsim`.

Every error derives from :class:`voxlidar.errors.VoxlidarError`, the root both
stages share.  Bad input raises :class:`InputError` and a device that cannot
run raises :class:`DeviceError`: the same classes in both stages (defined in
:mod:`voxlidar.errors`, re-exported here); clsim's own failures derive from
:class:`ClsimError`.
"""

from __future__ import annotations

from voxlidar.errors import DeviceError, InputError, VoxlidarError

__all__ = ["ClsimError", "DeviceError", "InputError"]


class ClsimError(VoxlidarError):
    """Base class of the errors that only clsim raises."""
