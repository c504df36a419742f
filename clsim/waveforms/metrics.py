"""Waveform metrics and the comparison of a simulated with a reference waveform.

All functions take plain arrays ``time_ns, waveform`` (samples at increasing
times, baseline already removed or given), so they serve measured (NEON,
LAS, PulseWaves) and simulated waveforms alike.

- Ground peak: the last local maximum that reaches ``min_fraction`` of the
  waveform maximum, refined to sub-sample precision by a parabola through the
  logarithm of the three samples around it (exact for a Gaussian peak).
- Alignment: shift one waveform in time so that the ground peaks coincide,
  then resample (linear interpolation) on the other's time grid.
- Similarity after normalisation (unit energy by default): Pearson r and RMSE.
- Canopy / ground energy ratio: ground energy by mirroring the ground return
  about its peak (twice the energy from the ground peak on), canopy = total -
  ground (the "mirror" method used with LVIS waveforms).
- Relative heights RH_p: height above the ground peak (c/2 per ns) at which
  the energy accumulated from the end of the waveform (the bottom) reaches
  p percent (Blair et al. 1999; Dubayah et al. 2020 for GEDI).

References
----------
Blair, J. B., Rabine, D. L. & Hofton, M. A. (1999). The Laser Vegetation
    Imaging Sensor: a medium-altitude, digitisation-only, airborne laser
    altimeter for mapping vegetation and topography. ISPRS J. 54(2-3), 115-122.
    doi:10.1016/S0924-2716(99)00002-7
Dubayah, R. et al. (2020). The Global Ecosystem Dynamics Investigation:
    high-resolution laser ranging of the Earth's forests and topography.
    Science of Remote Sensing 1, 100002. doi:10.1016/j.srs.2020.100002
Ni-Meister, W., Jupp, D. L. B. & Dubayah, R. (2001). Modeling lidar waveforms
    in heterogeneous and discrete canopies. IEEE TGRS 39(9), 1943-1958.
    doi:10.1109/36.951085
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from clsim.errors import InputError
from voxlidar.choices import Choice

__all__ = [
    "Normalization",
    "WaveformComparison",
    "align_on_ground",
    "canopy_ground_ratio",
    "compare_waveforms",
    "ground_peak_ns",
    "normalize",
    "pearson_r",
    "relative_heights",
]

#: Half the speed of light in air, m per ns of round-trip time.
C_HALF_M_PER_NS = 0.299792458 / 2.0 / 1.000293


class Normalization(str, Choice):
    """How waveforms are scaled before they are compared."""

    ENERGY = "energy"  # unit integral
    PEAK = "peak"  # unit maximum
    NONE = "none"



def _pair(time_ns, waveform, name="waveform"):
    t = np.asarray(time_ns, dtype=np.float64).reshape(-1)
    w = np.asarray(waveform, dtype=np.float64).reshape(-1)
    if t.size != w.size:
        raise InputError(f"time_ns has {t.size} samples but {name} has {w.size}; give one time "
                         "per sample")
    if t.size < 3:
        raise InputError(f"{name} needs at least 3 samples; got {t.size}")
    if not (np.all(np.isfinite(t)) and np.all(np.isfinite(w))):
        raise InputError(f"time_ns and {name} must be finite (no NaN/inf)")
    if np.any(np.diff(t) <= 0):
        raise InputError("time_ns must increase strictly; sort the samples by time")
    return t, w


def _energy(t, w) -> float:
    return float(np.trapezoid(w, t)) if hasattr(np, "trapezoid") else float(np.trapz(w, t))


def normalize(time_ns, waveform, *, method="energy") -> np.ndarray:
    """Scale a waveform to unit energy (integral over time) or unit peak.

    Examples
    --------
    >>> normalize([0, 1, 2], [0, 2, 0], method="peak").tolist()
    [0.0, 1.0, 0.0]
    """
    t, w = _pair(time_ns, waveform)
    m = Normalization.parse(method, "normalize")
    if m is Normalization.NONE:
        return w.copy()
    scale = _energy(t, w) if m is Normalization.ENERGY else float(np.max(w))
    if not scale > 0:
        raise InputError(f"cannot normalise to unit {m.value}: the waveform's {m.value} is "
                         f"{scale}; is the baseline removed and is there any signal?")
    return w / scale


_normalize = normalize  # compare_waveforms has a parameter of the same name


def ground_peak_ns(time_ns, waveform, *, min_fraction: float = 0.05) -> float:
    """Time of the ground return: the last peak reaching ``min_fraction`` of the maximum.

    Parameters
    ----------
    time_ns, waveform : (n,) array_like
        Baseline-removed waveform.
    min_fraction : float
        A peak counts when it reaches this fraction of the waveform maximum.

    Returns
    -------
    float, ns (sub-sample: Gaussian interpolation through three samples)

    Examples
    --------
    >>> t = np.arange(0.0, 60.0)
    >>> w = np.exp(-0.5 * ((t - 10) / 2) ** 2) + 0.5 * np.exp(-0.5 * ((t - 40.3) / 2) ** 2)
    >>> round(ground_peak_ns(t, w), 6)
    40.3
    """
    t, w = _pair(time_ns, waveform)
    if not 0 < min_fraction <= 1:
        raise InputError(f"min_fraction must be in (0, 1]; got {min_fraction}")
    top = float(np.max(w))
    if not top > 0:
        raise InputError("the waveform has no positive signal; remove the baseline first or "
                         "check the data")
    inner = (w[1:-1] >= w[:-2]) & (w[1:-1] > w[2:]) & (w[1:-1] >= min_fraction * top)
    idx = np.flatnonzero(inner) + 1
    if idx.size == 0:
        i = int(np.argmax(w))
    else:
        i = int(idx[-1])
    if 0 < i < w.size - 1 and np.all(w[i - 1:i + 2] > 0):
        y0, y1, y2 = np.log(w[i - 1:i + 2])
        denom = y0 - 2 * y1 + y2
        frac = 0.5 * (y0 - y2) / denom if denom < 0 else 0.0
        frac = float(np.clip(frac, -1.0, 1.0))
        dt = t[i + 1] - t[i] if frac > 0 else t[i] - t[i - 1]
        return float(t[i] + frac * dt)
    return float(t[i])


def align_on_ground(time_ns, waveform, ref_time_ns, ref_waveform, *, min_fraction=0.05):
    """Shift ``waveform`` in time so its ground peak falls on the reference's.

    Returns
    -------
    shifted : (m,) float64
        ``waveform`` resampled on ``ref_time_ns`` after the shift (0 outside).
    shift_ns : float
        Time added to ``time_ns``.
    """
    t, w = _pair(time_ns, waveform)
    rt, _rw = _pair(ref_time_ns, ref_waveform, "ref_waveform")
    shift = (ground_peak_ns(rt, _rw, min_fraction=min_fraction)
             - ground_peak_ns(t, w, min_fraction=min_fraction))
    return np.interp(rt, t + shift, w, left=0.0, right=0.0), float(shift)


def pearson_r(a, b) -> float:
    """Pearson correlation of two equal-length sample vectors.

    Examples
    --------
    >>> round(pearson_r([1, 2, 3], [2, 4, 6]), 12)
    1.0
    """
    x = np.asarray(a, dtype=np.float64).reshape(-1)
    y = np.asarray(b, dtype=np.float64).reshape(-1)
    if x.size != y.size or x.size < 2:
        raise InputError(f"pearson_r needs two vectors of the same length >= 2; got {x.size} "
                         f"and {y.size}")
    x = x - x.mean()
    y = y - y.mean()
    den = np.sqrt((x @ x) * (y @ y))
    if den == 0:
        raise InputError("pearson_r is undefined for a constant waveform")
    return float((x @ y) / den)


def canopy_ground_ratio(time_ns, waveform, *, ground_time_ns=None,
                        min_fraction: float = 0.05) -> float:
    """Canopy to ground return energy ratio (mirror method).

    Ground energy is twice the energy from the ground peak to the end of the
    waveform; canopy energy is the rest.

    Examples
    --------
    >>> t = np.arange(0.0, 100.0, 0.05)
    >>> g = lambda a, m, s: a * np.exp(-0.5 * ((t - m) / s) ** 2)
    >>> round(canopy_ground_ratio(t, g(1.0, 30, 4) + g(2.0, 70, 2)), 4)
    1.0
    """
    t, w = _pair(time_ns, waveform)
    tg = ground_peak_ns(t, w, min_fraction=min_fraction) if ground_time_ns is None else float(
        ground_time_ns)
    total = _energy(t, w)
    after = t >= tg
    tail_t = np.concatenate(([tg], t[after]))
    tail_w = np.concatenate(([np.interp(tg, t, w)], w[after]))
    ground = 2.0 * _energy(tail_t, tail_w)
    if not ground > 0:
        raise InputError("no ground energy found (nothing after the ground peak)")
    return float((total - ground) / ground)


def relative_heights(time_ns, waveform, *, percentiles=(25, 50, 75, 98), ground_time_ns=None,
                     min_fraction: float = 0.05) -> dict:
    """Relative heights RH_p above the ground peak, metres.

    Parameters
    ----------
    time_ns, waveform : (n,) array_like
        Baseline-removed, non-negative waveform (negative samples count as 0).
    percentiles : sequence of float in [0, 100]
    ground_time_ns : float, optional
        Ground peak time; default :func:`ground_peak_ns`.

    Returns
    -------
    dict {p: height_m}
    """
    t, w = _pair(time_ns, waveform)
    w = np.clip(w, 0.0, None)
    ps = np.asarray(percentiles, dtype=np.float64).reshape(-1)
    if np.any((ps < 0) | (ps > 100)):
        raise InputError(f"percentiles must be within 0-100; got {ps.tolist()}")
    tg = ground_peak_ns(t, w, min_fraction=min_fraction) if ground_time_ns is None else float(
        ground_time_ns)
    # cumulative energy from the end (bottom) toward the start, trapezoids
    seg = 0.5 * (w[1:] + w[:-1]) * np.diff(t)
    cum_from_end = np.concatenate((np.cumsum(seg[::-1])[::-1], [0.0]))
    total = cum_from_end[0]
    if not total > 0:
        raise InputError("the waveform has no energy; remove the baseline first")
    frac = cum_from_end / total  # decreasing with t
    heights = (tg - t) * C_HALF_M_PER_NS
    out = {}
    for p in ps:
        out[float(p)] = float(np.interp(p / 100.0, frac[::-1], heights[::-1]))
    return out


@dataclass
class WaveformComparison:
    """Result of :func:`compare_waveforms`.

    Attributes
    ----------
    pearson_r : float
    rmse : float
        RMSE of the normalised waveforms (unit 1/ns for energy normalisation).
    shift_ns : float
        Time added to the simulated waveform to align the ground peaks.
    ratio, ref_ratio : float
        Canopy/ground energy ratios of the simulated and reference waveforms.
    rh, ref_rh : dict
        Relative heights (m) of both.
    """

    pearson_r: float
    rmse: float
    shift_ns: float
    ratio: float
    ref_ratio: float
    rh: dict
    ref_rh: dict


def compare_waveforms(time_ns, waveform, ref_time_ns, ref_waveform, *, align: bool = True,
                      normalize="energy", min_fraction: float = 0.05) -> WaveformComparison:
    """Compare a (simulated) waveform with a reference (measured) one.

    Both must be baseline-removed. The waveform is aligned on the reference's
    ground peak (if ``align``), resampled on the reference time grid,
    normalised (``"energy"``, ``"peak"`` or ``"none"``), and scored.

    Returns
    -------
    WaveformComparison
    """
    method = Normalization.parse(normalize, "normalize")
    t, w = _pair(time_ns, waveform)
    rt, rw = _pair(ref_time_ns, ref_waveform, "ref_waveform")
    if align:
        ws, shift = align_on_ground(t, w, rt, rw, min_fraction=min_fraction)
    else:
        ws, shift = np.interp(rt, t, w, left=0.0, right=0.0), 0.0
    a = _normalize(rt, ws, method=method)
    b = _normalize(rt, rw, method=method)
    return WaveformComparison(
        pearson_r=pearson_r(a, b), rmse=float(np.sqrt(np.mean((a - b) ** 2))), shift_ns=shift,
        ratio=canopy_ground_ratio(t, w, min_fraction=min_fraction),
        ref_ratio=canopy_ground_ratio(rt, rw, min_fraction=min_fraction),
        rh=relative_heights(t, w, min_fraction=min_fraction),
        ref_rh=relative_heights(rt, rw, min_fraction=min_fraction))
