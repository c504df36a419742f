"""Decomposition of many waveforms at once, vectorised across waveforms.

The steps of :func:`decompose` with ``detection="matched"``, each one NumPy
call over a padded (N, n) array: robust baseline and noise, no-data gaps,
clipped samples, the matched filter and its threshold, candidates, start
widths (a log-parabola through the three samples around each maximum, exact
for a Gaussian: Caruana et al. 1986), then the Levenberg-Marquardt fit of all
waveforms with the same number of echoes together, its start amplitudes and
baseline by linear least squares, pruning of weak echoes (after a fit that stopped
on a collapsed echo, that echo first), and rounds of adding a resolved echo at the
highest residual feature while the BIC falls.
On an OpenCL device the detection runs there too, one waveform per work-item
(:mod:`._detect_cl`, ``clsim/kernels/decompose_detect.cl``; the NumPy steps
:func:`noise_stats_numpy` and :func:`candidates_numpy` are its reference), the
samples stay on the device, and the fits run there, one waveform per work-item
(:mod:`._batch_cl`, ``clsim/kernels/decompose_lm.cl``), which also returns each
fit's residual and its matched-filtered and smoothed twins for the search; two
chunks are in flight at once (threads), so one chunk's host steps overlap the
other's kernels. Without a device, everything is
vectorised in NumPy (:mod:`._batch_fit`).

Differences from :func:`decompose`, for speed: one pulse for the whole batch
(default: the 20th percentile of the widths of the strongest echoes), no
terraces but shoulders (minima of the smoothed curvature), a residual feature
tested for resolution from its start values (no lone fit), a rejected one ends
the search unless it was unresolved (at most 3 unresolved ones are passed over
in a row), and no retry with the baseline held.

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
from clsim.waveforms.decompose._batch_cl import device_fitter
from clsim.waveforms.decompose._batch_fit import fit_group, linear_start
from clsim.waveforms.decompose._detect_cl import MAX_CANDIDATES, NoiseStats
from clsim.waveforms.decompose._checks import _positive
from clsim.waveforms.decompose._fitting import _MIN_SIGMA_SAMPLES
from clsim.waveforms.decompose._matched import FALSE_ALARM, Pulse, _FALLBACK_SIGMA, filter_output
from clsim.waveforms.decompose._results import EchoTable

_SQRT_PI = np.sqrt(np.pi)
#: Chunks decomposed at once on a device (threads; see :func:`decompose_batch`).
_IN_FLIGHT = 2
#: Gaussian smoothing (samples) of the curvature used to find shoulders.
_CURV_SMOOTH = 1.5


def _pad(waveforms):
    """(N, n) samples, (N,) lengths from a 2-D array or a sequence of 1-D arrays."""
    y = None
    if not (isinstance(waveforms, np.ndarray) and waveforms.ndim != 2):
        try:  # a 2-D array, or a sequence of equal-length rows: one conversion
            y = np.asarray(waveforms, dtype=float)
        except (TypeError, ValueError):
            y = None  # ragged rows (or not numbers: said below)
    if y is not None and y.ndim == 2:
        lengths = np.full(y.shape[0], y.shape[1])
    else:
        try:
            if isinstance(waveforms, (list, tuple)) and all(
                    isinstance(w, np.ndarray) and w.ndim == 1 for w in waveforms):
                rows = waveforms  # 1-D arrays already (concatenated as float below)
            else:
                rows = [np.asarray(w, dtype=float).reshape(-1) for w in waveforms]
        except (TypeError, ValueError) as err:
            raise InputError("waveforms must be a 2-D array (N, n) or a sequence of 1-D "
                             f"arrays of numbers; got {type(waveforms).__name__}") from err
        if not rows:
            raise InputError("waveforms is empty; pass at least one waveform")
        lengths = np.array([r.size for r in rows])
        y = np.zeros((len(rows), lengths.max()))
        try:
            y[np.arange(lengths.max()) < lengths[:, None]] = np.concatenate(rows)
        except (TypeError, ValueError) as err:
            raise InputError("waveforms must be a 2-D array (N, n) or a sequence of 1-D "
                             "arrays of numbers; got arrays that are not numbers") from err
    if y.shape[0] == 0:
        raise InputError("waveforms is empty; pass at least one waveform")
    short = np.flatnonzero(lengths < 4)
    if short.size:
        raise InputError(f"every waveform needs at least 4 samples; waveforms "
                         f"{short[:5].tolist()} have {lengths[short[:5]].tolist()}")
    bad = ~np.isfinite(y)
    if bad.any():
        raise InputError(f"waveforms {np.flatnonzero(bad.any(axis=1))[:5].tolist()} contain "
                         "NaN or inf; remove padding or fill gaps before decomposing")
    return y, lengths


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


class _State:
    """Echo parameters of every waveform, (N, K_max) with an ``on`` mask."""

    def __init__(self, n_rows, k_max, n):
        shape = (n_rows, k_max)
        self.a, self.m, self.s = np.zeros(shape), np.zeros(shape), np.ones(shape)
        self.se = np.full((n_rows, 3, k_max), np.nan)
        self.on = np.zeros(shape, bool)
        self.b = np.zeros(n_rows)
        self.b_se = np.full(n_rows, np.nan)
        self.rss = np.full(n_rows, np.nan)
        self.n_eff = np.zeros(n_rows, int)
        # samples minus model of the last fit, its matched filter and smoothing (float32,
        # from the device), kept where ok
        self.resid = np.zeros((n_rows, 3, n), dtype=np.float32)
        self.resid_ok = np.zeros(n_rows, bool)

    def k(self):
        return self.on.sum(axis=1)


def _fit_rows(fit, rows, a, m, s, b, fit_baseline=True, linear=False):
    """Fit rows (R,) with start (R, K) arrays, grouped by the number of active echoes
    (``a`` NaN = inactive), all groups one call of ``fit`` (:func:`_group_fitter`;
    ``linear``: start amplitudes and baseline by linear least squares first).
    Returns per-row results padded back to (R, K)."""
    rk = np.isfinite(a).sum(axis=1)
    R, K = a.shape
    out_a, out_m, out_s = np.full((R, K), np.nan), np.full((R, K), np.nan), np.full((R, K), np.nan)
    out_se = np.full((R, 3, K), np.nan)
    out_b, out_bse, out_rss = b.astype(float).copy(), np.full(R, np.nan), np.full(R, np.nan)
    out_neff = np.zeros(R, int)
    out_resid = None
    groups, placed = [], []
    for k in np.unique(rk):
        if k == 0:
            continue
        sel = np.flatnonzero(rk == k)
        on = np.isfinite(a[sel])
        # compact the active echoes to the first k columns
        order = np.argsort(~on, axis=1, kind="stable")[:, :k]
        take = lambda v: np.take_along_axis(v[sel], order, axis=1)  # noqa: E731
        groups.append((rows[sel], take(a), take(m), take(s), b[sel]))
        placed.append((k, sel, order))
    for (k, sel, order), res in zip(placed, fit(groups, fit_baseline, linear)):
        ii = sel[:, None]
        out_a[ii, order], out_m[ii, order], out_s[ii, order] = res.a, res.m, res.s
        for q in range(3):
            out_se[ii, q, order] = res.se[:, q * k:(q + 1) * k]
        out_b[sel], out_rss[sel], out_neff[sel] = res.b, res.rss, res.n_eff
        if fit_baseline:
            out_bse[sel] = res.se[:, 3 * k]
        if res.resid is not None and res.filtered is not None:
            if out_resid is None:
                out_resid = np.full((R, 3, res.resid.shape[1]), np.nan, dtype=np.float32)
            out_resid[sel, 0] = res.resid
            out_resid[sel, 1:] = res.filtered
    return out_a, out_m, out_s, out_se, out_b, out_bse, out_rss, out_neff, out_resid


def _bad(a, m, s, se_a, u, sigma, n):
    with np.errstate(invalid="ignore"):
        weak = a * np.sqrt(np.abs(s) * _SQRT_PI) < (u * sigma)[:, None]
        return (weak | (s < _MIN_SIGMA_SAMPLES) | (s > n[:, None]) | (m < -s)
                | (m > n[:, None] - 1 + s) | ~np.isfinite(a)
                | (np.isfinite(se_a) & (a < 2.0 * se_a)))


#: Separation, in sums of the pair's sigmas, beyond which two echoes count as resolved
#: without a look at their curvature: each echo's inflection points then lie 6 or more
#: of the other's sigmas from that one's peak, where its curvature is under 1e-6 of its
#: peak value; it could remove them only if its peak curvature ``a / s^2`` exceeded
#: the other's about a million times.
_FAR = 6.0


def _resolved_rows(a, m, s, on, a1, m1, s1):
    """Sparrow's criterion between the new echo (a1, m1, s1) (R,) and each active
    echo (R, K): the pair's sum has four inflection points (looked for on a grid of
    160 points, for the pairs closer than :data:`_FAR` sigmas)."""
    with np.errstate(invalid="ignore"):
        near = on & ~(np.abs(m - m1[:, None]) >= _FAR * (s + s1[:, None]))
    r, c = np.nonzero(near)
    ok = np.ones(on.shape[0], bool)
    if r.size == 0:
        return ok
    a, m, s = a[r, c], m[r, c], s[r, c]
    a1, m1, s1 = a1[r], m1[r], s1[r]
    lo = np.minimum(m - 3 * s, m1 - 3 * s1)
    hi = np.maximum(m + 3 * s, m1 + 3 * s1)
    # in float32 (the exponentials are most of the search's time on many-echo
    # waveforms; a sign of the curvature is not changed by the rounding except within
    # 1e-6 of an inflection point)
    grid = np.linspace(0.0, 1.0, 160, dtype=np.float32)
    f32 = np.float32
    with np.errstate(invalid="ignore", over="ignore", divide="ignore"):
        # z^2 of each echo of the pair on the grid x = lo + (hi - lo) * grid
        z0 = ((lo - m) / s).astype(f32)[:, None] + ((hi - lo) / s).astype(f32)[:, None] * grid
        z1 = ((lo - m1) / s1).astype(f32)[:, None] + ((hi - lo) / s1).astype(f32)[:, None] * grid
        z0 *= z0
        z1 *= z1
        e0 = np.exp(np.multiply(z0, f32(-0.5)))
        e1 = np.exp(np.multiply(z1, f32(-0.5)))
        z0 -= f32(1.0)
        z1 -= f32(1.0)
        curv = z0 * e0 * (a / s ** 2).astype(f32)[:, None]
        curv += z1 * e1 * (a1 / s1 ** 2).astype(f32)[:, None]
    sign = np.sign(curv)
    changes = np.count_nonzero(sign[:, 1:] != sign[:, :-1], axis=-1)
    ok[r[changes < 4]] = False
    return ok


def decompose_batch(waveforms, *, dt_ns: float = 1.0, t0_ns=0.0, pulse=None,
                    pulse_sigma_ns=None, false_alarm: float = FALSE_ALARM,
                    saturation="auto", max_components: int = 8,
                    add_components: bool = True, chunk: int = 2000,
                    device=None) -> EchoTable:
    """Gaussian decomposition of many waveforms at once (see the module docstring).

    Parameters
    ----------
    waveforms : (N, n) array_like or sequence of (n_i,) arrays
        Waveforms, samples ``dt_ns`` apart; rows of different lengths are
        padded internally.
    dt_ns : float
        Sample spacing, ns, the same for every waveform.
    t0_ns : float or (N,) array_like
        Time of each waveform's first sample, ns.
    pulse : (m,) array_like, optional
        Measured system pulse for the matched filter (same spacing).
    pulse_sigma_ns : float, optional
        Else a Gaussian pulse of this standard deviation, ns. Default: the
        20th percentile of the widths of the batch's strongest echoes
        (those 20 noise sigma or more above the baseline); 2 samples when none.
    false_alarm : float
        Expected false echoes per noise-only waveform at detection.
    saturation : "auto", float or None
        Clipped samples, as in :func:`decompose`.
    max_components : int
        Upper bound on echoes per waveform.
    add_components : bool
        Add resolved echoes at residual features while the BIC falls.
    chunk : int
        Waveforms processed together (memory: about ``chunk * n * 100`` bytes).
    device : str, voxlidar.devices.DeviceInfo, pyopencl.Device or None
        Where the Levenberg-Marquardt fits run, one waveform per work-item
        (:mod:`._batch_cl`): None (default) ``VOXLIDAR_DEVICE``,
        ``PYOPENCL_CTX`` or the best OpenCL device that builds the fitting
        kernel, else NumPy; ``"numpy"``: the NumPy path (:mod:`._batch_fit`);
        ``"0:1"``, ``"cpu"``, ``"gpu"``, ``"intel"``...: that device.

    Returns
    -------
    EchoTable
        One row per echo; ``table[i]`` is waveform ``i``'s :class:`Components`.

    Raises
    ------
    InputError
        Empty input, a waveform under 4 samples, NaN or inf, non-positive
        ``dt_ns`` or ``false_alarm``, bad ``saturation``, ``pulse`` and
        ``pulse_sigma_ns`` both given.
    DeviceError
        ``device`` (or ``VOXLIDAR_DEVICE`` / ``PYOPENCL_CTX``) names a device
        that is absent or cannot build the fitting kernel.

    Examples
    --------
    >>> from clsim.waveforms.decompose import gaussian_sum
    >>> t = np.arange(60.0)
    >>> ys = [2 + gaussian_sum(t, [100, 40], [20, 31 + d], [2.0, 2.5]) for d in (0, 3)]
    >>> table = decompose_batch(ys)
    >>> table.counts.tolist(), np.round(table[1].location_ns, 3).tolist()
    ([2, 2], [20.0, 34.0])
    """
    dt = _positive(dt_ns, "dt_ns")
    fa = _positive(false_alarm, "false_alarm")
    if int(max_components) < 1:
        raise InputError(f"max_components must be >= 1; got {max_components!r}")
    if pulse is not None and pulse_sigma_ns is not None:
        raise InputError("give pulse (a measured response) or pulse_sigma_ns, not both")
    saturation = _saturation(saturation)
    fitter = device_fitter(device)
    y_all, len_all = _pad(waveforms)
    n_all = y_all.shape[0]
    t0 = np.broadcast_to(np.asarray(t0_ns, dtype=float), (n_all,))
    if pulse is not None:
        pl = pulse if isinstance(pulse, Pulse) else Pulse.measured(pulse)
    elif pulse_sigma_ns is not None:
        pl = Pulse.gaussian(_positive(pulse_sigma_ns, "pulse_sigma_ns") / dt)
    else:
        pl = None
    step = max(1, int(chunk))

    def one(lo):
        hi = min(n_all, lo + step)
        return _decompose_chunk(y_all[lo:hi, :len_all[lo:hi].max()], len_all[lo:hi], pl, fa,
                                saturation, int(max_components), add_components, fitter)

    starts = range(0, n_all, step)
    if fitter is None or len(starts) < 2:
        parts = [one(lo) for lo in starts]
    else:
        # two chunks in flight: one's host steps run while the other's kernels do (the
        # chunks are independent: the same results as one after the other)
        from concurrent.futures import ThreadPoolExecutor

        with ThreadPoolExecutor(max_workers=_IN_FLIGHT) as pool:
            parts = list(pool.map(one, starts))
    return _table(parts, t0, dt)


def _table(parts, t0, dt):
    wf, cols, per = [], {c: [] for c in EchoTable.COLUMNS}, {k: [] for k in
                                                              ("baseline", "baseline_se",
                                                               "noise_sigma", "rss")}
    offset = 0
    for st, sigma in parts:
        on = st.on
        order = np.argsort(np.where(on, st.m, np.inf), axis=1, kind="stable")
        srt = lambda v: np.take_along_axis(v, order, axis=1)  # noqa: E731
        on_s = srt(on)
        rows = np.nonzero(on_s)[0]
        wf.append(rows + offset)
        t0r = t0[offset + rows]
        cols["amplitude"].append(srt(st.a)[on_s])
        cols["location_ns"].append(t0r + srt(st.m)[on_s] * dt)
        cols["sigma_ns"].append(srt(st.s)[on_s] * dt)
        cols["amplitude_se"].append(srt(st.se[:, 0])[on_s])
        cols["location_se_ns"].append(srt(st.se[:, 1])[on_s] * dt)
        cols["sigma_se_ns"].append(srt(st.se[:, 2])[on_s] * dt)
        per["baseline"].append(st.b)
        per["baseline_se"].append(st.b_se)
        per["noise_sigma"].append(sigma)
        per["rss"].append(st.rss)
        offset += st.b.size
    return EchoTable(np.concatenate(wf).astype(np.int64),
                     **{c: np.concatenate(v) for c, v in cols.items()},
                     **{k: np.concatenate(v) for k, v in per.items()})


def _group_fitter(device, y, use, cens, noise, pulse):
    """``fit(groups, fit_baseline, linear) -> [GroupFit]`` for groups ``(rows, a, m,
    s, b)`` of a chunk's rows, each group its own number of echoes: one round on the
    OpenCL device (its samples uploaded once; :meth:`._batch_cl.BoundFitter.fit_groups`),
    else :func:`fit_group` per group."""
    if device is not None:
        bound = device.bind(y, use, cens, noise)
        bound.set_pulse(pulse)
        return _bound_fit(bound)

    def fit(groups, fb, linear):
        out = []
        for rows, a, m, s, b in groups:
            c = None if cens is None else cens[rows]
            if linear and fb:
                a, b = linear_start(y[rows], use[rows] if c is None else use[rows] & ~c, a, m,
                                    s, b)
            out.append(fit_group(y[rows], use[rows], a, m, s, b, fit_baseline=fb,
                                 noise=noise[rows], cens=c))
        return out

    return fit


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


def _bound_fit(bound):
    """:func:`_group_fitter`'s ``fit`` on a :class:`._batch_cl.BoundFitter`."""
    return lambda groups, fb, linear: bound.fit_groups(groups, fit_baseline=fb, linear=linear)


def _decompose_chunk(y, lengths, pl, fa, saturation, k_max, add_components, device):
    n_rows, n = y.shape
    rows = np.arange(n_rows)
    k_cap = max(1, min(k_max, int((n - 2) // 3)))
    # detection on the device (its samples then stay there for the fits), else NumPy
    det = None
    if device is not None and k_cap <= MAX_CANDIDATES:
        det = device.detector.bind(y, lengths)
        ns = det.noise_stats(saturation)
    else:
        ns = noise_stats_numpy(y, lengths, saturation)
    b, sigma, use, cens = ns.b, ns.sigma, ns.use, ns.cens
    if pl is None:
        pl = Pulse.gaussian(float(np.clip(_batch_pulse(ns.width), 0.7, max(0.7, n / 8.0))))
    u = _rice(ns.n_valid, pl, fa)
    level = u * sigma / pl.norm
    if det is not None:
        a, m, s, cand = det.candidates(pl, level, k_cap)
    else:
        a, m, s, cand = candidates_numpy(y, lengths, ns, pl, level, k_cap)
    st = _State(n_rows, k_cap, n)
    st.a, st.m, st.s, st.on = a, m, s, cand
    st.b = b.copy()
    st.noise = sigma
    if det is not None:
        bound = det.fitter()
        bound.set_pulse(pl)
        st.fit = _bound_fit(bound)
    else:
        st.fit = _group_fitter(device, y, use, cens, sigma, pl)
    start = (st.a.copy(), st.m.copy(), st.s.copy(), st.on.copy(), st.b.copy())
    # fit (amplitudes and baseline first by linear least squares), prune, add
    _refit(st, rows[st.k() > 0], y, use, cens, linear=True)
    _prune(st, y, use, cens, u, sigma, lengths)
    _rescue(st, start, y, use, cens, lengths)
    if add_components:
        _add(st, y, use, cens, u, sigma, lengths, pl, level, k_cap)
    empty = st.k() == 0
    st.b[empty] = b[empty]
    st.rss[empty] = np.sum(np.where(use[empty], y[empty] - b[empty, None], 0.0) ** 2, axis=1)
    return st, sigma


def _refit(st, rows, y, use, cens, linear=False):
    if rows.size == 0:
        return
    a = np.where(st.on[rows], st.a[rows], np.nan)
    res = _fit_rows(st.fit, rows, a, st.m[rows], st.s[rows], st.b[rows], linear=linear)
    _store(st, rows, *res)


def _store(st, rows, a, m, s, se, b, bse, rss, neff, resid):
    on = np.isfinite(a)
    st.on[rows] = on
    st.a[rows] = np.where(on, a, 0.0)
    st.m[rows] = np.where(on, m, 0.0)
    st.s[rows] = np.where(on, s, 1.0)
    st.se[rows] = se
    st.b[rows], st.b_se[rows], st.rss[rows], st.n_eff[rows] = b, bse, rss, neff
    _keep_resid(st, rows, resid)


def _keep_resid(st, rows, resid):
    """Keep the fits' residuals and their filtered twins (R, 3, n) of ``rows`` (None,
    or NaN rows: not kept)."""
    if resid is None:
        st.resid_ok[rows] = False
        return
    ok = ~np.isnan(resid[:, 0, 0]) & ~np.isnan(resid[:, 1, 0])
    st.resid[rows[ok]] = resid[ok]
    st.resid_ok[rows] = ok


def _broken(a, m, s, n):
    """Echoes that collapsed (height not positive, sigma under the resolvable limit) or
    left the record (peak more than one sigma beyond its ends)."""
    with np.errstate(invalid="ignore"):
        return (~np.isfinite(a) | (a <= 0) | (s < _MIN_SIGMA_SAMPLES) | (s > n[:, None])
                | (m < -s) | (m > n[:, None] - 1 + s))


def _prune(st, y, use, cens, u, sigma, lengths, rounds=5):
    """Drop weak, unresolvable or misplaced echoes and refit, until none is left to drop.
    A fit that stopped because an echo collapsed or left the record (the fits stop
    there) has only those echoes dropped first: its residual sum, and so the standard
    errors and significance of the others, are not yet those of a converged fit. A
    waveform whose echoes all fail keeps its strongest well-formed one (a detected
    echo exists), refitted alone and not pruned again."""
    locked = np.zeros(st.on.shape[0], bool)
    for _ in range(rounds):
        bad = _bad(st.a, st.m, st.s, st.se[:, 0], u, sigma, lengths) & st.on
        broken = _broken(st.a, st.m, st.s, lengths) & st.on
        bad = np.where(broken.any(axis=1)[:, None], broken, bad)
        bad[locked] = False
        rows = np.flatnonzero(bad.any(axis=1))
        if rows.size == 0:
            return
        keep = st.on[rows] & ~bad[rows]
        none = ~keep.any(axis=1)
        if none.any():
            a, m, s = st.a[rows], st.m[rows], st.s[rows]
            n = lengths[rows][:, None]
            usable = (st.on[rows] & np.isfinite(a) & (a > 0) & (s >= _MIN_SIGMA_SAMPLES)
                      & (s <= n) & (m >= -s) & (m <= n - 1 + s))
            best = np.argmax(np.where(usable, a, -np.inf), axis=1)
            fix = np.flatnonzero(none & usable.any(axis=1))
            keep[fix, best[fix]] = True
            locked[rows[fix]] = True
        st.on[rows] = keep
        st.resid_ok[rows] = False
        gone = rows[~keep.any(axis=1)]
        st.se[gone] = np.nan
        _refit(st, rows[keep.any(axis=1)], y, use, cens)


def _rescue(st, start, y, use, cens, lengths):
    """Waveforms with candidates whose fits all failed (every echo collapsed or left
    the record) get the strongest candidate fitted alone, kept when well formed."""
    a0, m0, s0, on0, b0 = start
    rows = np.flatnonzero((st.k() == 0) & on0.any(axis=1))
    if rows.size == 0:
        return
    best = np.argmax(np.where(on0[rows], a0[rows], -np.inf), axis=1)
    ii = np.arange(rows.size)
    res = _fit_rows(st.fit, rows, a0[rows, best][:, None], m0[rows, best][:, None],
                    s0[rows, best][:, None], b0[rows], linear=True)
    a, m, s = res[0][:, 0], res[1][:, 0], res[2][:, 0]
    n = lengths[rows]
    ok = (np.isfinite(a) & (a > 0) & (s >= _MIN_SIGMA_SAMPLES) & (s <= n) & (m >= -s)
          & (m <= n - 1 + s))
    rows, best, ii = rows[ok], best[ok], ii[ok]
    st.on[rows] = False
    st.on[rows, best] = True
    st.a[rows, best], st.m[rows, best], st.s[rows, best] = a[ok], m[ok], s[ok]
    st.se[rows] = np.nan
    st.se[rows, :, best] = res[3][ii, :, 0]
    st.b[rows], st.b_se[rows], st.rss[rows], st.n_eff[rows] = (res[4][ii], res[5][ii],
                                                             res[6][ii], res[7][ii])
    _keep_resid(st, rows, None if res[8] is None else res[8][ii])


def _bic(rss, n, p):
    return n * np.log(np.maximum(rss, 1e-300) / n) + p * np.log(n)


def _model(st, rows, n):
    """(R, n) baseline plus the active echoes of ``rows`` at samples 0..n-1 (only the
    columns some row uses; the exponential in float32, as in the fits)."""
    on = st.on[rows]
    k = int(on.sum(axis=1).max())
    order = np.argsort(~on, axis=1, kind="stable")[:, :k]
    take = lambda v: np.take_along_axis(v[rows], order, axis=1)  # noqa: E731
    a = np.where(np.take_along_axis(on, order, axis=1), take(st.a), 0.0)
    m, s = take(st.m).astype(np.float32), take(st.s).astype(np.float32)
    z = np.arange(n, dtype=np.float32) - m[:, :, None]
    z /= s[:, :, None]
    z *= z
    z *= np.float32(-0.5)
    e = np.exp(z, out=z)
    return st.b[rows][:, None] + np.matmul(a[:, None, :].astype(np.float32), e)[:, 0, :]


def _add(st, y, use, cens, u, sigma, lengths, pl, level, k_cap):
    n_rows, n = y.shape
    search = (st.k() > 0) & (st.k() < k_cap)
    skipped = np.zeros((n_rows, n), bool)
    passes = np.zeros(n_rows, int)
    for _ in range(3 * k_cap):
        rows = np.flatnonzero(search)
        if rows.size == 0:
            return
        on = st.on[rows]
        # the residual of the last fit and its matched filter and smoothing, kept from
        # the device (else computed here)
        kept = st.resid[rows]
        r, fm, fs = (kept[:, c].astype(float) for c in range(3))
        redo = np.flatnonzero(~st.resid_ok[rows])
        if redo.size:
            rr = np.where(use[rows[redo]], y[rows[redo]] - _model(st, rows[redo], n), 0.0)
            if cens is not None:
                rr = np.where(cens[rows[redo]], 0.0, rr)
            r[redo] = rr
            fm[redo] = filter_output(rr, pl)
            fs[redo] = gaussian_filter1d(rr, 1.0, axis=1, mode="constant")
        out = ~use[rows] | skipped[rows]
        fm /= level[rows][:, None]
        fm[out] = -np.inf
        fs /= (4.0 * sigma[rows])[:, None]
        fs[out] = -np.inf
        # the search follows whichever filter stands higher above its threshold
        ii = np.arange(rows.size)
        jm, js = np.argmax(fm, axis=1), np.argmax(fs, axis=1)
        use_m = fm[ii, jm] >= fs[ii, js]
        j = np.where(use_m, jm, js)
        go = np.where(use_m, fm[ii, jm], fs[ii, js]) >= 1.0
        search[rows[~go]] = False
        rows, j, use_m, on, ii = rows[go], j[go], use_m[go], on[go], ii[go]
        if rows.size == 0:
            return
        # the new echo's start: a log-parabola through the filtered residual's maximum
        # and its two neighbours (the filter's own width removed); amplitude from the
        # residual
        near3 = np.clip(j[:, None] + np.arange(-1, 2), 0, n - 1)
        filt = np.where(use_m[:, None], fm[ii[:, None], near3] * level[rows][:, None],
                        fs[ii[:, None], near3] * (4.0 * sigma[rows])[:, None])
        m1, var = _log_parabola(filt, np.arange(rows.size), np.ones_like(j), 3)
        # (a maximum on the first or last sample has no neighbour on that side)
        inner = (j > 0) & (j < n - 1)
        m1 = np.where(inner, m1 + j - 1, j)
        var = np.where(inner, var, np.nan)
        var = np.where(use_m, var - pl.sigma ** 2, var - 1.0)
        s0 = np.clip(np.where(np.isfinite(var) & (var > 0.25), np.sqrt(np.abs(var)),
                              pl.sigma), 0.5, n / 2.0)
        s1 = s0
        a1 = np.maximum(r[ii, j], filt[:, 1])
        res = _resolved_rows(st.a[rows], st.m[rows], st.s[rows], on, a1, m1, s1)
        res &= np.isfinite(a1) & (a1 > 0)
        # unresolved: pass over this feature (mask it) and try the next, up to 3 times
        un = rows[~res]
        if un.size:
            half = np.ceil(2.0 * s0[~res]).astype(int)[:, None]
            dist = np.abs(np.arange(n) - j[~res][:, None])
            skipped[un] |= dist <= half
        passes[un] += 1
        search[un[passes[un] >= 3]] = False
        if not res.any():
            continue
        rows, a1, m1, s1 = rows[res], a1[res], m1[res], s1[res]
        # the trial: every echo refitted with the new one in the first free column
        free = np.argmin(st.on[rows], axis=1)
        ta = np.where(st.on[rows], st.a[rows], np.nan)
        tm, ts = st.m[rows].copy(), st.s[rows].copy()
        ii = np.arange(rows.size)
        ta[ii, free], tm[ii, free], ts[ii, free] = a1, m1, s1
        fa, fm_, fs_, fse, fb, fbse, frss, fneff, fres = _fit_rows(st.fit, rows, ta, tm, ts,
                                                                   st.b[rows])
        k_old = st.k()[rows]
        bic_old = _bic(st.rss[rows], st.n_eff[rows], 3 * k_old + 1)
        bic_new = _bic(frss, fneff, 3 * (k_old + 1) + 1)
        bad = _bad(np.nan_to_num(fa, nan=0.0), fm_, fs_, fse[:, 0], u[rows], sigma[rows],
                   lengths[rows]) & np.isfinite(fa)
        ok = (bic_new < bic_old) & ~bad.any(axis=1) & np.isfinite(frss)
        acc = rows[ok]
        _store(st, acc, fa[ok], fm_[ok], fs_[ok], fse[ok], fb[ok], fbse[ok], frss[ok],
               fneff[ok], None if fres is None else fres[ok])
        skipped[acc] = False
        passes[acc] = 0
        search[rows[~ok]] = False
        search[acc] &= st.k()[acc] < k_cap
