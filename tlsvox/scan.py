"""One terrestrial laser scan: its echoes, its pulses, its pose.

A :class:`Scan` holds the echoes of one scanner position in the scanner's own
frame, with apparent reflectance (RIEGL dB) or raw intensity, return number and
count, the pulse each echo belongs to, and optionally the truth material (for
simulated scans).  Its :class:`PulseTable` lists *every* pulse fired, those
with no echo too: they carry the gap information that leaf area density
estimation needs.

Files (see docs/formats.md):

- ``NAME.las`` / ``NAME.laz``: LAS 1.4 point format 6, coordinates in the
  scanner frame, extra bytes ``reflectance_db`` (float32), ``pulse_id``
  (uint32), ``truth_material`` (uint8, simulated scans only), ``beam_fraction``
  (float32, when the scan has one: the share of the beam each echo intercepted).
- ``NAME.pulses.npz``: the pulse table (``direction`` (P, 3), ``n_echoes``
  (P,), ``origin`` (3,), and the angular grid).
- ``NAME.pose.json``: ``pose`` (4x4 world-from-scanner, when known) and, for
  simulated scans, ``pose_true``.
"""

from __future__ import annotations

import json
import os
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from tlsvox.errors import InputError
from voxlidar.safeio import json_text, staged, write_npz

__all__ = ["AngularGrid", "CLASSIFY_MARK", "PulseTable", "Scan", "las_data", "sidecar_paths"]


#: ``meta["classes"]`` of a scan whose LAS classification holds tlsvox.classify's PointClass codes
CLASSIFY_MARK = "tlsvox.classify.PointClass"


def sidecar_paths(path: str | os.PathLike) -> tuple[Path, Path]:
    """The pulse-table and pose files that belong to a scan file."""
    path = Path(path)
    stem = path.with_suffix("")
    return stem.with_name(stem.name + ".pulses.npz"), stem.with_name(stem.name + ".pose.json")


@dataclass(frozen=True)
class AngularGrid:
    """Regular scan grid of a scanner: zenith lines x azimuth columns, degrees."""

    zenith_start_deg: float
    zenith_step_deg: float
    n_zenith: int
    azimuth_start_deg: float
    azimuth_step_deg: float
    n_azimuth: int

    def __post_init__(self):
        for name in ("zenith_step_deg", "azimuth_step_deg"):
            v = getattr(self, name)
            if not (np.isfinite(v) and v > 0):
                raise InputError(f"{name}={v!r} must be a positive angle step in degrees")
        for name in ("n_zenith", "n_azimuth"):
            if int(getattr(self, name)) < 1:
                raise InputError(f"{name} must be >= 1")

    @property
    def n_pulses(self) -> int:
        return int(self.n_zenith) * int(self.n_azimuth)

    def angles(self) -> tuple[np.ndarray, np.ndarray]:
        """Zenith and azimuth (radians) of every grid pulse, zenith-major order."""
        zen = np.deg2rad(self.zenith_start_deg + self.zenith_step_deg * np.arange(self.n_zenith))
        az = np.deg2rad(self.azimuth_start_deg + self.azimuth_step_deg * np.arange(self.n_azimuth))
        zz, aa = np.meshgrid(zen, az, indexing="ij")
        return zz.ravel(), aa.ravel()

    def to_dict(self) -> dict:
        return {k: (float(v) if isinstance(v, float) else int(v)) for k, v in self.__dict__.items()}


def directions_from_angles(zenith, azimuth) -> np.ndarray:
    """Unit vectors (N, 3) from zenith and azimuth angles (radians)."""
    sz = np.sin(zenith)
    return np.column_stack([sz * np.cos(azimuth), sz * np.sin(azimuth), np.cos(zenith)])


@dataclass
class PulseTable:
    """Every pulse of a scan, in the scanner frame.

    Parameters
    ----------
    direction : (P, 3) float, unit vectors
        Beam direction of each pulse in the scanner frame.
    n_echoes : (P,) int
        Number of echoes recorded for the pulse (0 for a gap).
    origin : (3,) float, metres
        Beam origin in the scanner frame (the scanner's centre).
    grid : AngularGrid, optional
        The angular grid the pulses were fired on.
    """

    direction: np.ndarray
    n_echoes: np.ndarray
    origin: np.ndarray = field(default_factory=lambda: np.zeros(3))
    grid: AngularGrid | None = None

    def __post_init__(self):
        self.direction = np.asarray(self.direction, dtype=np.float32).reshape(-1, 3)
        self.n_echoes = np.asarray(self.n_echoes, dtype=np.uint8).reshape(-1)
        self.origin = np.asarray(self.origin, dtype=np.float64).reshape(3)
        if len(self.n_echoes) != len(self.direction):
            raise InputError(
                f"pulse table: {len(self.direction)} directions but {len(self.n_echoes)} echo counts"
            )

    def __len__(self) -> int:
        return len(self.direction)

    def save(self, path) -> Path:
        arrays = dict(direction=self.direction, n_echoes=self.n_echoes, origin=self.origin)
        if self.grid is not None:
            arrays["grid"] = np.str_(json.dumps(self.grid.to_dict()))
        return write_npz(path, arrays)

    @classmethod
    def load(cls, path) -> PulseTable:
        with np.load(path, allow_pickle=False) as z:
            grid = AngularGrid(**json.loads(str(z["grid"]))) if "grid" in z else None
            return cls(z["direction"], z["n_echoes"], z["origin"], grid)


@dataclass
class Scan:
    """The echoes of one scanner position (scanner frame) and its pulses.

    Parameters
    ----------
    xyz : (N, 3) float64, metres
        Echo positions in the scanner's own frame.
    reflectance_db : (N,) float32, optional
        Apparent reflectance in dB relative to a white Lambertian target.
    intensity : (N,) float, optional
        Raw intensity (when no calibrated reflectance exists).
    return_number, number_of_returns : (N,) uint8
        1-based echo index within its pulse, and the pulse's echo count.
    pulse_id : (N,) int64, optional
        Row of :attr:`pulses` each echo belongs to.
    truth_material : (N,) uint8, optional
        :class:`voxlidar.materials.Material` of the surface hit (simulated scans).
    beam_fraction : (N,) float32, optional
        Share of the pulse's beam power each echo intercepted, in [0, 1]
        (a simulated scan's sub-ray count over the beam's sub-rays; NaN where
        unknown).  ``voxelize(echo_weights="fraction")`` weights echoes by it
        (:mod:`tlsvox.voxel.weights`).
    classification : (N,) uint8, optional
        :class:`tlsvox.classify.PointClass` codes (LAS ``classification``) of a
        scan that ``tlsvox classify`` wrote; ``tlsvox voxelize`` uses them.
    pose : (4, 4) float64, optional
        World-from-scanner transform (estimated, or known).
    pose_true : (4, 4) float64, optional
        The true pose (simulated scans only).
    pulses : PulseTable, optional
    scan_id : int
    name : str
    """

    xyz: np.ndarray
    reflectance_db: np.ndarray | None = None
    intensity: np.ndarray | None = None
    return_number: np.ndarray | None = None
    number_of_returns: np.ndarray | None = None
    pulse_id: np.ndarray | None = None
    truth_material: np.ndarray | None = None
    classification: np.ndarray | None = None
    beam_fraction: np.ndarray | None = None
    pose: np.ndarray | None = None
    pose_true: np.ndarray | None = None
    pulses: PulseTable | None = None
    scan_id: int = 0
    name: str = "scan"
    meta: dict = field(default_factory=dict)

    def __post_init__(self):
        self.xyz = np.asarray(self.xyz, dtype=np.float64).reshape(-1, 3)
        n = len(self.xyz)
        if not np.all(np.isfinite(self.xyz)):
            bad = int(np.count_nonzero(~np.isfinite(self.xyz).all(axis=1)))
            raise InputError(
                f"scan {self.name!r}: {bad} of {n} points have NaN or inf coordinates; "
                "remove them before building a Scan"
            )

        def col(name, dtype):
            v = getattr(self, name)
            if v is None:
                return None
            v = np.asarray(v, dtype=dtype).reshape(-1)
            if len(v) != n:
                raise InputError(f"scan {self.name!r}: {name} has {len(v)} values for {n} points")
            return v

        self.reflectance_db = col("reflectance_db", np.float32)
        self.intensity = col("intensity", np.float32)
        self.return_number = col("return_number", np.uint8)
        self.number_of_returns = col("number_of_returns", np.uint8)
        self.pulse_id = col("pulse_id", np.int64)
        self.truth_material = col("truth_material", np.uint8)
        self.classification = col("classification", np.uint8)
        self.beam_fraction = col("beam_fraction", np.float32)
        if self.beam_fraction is not None:
            f = self.beam_fraction
            bad = ~np.isnan(f) & ~((f >= 0) & (f <= 1))
            if bad.any():
                raise InputError(f"scan {self.name!r}: beam_fraction must lie in [0, 1] (or NaN where unknown); "
                                 f"{int(bad.sum())} of {n} values do not (e.g. {float(f[bad][0])!r})")
        if self.return_number is None:
            self.return_number = np.ones(n, np.uint8)
        if self.number_of_returns is None:
            self.number_of_returns = np.ones(n, np.uint8)
        for name in ("pose", "pose_true"):
            v = getattr(self, name)
            if v is not None:
                v = np.asarray(v, dtype=np.float64)
                if v.shape != (4, 4) or not np.all(np.isfinite(v)):
                    raise InputError(f"scan {self.name!r}: {name} must be a finite 4x4 matrix")
                setattr(self, name, v)

    def __len__(self) -> int:
        return len(self.xyz)

    @property
    def reflectance(self) -> np.ndarray | None:
        """Apparent reflectance (linear): 10^(dB/10)."""
        if self.reflectance_db is None:
            return None
        return np.power(10.0, self.reflectance_db.astype(np.float64) / 10.0)

    def world_xyz(self, pose=None) -> np.ndarray:
        """Echo positions in the world frame, using ``pose`` or the scan's own."""
        pose = self.pose if pose is None else np.asarray(pose, dtype=float)
        if pose is None:
            raise InputError(
                f"scan {self.name!r} has no pose: register it (tlsvox register) or pass pose="
            )
        return self.xyz @ pose[:3, :3].T + pose[:3, 3]

    # -- LAS I/O ------------------------------------------------------------------
    def write(self, path: str | os.PathLike) -> Path:
        """Write LAS/LAZ (point format 6 + extra bytes, :func:`las_data`) and the sidecar files.

        Every file goes to a temporary name first and is renamed when complete.
        """
        path = Path(path)
        if path.suffix.lower() not in (".las", ".laz"):
            raise InputError(f"scan output {str(path)!r} must end in .las or .laz")
        las = las_data([self], self.xyz, classification=None if self.classification is None
                       else [self.classification])
        pulses_path, pose_path = sidecar_paths(path)
        pose_doc = {"name": self.name, "scan_id": int(self.scan_id), "frame": "scanner",
                    "meta": self.meta}
        if self.pose is not None:
            pose_doc["pose"] = self.pose.tolist()
        if self.pose_true is not None:
            pose_doc["pose_true"] = self.pose_true.tolist()
        with staged([path, pulses_path if self.pulses is not None else None, pose_path]) as tmp:
            las.write(str(tmp[path]))  # the points and their sidecars: all or none (Ctrl-C included)
            if self.pulses is not None:
                self.pulses.save(tmp[pulses_path])
            tmp[pose_path].write_text(json_text(pose_doc, indent=1))
        if self.pulses is None and pulses_path.exists():
            pulses_path.unlink()  # an older scan's pulse table must not pair with these points
        return path

    @classmethod
    def read(cls, path: str | os.PathLike, *, scan_id: int | None = None, origin=None) -> Scan:
        """Read a LAS/LAZ scan and its sidecar files (:func:`tlsvox.readers.las.read_las`)."""
        from tlsvox.readers.las import read_las

        return read_las(path, scan_id=scan_id, cls=cls, origin=origin)


def las_data(scans: list[Scan], xyz: np.ndarray, *, classification=None):
    """The points of ``scans`` as one ``laspy.LasData``: the one LAS layout of tlsvox.

    LAS 1.4 point format 6, scale 0.1 mm, offsets at the floor of the
    minimum (so projected coordinates such as UTM fit the 32-bit integers);
    ``point_source_id`` = scan id; ``intensity`` = the raw intensity when a
    scan has one, else the linear reflectance x 10,000 (0 dB -> 10,000);
    ``gps_time`` = the pulse id (scans carry no clock); extra bytes
    ``reflectance_db``, ``pulse_id`` and, when every scan has it,
    ``truth_material``; ``beam_fraction`` when any scan has it (NaN for
    the echoes of scans without).

    Parameters
    ----------
    scans : list of Scan
    xyz : (N, 3) float64, metres
        Their points in the frame to write (scanner frame for one scan,
        the reference frame for a merged registration), N = total echoes.
    classification : list of (N_i,) uint8, optional
        Per-scan classes for the LAS ``classification`` field.
    """
    import laspy

    n = len(xyz)
    header = laspy.LasHeader(point_format=6, version="1.4")
    header.scales = np.array([1e-4, 1e-4, 1e-4])
    header.offsets = np.floor(xyz.min(axis=0)) if n else np.zeros(3)
    extra = [laspy.ExtraBytesParams(name="reflectance_db", type=np.float32, description="apparent reflectance dB"),
             laspy.ExtraBytesParams(name="pulse_id", type=np.uint32, description="pulse row")]
    with_truth = bool(scans) and all(s.truth_material is not None for s in scans)
    if with_truth:
        extra.append(laspy.ExtraBytesParams(name="truth_material", type=np.uint8, description="tlsvox Material id"))
    with_fraction = any(s.beam_fraction is not None for s in scans)
    if with_fraction:
        extra.append(laspy.ExtraBytesParams(name="beam_fraction", type=np.float32,
                                            description="beam share intercepted"))
    header.add_extra_dims(extra)
    las = laspy.LasData(header)
    las.x, las.y, las.z = xyz[:, 0], xyz[:, 1], xyz[:, 2]

    def cat(get, dtype):
        return np.concatenate([np.asarray(get(s), dtype=dtype) for s in scans]) if scans else np.zeros(0, dtype)

    def intensity(s):
        if s.intensity is not None:
            return np.clip(s.intensity, 0, 65535)
        if s.reflectance_db is not None:
            return np.clip(np.nan_to_num(s.reflectance * 1e4), 0, 65535)
        return np.zeros(len(s))

    pid = cat(lambda s: s.pulse_id if s.pulse_id is not None else np.arange(len(s)), np.uint32)
    las.return_number = cat(lambda s: np.clip(s.return_number, 1, 15), np.uint8)
    las.number_of_returns = cat(lambda s: np.clip(s.number_of_returns, 1, 15), np.uint8)
    las.point_source_id = cat(lambda s: np.full(len(s), s.scan_id & 0xFFFF), np.uint16)
    las.reflectance_db = cat(lambda s: s.reflectance_db if s.reflectance_db is not None
                             else np.full(len(s), np.nan), np.float32)
    las.intensity = cat(intensity, np.uint16)
    las.pulse_id = pid
    las.gps_time = pid.astype(np.float64)
    if with_truth:
        las.truth_material = cat(lambda s: s.truth_material, np.uint8)
    if with_fraction:
        las.beam_fraction = cat(lambda s: s.beam_fraction if s.beam_fraction is not None
                                else np.full(len(s), np.nan), np.float32)
    if classification is not None:
        if len(classification) != len(scans) or any(len(c) != len(s) for c, s in zip(classification, scans)):
            raise InputError("classification must hold one (N_i,) array per scan")
        las.classification = np.concatenate([np.asarray(c, dtype=np.uint8) for c in classification])
    return las
