"""A single flight line over the middle of a box, its swath spanning the box."""

from __future__ import annotations

import math
from typing import NamedTuple

import numpy as np

from clsim.errors import InputError
from clsim.survey._pattern import Flight, ScanPattern, typical_flight
from clsim.survey._trajectory import Trajectory

__all__ = ["CentreLine", "centre_line"]


class CentreLine(NamedTuple):
    """What :func:`centre_line` plans."""

    trajectory: Trajectory
    pattern: ScanPattern
    first: int          #: the first of the ``count`` pulses, centred on the box
    fov_deg: float      #: the field of view that spans the box across track
    flight: Flight      #: the preset's flying height and speed


def centre_line(lo, hi, preset, *, count: int, fill: bool = False, line_spacing_m: float | None = None) -> CentreLine:
    """One level line along x through the middle of the box ``lo .. hi``, at
    the preset's typical flying height and speed, its field of view set so
    that the swath on the ground (z = 0) spans the box's y extent.

    Parameters
    ----------
    lo, hi : sequence of float, metres
        Corners of the box; only x and y are used (a scene's ``origin`` and
        ``origin + voxel_size * shape`` will do).
    preset : str or Path
        Sensor preset (name or ``.toml``) whose ``[survey]`` table gives the
        scan pattern and :func:`typical_flight`.
    count : int
        Pulses to fly over the box.
    fill : bool
        True: the pulse rate is lowered or raised so that ``count`` pulses
        exactly span the box's x extent and the line is that long.  False: the
        preset's pulse rate; the line is as long as the box or as long as
        ``count`` pulses need, whichever is longer.
    line_spacing_m : float or None
        Scan lines this far apart along track (the scan rate is speed /
        spacing); None keeps the preset's scan rate.

    Returns
    -------
    CentreLine
        ``(trajectory, pattern, first, fov_deg, flight)``: fly pulses
        ``first .. first + count - 1`` (as ``SurveyJob(first=, count=)`` or
        ``survey_pulses(first=, count=)`` take them).

    Examples
    --------
    >>> c = centre_line((-10, -5), (10, 5), "riegl-lms-q680i", count=1000, fill=True)
    >>> round(c.fov_deg, 3), c.first, round(c.trajectory.duration_s * c.pattern.pulse_rate_hz)
    (0.955, 0, 1000)
    """
    lo = np.asarray(lo, dtype=np.float64).ravel()[:2]
    hi = np.asarray(hi, dtype=np.float64).ravel()[:2]
    if lo.size < 2 or hi.size < 2:
        raise InputError(f"the box corners need x and y (metres), got lo={lo.tolist()}, hi={hi.tolist()}")
    width, depth = hi - lo
    if not (np.all(np.isfinite(lo)) and np.all(np.isfinite(hi)) and width > 0 and depth > 0):
        raise InputError(f"the box must have hi > lo in x and y (metres), got lo={lo.tolist()}, hi={hi.tolist()}")
    if int(count) < 1:
        raise InputError(f"count must be >= 1 pulse, got {count!r}")
    flight = typical_flight(preset)
    H, v = flight
    fov = 2.0 * math.degrees(math.atan(0.5 * depth / H))
    overrides = {"fov_deg": fov}
    if fill:
        overrides["pulse_rate_hz"] = count * v / width
    if line_spacing_m is not None:
        if not (math.isfinite(line_spacing_m) and line_spacing_m > 0):
            raise InputError(f"line_spacing_m must be > 0 m, got {line_spacing_m!r}")
        overrides["scan_rate_hz"] = v / line_spacing_m
    pattern = ScanPattern.preset(preset, **overrides)
    length = width if fill else max(width, 1.001 * count * v / pattern.pulse_rate_hz)
    xm, ym = lo + 0.5 * (hi - lo)
    tr = Trajectory.line((xm - 0.5 * length, ym), (xm + 0.5 * length, ym), altitude_m=H, speed_mps=v)
    first = max(0, int((tr.duration_s * pattern.pulse_rate_hz - count) / 2))
    return CentreLine(tr, pattern, first, fov, flight)
