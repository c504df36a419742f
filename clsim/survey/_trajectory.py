"""The platform's path: straight legs flown at constant speed, one after another."""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from clsim.errors import InputError

__all__ = ["Leg", "Trajectory"]


def _point(value, name: str) -> tuple[float, float, float]:
    try:
        p = np.asarray(value, dtype=np.float64).ravel()
    except (TypeError, ValueError) as err:
        raise InputError(f"{name} must be (x, y, altitude) in metres, got {value!r}") from err
    if p.shape != (3,) or not np.all(np.isfinite(p)):
        raise InputError(f"{name} must be three finite numbers (x, y, altitude) in metres, got {value!r}")
    return float(p[0]), float(p[1]), float(p[2])


@dataclass(frozen=True)
class Leg:
    """One straight leg flown at constant speed.

    Parameters
    ----------
    start, end : (3,) float, metres
        x, y and altitude of the platform at the ends of the leg.  The altitude
        is the height above z = 0 of the scene frame (the flat ground's datum).
    speed_mps : float, m/s
        Speed along the leg (> 0).
    """

    start: tuple[float, float, float]
    end: tuple[float, float, float]
    speed_mps: float

    def __post_init__(self):
        object.__setattr__(self, "start", _point(self.start, "leg start"))
        object.__setattr__(self, "end", _point(self.end, "leg end"))
        try:
            v = float(self.speed_mps)
        except (TypeError, ValueError) as err:
            raise InputError(f"leg speed_mps must be a number in m/s, got {self.speed_mps!r}") from err
        if not (math.isfinite(v) and v > 0):
            raise InputError(f"leg speed_mps must be > 0 m/s, got {self.speed_mps!r}")
        object.__setattr__(self, "speed_mps", v)
        if min(self.start[2], self.end[2]) <= 0:
            raise InputError(f"leg altitude must be > 0 m (above the ground datum z = 0), got "
                             f"start={self.start[2]!r}, end={self.end[2]!r}")
        if math.hypot(self.end[0] - self.start[0], self.end[1] - self.start[1]) == 0:
            raise InputError(f"leg start and end must differ in x or y (the heading is the horizontal "
                             f"direction of flight), got start={self.start!r}, end={self.end!r}")

    @property
    def length_m(self) -> float:
        """Length of the leg, metres (3-D)."""
        return float(np.linalg.norm(np.subtract(self.end, self.start)))

    @property
    def duration_s(self) -> float:
        return self.length_m / self.speed_mps

    @property
    def heading_deg(self) -> float:
        """Direction of flight, degrees from +x towards +y, in [0, 360)."""
        h = math.degrees(math.atan2(self.end[1] - self.start[1], self.end[0] - self.start[0]))
        return h % 360.0


class Trajectory:
    """Straight legs flown one after another; turns between legs take no time
    and no pulse is fired in them.

    Parameters
    ----------
    legs : sequence of Leg

    Examples
    --------
    >>> tr = Trajectory.line((0.0, -100.0), (0.0, 100.0), altitude_m=400.0, speed_mps=50.0)
    >>> tr.duration_s
    4.0
    >>> pos, heading, leg = tr.at([0.0, 2.0])
    >>> pos[1].tolist(), heading.tolist()
    ([0.0, 0.0, 400.0], [90.0, 90.0])
    """

    def __init__(self, legs):
        legs = list(legs)
        if not legs or not all(isinstance(g, Leg) for g in legs):
            raise InputError(f"a trajectory needs one or more Leg, got {legs!r}")
        self.legs = tuple(legs)
        d = np.array([g.duration_s for g in legs])
        #: (n_legs + 1,) start time of each leg and the end of the last, seconds
        self.leg_start_s = np.concatenate([[0.0], np.cumsum(d)])
        self._start = np.array([g.start for g in legs])
        self._vel = np.array([np.subtract(g.end, g.start) / g.duration_s for g in legs])
        self._heading = np.array([g.heading_deg for g in legs])

    @classmethod
    def line(cls, start_xy, end_xy, *, altitude_m: float, speed_mps: float) -> Trajectory:
        """One level leg from ``start_xy`` to ``end_xy`` (metres) at ``altitude_m``."""
        (x0, y0), (x1, y1) = np.asarray(start_xy, float).ravel()[:2], np.asarray(end_xy, float).ravel()[:2]
        return cls([Leg((x0, y0, altitude_m), (x1, y1, altitude_m), speed_mps)])

    @classmethod
    def lawnmower(cls, start_xy, *, length_m: float, spacing_m: float, lines: int, heading_deg: float = 90.0,
                  altitude_m: float, speed_mps: float) -> Trajectory:
        """``lines`` parallel level legs of ``length_m``, ``spacing_m`` apart,
        flown back and forth; the first starts at ``start_xy`` heading
        ``heading_deg`` and the next lie to its right."""
        if int(lines) < 1:
            raise InputError(f"lines must be >= 1, got {lines!r}")
        if not float(length_m) > 0:
            raise InputError(f"length_m must be > 0, got {length_m!r}")
        h = math.radians(heading_deg)
        f = np.array([math.cos(h), math.sin(h)])
        r = np.array([math.sin(h), -math.cos(h)])
        p0 = np.asarray(start_xy, float).ravel()[:2]
        legs = []
        for k in range(int(lines)):
            a = p0 + k * float(spacing_m) * r
            b = a + float(length_m) * f
            if k % 2:
                a, b = b, a
            legs.append(Leg((*a, altitude_m), (*b, altitude_m), speed_mps))
        return cls(legs)

    @property
    def duration_s(self) -> float:
        """Time to fly every leg, seconds."""
        return float(self.leg_start_s[-1])

    def at(self, t) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Platform position, heading and leg at times ``t``.

        Parameters
        ----------
        t : (N,) float, seconds from the start of the first leg, in [0, duration_s]

        Returns
        -------
        position : (N, 3) float64, metres (x, y, altitude)
        heading_deg : (N,) float64, degrees from +x towards +y
        leg : (N,) int64, index of the leg flown
        """
        t = np.atleast_1d(np.asarray(t, dtype=np.float64))
        if t.size and not (np.all(np.isfinite(t)) and t.min() >= 0 and t.max() <= self.duration_s * (1 + 1e-12)):
            raise InputError(f"times must lie in [0, {self.duration_s!r}] s (the trajectory's duration), "
                             f"got [{t.min()!r}, {t.max()!r}]")
        leg = np.clip(np.searchsorted(self.leg_start_s, t, side="right") - 1, 0, len(self.legs) - 1)
        dt = (t - self.leg_start_s[leg])[:, None]
        return self._start[leg] + dt * self._vel[leg], self._heading[leg], leg.astype(np.int64)

    def __repr__(self) -> str:
        return f"Trajectory({len(self.legs)} legs, {self.duration_s:.3f} s)"
