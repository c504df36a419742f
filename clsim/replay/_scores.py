"""Scores of a predicted waveform against the measured one, on the measured record's samples.

Every method (the simulation, the baselines) predicts each test pulse's
waveform on the record's own samples, in the file's units with the baseline
removed; :func:`score_pulse` compares the two:

- ``r``: Pearson correlation on the recorded samples, as predicted (the time
  offset is the calibration's, fitted on training pulses only);
- ``r_best`` and ``lag_ns``: the best correlation over whole-sample shifts of
  the prediction within ``max_lag_ns``, and that shift (positive: the
  prediction is late);
- ``energy_ratio``: predicted over measured energy (sums of the samples);
- ``rh25 .. rh98``: relative heights, metres above the measured record's
  lowest significant peak (the ground echo when the record reaches the ground,
  else its lowest canopy echo), the same reference for the measured and the
  predicted waveform, so their difference is the predicted energy quantile's
  height error (:func:`clsim.waveforms.metrics.relative_heights`);
- ``cover``: canopy cover, one minus the lowest echo's mirrored energy over
  the total (:func:`clsim.waveforms.metrics.canopy_ground_ratio`, the LVIS
  "mirror" method), for both; clipped to 0-1, since the mirror doubles the
  trailing half of the lowest echo, and a system's long tail can make that
  more than the whole record.

References
----------
Blair, J. B. & Hofton, M. A. (1999). Modeling laser altimeter return
    waveforms over complex vegetation using high-resolution elevation data.
    Geophys. Res. Lett. 26(16), 2509-2512. doi:10.1029/1999GL010484
Hancock, S. et al. (2019). The GEDI simulator: a large-footprint waveform
    lidar simulator for calibration and validation of spaceborne missions.
    Earth and Space Science 6, 294-310. doi:10.1029/2018EA000506
"""

from __future__ import annotations

import numpy as np

from clsim.errors import InputError
from clsim.waveforms.metrics import canopy_ground_ratio, ground_peak_ns, relative_heights

__all__ = ["PERCENTILES", "score_pulse", "summarize"]

#: Relative-height percentiles scored.
PERCENTILES = (25, 50, 75, 98)


def _pearson(a, b) -> float:
    a = a - a.mean()
    b = b - b.mean()
    den = float(np.sqrt((a * a).sum() * (b * b).sum()))
    return float((a * b).sum() / den) if den > 0 else float("nan")


def _shifted(pred: np.ndarray, lag: int) -> np.ndarray:
    """``pred`` delayed by ``lag`` samples (zeros shifted in)."""
    out = np.zeros_like(pred)
    if lag >= 0:
        out[lag:] = pred[: pred.size - lag]
    else:
        out[:lag] = pred[-lag:]
    return out


def _heights(t, w, tg):
    w = np.clip(w, 0.0, None)
    if not w.sum() > 0:
        return {p: float("nan") for p in PERCENTILES}, float("nan")
    rh = relative_heights(t, w, percentiles=PERCENTILES, ground_time_ns=tg)
    try:
        ratio = canopy_ground_ratio(t, w, ground_time_ns=tg)
        # the mirror doubles the lowest echo's trailing half: with a system's long tail it can pass the total
        cover = float(np.clip(ratio / (1.0 + ratio), 0.0, 1.0)) if ratio > -1.0 else 0.0
    except InputError:
        cover = float("nan")
    return rh, cover


def score_pulse(measured, predicted, *, dt_ns: float = 1.0, max_lag_ns: float = 5.0) -> dict:
    """Scores of one predicted waveform against the measured one.

    Parameters
    ----------
    measured : (S,) float, counts above the baseline
        The recorded samples (padding and no-data fill already dropped).
    predicted : (S,) float, counts above the baseline
        The prediction on the same samples.
    dt_ns : float
        Sample spacing, ns.
    max_lag_ns : float
        Largest shift searched for ``r_best``.

    Returns
    -------
    dict
        ``r, r_best, lag_ns, energy_ratio, cover, cover_measured``, and
        ``rh{p}`` (predicted) and ``rh{p}_measured`` for each percentile, metres.
    """
    y = np.asarray(measured, dtype=np.float64).reshape(-1)
    s = np.asarray(predicted, dtype=np.float64).reshape(-1)
    if y.shape != s.shape or y.size < 4:
        raise InputError(f"measured ({y.size}) and predicted ({s.size}) need the same samples, at least 4")
    t = dt_ns * np.arange(y.size)
    out = {"r": _pearson(y, s)}
    best, lag = -np.inf, 0
    for k in range(-int(max_lag_ns / dt_ns), int(max_lag_ns / dt_ns) + 1):
        r = _pearson(y, _shifted(s, k))
        if r > best:
            best, lag = r, k
    out["r_best"] = float(best) if np.isfinite(best) else float("nan")
    out["lag_ns"] = float(-lag * dt_ns)  # the shift that aligns it, negated: > 0 for a late prediction
    ey = float(y.sum())
    out["energy_ratio"] = float(s.sum() / ey) if ey > 0 else float("nan")
    yc = np.clip(y, 0.0, None)
    tg = ground_peak_ns(t, yc) if yc.max() > 0 else float("nan")
    rh_m, cover_m = _heights(t, y, tg)
    rh_s, cover_s = _heights(t, s, tg)
    for p in PERCENTILES:
        out[f"rh{p}"] = float(rh_s[p])
        out[f"rh{p}_measured"] = float(rh_m[p])
    out["cover"] = float(cover_s)
    out["cover_measured"] = float(cover_m)
    return out


def summarize(rows: list[dict]) -> dict:
    """Overall scores of many pulses' :func:`score_pulse` rows.

    Returns
    -------
    dict
        ``pulses``; ``r_median``, ``r_best_median``, ``lag_median_ns``;
        ``energy_ratio_median``, ``energy_ratio_q25``, ``energy_ratio_q75``;
        per percentile ``rh{p}_bias`` (median of predicted minus measured),
        ``rh{p}_mae`` (median absolute error), ``rh{p}_rmse``; ``cover_bias``
        and ``cover_mae`` (fractions).
    """
    if not rows:
        raise InputError("no pulses to summarise")

    def col(k):
        return np.array([r[k] for r in rows], dtype=np.float64)

    def med(a):
        a = a[np.isfinite(a)]
        return float(np.median(a)) if a.size else float("nan")

    out = {"pulses": len(rows), "r_median": med(col("r")), "r_best_median": med(col("r_best")),
           "lag_median_ns": med(col("lag_ns"))}
    e = col("energy_ratio")
    e = e[np.isfinite(e)]
    out["energy_ratio_median"] = float(np.median(e)) if e.size else float("nan")
    out["energy_ratio_q25"], out["energy_ratio_q75"] = (
        (float(np.percentile(e, 25)), float(np.percentile(e, 75))) if e.size else (float("nan"),) * 2)
    for p in PERCENTILES:
        d = col(f"rh{p}") - col(f"rh{p}_measured")
        d = d[np.isfinite(d)]
        out[f"rh{p}_bias"] = float(np.median(d)) if d.size else float("nan")
        out[f"rh{p}_mae"] = float(np.median(np.abs(d))) if d.size else float("nan")
        out[f"rh{p}_rmse"] = float(np.sqrt(np.mean(d * d))) if d.size else float("nan")
    d = col("cover") - col("cover_measured")
    d = d[np.isfinite(d)]
    out["cover_bias"] = float(np.median(d)) if d.size else float("nan")
    out["cover_mae"] = float(np.median(np.abs(d))) if d.size else float("nan")
    return out
