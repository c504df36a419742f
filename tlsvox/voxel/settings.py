"""The settings of a :func:`~tlsvox.voxel.stages.voxelize` run, grouped by stage, and their TOML file.

Each group is one dataclass, and one argument group of ``tlsvox voxelize``
(the CLI's flags are the fields' names with dashes):

=====================  ===================================================  =================================
group                  fields                                               the stage that reads it
=====================  ===================================================  =================================
``grid``               voxel_size, bounds, snap, margin, layout,            the grid, the memory plan
                       lad_voxel_size, lad_placement
``model``              leaf_angle, leaf_azimuth, crown_center, estimator,   the estimate and the fill
                       fill, n_min, min_explored, leaf_size,
                       small_voxel_factor, wood, wood_percentile
``ground``             ground, ground_tolerance                             the ground
``echoes``             class_codes, echo_weights, leaf_reflectance,         the beams
                       wood_reflectance
``undetected``         undetected, detection_threshold_db, leaf_shape,      the undetected echoes
                       undetected_iterations
``poses``              scanner_frame, angular_grid, socs_rotation,          the echoes in the world, the beams
                       max_range
=====================  ===================================================  =================================

:class:`VoxelizeSettings` holds the six; ``scene.meta["settings"]`` records
them in full (:meth:`VoxelizeSettings.to_dict`), so a run can be repeated
from its output (``tlsvox voxelize --config scene.npz``) or from a TOML file
(:meth:`VoxelizeSettings.read`, :meth:`VoxelizeSettings.write`).

Examples
--------
>>> s = VoxelizeSettings.from_kwargs(voxel_size=0.5, estimator="voxlad")
>>> s.grid.voxel_size, s.model.estimator, s.model.n_min
(0.5, 'voxlad', 5)
>>> VoxelizeSettings.from_dict(s.to_dict()) == s
True
>>> print(s.to_toml().splitlines()[0])
[grid]
"""

from __future__ import annotations

import dataclasses
import json
import tomllib
from dataclasses import dataclass, field, fields
from pathlib import Path

import numpy as np

from tlsvox.errors import InputError

__all__ = ["EchoSettings", "GridSettings", "GroundSettings", "ModelSettings", "PoseSettings", "UndetectedSettings",
           "VoxelizeSettings"]


@dataclass(frozen=True)
class GridSettings:
    """Where the voxels are: their size, the region, the tracer's memory layout."""

    voxel_size: float = 0.2  #: voxel edge, metres
    bounds: tuple | None = None  #: ((xmin, ymin, zmin), (xmax, ymax, zmax)); default the vegetation's box
    snap: bool = False  #: snap given bounds outwards to multiples of voxel_size
    margin: float = 0.0  #: metres added around the bounds
    layout: str = "auto"  #: "auto", "dense" or "sparse"
    max_bytes: int | None = None  #: memory limit; default 80 % of what is available
    lad_voxel_size: float | None = None  #: estimate the LAD on this coarser grid
    lad_placement: str = "even"  #: "even" or "echoes"


@dataclass(frozen=True)
class ModelSettings:
    """How leaf area and wood are estimated from the traced sums."""

    leaf_angle: str | dict = "uniform"  #: a LeafAngle name or its dict
    leaf_azimuth: str = "uniform"  #: "uniform" or "outward"
    crown_center: tuple | None = None  #: (x, y) of the crown axis for outward leaves
    estimator: str = "bcmle"
    fill: str = "none"  #: occluded voxels: "none", "layer", "neighbourhood", "calibrated"
    n_min: int = 5  #: beams a voxel needs, else occluded
    min_explored: float = 0.05  #: explored depth fraction a voxel needs, else occluded
    leaf_size: float | None = 0.05  #: metres, for the large-leaf flag
    small_voxel_factor: float = 1.0  #: every LAD multiplied by it
    wood: str = "count_stretch"
    wood_percentile: float = 90.0


@dataclass(frozen=True)
class GroundSettings:
    """The ground under the scene."""

    ground: str | float | None = "ransac"  #: "ransac", a height in metres, or None
    ground_tolerance: float = 0.15  #: metres above the plane that stop beams as ground


@dataclass(frozen=True)
class EchoSettings:
    """What each echo is and how echoes share their pulse."""

    class_codes: str = "pointclass"  #: "pointclass" (tlsvox.classify) or "material"
    echo_weights: str = "auto"  #: "auto", "uniform", "fraction" or "threshold"
    leaf_reflectance: float | None = None  #: of a full hit; default the optics at the wavelength
    wood_reflectance: float | None = None


@dataclass(frozen=True)
class UndetectedSettings:
    """Leaf hits under the scanner's detection threshold."""

    undetected: str = "ignore"  #: "ignore" or "model"
    detection_threshold_db: float | None = None  #: default the scan's preset
    leaf_shape: tuple = (0.05, 0.025)  #: leaf length, width, metres
    undetected_iterations: int = 4


@dataclass(frozen=True)
class PoseSettings:
    """Scans without a pose, and the empty pulses of scans without a pulse table."""

    scanner_frame: bool = False  #: a single scan without pose: its own frame is the world
    angular_grid: dict | None = None  #: an AngularGrid's fields, to rebuild empty pulses
    socs_rotation: tuple | None = None  #: 3x3, the scanner's own frame in the scan's frame
    max_range: float | None = None  #: follow empty pulses this far, metres


#: settings whose default is not None but which may be None: a TOML file (no null) writes it "none"
NULLABLE = ("ground", "leaf_size")

GROUPS = {"grid": GridSettings, "model": ModelSettings, "ground": GroundSettings, "echoes": EchoSettings,
          "undetected": UndetectedSettings, "poses": PoseSettings}


def _plain(value):
    """``value`` as plain Python (tuples for arrays, dicts for dataclasses), for equality and files."""
    if value is None or isinstance(value, bool | str):
        return value
    if isinstance(value, np.bool_):
        return bool(value)
    if isinstance(value, int | np.integer):
        return int(value)
    if isinstance(value, float | np.floating):
        return float(value)
    if hasattr(value, "to_dict") and not isinstance(value, dict):  # LeafAngle: its own file form
        return _plain(value.to_dict())
    if dataclasses.is_dataclass(value) and not isinstance(value, type):  # GroundPlane, AngularGrid
        return {f.name: _plain(getattr(value, f.name)) for f in fields(value)}
    if isinstance(value, dict):
        return {str(k): _plain(v) for k, v in value.items()}
    if isinstance(value, np.ndarray):
        value = value.tolist()
    if isinstance(value, list | tuple):
        return tuple(_plain(v) for v in value)
    raise InputError(f"a voxelize setting must be a number, text, a list or a table; got {type(value).__name__}")


@dataclass(frozen=True)
class VoxelizeSettings:
    """Every setting of a :func:`~tlsvox.voxel.stages.voxelize` run, in six groups (module docstring)."""

    grid: GridSettings = field(default_factory=GridSettings)
    model: ModelSettings = field(default_factory=ModelSettings)
    ground: GroundSettings = field(default_factory=GroundSettings)
    echoes: EchoSettings = field(default_factory=EchoSettings)
    undetected: UndetectedSettings = field(default_factory=UndetectedSettings)
    poses: PoseSettings = field(default_factory=PoseSettings)

    @staticmethod
    def names() -> dict[str, str]:
        """Every field's name -> its group's name."""
        return {f.name: g for g, cls in GROUPS.items() for f in fields(cls)}

    @classmethod
    def from_kwargs(cls, base: VoxelizeSettings | None = None, **kwargs) -> VoxelizeSettings:
        """``base`` (default: the defaults) with the named fields replaced; unknown names are refused."""
        base = base or cls()
        where = cls.names()
        unknown = sorted(set(kwargs) - set(where))
        if unknown:
            raise InputError(f"unknown voxelize setting(s) {unknown}; the settings are: {sorted(where)}")
        groups: dict[str, dict] = {g: {} for g in GROUPS}
        for k, v in kwargs.items():
            if k in NULLABLE and isinstance(v, str) and v.lower() == "none":
                v = None
            groups[where[k]][k] = _plain(v)
        return cls(**{g: dataclasses.replace(getattr(base, g), **kw) for g, kw in groups.items()})

    def to_kwargs(self) -> dict:
        """All fields as one flat dict of keyword arguments."""
        return {f.name: getattr(getattr(self, g), f.name) for g, c in GROUPS.items() for f in fields(c)}

    def to_dict(self) -> dict:
        """``{group: {field: value}}`` in plain JSON types (what ``scene.meta["settings"]`` holds)."""
        return {g: {k: _json(v) for k, v in dataclasses.asdict(getattr(self, g)).items()} for g in GROUPS}

    @classmethod
    def from_dict(cls, d: dict) -> VoxelizeSettings:
        """The inverse of :meth:`to_dict` (groups may be missing: their defaults; a field missing: its default)."""
        if not isinstance(d, dict):
            raise InputError(f"voxelize settings must be a table of groups {sorted(GROUPS)}; got {type(d).__name__}")
        unknown = sorted(set(d) - set(GROUPS))
        if unknown:
            raise InputError(f"unknown voxelize settings group(s) {unknown}; the groups are {sorted(GROUPS)}")
        flat = {}
        for g, values in d.items():
            if not isinstance(values, dict):
                raise InputError(f"voxelize settings [{g}] must be a table of fields, got {values!r}")
            known = {f.name for f in fields(GROUPS[g])}
            bad = sorted(set(values) - known)
            if bad:
                raise InputError(f"unknown field(s) {bad} in voxelize settings [{g}]; it holds {sorted(known)}")
            flat.update(values)
        return cls.from_kwargs(**flat)

    def to_toml(self) -> str:
        """The settings as a TOML document (a setting at None is left out where None is its default, else
        written ``"none"``)."""
        lines = []
        for g, values in self.to_dict().items():
            lines.append(f"[{g}]")
            lines += [f"{k} = {_toml_value('none' if v is None else v)}" for k, v in values.items()
                      if v is not None or k in NULLABLE]
            lines.append("")
        return "\n".join(lines)

    def write(self, path) -> Path:
        """Write :meth:`to_toml` to ``path`` (atomically)."""
        from voxlidar.safeio import atomic_write

        text = self.to_toml()
        return atomic_write(path, lambda tmp: Path(tmp).write_text(text, encoding="utf-8"))

    @classmethod
    def read(cls, path) -> VoxelizeSettings:
        """Settings from a TOML file (:meth:`write`'s), or from a scene NPZ's ``meta["settings"]``."""
        path = Path(path)
        if not path.is_file():
            raise InputError(f"{path}: no such settings file (a TOML file, or a scene .npz written by voxelize)")
        if path.suffix.lower() == ".npz":
            from voxlidar.scene import Scene

            meta = Scene.load(path).meta
            if "settings" not in meta:
                raise InputError(f"{path} is a scene without recorded settings (written before voxlidar 0.2, or "
                                 "not by voxelize); pass a TOML file instead")
            return cls.from_dict(meta["settings"])
        try:
            d = tomllib.loads(path.read_text(encoding="utf-8"))
        except (tomllib.TOMLDecodeError, UnicodeDecodeError) as err:
            raise InputError(f"{path} is not a TOML file ({err}); see VoxelizeSettings.write for one") from None
        return cls.from_dict(d)


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
