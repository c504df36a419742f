"""Decomposition of one waveform: the pipeline of the package docstring."""

from __future__ import annotations

import numpy as np
from scipy.ndimage import gaussian_filter1d

from clsim.errors import InputError
from clsim.waveforms.decompose._checks import _as_waveform, _positive
from clsim.waveforms.decompose._deconvolve import deconvolve
from clsim.waveforms.decompose._detection import _detect
from clsim.waveforms.decompose._fitting import _linear_start, _split, _standard_errors
from clsim.waveforms.decompose._matched import (
    FALSE_ALARM,
    Detection,
)
from clsim.waveforms.decompose._model import MAX_COMPONENTS, Components
from clsim.waveforms.decompose._noise import _gaps, _saturated, noise_level
from clsim.waveforms.decompose._selection import _AmplitudeRule, _order_and_fit


def decompose(samples, *, dt_ns: float = 1.0, t0_ns: float = 0.0, min_amplitude=None,
              smooth_ns: float | None = None, terraces: bool | None = None,
              max_components: int = MAX_COMPONENTS,
              add_components: bool = True, fit_baseline: bool | None = None, baseline=None,
              impulse=None, deconvolution_iterations: int = 30, saturation="auto",
              max_nfev: int | None = None, detection=None, pulse=None, pulse_sigma_ns=None,
              false_alarm: float = FALSE_ALARM, device=None) -> Components:
    """Gaussian decomposition of one waveform (see the module docstring).

    With the default detection (``"matched"``) this is
    ``decompose_batch([samples], ...)[0]``: the one algorithm of
    :func:`decompose_batch`, with its defaults, run on a batch of one (on the
    OpenCL device it chooses, ``device=``). The earlier amplitude rule
    (``detection="amplitude"``, selected by ``min_amplitude`` or ``impulse``)
    is this function's own, with the options that belong to it alone
    (``smooth_ns``, ``terraces``, ``fit_baseline``, ``baseline``,
    ``max_nfev``, ``impulse``).

    Parameters
    ----------
    samples : (n,) array_like
        One waveform, samples ``dt_ns`` apart (digitiser counts or volts).
    dt_ns : float
        Sample spacing, ns.
    t0_ns : float
        Time of the first sample, ns (locations are reported on this clock).
    min_amplitude : float, optional
        Amplitude detection threshold above the baseline, sample units, for
        ``detection="amplitude"`` (default 4 noise standard deviations). Giving
        it selects that detection.
    smooth_ns : float, optional
        Amplitude rule: Gaussian smoothing (standard deviation, ns, default 1)
        used for detection and for the residual search only; the fit always
        uses the raw samples.
    terraces : bool, optional
        Amplitude rule: detect runs of equal samples on flanks as weak echoes
        (default True).
    max_components : int
        Upper bound on the number of echoes (the same default as
        :func:`decompose_batch`).
    add_components : bool
        Add echoes at residual maxima while the BIC decreases; a new echo must
        be resolved from the others where it appears (Sparrow's criterion).
    fit_baseline : bool, optional
        Amplitude rule: fit the baseline (default), else hold it at
        ``baseline`` or the estimate.
    baseline : float, optional
        Amplitude rule: baseline value (start value when fitted). Default:
        estimated.
    impulse : (m,) array_like, optional
        Measured system impulse response; when given the waveform is first
        deconvolved (:func:`deconvolve`) and the echoes are those of the
        deconvolved signal (time zero at the impulse peak, baseline 0).
    deconvolution_iterations : int
        Richardson-Lucy iterations.
    saturation : "auto", float or None
        Clipped samples are censored: the true value is at least the recorded
        one, so they count in the fit only where the model falls below them
        (the unsaturated flanks then set the echo's height and width).
        ``"auto"``: a run of 3 or more equal samples at the record maximum
        (a Gaussian echo sampled at 1 ns cannot give three equal top samples
        unless it is clipped or wider than the quantisation allows);
        a number: the digitiser's full-scale value (samples at or above it are
        clipped); None: no censoring.
    max_nfev : int, optional
        Amplitude rule: function evaluations per Levenberg-Marquardt run
        (default 400).
    detection : {"matched", "amplitude"}, optional
        ``"matched"`` (default): :func:`decompose_batch`'s algorithm on a
        batch of one (candidates where the matched filter with the system
        pulse exceeds the threshold for ``false_alarm``, Rice 1944; an echo
        kept when its own matched-filter SNR reaches the same threshold).
        ``"amplitude"``: the earlier rule, candidates and echoes
        ``min_amplitude`` above the baseline. Default ``"amplitude"`` when
        ``min_amplitude`` or ``impulse`` is given, else ``"matched"``.
    pulse : (m,) array_like, optional
        Measured system pulse for the matched filter (same sample spacing).
    pulse_sigma_ns : float, optional
        Else a Gaussian pulse of this standard deviation, ns. Default: the
        width of the waveform's strongest echo (as :func:`decompose_batch`
        takes it for a batch of one).
    false_alarm : float
        Expected false echoes per noise-only waveform at detection (white
        Gaussian noise); the residual search for further echoes uses the same
        threshold.
    device : str, DeviceInfo, pyopencl.Device or None
        Matched detection: where the batch of one runs (as
        :func:`decompose_batch`'s ``device``; ``"numpy"`` for NumPy).

    Returns
    -------
    Components
        Echoes sorted by time, with standard errors.

    Raises
    ------
    InputError
        Samples not 1-D, not finite, fewer than 4; non-positive ``dt_ns``;
        ``saturation`` neither "auto", None nor a positive number; unknown
        ``detection``; ``detection="matched"`` with ``min_amplitude`` or
        ``impulse``; with matched detection, an option of the amplitude rule.

    Examples
    --------
    >>> from clsim.waveforms.decompose import gaussian_sum
    >>> t = np.arange(60.0)
    >>> y = 2 + gaussian_sum(t, [100, 40], [20, 31], [2.0, 2.5])
    >>> c = decompose(y)
    >>> np.round(c.location_ns, 3).tolist(), np.round(c.sigma_ns, 3).tolist()
    ([20.0, 31.0], [2.0, 2.5])
    """
    y = _as_waveform(samples)
    dt = _positive(dt_ns, "dt_ns")
    if detection is None:
        detection = ("amplitude" if min_amplitude is not None or impulse is not None
                     else "matched")
    detection = Detection.parse(detection, "detection")
    if detection is Detection.MATCHED and (min_amplitude is not None or impulse is not None):
        raise InputError("detection='matched' sets its threshold from false_alarm and fits "
                         "the recorded samples; drop min_amplitude and impulse, or pass "
                         "detection='amplitude'")
    if int(max_components) < 1:
        raise InputError(f"max_components must be >= 1; got {max_components!r}")
    if detection is Detection.MATCHED:
        own = [k for k, v in (("smooth_ns", smooth_ns), ("terraces", terraces), ("fit_baseline", fit_baseline),
                              ("baseline", baseline), ("max_nfev", max_nfev)) if v is not None]
        if own:
            raise InputError(f"{', '.join(own)} belong(s) to detection='amplitude'; the matched detection (the "
                             "default) is decompose_batch's algorithm, which sets them itself: drop them, or pass "
                             "detection='amplitude'")
        from clsim.waveforms.decompose._batch import decompose_batch

        return decompose_batch([y], dt_ns=dt, t0_ns=t0_ns, pulse=pulse, pulse_sigma_ns=pulse_sigma_ns,
                               false_alarm=false_alarm, saturation=saturation, max_components=max_components,
                               add_components=add_components, device=device)[0]
    smooth_ns = 1.0 if smooth_ns is None else smooth_ns
    terraces = True if terraces is None else bool(terraces)
    fit_baseline = True if fit_baseline is None else bool(fit_baseline)
    max_nfev = 400 if max_nfev is None else int(max_nfev)
    # no-data fill (exact zeros far below the baseline, e.g. the gap between two digitised
    # segments of a NEON record) is left out of the fit; detection sees it interpolated
    valid = _gaps(y) if impulse is None else None
    if valid is not None:
        keep = np.flatnonzero(valid)
        y = y.copy()
        y[~valid] = np.interp(np.flatnonzero(~valid), keep, y[keep])
    base0, sigma = noise_level(y)
    if baseline is not None:
        base0 = float(baseline)
    if impulse is not None:
        y = deconvolve(y, impulse, iterations=deconvolution_iterations, baseline=base0)
        base0, fit_baseline = 0.0, False
        sigma = noise_level(y)[1]
    thr = 4.0 * sigma if min_amplitude is None else float(min_amplitude)
    n = y.size
    smooth = smooth_ns / dt
    ys = gaussian_filter1d(y, smooth) if smooth > 0 else y
    # clipping is a property of the recorded samples: validate always, censor only when
    # the fit is to them (a deconvolved waveform has no clipped samples of its own)
    censored = _saturated(np.asarray(samples, dtype=float) if impulse is not None else y,
                          saturation)
    if impulse is not None:
        censored = None
    cand, rule = _detect(ys, base0, thr, terraces, True), _AmplitudeRule(thr, smooth)
    if not cand:
        return Components.empty(baseline=base0, noise_sigma=sigma,
                                rss=float(np.sum((y - base0) ** 2)))
    # at least one degree of freedom left for the standard errors: 3 K + 1 < n
    k_max = max(1, min(int(max_components), (n - 2) // 3))
    cand.sort(key=lambda c: -c[1])
    cand = cand[:k_max]
    amp = np.array([c[1] for c in cand])
    loc = np.array([c[0] for c in cand])
    sig = np.array([c[2] for c in cand])
    sig = np.clip(np.where(np.isfinite(sig), sig, max(1.0, 2.0 / dt)), 0.5, n / 2.0)
    amp, base_start = _linear_start(y, amp, loc, sig, base0, fit_baseline, valid, censored)
    opts = dict(y=y, valid=valid, rule=rule, k_max=k_max, censored=censored,
                add_components=add_components, max_nfev=max_nfev)
    n_fit = n if valid is None else int(valid.sum())
    state = _order_and_fit(amp, loc, sig, base_start, fit_baseline=fit_baseline, **opts)
    if fit_baseline and (state is None or state[3] > 25.0 * sigma * sigma * n_fit):
        # every echo rejected, or residual RMS above 5 noise sigma: LM wandered off with
        # the baseline (seen on a few NEON waveforms with long tails); retry with the
        # baseline held at its robust estimate and keep the better fit
        alt = _order_and_fit(amp, loc, sig, base0, fit_baseline=False, **opts)
        if alt is not None and (state is None or alt[3] < state[3]):
            state = alt
    if state is None:
        return Components.empty(baseline=base0, noise_sigma=sigma,
                                rss=float(np.sum((y - base0) ** 2)))
    p, free, cov, rss = state
    n_fit -= 0 if censored is None else int(censored[valid].sum() if valid is not None
                                               else censored.sum())
    se = _standard_errors(p, free, cov, rss, n_fit)
    a, m, s, b = _split(p)
    order = np.argsort(m)
    return Components(
        amplitude=a[order], location_ns=t0_ns + m[order] * dt, sigma_ns=s[order] * dt,
        amplitude_se=se[0:-1:3][order], location_se_ns=se[1:-1:3][order] * dt,
        sigma_se_ns=se[2:-1:3][order] * dt, baseline=b, baseline_se=float(se[-1]),
        noise_sigma=sigma, rss=rss)
