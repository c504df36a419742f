"""Echo detection: local maxima and terraces above a threshold, with width guesses."""

from __future__ import annotations

import numpy as np
from scipy.ndimage import gaussian_filter1d

from clsim.waveforms.decompose._checks import _as_waveform, _positive
from clsim.waveforms.decompose._model import FWHM_PER_SIGMA, Components
from clsim.waveforms.decompose._noise import _runs, noise_level


def _half_width(y: np.ndarray, i0: int, i1: int, height: float, base: float, step: int):
    """Half width at half maximum of the peak run [i0, i1] seen from one flank, samples.

    Walks down the flank (``step`` -1: left, +1: right) from the edge of the
    peak's run of equal samples. When the flank falls below half height before
    it rises again, the half-maximum crossing is interpolated linearly between
    the two samples around it (Hofton et al. 2000). When a neighbouring echo
    stops the flank first (it rises again above half height), the Gaussian is
    inverted through the valley sample, ``d sqrt(ln 2 / ln(h / v))``: the
    neighbour adds to ``v``, so this is an upper bound on the half width. At
    the end of the record the last sample is used the same way. None when no
    sample of the flank lies below the peak height.
    """
    h = height - base
    half = 0.5 * h
    j = i1 if step > 0 else i0
    prev = y[j] - base
    edge = j
    while 0 <= j + step < y.size:
        nxt = y[j + step] - base
        if nxt > prev:
            break
        if nxt < half:
            return abs(j - edge) + (prev - half) / (prev - nxt)
        prev = nxt
        j += step
    v = y[j] - base
    if j == edge or not 0 < v < h:
        return None
    return abs(j - edge) * np.sqrt(np.log(2.0) / np.log(h / v))


def _detect(y: np.ndarray, base: float, threshold: float, terraces: bool, edges: bool):
    """Candidate echoes (location, height, sigma guess) in sample units."""
    starts, ends = _runs(y)
    vals = y[starts]
    out = []
    last = len(starts) - 1
    for r in range(last + 1):
        if r in (0, last):
            if not edges:
                continue
            # an echo cut by the end of the record (the waveform still rising at its last
            # sample, or already falling at its first) is an echo too: its maximum is the edge
            is_max = last > 0 and (vals[1] < vals[0] if r == 0 else vals[r] > vals[r - 1])
            is_terrace = False
        else:
            up_in = vals[r] > vals[r - 1]
            up_out = vals[r + 1] > vals[r]
            is_max = up_in and not up_out
            is_terrace = terraces and (ends[r] > starts[r]) and (up_in == up_out)
        if not (is_max or is_terrace):
            continue
        height = vals[r]
        if height - base < threshold:
            continue
        i0, i1 = int(starts[r]), int(ends[r])
        lo = _half_width(y, i0, i1, height, base, -1)
        hi = _half_width(y, i0, i1, height, base, +1)
        widths = [w for w in (lo, hi) if w is not None]
        # FWHM = plateau length + the two half widths (the mean one where a flank is missing)
        fwhm = (i1 - i0) + 2.0 * float(np.mean(widths)) if widths else np.nan
        out.append((0.5 * (i0 + i1), height - base, fwhm / FWHM_PER_SIGMA))
    return out


def detect_peaks(samples, *, dt_ns: float = 1.0, t0_ns: float = 0.0, min_amplitude=None,
                 baseline=None, smooth_ns: float = 0.0, terraces: bool = True,
                 edges: bool = False) -> Components:
    """Initial echo guesses: local maxima and terraces above a threshold.

    Parameters
    ----------
    samples : (n,) array_like
        One waveform, samples ``dt_ns`` apart.
    dt_ns : float
        Sample spacing, ns.
    t0_ns : float
        Time of the first sample, ns.
    min_amplitude : float, optional
        A candidate must rise more than this above the baseline (sample
        units). Default: 4 noise standard deviations (false-alarm probability
        about 3e-5 per sample for Gaussian noise).
    baseline : float, optional
        Baseline to measure heights from. Default: estimated
        (:func:`noise_level`). Pass 0 to use raw sample values.
    smooth_ns : float
        Standard deviation of a Gaussian smoothing applied before detection,
        ns (0: none).
    terraces : bool
        Also report runs of equal samples on a flank (weak overlapping echoes).
    edges : bool
        Also report an echo cut by the record: the first (last) sample when the
        waveform falls from (rises to) the edge. :func:`decompose` uses them.

    Returns
    -------
    Components
        Guesses; amplitude is the sample height above the baseline, location
        the centre of the peak's run of equal samples, sigma from the full
        width at half maximum (interpolated half-maximum crossings; see
        ``_half_width``; NaN only when neither flank has a sample below the
        peak).
        Standard errors are NaN.

    Examples
    --------
    >>> c = detect_peaks([0, 1, 5, 9, 9, 5, 1, 0, 0], baseline=0, min_amplitude=2)
    >>> c.amplitude.tolist(), c.location_ns.tolist()
    ([9.0], [3.5])
    """
    y = _as_waveform(samples)
    dt = _positive(dt_ns, "dt_ns")
    b_est, sigma = noise_level(y)
    base = b_est if baseline is None else float(baseline)
    thr = 4.0 * sigma if min_amplitude is None else float(min_amplitude)
    ys = gaussian_filter1d(y, smooth_ns / dt) if smooth_ns > 0 else y
    cand = _detect(ys, base, thr, terraces, edges)
    if not cand:
        return Components.empty(baseline=base, noise_sigma=sigma)
    loc, amp, sig = (np.array(c, dtype=float) for c in zip(*cand))
    nan = np.full(loc.size, np.nan)
    return Components(amp, t0_ns + loc * dt, sig * dt, nan, nan.copy(), nan.copy(),
                      baseline=base, noise_sigma=sigma)

