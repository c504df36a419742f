"""The pulses of a survey: time, platform position, beam direction, ground target, seed."""

from __future__ import annotations

import math
from dataclasses import dataclass, fields

import numpy as np

from clsim.errors import InputError
from clsim.sensor import Sensor
from clsim.survey._pattern import ScanPattern
from clsim.survey._trajectory import Trajectory
from clsim.transport.rng import check_seed
from voxlidar.errors import finite_number

__all__ = ["Pulses", "pulse_count", "pulse_range", "survey_pulses"]

#: Bisection steps of the DEM intersection (bracket / 2**48: far below a micrometre).
_BISECT = 48


@dataclass(frozen=True)
class Pulses:
    """The pulses of a survey, one row each (N pulses).

    Attributes
    ----------
    index : (N,) int64
        Pulse number since the start of the trajectory (emitted at
        ``index / pulse_rate_hz``).
    seed : (N,) uint64
        Seed of the pulse's photons: ``base seed + index`` (mod 2**64), so a
        pulse gets the same seed whatever batch it is simulated in.
    time_s : (N,) float64, seconds from the start of the trajectory
    position : (N, 3) float64, metres; the platform (sensor) at emission
    heading_deg : (N,) float64, degrees from +x towards +y
    leg : (N,) int64
    direction : (N, 3) float64, unit vectors from the sensor along the beam (world frame)
    scan_angle_deg : (N,) float64
        Across-track angle of the beam from nadir in the body frame,
        positive to the right of the flight direction (LAS convention).
    off_nadir_deg, azimuth_deg : (N,) float64, degrees
        The beam's zenith angle at the target and the azimuth of the sensor as
        seen from the target (from +x towards +y), as :class:`clsim.Sensor` takes them.
    target : (N, 3) float64, metres; where the beam axis meets the ground
    range_m : (N,) float64, metres; sensor to target
    footprint_m : (N,) float64, metres
        Beam diameter at the target (1/e^2), ``2 range tan(divergence)``,
        measured across the beam (not stretched by the incidence angle).
    """

    index: np.ndarray
    seed: np.ndarray
    time_s: np.ndarray
    position: np.ndarray
    heading_deg: np.ndarray
    leg: np.ndarray
    direction: np.ndarray
    scan_angle_deg: np.ndarray
    off_nadir_deg: np.ndarray
    azimuth_deg: np.ndarray
    target: np.ndarray
    range_m: np.ndarray
    footprint_m: np.ndarray

    def __len__(self) -> int:
        return len(self.index)

    def __getitem__(self, key) -> Pulses:
        """The pulses at ``key`` (a slice, an index array or a boolean mask)."""
        if isinstance(key, (int, np.integer)):
            key = slice(int(key), int(key) + 1 if int(key) != -1 else None)
        return Pulses(**{f.name: getattr(self, f.name)[key] for f in fields(self)})

    def batches(self, size: int):
        """Consecutive slices of at most ``size`` pulses."""
        if int(size) < 1:
            raise InputError(f"batch size must be >= 1, got {size!r}")
        for a in range(0, len(self), int(size)):
            yield self[a:a + int(size)]

    def sensor(self, i: int, base: Sensor) -> Sensor:
        """``base`` placed for pulse ``i``: its altitude above the target, off-nadir
        and azimuth angles; pass it with ``target=pulses.target[i]`` and
        ``seed=int(pulses.seed[i])`` to :meth:`clsim.Simulator.run`."""
        return base.replace(altitude_m=float(self.position[i, 2] - self.target[i, 2]),
                            off_nadir_deg=float(self.off_nadir_deg[i]), azimuth_deg=float(self.azimuth_deg[i]))


def _ceil(x: float) -> int:
    """Ceiling that forgives float noise (x = 2.0000000000000004 -> 2)."""
    return int(math.ceil(x - 1e-9 * max(1.0, abs(x))))


def pulse_count(duration_s: float, pulse_rate_hz: float) -> int:
    """The pulses fired in the first ``duration_s`` seconds: those with ``t_k = k / rate < duration_s``.

    >>> pulse_count(0.02, 100.0), pulse_count(0.0201, 100.0)
    (2, 3)
    """
    return _ceil(float(duration_s) * float(pulse_rate_hz))


def pulse_range(pattern: ScanPattern, trajectory: Trajectory, first, count, start_s, duration_s):
    """(first, count) of the pulses asked for; every pulse has ``t_k`` in ``[0, duration)``."""
    rate = pattern.pulse_rate_hz
    total = pulse_count(trajectory.duration_s, rate)           # pulses 0 .. total - 1 fit
    if start_s is not None or duration_s is not None:
        if first is not None or count is not None:
            raise InputError("give either first/count (pulse numbers) or start_s/duration_s (seconds), not both")
        start_s = 0.0 if start_s is None else float(start_s)
        duration_s = trajectory.duration_s - start_s if duration_s is None else float(duration_s)
        if not (math.isfinite(start_s) and start_s >= 0 and math.isfinite(duration_s) and duration_s >= 0):
            raise InputError(f"start_s and duration_s must be >= 0 s, got start_s={start_s!r}, "
                             f"duration_s={duration_s!r}")
        first, end = _ceil(start_s * rate), _ceil((start_s + duration_s) * rate)
    else:
        first = 0 if first is None else first
        try:
            ok = int(first) == first and (count is None or int(count) == count)
        except (TypeError, ValueError, OverflowError):
            ok = False
        if not ok or first < 0 or (count is not None and count < 0):
            raise InputError(f"first and count must be integers >= 0, got first={first!r}, count={count!r}")
        first = int(first)
        end = total if count is None else first + int(count)
    if end > total:
        raise InputError(f"pulses {first}..{end - 1} do not fit the trajectory: it lasts "
                         f"{trajectory.duration_s!r} s, pulses 0..{total - 1} at {rate!r} Hz; "
                         "fix: ask for fewer pulses or a shorter span")
    return first, max(0, end - first)


def _hit_ground(origin, d, ground, z_range, step_m):
    """Distance along each ray to the ground: a plane z = ``ground`` or the
    first crossing of a DEM ``ground(x, y) -> z`` bounded by ``z_range``."""
    if callable(ground):
        if z_range is None:
            raise InputError("a DEM ground(x, y) needs z_range=(zmin, zmax), the heights that bound it")
        try:
            zlo, zhi = (float(z) for z in z_range)
        except (TypeError, ValueError) as err:
            raise InputError(f"z_range must be (zmin, zmax) in metres, got {z_range!r}") from err
        if not (math.isfinite(zlo) and math.isfinite(zhi) and zlo <= zhi):
            raise InputError(f"z_range must be (zmin, zmax) with zmin <= zmax, got {z_range!r}")
        if np.any(origin[:, 2] <= zhi):
            raise InputError(f"the platform must fly above the DEM's top z_range[1]={zhi!r}; lowest platform "
                             f"height {origin[:, 2].min()!r}")
        s_top = (origin[:, 2] - zhi) / -d[:, 2]           # where the ray enters the DEM's band
        s_bot = (origin[:, 2] - zlo) / -d[:, 2]
        n_steps = max(1, int(np.ceil((s_bot - s_top).max() / step_m)))

        def above(s, rows):                               # ray height minus ground height
            p = origin[rows] + s[:, None] * d[rows]
            return p[:, 2] - np.asarray(ground(p[:, 0], p[:, 1]), dtype=np.float64)

        lo, hi = s_top.copy(), np.full(len(d), np.nan)
        found = np.zeros(len(d), bool)
        for k in range(1, n_steps + 1):                   # march to the first step below the ground
            todo = np.flatnonzero(~found)
            if todo.size == 0:
                break
            s = np.minimum(s_top[todo] + k * step_m, s_bot[todo])
            below = above(s, todo) <= 0
            hi[todo[below]] = s[below]
            lo[todo[~below]] = s[~below]
            found[todo[below]] = True
        if not found.all():
            raise InputError(f"{int((~found).sum())} beams do not meet the DEM within z_range={z_range!r}; "
                             "fix: widen z_range to bound the DEM")
        rows = np.arange(len(d))
        for _ in range(_BISECT):
            mid = 0.5 * (lo + hi)
            b = above(mid, rows) <= 0
            hi, lo = np.where(b, mid, hi), np.where(b, lo, mid)
        return hi
    zg = finite_number(ground, "ground (a height in m, or a callable DEM (x, y) -> z)")
    if np.any(origin[:, 2] <= zg):
        raise InputError(f"the platform must fly above the ground z={zg!r}; lowest platform height "
                         f"{origin[:, 2].min()!r}")
    return (origin[:, 2] - zg) / -d[:, 2]


def survey_pulses(trajectory: Trajectory, pattern: ScanPattern, sensor: Sensor | None = None, *,
                  first: int | None = None, count: int | None = None, start_s: float | None = None,
                  duration_s: float | None = None, ground=0.0, z_range=None, dem_step_m: float = 0.5,
                  seed: int = 0) -> Pulses:
    """The pulses fired while flying ``trajectory`` with ``pattern``.

    Pulse ``k`` leaves at ``t_k = k / pulse_rate_hz`` from the start of the
    trajectory.  Choose them by number (``first``, ``count``; default every
    pulse) or by time (``start_s``, ``duration_s``: the pulses with ``t_k`` in
    ``[start_s, start_s + duration_s)``, ``pulse_rate_hz * duration_s`` of them).

    Parameters
    ----------
    trajectory : Trajectory
    pattern : ScanPattern
    sensor : Sensor, optional
        Gives the beam divergence for the footprints (default ``Sensor()``).
    first, count : int, optional
    start_s, duration_s : float, optional, seconds
    ground : float or callable, metres
        Height of a flat ground, or a DEM: ``ground(x, y) -> z`` over arrays.
    z_range : (2,) float, metres
        With a DEM: heights that bound it (the beams are marched through
        this band in steps of ``dem_step_m`` metres, then bisected).
    seed : int
        Base seed; pulse ``k`` gets ``seed + k`` (mod 2**64).

    Returns
    -------
    Pulses

    Examples
    --------
    >>> tr = Trajectory.line((0, 0), (100, 0), altitude_m=500.0, speed_mps=50.0)
    >>> pat = ScanPattern(kind="polygon", pulse_rate_hz=1000.0, scan_rate_hz=10.0, fov_deg=60.0)
    >>> p = survey_pulses(tr, pat, seed=7)
    >>> len(p), int(p.seed[3])
    (2000, 10)
    >>> round(float(p.target[0, 1]), 3)           # the first pulse of a line, 30 deg to the left
    288.675
    """
    if not isinstance(trajectory, Trajectory):
        raise InputError(f"trajectory must be a clsim.survey.Trajectory, got {type(trajectory).__name__}")
    if not isinstance(pattern, ScanPattern):
        raise InputError(f"pattern must be a clsim.survey.ScanPattern, got {type(pattern).__name__}")
    sensor = Sensor() if sensor is None else sensor
    if not isinstance(sensor, Sensor):
        raise InputError(f"sensor must be a clsim.Sensor (for its beam divergence), got {type(sensor).__name__}")
    seed = check_seed(seed)
    if not float(dem_step_m) > 0:
        raise InputError(f"dem_step_m must be > 0 m, got {dem_step_m!r}")
    first, count = pulse_range(pattern, trajectory, first, count, start_s, duration_s)

    index = np.arange(first, first + count, dtype=np.int64)
    t = index / pattern.pulse_rate_hz
    position, heading, leg = trajectory.at(t)
    body = pattern.body_directions(t) if count else np.empty((0, 3))
    h = np.radians(heading)
    fwd = np.stack([np.cos(h), np.sin(h), np.zeros_like(h)], axis=1)
    right = np.stack([np.sin(h), -np.cos(h), np.zeros_like(h)], axis=1)
    d = body[:, :1] * fwd + body[:, 1:2] * right
    d[:, 2] = body[:, 2]
    d /= np.linalg.norm(d, axis=1, keepdims=True) if count else 1.0
    rng = _hit_ground(position, d, ground, z_range, float(dem_step_m)) if count else np.empty(0)
    target = position + rng[:, None] * d
    if not callable(ground):
        target[:, 2] = float(ground)                      # exactly on the plane
    seeds = np.uint64(seed) + index.astype(np.uint64)     # wraps modulo 2**64
    return Pulses(
        index=index, seed=seeds, time_s=t, position=position, heading_deg=heading, leg=leg, direction=d,
        scan_angle_deg=np.degrees(np.arctan2(body[:, 1], -body[:, 2])),
        off_nadir_deg=np.degrees(np.arccos(np.clip(-d[:, 2], -1.0, 1.0))),
        azimuth_deg=np.degrees(np.arctan2(-d[:, 1], -d[:, 0])) % 360.0,
        target=target, range_m=rng,
        footprint_m=2.0 * rng * math.tan(sensor.divergence_mrad * 1e-3),
    )
