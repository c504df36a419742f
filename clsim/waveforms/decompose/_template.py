"""Echoes as the instrument sees them: decomposition with the system's own pulse as the template.

A real system's return from a hard target is not a Gaussian: it rings, it
trails, it undershoots.  A Gaussian decomposition fits that shape with extra
Gaussians behind every strong echo, which are not targets.  Here each echo is
the measured system response itself (a hard target's return, or the file's
own strongest single returns), shifted and scaled:

.. math::  y(t) = b + \\sum_k E_k\\, h(t - \\tau_k)

with ``h`` of unit sum and its peak at lag 0.  The energies on a grid of
shifts (half a sample apart) are the non-negative least-squares solution
(Lawson & Hanson 1974) above the waveform's robust baseline ``b``; runs of neighbouring
non-zero shifts are one echo (its energy the run's sum, its time the
energy-weighted mean shift; an extended target spreads over several shifts).
An echo is kept when its matched-filter signal-to-noise ratio
``E ||h||_2 / sigma_eff`` passes the detection threshold of
:func:`clsim.waveforms.decompose._matched.threshold` for the false-alarm
rate (the noise ``sigma`` at least one digitiser step: a slowly varying
record's rounding error is not white; and at least what the filter itself
reads over the record's quiet stretches, where a slow baseline wander shows),
where ``sigma_eff^2 = sigma^2 + (tolerance * m)^2`` adds to the noise a
share ``tolerance`` of the other echoes' model ``m`` at its time: the pulse
changes a little from shot to shot, and the misfit of a strong echo's tail
must not pass for a weak echo.

References
----------
Lawson, C. L. & Hanson, R. J. (1974). Solving Least Squares Problems.
    Prentice-Hall, ch. 23 (NNLS).
Hofton, M. A., Minster, J. B. & Blair, J. B. (2000). Decomposition of laser
    altimeter waveforms. IEEE TGRS 38(4), 1989-1996. doi:10.1109/36.851780
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from clsim.errors import InputError
from clsim.waveforms.decompose._matched import FALSE_ALARM, Pulse, clipped_baseline, threshold
from clsim.waveforms.decompose._noise import _gaps, noise_level

__all__ = ["TemplateEchoes", "decompose_template", "subsample_peak", "template_from_returns"]

#: Shifts per sample of the template grid.
_GRID = 2
#: Default share of the model that counts as noise near strong echoes.
TOLERANCE = 0.05


@dataclass(frozen=True)
class TemplateEchoes:
    """Echoes of N waveforms, each the system template shifted and scaled; one row per echo.

    Attributes
    ----------
    waveform : (E,) int64
        Waveform of each echo, sorted by waveform then time.
    location_ns : (E,) float64
        Time of the echo's template peak, ns on the waveform clock.
    energy : (E,) float64
        Echo energy above the baseline, sample units x ns (the template has unit area).
    amplitude : (E,) float64
        Peak height above the baseline, sample units.
    extent_ns : (E,) float64
        Energy-weighted spread (standard deviation) of the echo's shifts, ns:
        about 0 for a hard target, more for a target extended in range.
    snr : (E,) float64
        Matched-filter signal-to-noise ratio of each echo.
    baseline, noise_sigma : (N,) float64
    """

    waveform: np.ndarray
    location_ns: np.ndarray
    energy: np.ndarray
    amplitude: np.ndarray
    extent_ns: np.ndarray
    snr: np.ndarray
    baseline: np.ndarray
    noise_sigma: np.ndarray

    def __len__(self) -> int:
        return int(self.baseline.size)

    @property
    def counts(self) -> np.ndarray:
        """(N,) echoes per waveform."""
        return np.bincount(self.waveform, minlength=len(self))


def _unit_template(template, name="template"):
    h = np.asarray(template, dtype=np.float64).reshape(-1)
    if h.size < 3 or not np.all(np.isfinite(h)):
        raise InputError(f"{name} must be a finite 1-D array of at least 3 samples (a hard target's return)")
    h = np.clip(h - min(0.0, float(np.median(h[:2]))), 0.0, None) if h.min() < 0 else np.clip(h, 0.0, None)
    if not h.max() > 0:
        raise InputError(f"{name} has no positive samples: pass the system's return from a hard target, baseline "
                         "removed")
    above = np.flatnonzero(h >= 0.01 * h.max())
    h = h[above[0]: above[-1] + 1]
    return h / h.sum(), subsample_peak(h)


def subsample_peak(h) -> float:
    """Position of the maximum of ``h``, samples, refined by a parabola through the three samples around it."""
    h = np.asarray(h, dtype=np.float64)
    i = int(np.argmax(h))
    if 0 < i < h.size - 1:
        a, b, c = h[i - 1: i + 2]
        den = a - 2 * b + c
        if den < 0:
            return i + 0.5 * (a - c) / den
    return float(i)


def template_from_returns(waveforms, *, count: int = 20, width: int = 40) -> np.ndarray:
    """A system template from a file's own returns: the median of its strongest single-peaked waveforms.

    For files that record no outgoing pulse or impulse response (the Leica
    LAS 1.3 tile): each of the ``count`` waveforms with the highest peak whose
    samples above half that peak form one run (one hard return) is cut
    ``width`` samples either side of its peak, scaled to unit peak and the
    median taken sample by sample.

    Parameters
    ----------
    waveforms : sequence of (n_i,) array_like
    count, width : int

    Returns
    -------
    (2 width,) float64, unit peak at index ``width``, baseline removed
    """
    picks = []
    for w in waveforms:
        y = np.asarray(w, dtype=np.float64)
        if y.size < 8:
            continue
        b, s = noise_level(y)
        y = y - b
        p = int(np.argmax(y))
        if y[p] < 20 * s or p < 3 or p > y.size - 4:
            continue
        half = np.flatnonzero(y >= 0.5 * y[p])
        if half[-1] - half[0] + 1 != half.size:  # two returns above half height
            continue
        picks.append((y[p], y, p))
    if len(picks) < 3:
        raise InputError(f"found {len(picks)} strong single returns to build a template from (need 3); pass the "
                         "system's impulse response")
    picks.sort(key=lambda t: -t[0])
    stack = []
    for top, y, p in picks[:count]:
        seg = np.zeros(2 * width)
        lo, hi = max(0, p - width), min(y.size, p + width)
        seg[lo - p + width: hi - p + width] = y[lo:hi] / top
        stack.append(seg)
    return np.clip(np.median(np.array(stack), axis=0), 0.0, None)


def _design(n: int, h: np.ndarray, peak: float, shifts: np.ndarray) -> np.ndarray:
    t = np.arange(n)[:, None] - shifts[None, :] + peak
    return np.interp(t, np.arange(h.size), h, left=0.0, right=0.0)


def decompose_template(waveforms, template, *, dt_ns: float = 1.0, t0_ns=0.0, false_alarm: float = FALSE_ALARM,
                       tolerance: float = TOLERANCE, merge_ns: float | None = None,
                       min_relative: float = 0.0) -> TemplateEchoes:
    """Decompose waveforms into shifted, scaled copies of the system template (module docstring).

    Parameters
    ----------
    waveforms : (N, n) array_like or sequence of (n_i,) array_like
        Raw samples (baseline included); exact zeros far below the baseline
        are no-data fill and are left out.
    template : (m,) array_like
        The system's return from a hard target (baseline removed), on the
        same sample clock; see :func:`template_from_returns` when the file
        has none.
    dt_ns : float
        Sample spacing, ns.
    t0_ns : float or (N,) array_like
        Time of each waveform's first sample, ns.
    false_alarm : float
        Expected false echoes per noise-only waveform.
    tolerance : float
        Share of the model counted as noise near other echoes (shot-to-shot
        change of the pulse), 0 to switch off.
    min_relative : float
        Drop echoes whose peak is under this share of the waveform's
        strongest echo (0: keep every significant echo, as a scene that needs
        all the energy does; an instrument's own discrete returns seldom go
        below a few per cent, docs/bench/decompose_returns.md).
    merge_ns : float, optional
        Non-zero shifts closer than this are one echo; default the template's
        Gaussian-equivalent standard deviation (FWHM / 2.355): two targets
        closer than that are not resolved by the pulse.

    Returns
    -------
    TemplateEchoes
    """
    if not dt_ns > 0:
        raise InputError(f"dt_ns must be > 0, got {dt_ns!r}")
    if not 0 < false_alarm < 1:
        raise InputError(f"false_alarm must be in (0, 1), got {false_alarm!r}")
    if not 0 <= tolerance < 1:
        raise InputError(f"tolerance must be in [0, 1), got {tolerance!r}")
    if not 0 <= min_relative < 1:
        raise InputError(f"min_relative must be in [0, 1), got {min_relative!r}")
    from scipy.optimize import nnls

    h, peak = _unit_template(template)
    rows = [np.asarray(w, dtype=np.float64).reshape(-1) for w in waveforms]
    if not rows:
        raise InputError("no waveforms to decompose")
    t0 = np.broadcast_to(np.asarray(t0_ns, dtype=np.float64), (len(rows),))
    unit = Pulse.measured(h)
    gap = unit.sigma if merge_ns is None else float(merge_ns) / dt_ns
    if not gap >= 0:
        raise InputError(f"merge_ns must be >= 0 ns, got {merge_ns!r}")
    hnorm = float(np.sqrt((h * h).sum()))
    cols = {k: [] for k in ("waveform", "location_ns", "energy", "amplitude", "extent_ns", "snr")}
    base, noise = np.zeros(len(rows)), np.zeros(len(rows))
    for i, y in enumerate(rows):
        if y.size < 4 or not np.all(np.isfinite(y)):
            raise InputError(f"waveform {i} needs at least 4 finite samples, got {y.size}")
        ok = _gaps(y)
        ok = np.ones(y.size, bool) if ok is None else ok
        b, s = noise_level(y[ok])
        b = clipped_baseline(y[ok], s, b)  # the lowest fifth's median sits about 1.3 sigma under the noise's mean
        # a record that sits still between steps of the digitiser has no white noise to average: its rounding
        # error follows the slow signal and a matched filter does not beat it down; floor at one step
        steps = np.abs(np.diff(y[ok]))
        steps = steps[steps > 0]
        s = max(s, float(steps.min()) if steps.size else 0.0)
        base[i], noise[i] = b, s
        shifts = np.arange(-2 * _GRID, _GRID * (y.size + 1)) / _GRID
        A = _design(y.size, h, peak, shifts)[ok]
        e, _ = nnls(A, y[ok] - b, maxiter=50 * A.shape[1])
        nz = np.flatnonzero(e > 1e-9 * max(e.max(initial=0.0), 1e-300))
        if not nz.size:
            continue
        runs = np.split(nz, np.flatnonzero(np.diff(shifts[nz]) > max(gap, 1.0 / _GRID) + 1e-9) + 1)
        energy = np.array([e[r].sum() for r in runs])
        loc = np.array([(e[r] * shifts[r]).sum() for r in runs]) / energy
        ext = np.array([np.sqrt(max((e[r] * (shifts[r] - m) ** 2).sum() / w, 0.0)) for r, m, w in zip(runs, loc, energy)])
        model = [(_design(y.size, h, peak, shifts[r]) @ e[r]) for r in runs]
        total = np.sum(model, axis=0)
        u = threshold(int(ok.sum()), unit, false_alarm=false_alarm)
        peaks = np.array([m.max() for m in model])
        # the noise as the matched filter sees it: its output over the record's quiet stretches (no sample
        # 3 sigma off the baseline under the template), which holds a slow wander that white noise does not
        sigma_e = s / hnorm
        yb = np.where(ok, y - b, 0.0)
        loud = np.convolve((np.abs(yb) > 3.0 * s).astype(float), np.ones(h.size), mode="full")[h.size - 1:]
        quiet = np.flatnonzero(loud[: max(y.size - h.size + 1, 0)] == 0)
        if quiet.size >= 10:
            est = np.correlate(yb, h, mode="valid")[quiet] / float((h * h).sum())
            sigma_e = max(sigma_e, 1.4826 * float(np.median(np.abs(est - np.median(est)))))
        for k, r in enumerate(runs):
            if peaks[k] < min_relative * peaks.max():
                continue
            at = int(np.clip(round(loc[k]), 0, y.size - 1))
            others = total[at] - model[k][at]
            snr = energy[k] / np.sqrt(sigma_e ** 2 + (tolerance * others / hnorm) ** 2)
            if snr < u:
                continue
            cols["waveform"].append(i)
            cols["location_ns"].append(t0[i] + loc[k] * dt_ns)
            cols["energy"].append(energy[k] * dt_ns)
            cols["amplitude"].append(float(peaks[k]))
            cols["extent_ns"].append(ext[k] * dt_ns)
            cols["snr"].append(snr)
    arr = {k: np.asarray(v, dtype=np.int64 if k == "waveform" else np.float64) for k, v in cols.items()}
    return TemplateEchoes(**arr, baseline=base, noise_sigma=noise)
