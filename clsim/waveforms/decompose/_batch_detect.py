"""The detection of :func:`._batch.decompose_batch` in NumPy, each step one call
over a padded (N, n) array of waveforms: robust baseline and noise, no-data gaps,
clipped samples, the clipping-tolerant baseline and the width of each waveform's
strongest echo (:func:`noise_stats_numpy`), the batch's pulse and the false-alarm
level (:func:`_batch_pulse`, :func:`_rice`), then the matched filter, peaks,
shoulders and matched-filter maxima with their start values
(:func:`candidates_numpy`). The OpenCL kernels of :mod:`._detect_cl` are their
twins (``clsim/kernels/decompose_detect.cl``); these are the reference.

References
----------
Caruana, R. A., Searle, R. B., Heller, T. & Shupack, S. I. (1986). Fast
    algorithm for the resolution of spectra. Anal. Chem. 58(6), 1162-1167.
    doi:10.1021/ac00297a041
"""

from __future__ import annotations

import numpy as np
from scipy.ndimage import gaussian_filter1d, maximum_filter1d

from clsim.errors import InputError
from clsim.waveforms.decompose._checks import _positive
from clsim.waveforms.decompose._detect_cl import NoiseStats
from clsim.waveforms.decompose._matched import _FALLBACK_SIGMA, filter_output

_SQRT_PI = np.sqrt(np.pi)
#: Gaussian smoothing (samples) of the curvature used to find shoulders.
_CURV_SMOOTH = 1.5


def _order_mean(x, lo, hi):
    """Per row, the mean of the ``lo``-th and ``hi``-th smallest entries of ``x``
    (N, n) (indices (N,) int; NaN where ``hi`` is negative): a partial sort per group
    of rows that share both indices."""
    out = np.full(x.shape[0], np.nan)
    key = lo * (x.shape[1] + 1) + hi
    for kv in np.unique(key[hi >= 0]):
        r = np.flatnonzero(key == kv)
        i, j = int(lo[r[0]]), int(hi[r[0]])
        part = np.partition(x[r] if r.size < x.shape[0] else x, (i, j) if i != j else i, axis=1)
        out[r] = 0.5 * (part[:, i] + part[:, j])
    return out


def _noise(y, use):
    """Per row: median of the lowest fifth, and 1.4826 MAD(diff) / sqrt(2) floored at q/sqrt(12)."""
    nv = use.sum(axis=1)
    k = np.maximum(3, nv // 5)
    base = _order_mean(np.where(use, y, np.inf), (k - 1) // 2, k // 2)
    d = np.diff(y, axis=1)
    dv = use[:, 1:] & use[:, :-1]
    c = dv.sum(axis=1)
    med = _order_mean(np.where(dv, d, np.inf), (c - 1) // 2, c // 2 - (c == 0))
    dev = np.where(dv, np.abs(d - med[:, None]), np.inf)
    sigma = 1.4826 * _order_mean(dev, (c - 1) // 2, c // 2 - (c == 0)) / np.sqrt(2.0)
    q = np.where(dv & (d != 0), np.abs(d), np.inf).min(axis=1)
    q = np.where(np.isfinite(q), q, 1.0)
    return base, np.maximum(np.nan_to_num(sigma), q / np.sqrt(12.0))


def _clipped_baseline(y, use, sigma, start):
    b = start.copy()
    for _ in range(5):
        near = use & (np.abs(y - b[:, None]) < 2.5 * sigma[:, None])
        cnt = near.sum(axis=1)
        b = np.where(cnt >= 3, np.sum(np.where(near, y, 0.0), axis=1) / np.maximum(cnt, 1), b)
    return b


def _maxima(f, inside):
    """Mask of local maxima of each row of ``f`` (first sample of a plateau)."""
    z = np.where(inside, f, -np.inf)
    pad = np.pad(z, ((0, 0), (1, 1)), constant_values=-np.inf)
    return inside & (pad[:, 1:-1] > pad[:, :-2]) & (pad[:, 1:-1] >= pad[:, 2:])


def _log_parabola(f, rows, idx, n):
    """Sub-sample location and Gaussian sigma of the maxima ``f[rows, idx]`` (NaN sigma
    where the three samples are not a positive log-concave triple)."""
    lo = np.clip(idx - 1, 0, n - 1)
    hi = np.clip(idx + 1, 0, n - 1)
    f0, fl, fh = f[rows, idx], f[rows, lo], f[rows, hi]
    with np.errstate(divide="ignore", invalid="ignore"):
        ll, l0, lh = np.log(fl), np.log(f0), np.log(fh)
        den = ll - 2.0 * l0 + lh
        ok = (fl > 0) & (fh > 0) & (f0 > 0) & (den < 0) & (lo < idx) & (hi > idx)
        shift = np.where(ok, 0.5 * (ll - lh) / den, 0.0)
        var = np.where(ok, -1.0 / den, np.nan)
    return idx + np.clip(shift, -0.5, 0.5), var


def _echo_widths(y, use, base, sigma, lengths):
    """Gaussian-equivalent width (samples) of each waveform's strongest echo, from its
    interpolated half-maximum crossings; NaN unless it stands 20 sigma or more above
    the baseline with both crossings inside the record."""
    n = y.shape[1]
    h = np.where(use, y - base[:, None], -np.inf)
    i = np.argmax(h, axis=1)
    top = h[np.arange(y.shape[0]), i]
    half = 0.5 * top
    j = np.arange(n)
    below = (h < half[:, None]) & (j < lengths[:, None])
    left = np.where(below & (j < i[:, None]), j, -1).max(axis=1)
    right = np.where(below & (j > i[:, None]), j, n).min(axis=1)
    good = (top >= 20.0 * sigma) & (left >= 0) & (right < lengths)
    width = np.full(y.shape[0], np.nan)
    r = np.flatnonzero(good)
    hl, hl1 = h[r, left[r]], h[r, left[r] + 1]
    hr, hr1 = h[r, right[r]], h[r, right[r] - 1]
    with np.errstate(invalid="ignore"):
        xl = left[r] + (half[r] - hl) / (hl1 - hl)
        xr = right[r] - (half[r] - hr) / (hr1 - hr)
    width[r] = (xr - xl) / (2.0 * np.sqrt(2.0 * np.log(2.0)))
    return width


def _batch_pulse(width):
    """Gaussian-equivalent pulse width: the 20th percentile of the widths of each
    waveform's strongest echo (:func:`_echo_widths`; blends and canopy returns are
    wider than the pulse), or the fallback when none is usable."""
    w = width[np.isfinite(width) & (width > 0)]
    if w.size == 0:
        return _FALLBACK_SIGMA
    return float(np.percentile(w, 20.0))


def _rice(n_valid, pulse, false_alarm):
    g = pulse.shape / pulse.norm
    rate = n_valid * np.sqrt(float(np.sum(np.diff(g) ** 2))) / (2.0 * np.pi)
    return np.sqrt(2.0 * np.log(np.maximum(rate / false_alarm, 1.0)))


def _saturation(saturation):
    """``saturation`` checked: None, "auto" or a positive full-scale value (float)."""
    if saturation is None:
        return None
    if isinstance(saturation, bool) or (isinstance(saturation, str) and saturation != "auto"):
        raise InputError(f"saturation must be 'auto', None or the digitiser's full-scale "
                         f"value (a number); got {saturation!r}")
    return saturation if isinstance(saturation, str) else _positive(saturation, "saturation")


def _censored(y, inside, saturation):
    saturation = _saturation(saturation)
    if saturation is None:
        return None
    if isinstance(saturation, str):
        top = np.where(inside, y, -np.inf).max(axis=1)
        at = inside & (y == top[:, None])
        run3 = at[:, :-2] & at[:, 1:-1] & at[:, 2:]
        mask = np.zeros_like(at)
        for k in range(3):
            mask[:, k:k + run3.shape[1]] |= run3
    else:
        mask = inside & (y >= saturation)
    return mask if mask.any() else None


def noise_stats_numpy(y, lengths, saturation):
    """The NumPy detection's first step for a chunk (N, n): robust baseline and noise,
    no-data zeros, clipped samples, clipping-tolerant baseline, width of the strongest
    echo (:class:`._detect_cl.NoiseStats`; the kernel ``noise_stats`` is its twin)."""
    n = y.shape[1]
    inside = np.arange(n) < lengths[:, None]
    # no-data fill: exact zeros when the rest of the record sits > 4 sigma above zero
    zero = inside & (y == 0.0)
    nz = inside & ~zero
    base0, sigma = _noise(y, nz)
    gap = zero.any(axis=1) & (zero.sum(axis=1) <= lengths - 4) & (base0 > 4.0 * sigma)
    redo = zero.any(axis=1) & ~gap
    if redo.any():
        base0[redo], sigma[redo] = _noise(y[redo], inside[redo])
    use = np.where(gap[:, None], nz, inside)
    cens = _censored(y, use, saturation)
    b = _clipped_baseline(y, use, sigma, base0)
    return NoiseStats(b, sigma, use.sum(axis=1), _echo_widths(y, use, b, sigma, lengths), use,
                      cens)


def candidates_numpy(y, lengths, ns, pl, level, k_cap):
    """The NumPy detection's second step (the kernel ``candidates`` is its twin): start
    amplitude, location, sigma (N, k_cap) of each waveform's highest candidates, highest
    first, and their mask."""
    n_rows, n = y.shape
    b, sigma, use, cens = ns.b, ns.sigma, ns.use, ns.cens
    inside = np.arange(n) < lengths[:, None]
    # detection: matched filter (amplitude units) and the smoothed samples
    yb = np.where(use, y - b[:, None], 0.0)
    f = filter_output(yb, pl)
    ys = gaussian_filter1d(yb, 1.0, axis=1, mode="constant")
    sig_f = f >= level[:, None]
    d = int(np.ceil(max(1.0, pl.sigma)))
    peak = _maxima(ys, inside) & (ys >= 4.0 * sigma[:, None]) & sig_f
    # shoulders: minima of the curvature (Hofton et al. 2000: one Gaussian per pair of
    # inflection points) standing 4 sigma below the curvature's noise, away from peaks
    # and clipped runs
    d2 = gaussian_filter1d(yb, _CURV_SMOOTH, axis=1, order=2, mode="constant")
    yc = gaussian_filter1d(yb, _CURV_SMOOTH, axis=1, mode="constant")
    d2_noise = sigma * np.sqrt(3.0 / (8.0 * _SQRT_PI * _CURV_SMOOTH ** 5))
    blocked = maximum_filter1d(peak.astype(np.uint8), 3, axis=1) > 0
    if cens is not None:
        blocked |= maximum_filter1d(cens.astype(np.uint8), 2 * d + 1, axis=1) > 0
    shoulder = (_maxima(-d2, inside) & (-d2 >= 4.0 * d2_noise[:, None])
                & (yc >= 4.0 * sigma[:, None]) & sig_f & ~blocked)
    strong = peak | shoulder
    near = maximum_filter1d(strong.astype(np.uint8), 2 * d + 1, axis=1) > 0
    weak = _maxima(f, inside) & sig_f & ~near & use
    # start values: location and width from a log-parabola (peaks, matched-filter
    # maxima) or from the curvature (shoulders: sigma^2 = -y/y'' - smoothing^2); the
    # amplitudes by linear least squares below
    height = np.where(peak, ys, np.where(shoulder, yc, np.where(weak, f, -np.inf)))
    # the k_cap highest candidates of each row, highest first (candidates are sparse)
    r_all, i_all = np.nonzero(height > -np.inf)
    o = np.lexsort((-height[r_all, i_all], r_all))
    r_all, i_all = r_all[o], i_all[o]
    rank = np.arange(r_all.size) - np.searchsorted(r_all, r_all)
    keep = rank < k_cap
    r_c, c_c, idx = r_all[keep], rank[keep], i_all[keep]
    cand = np.zeros((n_rows, k_cap), bool)
    cand[r_c, c_c] = True
    is_peak = peak[r_c, idx]
    is_sh = shoulder[r_c, idx]
    # the three samples around each candidate, from the curve that found it
    near3 = np.clip(idx[:, None] + np.arange(-1, 2), 0, n - 1)
    rr = r_c[:, None]
    src = np.where(is_peak[:, None], ys[rr, near3], np.where(is_sh[:, None], -d2[rr, near3],
                                                              f[rr, near3]))
    loc, var = _log_parabola(src, np.arange(r_c.size), np.ones_like(idx), 3)
    # (a candidate on the first or last sample has no neighbour on that side)
    inner = (idx > 0) & (idx < n - 1)
    loc = np.where(inner, loc + idx - 1, idx)
    var = np.where(inner, var, np.nan)
    with np.errstate(divide="ignore", invalid="ignore"):
        var_sh = -yc[r_c, idx] / d2[r_c, idx] - _CURV_SMOOTH ** 2
    var = np.where(is_peak, var - 1.0, np.where(is_sh, var_sh, var - pl.sigma ** 2))
    sig0 = np.where(np.isfinite(var) & (var > 0.25), np.sqrt(np.abs(var)), pl.sigma)
    a, m, s = np.zeros((n_rows, k_cap)), np.zeros((n_rows, k_cap)), np.ones((n_rows, k_cap))
    m[r_c, c_c], s[r_c, c_c] = loc, np.clip(sig0, 0.5, n / 2.0)
    a[r_c, c_c] = height[r_c, idx]
    return a, m, s, cand
