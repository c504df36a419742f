"""Settings in groups: the base of every settings class of tlsvox, and their TOML files.

A settings class is a frozen dataclass whose fields are groups, each group a
frozen dataclass of plain values (numbers, text, tuples, tables). The flat
names of all groups' fields are unique, so a function can take them as
keyword arguments (``voxelize(scans, voxel_size=0.1)``) and the settings
class maps them back onto their groups (:meth:`GroupedSettings.from_kwargs`).
Each settings class names its groups (``GROUPS``), the fields that may be
None although their default is not (``NULLABLE``: TOML has no null, they are
written ``"none"``) and what it is the settings of (``LABEL``, for messages).

Examples
--------
>>> from tlsvox.leafangles import LeafAngleSettings
>>> s = LeafAngleSettings.from_kwargs(radius=0.03, layers=2)
>>> s.planes.radius, s.histogram.layers
(0.03, 2)
>>> LeafAngleSettings.from_dict(s.to_dict()) == s
True
"""

from __future__ import annotations

import dataclasses
import json
import tomllib
from dataclasses import fields
from enum import Enum
from pathlib import Path
from typing import ClassVar, TypeVar

import numpy as np

from tlsvox.errors import InputError

__all__ = ["GroupedSettings"]

S = TypeVar("S", bound="GroupedSettings")


def plain(value, label: str = "tlsvox"):
    """``value`` as plain Python (tuples for arrays, dicts for dataclasses), for equality and files."""
    if isinstance(value, Enum):  # a str choice: its text
        value = value.value
    if value is None or isinstance(value, bool | str):
        return value
    if isinstance(value, np.bool_):
        return bool(value)
    if isinstance(value, int | np.integer):
        return int(value)
    if isinstance(value, float | np.floating):
        return float(value)
    if hasattr(value, "to_dict") and not isinstance(value, dict):  # LeafAngle: its own file form
        return plain(value.to_dict(), label)
    if dataclasses.is_dataclass(value) and not isinstance(value, type):  # GroundPlane, AngularGrid
        return {f.name: plain(getattr(value, f.name), label) for f in fields(value)}
    if isinstance(value, dict):
        return {str(k): plain(v, label) for k, v in value.items()}
    if isinstance(value, np.ndarray):
        value = value.tolist()
    if isinstance(value, list | tuple):
        return tuple(plain(v, label) for v in value)
    raise InputError(f"a {label} setting must be a number, text, a list or a table; got {type(value).__name__}")


class GroupedSettings:
    """Mixin of a frozen dataclass of setting groups (module docstring)."""

    GROUPS: ClassVar[dict[str, type]] = {}
    NULLABLE: ClassVar[tuple[str, ...]] = ()
    LABEL: ClassVar[str] = "tlsvox"

    @classmethod
    def names(cls) -> dict[str, str]:
        """Every field's name -> its group's name."""
        return {f.name: g for g, c in cls.GROUPS.items() for f in fields(c)}

    @classmethod
    def from_kwargs(cls: type[S], base: S | None = None, **kwargs) -> S:
        """``base`` (default: the defaults) with the named fields replaced; unknown names are refused."""
        base = base if base is not None else cls()
        if not isinstance(base, cls):
            raise InputError(f"settings must be a {cls.__name__}; got {type(base).__name__}")
        where = cls.names()
        unknown = sorted(set(kwargs) - set(where))
        if unknown:
            raise InputError(f"unknown {cls.LABEL} setting(s) {unknown}; the settings are: {sorted(where)}")
        groups: dict[str, dict] = {g: {} for g in cls.GROUPS}
        for k, v in kwargs.items():
            if k in cls.NULLABLE and isinstance(v, str) and v.lower() == "none":
                v = None
            groups[where[k]][k] = plain(v, cls.LABEL)
        return cls(**{g: dataclasses.replace(getattr(base, g), **kw) for g, kw in groups.items()})

    def to_kwargs(self) -> dict:
        """All fields as one flat dict of keyword arguments."""
        return {f.name: getattr(getattr(self, g), f.name) for g, c in self.GROUPS.items() for f in fields(c)}

    def to_dict(self) -> dict:
        """``{group: {field: value}}`` in plain JSON types (what a result's meta records)."""
        return {g: {k: _json(v) for k, v in dataclasses.asdict(getattr(self, g)).items()} for g in self.GROUPS}

    @classmethod
    def from_dict(cls: type[S], d: dict) -> S:
        """The inverse of :meth:`to_dict` (groups may be missing: their defaults; a field missing: its default)."""
        groups = cls.GROUPS
        if not isinstance(d, dict):
            raise InputError(f"{cls.LABEL} settings must be a table of groups {sorted(groups)}; got "
                             f"{type(d).__name__}")
        unknown = sorted(set(d) - set(groups))
        if unknown:
            raise InputError(f"unknown {cls.LABEL} settings group(s) {unknown}; the groups are {sorted(groups)}")
        flat = {}
        for g, values in d.items():
            if not isinstance(values, dict):
                raise InputError(f"{cls.LABEL} settings [{g}] must be a table of fields, got {values!r}")
            known = {f.name for f in fields(groups[g])}
            bad = sorted(set(values) - known)
            if bad:
                raise InputError(f"unknown field(s) {bad} in {cls.LABEL} settings [{g}]; it holds {sorted(known)}")
            flat.update(values)
        return cls.from_kwargs(**flat)

    def to_toml(self) -> str:
        """The settings as a TOML document (a setting at None is left out where None is its default, else
        written ``"none"``)."""
        lines = []
        for g, values in self.to_dict().items():
            lines.append(f"[{g}]")
            lines += [f"{k} = {_toml_value('none' if v is None else v)}" for k, v in values.items()
                      if v is not None or k in self.NULLABLE]
            lines.append("")
        return "\n".join(lines)

    def write(self, path) -> Path:
        """Write :meth:`to_toml` to ``path`` (atomically)."""
        from voxlidar.safeio import atomic_write

        text = self.to_toml()
        return atomic_write(path, lambda tmp: Path(tmp).write_text(text, encoding="utf-8"))

    @classmethod
    def read(cls: type[S], path) -> S:
        """Settings from a TOML file (:meth:`write`'s)."""
        path = Path(path)
        if not path.is_file():
            raise InputError(f"{path}: no such {cls.LABEL} settings file (a TOML file)")
        return cls.from_dict(_read_toml(path, cls.__name__))


def _read_toml(path: Path, name: str) -> dict:
    try:
        return tomllib.loads(path.read_text(encoding="utf-8"))
    except (tomllib.TOMLDecodeError, UnicodeDecodeError) as err:
        raise InputError(f"{path} is not a TOML file ({err}); see {name}.write for one") from None


def _json(v):
    """Tuples as lists (JSON and TOML arrays)."""
    if isinstance(v, tuple):
        return [_json(x) for x in v]
    if isinstance(v, dict):
        return {k: _json(x) for k, x in v.items()}
    return v


def _toml_value(v) -> str:
    if isinstance(v, bool):
        return "true" if v else "false"
    if isinstance(v, int | float):
        if not np.isfinite(v):
            return ("-inf" if v < 0 else "inf") if np.isinf(v) else "nan"
        return repr(v)
    if isinstance(v, str):
        return json.dumps(v)  # a TOML basic string is a JSON string
    if isinstance(v, list):
        return "[" + ", ".join(_toml_value(x) for x in v) + "]"
    if isinstance(v, dict):
        return "{ " + ", ".join(f"{k} = {_toml_value(x)}" for k, x in v.items() if x is not None) + " }"
    raise InputError(f"cannot write {v!r} to TOML")
