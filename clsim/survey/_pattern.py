"""Scan patterns: where the mirror points the beam at each moment.

A pattern gives the beam's direction in the platform's body frame (forward,
right, up; no roll, pitch or yaw) as a function of time.  Three mechanisms:

``mirror``
    An oscillating mirror (e.g. Leica ALS50/60/70): the beam swings across
    track and back, a triangle wave in angle; on the ground a zigzag.
``polygon``
    A rotating polygon mirror (e.g. RIEGL LMS-Q560/Q680i): every line is
    swept from left to right, then the next facet starts again; parallel lines.
``palmer``
    A Palmer (nutating) scanner (e.g. AHAB Chiroptera, RIEGL VQ-840): the
    beam turns on a cone around nadir, an ellipse (or circle) on the ground.
"""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass
from typing import NamedTuple

import numpy as np

from clsim.errors import InputError
from clsim.sensor import SURVEY_TABLE, read_preset
from voxlidar.choices import Choice
from voxlidar.errors import finite_number

__all__ = ["Flight", "ScanKind", "ScanPattern", "typical_flight"]


class ScanKind(str, Choice):
    """The scanning mechanism."""

    MIRROR = "mirror"
    POLYGON = "polygon"
    PALMER = "palmer"


@dataclass(frozen=True)
class ScanPattern:
    """How a scanner sweeps its beam, and how often it fires.

    Parameters
    ----------
    kind : {"mirror", "polygon", "palmer"}
    pulse_rate_hz : float, Hz
        Pulses emitted per second (> 0); all fall in the field of view.
    scan_rate_hz : float, Hz
        Scan lines per second for ``mirror`` and ``polygon`` (a mirror's full
        oscillation is two lines), rotations per second for ``palmer`` (> 0).
    fov_deg : float, degrees
        Full scan angle range across track, in [0, 180): the beam swings from
        ``-fov_deg/2`` (left) to ``+fov_deg/2`` (right) of nadir.  For
        ``palmer`` twice the off-nadir angle across track, in (0, 180).
    along_fov_deg : float or None, degrees
        ``palmer`` only: twice the off-nadir angle along track (None: the
        same as ``fov_deg``, a circular cone).
    phase : float
        Scan phase at time 0, in [0, 1) of a line or rotation.

    Examples
    --------
    >>> p = ScanPattern(kind="polygon", pulse_rate_hz=100e3, scan_rate_hz=100.0, fov_deg=60.0)
    >>> p.across_deg(np.array([0.0, 0.005]))     # start and middle of a line
    array([-30.,   0.])
    >>> ScanPattern(kind="mirror", fov_deg=200.0)
    Traceback (most recent call last):
    ...
    voxlidar.errors.InputError: scan fov_deg must lie in [0, 180) degrees, got 200.0; the full scan angle range across track
    """

    kind: ScanKind | str = ScanKind.POLYGON
    pulse_rate_hz: float = 100e3
    scan_rate_hz: float = 100.0
    fov_deg: float = 60.0
    along_fov_deg: float | None = None
    phase: float = 0.0

    def __post_init__(self):
        object.__setattr__(self, "kind", ScanKind.parse(self.kind, "scan kind"))
        for name in ("pulse_rate_hz", "scan_rate_hz", "fov_deg", "along_fov_deg", "phase"):
            v = getattr(self, name)
            if v is None and name == "along_fov_deg":
                continue
            object.__setattr__(self, name, finite_number(v, f"scan {name}"))
        for name in ("pulse_rate_hz", "scan_rate_hz"):
            if getattr(self, name) <= 0:
                raise InputError(f"scan {name} must be > 0 Hz, got {getattr(self, name)!r}")
        low_ok = self.fov_deg > 0 if self.kind is ScanKind.PALMER else self.fov_deg >= 0
        if not (low_ok and self.fov_deg < 180):
            bracket = "(0, 180)" if self.kind is ScanKind.PALMER else "[0, 180)"
            raise InputError(f"scan fov_deg must lie in {bracket} degrees, got {self.fov_deg!r}; "
                             "the full scan angle range across track")
        if self.along_fov_deg is not None:
            if self.kind is not ScanKind.PALMER:
                raise InputError(f"scan along_fov_deg is for kind='palmer' only, got {self.along_fov_deg!r} "
                                 f"with kind={self.kind.value!r}; leave it None")
            if not 0 < self.along_fov_deg < 180:
                raise InputError(f"scan along_fov_deg must lie in (0, 180) degrees, got {self.along_fov_deg!r}")
        if not 0 <= self.phase < 1:
            raise InputError(f"scan phase must lie in [0, 1) of a line or rotation, got {self.phase!r}")

    # -- construction -----------------------------------------------------------
    @classmethod
    def preset(cls, name, **overrides) -> ScanPattern:
        """The ``[survey]`` table of a sensor preset (by name or ``.toml`` path)."""
        table, where = _survey_table(name)
        names = {f.name for f in dataclasses.fields(cls)}
        data = {k: v for k, v in table.items() if k in names}
        unknown = sorted(set(overrides) - names)
        if unknown:
            raise InputError(f"unknown scan pattern keys {unknown}; valid keys: {sorted(names)}")
        return cls(**{**data, **overrides})

    def replace(self, **changes) -> ScanPattern:
        return dataclasses.replace(self, **changes)

    # -- angles ---------------------------------------------------------------
    def scan_phase(self, t) -> np.ndarray:
        """Fraction of the current line (mirror, polygon) or rotation (palmer), in [0, 1)."""
        u = np.asarray(t, dtype=np.float64) * self.scan_rate_hz + self.phase
        return u - np.floor(u)

    def across_deg(self, t) -> np.ndarray:
        """Mirror and polygon: the across-track scan angle at times ``t`` (s), degrees, + to the right."""
        if self.kind is ScanKind.PALMER:
            raise InputError("across_deg is for kind='mirror' or 'polygon'; a palmer scan's angles are "
                             "body_directions(t)")
        half = 0.5 * self.fov_deg
        t = np.asarray(t, dtype=np.float64)
        if self.kind is ScanKind.POLYGON:
            return -half + self.fov_deg * self.scan_phase(t)
        u = t * self.scan_rate_hz + self.phase            # lines since time 0
        line = np.floor(u)
        s = u - line
        s = np.where(line % 2 == 0, s, 1.0 - s)             # even lines left to right, odd back
        return -half + self.fov_deg * s

    def body_directions(self, t) -> np.ndarray:
        """(N, 3) unit beam directions in the body frame (forward, right, up) at times ``t`` (s)."""
        t = np.atleast_1d(np.asarray(t, dtype=np.float64))
        d = np.empty((t.size, 3))
        if self.kind is ScanKind.PALMER:
            phi = 2.0 * math.pi * self.scan_phase(t)
            along = self.fov_deg if self.along_fov_deg is None else self.along_fov_deg
            d[:, 0] = math.tan(math.radians(0.5 * along)) * np.cos(phi)
            d[:, 1] = math.tan(math.radians(0.5 * self.fov_deg)) * np.sin(phi)
            d[:, 2] = -1.0
            d /= np.linalg.norm(d, axis=1, keepdims=True)
        else:
            a = np.radians(self.across_deg(t))
            d[:, 0] = 0.0
            d[:, 1] = np.sin(a)
            d[:, 2] = -np.cos(a)
        return d


class Flight(NamedTuple):
    """A typical flight of a preset: height above ground (m) and speed (m/s)."""

    altitude_m: float
    speed_mps: float


def typical_flight(name) -> Flight:
    """The ``[survey]`` table's ``flying_height_m`` and ``speed_mps`` of a preset."""
    table, where = _survey_table(name)
    try:
        return Flight(float(table["flying_height_m"]), float(table["speed_mps"]))
    except KeyError as err:
        raise InputError(f"{where}: the [survey] table has no {err.args[0]!r}") from err


def _survey_table(name) -> tuple[dict, str]:
    data, where = read_preset(name)
    table = data.get(SURVEY_TABLE)
    if not isinstance(table, dict):
        raise InputError(f"{where} has no [{SURVEY_TABLE}] table (scan pattern, pulse rate, flight); "
                         f"add one as clsim/presets/ahab-chiroptera-i.toml does")
    known = {f.name for f in dataclasses.fields(ScanPattern)} | {"flying_height_m", "speed_mps"}
    unknown = sorted(set(table) - known)
    if unknown:
        raise InputError(f"{where}: unknown [{SURVEY_TABLE}] keys {unknown}; valid keys: {sorted(known)}")
    return table, where
