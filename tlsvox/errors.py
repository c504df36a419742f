"""Exceptions raised by :mod:`tlsvox`.

Every error derives from :class:`voxlidar.errors.VoxlidarError`, the root both
stages share.  Bad input raises :class:`InputError` and a device that cannot
run raises :class:`DeviceError`: the same classes in both stages (defined in
:mod:`voxlidar.errors`, re-exported here); tlsvox's own failures derive from
:class:`TlsvoxError`.
"""

from __future__ import annotations

from voxlidar.errors import DeviceError, InputError, VoxlidarError

__all__ = ["DeviceError", "InputError", "RegistrationError", "RenderError", "ScanFileError", "TlsvoxError"]


class TlsvoxError(VoxlidarError):
    """Base class of the errors that only tlsvox raises."""


class ScanFileError(TlsvoxError, OSError):
    """A scan file could not be read or written."""


class RegistrationError(TlsvoxError, RuntimeError):
    """Registration failed or its result cannot be trusted.

    Attributes
    ----------
    figures : dict
        Fitness, inlier RMSE and whatever else was measured before failing.
    """

    def __init__(self, message: str, figures: dict | None = None):
        super().__init__(message)
        self.figures = dict(figures or {})


class RenderError(TlsvoxError, RuntimeError):
    """The off-screen Open3D renderer failed (``backend="open3d"``; ``"auto"`` falls back to matplotlib)."""
