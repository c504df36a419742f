"""Exceptions raised by :mod:`tlsvox`.

Every error the package raises on purpose derives from :class:`TlsvoxError`,
so a caller can catch them all with one ``except`` clause.
"""

from __future__ import annotations


class TlsvoxError(Exception):
    """Base class of every error raised by tlsvox."""


class InputError(TlsvoxError, ValueError):
    """An argument or input file is not what was expected.

    The message names the parameter, what was expected, what came, and how to
    fix it.
    """


class ScanFileError(TlsvoxError, OSError):
    """A scan file could not be read or written."""
