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

__all__ = ["TemplateEchoes", "decompose_template", "echo_template", "receiver_response", "subsample_peak",
           "template_from_returns"]

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
    part_echo : (P,) int64
        The non-zero template shifts each echo is the sum of (the
        deconvolved profile of an extended target): their echo,
    part_location_ns, part_energy : (P,) float64
        time (ns on the waveform clock) and energy (as ``energy``).
    """

    waveform: np.ndarray
    location_ns: np.ndarray
    energy: np.ndarray
    amplitude: np.ndarray
    extent_ns: np.ndarray
    snr: np.ndarray
    baseline: np.ndarray
    noise_sigma: np.ndarray
    part_echo: np.ndarray = None
    part_location_ns: np.ndarray = None
    part_energy: np.ndarray = None

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


def _above_base(y) -> np.ndarray:
    """``y`` less its robust baseline (:func:`noise_level`'s)."""
    y = np.asarray(y, dtype=np.float64).reshape(-1)
    return y - noise_level(y)[0]


def receiver_response(outgoing, returns, *, length: int = 40, lead: int = 8) -> np.ndarray:
    """The receiver's response to the recorded outgoing pulse, fitted on hard-target returns.

    A file that records each shot's outgoing pulse (RIEGL PulseWaves) records
    it through another path than the returns: a return is the outgoing pulse
    convolved with the receiver's response ``r`` (wider, with a trailing
    tail at a few per cent of the peak), so the outgoing pulse alone is not
    the echo shape, and its misfit reads as extra echoes.  ``r`` is the
    non-negative least-squares solution of ``y_j(t) = sum_k r_k o_j(t - s_j - k)``
    over the given pairs, each return ``y_j`` scaled to unit peak and lined up
    on its outgoing pulse ``o_j`` by their peaks (``s_j``, less ``lead``
    samples so that ``r`` can start before the peak).  Fit it on other pulses
    than the ones decomposed with it (the benchmark holds each out).

    Parameters
    ----------
    outgoing, returns : sequences of (n_j,) array_like
        The pairs, raw samples of one shot's outgoing pulse and of its return
        from a single hard target.
    length : int
        Samples of ``r``.
    lead : int
        Samples of ``r`` before the peaks' alignment.

    Returns
    -------
    (length,) float64, non-negative
    """
    from scipy.optimize import nnls

    if len(outgoing) != len(returns) or not len(returns):
        raise InputError(f"receiver_response needs pairs of outgoing and returning waveforms, got {len(outgoing)} "
                         f"and {len(returns)}")
    if not 0 <= lead < length:
        raise InputError(f"lead must be in [0, length), got {lead!r} with length {length!r}")
    rows, rhs = [], []
    for o, y in zip(outgoing, returns):
        o = np.clip(_above_base(o), 0.0, None)
        y = _above_base(y)
        if not (o.max() > 0 and y.max() > 0):
            raise InputError("an outgoing or returning waveform has no samples above its baseline")
        start = int(np.argmax(y)) - int(np.argmax(o)) - lead
        m = np.zeros((y.size, length))
        for k in range(length):
            lo = start + k  # o's sample 0 lands on the return's sample lo
            a, b = max(0, lo), min(y.size, lo + o.size)
            if b > a:
                m[a:b, k] = o[a - lo: b - lo]
        rows.append(m / y.max())
        rhs.append(y / y.max())
    r, _ = nnls(np.vstack(rows), np.concatenate(rhs))
    return r


def echo_template(outgoing, response) -> np.ndarray:
    """One shot's echo shape: its recorded outgoing pulse convolved with the receiver's response."""
    o = np.clip(_above_base(outgoing), 0.0, None)
    return np.convolve(o, np.asarray(response, dtype=np.float64))


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


def _half_width(y, half) -> float:
    """Width at half height of the one run ``half`` around the peak of ``y``, samples (linear crossings)."""
    lo, hi = int(half[0]), int(half[-1])
    top = 0.5 * y[half].max()
    left = lo - ((y[lo] - top) / (y[lo] - y[lo - 1]) if lo > 0 and y[lo] > y[lo - 1] else 0.0)
    right = hi + ((y[hi] - top) / (y[hi] - y[hi + 1]) if hi < y.size - 1 and y[hi] > y[hi + 1] else 0.0)
    return float(right - left)


def template_from_returns(waveforms, *, count: int = 20, width: int = 40, widen: float = 1.25) -> np.ndarray:
    """A system template from a file's own returns: the median of its strongest narrow single-peaked waveforms.

    For files that record no outgoing pulse or impulse response (the Leica
    LAS 1.3 tile): of the waveforms whose samples above half their peak
    form one run (one return) and whose peak stands 20 noise sigma up, those
    whose half-height width is at most ``widen`` times the narrowest tenth's
    are the hard targets (an extended target such as a crown or a leaf
    layer widens its return); each of the ``count`` highest of those is cut
    ``width`` samples either side of its peak, scaled to unit peak and the
    median taken sample by sample.

    Parameters
    ----------
    waveforms : sequence of (n_i,) array_like
    count, width : int
    widen : float >= 1
        Widest half-height width kept, over the 10th percentile of the
        single returns' widths (``inf``: the strongest regardless of width).

    Returns
    -------
    (2 width,) float64, unit peak at index ``width``, baseline removed
    """
    if not widen >= 1:
        raise InputError(f"widen must be >= 1, got {widen!r}")
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
        picks.append((y[p], y, p, _half_width(y, half)))
    if len(picks) < 3:
        raise InputError(f"found {len(picks)} strong single returns to build a template from (need 3); pass the "
                         "system's impulse response")
    widths = np.array([t[3] for t in picks])
    cut = max(float(np.sort(widths)[2]), widen * float(np.percentile(widths, 10)))
    picks = [t for t in picks if t[3] <= cut]
    picks.sort(key=lambda t: -t[0])
    stack = []
    for top, y, p, _ in picks[:count]:
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
    parts = {k: [] for k in ("part_echo", "part_location_ns", "part_energy")}
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
            parts["part_echo"].append(np.full(r.size, len(cols["snr"]) - 1))
            parts["part_location_ns"].append(t0[i] + shifts[r] * dt_ns)
            parts["part_energy"].append(e[r] * dt_ns)
    arr = {k: np.asarray(v, dtype=np.int64 if k == "waveform" else np.float64) for k, v in cols.items()}
    arr.update({k: np.concatenate(v) if v else np.zeros(0, np.int64 if k == "part_echo" else np.float64)
                for k, v in parts.items()})
    return TemplateEchoes(**arr, baseline=base, noise_sigma=noise)
