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

from dataclasses import dataclass, field
from pathlib import Path
from typing import ClassVar

from tlsvox.errors import InputError
from tlsvox.grouped import GroupedSettings, _read_toml

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


@dataclass(frozen=True)
class VoxelizeSettings(GroupedSettings):
    """Every setting of a :func:`~tlsvox.voxel.stages.voxelize` run, in six groups (module docstring)."""

    GROUPS: ClassVar[dict[str, type]] = GROUPS
    NULLABLE: ClassVar[tuple[str, ...]] = NULLABLE
    LABEL: ClassVar[str] = "voxelize"

    grid: GridSettings = field(default_factory=GridSettings)
    model: ModelSettings = field(default_factory=ModelSettings)
    ground: GroundSettings = field(default_factory=GroundSettings)
    echoes: EchoSettings = field(default_factory=EchoSettings)
    undetected: UndetectedSettings = field(default_factory=UndetectedSettings)
    poses: PoseSettings = field(default_factory=PoseSettings)

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
        return cls.from_dict(_read_toml(path, cls.__name__))
