"""One parser for every string choice of voxlidar (methods, modes, estimators, ...)."""

from __future__ import annotations

import enum

from voxlidar.errors import InputError

__all__ = ["Choice"]


class Choice(enum.Enum):
    """A string option; :meth:`parse` is case-insensitive and lists the valid values.

    Examples
    --------
    Subclasses that want members equal to their strings mix in ``str``:
    ``class Mode(str, Choice)``.

    >>> class Colour(Choice):
    ...     RED = "red"
    >>> Colour.parse("RED", "colour").value
    'red'
    """

    @classmethod
    def parse(cls, value, name: str):
        """The member for ``value``, or an InputError naming ``name`` and the choices."""
        if isinstance(value, cls):
            return value
        try:
            return cls(str(value).lower())
        except ValueError:
            raise InputError(
                f"{name}={value!r} is not known; choose one of: {', '.join(m.value for m in cls)}"
            ) from None
