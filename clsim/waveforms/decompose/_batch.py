"""Decomposition of many waveforms at once, vectorised across waveforms.

The one algorithm of matched detection (:func:`decompose` runs it on a batch of
one), each step one NumPy call over a padded (N, n) array: robust baseline and noise, no-data gaps,
clipped samples, the matched filter and its threshold, candidates, start
widths (a log-parabola through the three samples around each maximum, exact
for a Gaussian: Caruana et al. 1986), then the Levenberg-Marquardt fit of all
waveforms with the same number of echoes together, its start amplitudes and
baseline by linear least squares, pruning of weak echoes (after a fit that stopped
on a collapsed echo, that echo first), and rounds of adding a resolved echo at the
highest residual feature while the BIC falls.
On an OpenCL device the detection runs there too, one waveform per work-item
(:mod:`._detect_cl`, ``clsim/kernels/decompose_detect.cl``; the NumPy steps of
:mod:`._batch_detect` are its reference), the samples stay on the device, and the
fits run there, one waveform per work-item (:mod:`._batch_cl`,
``clsim/kernels/decompose_lm.cl``), which also returns each fit's residual and
its matched-filtered and smoothed twins for the search. Each round of fits is one
upload of its rows and start values, a launch per number of echoes and one
result buffer, each group's results read back while the next computes; two
chunks are in flight at once (threads), so one chunk's host steps overlap the
other's kernels. Without a device, everything is vectorised in NumPy (:mod:`._batch_detect`, :mod:`._batch_fit`).

One pulse for the whole call (default: the 20th percentile of the widths of
every waveform's strongest echo, taken before the waveforms are split into
chunks, so that no result depends on ``chunk`` or on the input's order);
shoulders (minima of the smoothed curvature) as candidates; a residual feature
tested for resolution from its start values; a rejected one ends the search
unless it was unresolved (at most 3 unresolved ones are passed over in a row).

Modules: :mod:`._batch_detect` (the NumPy detection), :mod:`._batch_select`
(fits of grouped rows, pruning, additions), :mod:`._batch_fit` (NumPy fits),
:mod:`._batch_cl` and :mod:`._detect_cl` (the OpenCL fits and detection); this
one pads the input, runs the chunks and assembles the :class:`EchoTable`.
"""

from __future__ import annotations

import numpy as np

from clsim.errors import InputError
from clsim.waveforms.decompose._batch_cl import device_fitter
from clsim.waveforms.decompose._batch_detect import (
    _batch_pulse,
    _rice,
    _saturation,
    candidates_numpy,
    noise_stats_numpy,
)
from clsim.waveforms.decompose._batch_fit import fit_group, linear_start
from clsim.waveforms.decompose._batch_select import _add, _prune, _refit, _rescue, _State
from clsim.waveforms.decompose._checks import _positive
from clsim.waveforms.decompose._detect_cl import MAX_CANDIDATES
from clsim.waveforms.decompose._matched import FALSE_ALARM, Pulse
from clsim.waveforms.decompose._model import MAX_COMPONENTS
from clsim.waveforms.decompose._results import EchoTable

__all__ = ["decompose_batch"]

#: Chunks decomposed at once on a device (threads; see :func:`decompose_batch`).
_IN_FLIGHT = 2


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


def decompose_batch(waveforms, *, dt_ns: float = 1.0, t0_ns=0.0, pulse=None,
                    pulse_sigma_ns=None, false_alarm: float = FALSE_ALARM,
                    saturation="auto", max_components: int = MAX_COMPONENTS,
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
    starts = range(0, n_all, step)
    n_pad = y_all.shape[1]
    # every waveform's result depends on itself and on what the whole call shares (the
    # pulse, the cap on echoes), never on its chunk: both are set here from all waveforms
    k_cap = max(1, min(int(max_components), int((n_pad - 2) // 3)))
    stats = {}
    if pl is None:
        widths = []
        for lo in starts:
            hi = min(n_all, lo + step)
            det, ns = _noise_stats(y_all[lo:hi, :len_all[lo:hi].max()], len_all[lo:hi], saturation, fitter, k_cap)
            widths.append(ns.width)
            stats[lo] = det, ns  # each chunk goes on from its statistics (and its samples on the device)
        pl = Pulse.gaussian(float(np.clip(_batch_pulse(np.concatenate(widths) if widths else np.zeros(0)),
                                          0.7, max(0.7, n_pad / 8.0))))

    def one(lo):
        hi = min(n_all, lo + step)
        return _decompose_chunk(y_all[lo:hi, :len_all[lo:hi].max()], len_all[lo:hi], pl, fa, saturation, k_cap,
                                add_components, fitter, stats.pop(lo, None))

    if fitter is None or len(starts) < 2:
        parts = [one(lo) for lo in starts]
    else:
        # two chunks in flight: one's host steps run while the other's kernels do (the
        # chunks are independent: the same results as one after the other)
        from concurrent.futures import ThreadPoolExecutor

        with ThreadPoolExecutor(max_workers=_IN_FLIGHT) as pool:
            parts = list(pool.map(one, starts))
    return _table(parts, t0, dt)


def _noise_stats(y, lengths, saturation, device, k_cap):
    """The first detection step of a chunk: ``(bound detector, stats)`` on the device when the
    chunk's detection runs there (its samples stay there), else ``(None, stats)``."""
    if device is not None and k_cap <= MAX_CANDIDATES:
        det = device.detector.bind(y, lengths)
        return det, det.noise_stats(saturation)
    return None, noise_stats_numpy(y, lengths, saturation)


def _decompose_chunk(y, lengths, pl, fa, saturation, k_cap, add_components, device, pre=None):
    n_rows, n = y.shape
    rows = np.arange(n_rows)
    # detection on the device (its samples then stay there for the fits), else NumPy;
    # ``pre``: the first step already run while the call's pulse was estimated
    det, ns = pre if pre is not None else _noise_stats(y, lengths, saturation, device, k_cap)
    b, sigma, use, cens = ns.b, ns.sigma, ns.use, ns.cens
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
        bound.set_pulse(pl, residuals=add_components)
        st.fit = _bound_fit(bound)
    else:
        st.fit = _group_fitter(device, y, use, cens, sigma, pl, add_components)
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


def _group_fitter(device, y, use, cens, noise, pulse, residuals=True):
    """``fit(groups, fit_baseline, linear) -> [GroupFit]`` for groups ``(rows, a, m,
    s, b)`` of a chunk's rows, each group its own number of echoes: one round on the
    OpenCL device (its samples uploaded once; :meth:`._batch_cl.BoundFitter.fit_groups`),
    else :func:`fit_group` per group."""
    if device is not None:
        bound = device.bind(y, use, cens, noise)
        bound.set_pulse(pulse, residuals=residuals)
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


def _bound_fit(bound):
    """:func:`_group_fitter`'s ``fit`` on a :class:`._batch_cl.BoundFitter`."""
    return lambda groups, fb, linear: bound.fit_groups(groups, fit_baseline=fb, linear=linear)


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
    return EchoTable(waveform=np.concatenate(wf).astype(np.int64),
                     **{c: np.concatenate(v) for c, v in cols.items()},
                     **{k: np.concatenate(v) for k, v in per.items()})
