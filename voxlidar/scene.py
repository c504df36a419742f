"""The voxel scene: the contract between tlsvox and clsim.

A :class:`Scene` is a sparse voxel grid of leaf area density (LAD, m2/m3),
wood (probability of a full-voxel crossing being stopped, or wood area
density), an occlusion flag, the leaf angle model, a ground plane, and the
optical properties of each material.  It is saved as a compressed NPZ whose
keys are documented in ``docs/formats.md``.

Examples
--------
>>> import numpy as np
>>> s = Scene(origin=(0, 0, 0), voxel_size=0.5, shape=(2, 2, 2),
...           ijk=[[0, 0, 0], [1, 1, 1]], lad=[1.0, 0.5])
>>> s.n_voxels, s.total_leaf_area()
(2, 0.1875)
>>> float(s.dense("lad")[1, 1, 1])
0.5
"""

from __future__ import annotations

import json
import os
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from voxlidar.errors import InputError
from voxlidar.leaf_orientation import LeafAngle, LeafAzimuth
from voxlidar.safeio import describe_kind, file_kind, json_text, open_npz, write_npz

__all__ = ["Scene", "FORMAT_VERSION", "WOOD_KINDS"]

FORMAT_VERSION = 1
WOOD_KINDS = ("probability", "area_density")
LEAF_AZIMUTHS = tuple(a.value for a in LeafAzimuth)


def _default_materials() -> dict:
    from voxlidar.materials import DEFAULT_OPTICS, Material

    out = {}
    for wl, table in DEFAULT_OPTICS.items():
        for mat in (Material.LEAF, Material.BARK, Material.GROUND):
            o = table[mat]
            out.setdefault(mat.name.lower(), {})[str(wl)] = [o.reflectance, o.transmittance]
    return out


#: Largest leaf area density a scene accepts, m2/m3: a solid stack of 0.2 mm leaves
#: holds 5000 m2 per m3, so nothing above it can be leaves.  Estimates from real
#: scans do reach a few hundred in single voxels (noise, partial hits); tlsvox
#: voxelize warns above 20 (LAD_PLAUSIBLE_MAX) instead of refusing.
LAD_MAX = 5000.0


@dataclass
class Scene:
    """Sparse voxel scene (see module docstring and docs/formats.md).

    Parameters
    ----------
    origin : (3,) float, metres
        World position of the grid's lower corner (voxel (0,0,0) spans
        ``origin .. origin + voxel_size``).
    voxel_size : float, metres
        Edge length of the cubic voxels.
    shape : (3,) int
        Grid dimensions (nx, ny, nz).
    ijk : (M, 3) int32
        Indices of the stored voxels; every other voxel is empty.
    lad : (M,) float, m2/m3
        One-sided leaf area density.
    wood : (M,) float, optional
        Wood value per voxel, its meaning given by ``wood_kind``.
    wood_kind : {"probability", "area_density"}
        ``probability``: chance that a beam crossing the whole voxel is stopped
        by wood, averaged over directions; ``area_density``: wood (bark) area
        density, m2/m3.
    wood_axis : (M, 3) float, optional
        Unit axis of each voxel's bark (sign free; default +z).
    wood_beta : (M,) float in [0, 1], optional
        Anisotropy of each voxel's bark: 0 (default) randomly oriented facets,
        1 a cylinder side whose normals are all perpendicular to ``wood_axis``.
        The wood extinction along a direction at angle psi to the axis is the
        direction-averaged one times ``1 + beta (4 sin(psi) / pi - 1)``
        (docs/method.md, "Directional wood").
    wood_solid : (M,) bool, optional
        Voxels inside a solid branch or trunk (default none): opaque from every
        direction whatever ``wood`` says, their surface the side of a cylinder
        about ``wood_axis`` and its end caps (``wood_beta`` is not used there;
        docs/method.md, "Solid wood").
    wood_cap : (M,) float in [0, 1], optional
        For solid voxels, the share of the nearby bark surface on the cylinder's
        end caps (normals along ``wood_axis``); the rest is its side. Default 0.
    occluded : (M,) bool, optional
        Voxels whose LAD could not be estimated (too few beams).
    lad_std : (M,) float, optional
        Standard error of ``lad``.
    leaf_angle : LeafAngle, dict or str
        Leaf inclination distribution.
    leaf_azimuth : {"uniform", "outward"}
        Leaf normal azimuths: uniform, or facing out from ``crown_center``.
    crown_center : (2,) float, metres
    ground_z : float or None, metres
        Height of a horizontal ground plane; None for no ground.
    materials : dict
        ``{material: {wavelength_nm (str): [R, T]}}`` for leaf, bark, ground.
    """

    origin: np.ndarray
    voxel_size: float
    shape: tuple
    ijk: np.ndarray
    lad: np.ndarray
    wood: np.ndarray | None = None
    wood_kind: str = "probability"
    wood_axis: np.ndarray | None = None
    wood_beta: np.ndarray | None = None
    wood_solid: np.ndarray | None = None
    wood_cap: np.ndarray | None = None
    occluded: np.ndarray | None = None
    lad_std: np.ndarray | None = None
    leaf_angle: LeafAngle = field(default_factory=LeafAngle)
    leaf_azimuth: str = "uniform"
    crown_center: np.ndarray = field(default_factory=lambda: np.zeros(2))
    ground_z: float | None = None
    materials: dict = field(default_factory=_default_materials)
    meta: dict = field(default_factory=dict)

    def __post_init__(self):
        self.origin = np.asarray(self.origin, dtype=np.float64).reshape(-1)
        if self.origin.shape != (3,) or not np.all(np.isfinite(self.origin)):
            raise InputError(f"origin must be 3 finite numbers, got {self.origin!r}")
        self.voxel_size = float(self.voxel_size)
        if not (np.isfinite(self.voxel_size) and self.voxel_size > 0):
            raise InputError(f"voxel_size must be > 0 metres, got {self.voxel_size!r}")
        self.shape = tuple(int(v) for v in np.asarray(self.shape).reshape(-1))
        if len(self.shape) != 3 or min(self.shape) < 1:
            raise InputError(f"shape must be 3 positive integers, got {self.shape!r}")
        self.ijk = np.asarray(self.ijk, dtype=np.int32).reshape(-1, 3)
        m = len(self.ijk)
        if m and (self.ijk.min() < 0 or np.any(self.ijk.max(axis=0) >= np.array(self.shape))):
            raise InputError(
                f"ijk indices must lie inside shape {self.shape}; got range "
                f"{self.ijk.min(axis=0).tolist()}..{self.ijk.max(axis=0).tolist()}"
            )
        self.lad = self._column("lad", self.lad, np.float64, m)
        if np.any(self.lad < 0):
            raise InputError("lad must be >= 0 m2/m3 everywhere (found negative values)")
        if self.lad.size and self.lad.max() > LAD_MAX:
            raise InputError(f"lad reaches {self.lad.max():g} m2/m3, above {LAD_MAX:g} (a solid stack of leaves): "
                             "no canopy is that dense; a wrong unit, or leaf area per voxel instead of per m3?")
        self.wood = self._column("wood", self.wood, np.float64, m, default=0.0)
        self.occluded = self._column("occluded", self.occluded, bool, m, default=False)
        self._wood_direction(m)
        if self.lad_std is not None:
            self.lad_std = self._column("lad_std", self.lad_std, np.float64, m)
        if self.wood_kind not in WOOD_KINDS:
            raise InputError(f"wood_kind={self.wood_kind!r} must be one of {WOOD_KINDS}")
        if self.wood_kind == "probability" and np.any((self.wood < 0) | (self.wood > 1)):
            raise InputError("wood probabilities must lie in [0, 1]")
        self.leaf_angle = LeafAngle.from_dict(self.leaf_angle)
        self.leaf_azimuth = LeafAzimuth.parse(self.leaf_azimuth, "leaf_azimuth").value
        self.crown_center = np.asarray(self.crown_center, dtype=np.float64).reshape(2)
        if self.ground_z is not None:
            self.ground_z = float(self.ground_z)

    def _wood_direction(self, m):
        self.wood_beta = self._column("wood_beta", self.wood_beta, np.float64, m, default=0.0)
        if np.any((self.wood_beta < 0) | (self.wood_beta > 1)):
            raise InputError("wood_beta must lie in [0, 1] (0: randomly oriented bark, 1: a pure cylinder)")
        self.wood_solid = self._column("wood_solid", self.wood_solid, bool, m, default=False)
        self.wood_cap = self._column("wood_cap", self.wood_cap, np.float64, m, default=0.0)
        if np.any((self.wood_cap < 0) | (self.wood_cap > 1)):
            raise InputError("wood_cap must lie in [0, 1] (the share of a solid voxel's bark on end caps)")
        if self.wood_axis is None:
            self.wood_axis = np.tile([0.0, 0.0, 1.0], (m, 1))
            return
        a = np.asarray(self.wood_axis, dtype=np.float64)
        if a.shape != (m, 3):
            raise InputError(f"wood_axis must be one 3-vector per voxel: expected ({m}, 3), got {a.shape}")
        if not np.all(np.isfinite(a)):
            raise InputError("wood_axis contains NaN or inf; every value must be finite")
        norm = np.linalg.norm(a, axis=1)
        bad = (norm < 1e-6) & ((self.wood_beta > 0) | self.wood_solid)
        if np.any(bad):
            raise InputError(f"wood_axis has {int(bad.sum())} zero-length vectors where wood_beta > 0 or wood_solid; "
                             "give a unit bark axis there (or wood_beta = 0 and wood_solid False)")
        a = np.where(norm[:, None] < 1e-6, [[0.0, 0.0, 1.0]], a / np.maximum(norm, 1e-300)[:, None])
        self.wood_axis = a

    @property
    def wood_directional(self) -> bool:
        """True when some voxel's bark has a direction (``wood_beta > 0`` or a solid voxel)."""
        return bool(np.any(self.wood_beta > 0) or np.any(self.wood_solid))

    @staticmethod
    def _column(name, values, dtype, m, default=None):
        if values is None:
            if default is None:
                raise InputError(f"{name} is required")
            return np.full(m, default, dtype=dtype)
        arr = np.asarray(values, dtype=dtype).reshape(-1)
        if arr.shape != (m,):
            raise InputError(f"{name} must have one value per voxel: expected ({m},), got {arr.shape}")
        if dtype is not bool and not np.all(np.isfinite(arr)):
            raise InputError(f"{name} contains NaN or inf; every value must be finite")
        return arr

    # -- derived ------------------------------------------------------------
    @property
    def n_voxels(self) -> int:
        return len(self.ijk)

    @property
    def voxel_volume(self) -> float:
        return self.voxel_size**3

    @property
    def extent(self) -> np.ndarray:
        """(2, 3) lower and upper corner of the grid, metres."""
        return np.stack([self.origin, self.origin + self.voxel_size * np.array(self.shape)])

    def centers(self) -> np.ndarray:
        """(M, 3) voxel centres, metres."""
        return self.origin + (self.ijk + 0.5) * self.voxel_size

    def total_leaf_area(self) -> float:
        """Sum of LAD x voxel volume, m2."""
        return float(self.lad.sum() * self.voxel_volume)

    def dense(self, name: str = "lad") -> np.ndarray:
        """A dense (nx, ny, nz) array of one per-voxel field ((nx, ny, nz, 3) for ``wood_axis``)."""
        values = getattr(self, name)
        out = np.zeros(tuple(self.shape) + values.shape[1:], dtype=values.dtype)
        i, j, k = self.ijk.T
        out[i, j, k] = values
        return out

    def optics(self, material: str, wavelength_nm: float) -> tuple[float, float]:
        """(R, T) of ``material`` at ``wavelength_nm``."""
        table = self.materials.get(material)
        key = str(int(round(float(wavelength_nm))))
        if table is None or key not in table:
            have = {m: sorted(t) for m, t in self.materials.items()}
            raise InputError(
                f"scene has no optics for {material!r} at {wavelength_nm} nm; it has {have}. "
                "Add them with scene.materials[material][str(wavelength)] = [R, T]"
            )
        r, t = table[key]
        return float(r), float(t)

    # -- files ----------------------------------------------------------------
    def save(self, path: str | os.PathLike) -> Path:
        """Write the scene as compressed NPZ (atomic: temp file + rename)."""
        arrays = dict(
            format_version=np.int32(FORMAT_VERSION),
            origin=self.origin,
            voxel_size=np.float64(self.voxel_size),
            shape=np.asarray(self.shape, dtype=np.int64),
            ijk=self.ijk,
            lad=self.lad,
            wood=self.wood,
            wood_kind=np.str_(self.wood_kind),
            occluded=self.occluded,
            leaf_angle=np.str_(json.dumps(self.leaf_angle.to_dict())),
            leaf_azimuth=np.str_(self.leaf_azimuth),
            crown_center=self.crown_center,
            ground_z=np.float64(np.nan if self.ground_z is None else self.ground_z),
            materials=np.str_(json.dumps(self.materials)),
            meta=np.str_(json_text(self.meta)),
        )
        if self.lad_std is not None:
            arrays["lad_std"] = self.lad_std
        if self.wood_directional:
            arrays["wood_axis"] = self.wood_axis
            arrays["wood_beta"] = self.wood_beta
        if np.any(self.wood_solid):
            arrays["wood_solid"] = self.wood_solid
            arrays["wood_cap"] = self.wood_cap
        return write_npz(path, arrays)

    @classmethod
    def load(cls, path: str | os.PathLike) -> Scene:
        """Read a scene NPZ written by :meth:`save` (or by hand, see docs/formats.md)."""
        path = Path(path)
        if not path.exists():
            raise InputError(f"scene file {str(path)!r} does not exist")
        if path.is_dir():
            raise InputError(f"scene file {str(path)!r} is a folder; give the .npz that tlsvox voxelize wrote")
        kind = file_kind(path)
        if kind != "npz":
            hint = " (read it with tlsvox.voxel.amapvox.read_vox)" if kind == "vox" else ""
            raise InputError(f"{str(path)!r} is not a readable NPZ scene file: it is {describe_kind(kind)}{hint}")
        with open_npz(path, "scene") as z:
            missing = [k for k in ("format_version", "origin", "voxel_size", "shape", "ijk", "lad") if k not in z]
            if missing:
                raise InputError(f"{str(path)!r} is not a voxlidar scene: missing keys {missing}")
            version = int(z["format_version"])
            if version > FORMAT_VERSION:
                raise InputError(
                    f"{str(path)!r} has format_version {version}; this voxlidar reads up to "
                    f"{FORMAT_VERSION}. Upgrade voxlidar."
                )

            def opt(key, conv, default=None):
                return conv(z[key]) if key in z else default

            ground = opt("ground_z", float)
            return cls(
                origin=z["origin"],
                voxel_size=float(z["voxel_size"]),
                shape=tuple(z["shape"]),
                ijk=z["ijk"],
                lad=z["lad"],
                wood=opt("wood", np.asarray),
                wood_kind=opt("wood_kind", str, "probability"),
                wood_axis=opt("wood_axis", np.asarray),
                wood_beta=opt("wood_beta", np.asarray),
                wood_solid=opt("wood_solid", np.asarray),
                wood_cap=opt("wood_cap", np.asarray),
                occluded=opt("occluded", np.asarray),
                lad_std=opt("lad_std", np.asarray),
                leaf_angle=opt("leaf_angle", lambda v: json.loads(str(v)), "uniform"),
                leaf_azimuth=opt("leaf_azimuth", str, "uniform"),
                crown_center=opt("crown_center", np.asarray, np.zeros(2)),
                ground_z=None if ground is None or np.isnan(ground) else ground,
                materials=opt("materials", lambda v: json.loads(str(v)), None) or _default_materials(),
                meta=opt("meta", lambda v: json.loads(str(v)), {}),
            )
