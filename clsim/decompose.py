"""Gaussian decomposition of full waveforms.

A received waveform is modelled as a constant baseline plus a sum of Gaussian
echoes (Hofton et al. 2000; Wagner et al. 2006)

.. math::  y(t) = b + \\sum_k A_k \\exp\\left(-\\frac{(t-\\mu_k)^2}{2\\sigma_k^2}\\right)

The steps, each an option of :func:`decompose`:

1. Baseline ``b`` and noise standard deviation are estimated robustly (lowest
   fifth of the samples; median absolute first difference).
2. Optional deconvolution with a measured system impulse response
   (Richardson-Lucy; Zhou et al. 2017 used it on the same NEON waveforms).
3. Candidate echoes: local maxima of the (optionally Gaussian-smoothed)
   waveform plus "terraces" (runs of equal samples on a rising or falling
   flank, the trace of a weak echo riding on a strong one in 8-bit data),
   kept when they rise ``min_amplitude`` above the baseline.
4. Levenberg-Marquardt least squares (MINPACK ``lmder`` through
   :func:`scipy.optimize.leastsq`) with the analytic Jacobian; location,
   width, amplitude of every echo and the baseline are free.
5. Component count: echoes that are not significant (amplitude under half the
   detection threshold or under two standard errors) or not resolvable
   (sigma under 0.3 sample) are dropped and the fit repeated; then echoes are
   added one at a time at the largest smoothed residual, each kept only if
   the Bayesian information criterion decreases (Schwarz 1978).
6. Standard errors from the covariance ``s^2 (J^T J)^{-1}`` with
   ``s^2 = RSS / (n - p)``.

References
----------
Hofton, M. A., Minster, J. B. & Blair, J. B. (2000). Decomposition of laser
    altimeter waveforms. IEEE TGRS 38(4), 1989-1996. doi:10.1109/36.851780
Wagner, W., Ullrich, A., Ducic, V., Melzer, T. & Studnicka, N. (2006).
    Gaussian decomposition and calibration of a novel small-footprint
    full-waveform digitising airborne laser scanner. ISPRS J. 60(2), 100-112.
    doi:10.1016/j.isprsjprs.2005.12.001
Zhou, T., Popescu, S. C., Krause, K., Sheridan, R. D. & Putman, E. (2017).
    Gold - a novel deconvolution algorithm with optimization for waveform
    LiDAR processing. ISPRS J. 129, 131-150. doi:10.1016/j.isprsjprs.2017.04.021
Schwarz, G. (1978). Estimating the dimension of a model. Ann. Stat. 6(2),
    461-464. doi:10.1214/aos/1176344136
Lucy, L. B. (1974). An iterative technique for the rectification of observed
    distributions. AJ 79, 745. doi:10.1086/111605
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy import optimize
from scipy.ndimage import gaussian_filter1d

from .errors import InputError

__all__ = [
    "Components",
    "decompose",
    "deconvolve",
    "detect_peaks",
    "echo_positions",
    "gaussian_sum",
    "noise_level",
]

FWHM_PER_SIGMA = 2.0 * np.sqrt(2.0 * np.log(2.0))
_MIN_SIGMA_SAMPLES = 0.3


@dataclass
class Components:
    """Gaussian echoes of one waveform: a table of equal-length columns.

    Attributes
    ----------
    amplitude : (K,) float64
        Peak height above the baseline, in the units of the samples.
    location_ns : (K,) float64
        Peak time, ns from the first sample (plus ``t0_ns``).
    sigma_ns : (K,) float64
        Gaussian standard deviation, ns (FWHM = 2.3548 sigma).
    amplitude_se, location_se_ns, sigma_se_ns : (K,) float64
        Standard errors (NaN for initial guesses that were not fitted).
    baseline, baseline_se : float
        Fitted constant background and its standard error.
    noise_sigma : float
        Robust noise standard deviation of the samples.
    rss : float
        Residual sum of squares of the fit.
    """

    amplitude: np.ndarray
    location_ns: np.ndarray
    sigma_ns: np.ndarray
    amplitude_se: np.ndarray
    location_se_ns: np.ndarray
    sigma_se_ns: np.ndarray
    baseline: float = 0.0
    baseline_se: float = float("nan")
    noise_sigma: float = float("nan")
    rss: float = float("nan")

    COLUMNS = ("amplitude", "location_ns", "sigma_ns", "amplitude_se", "location_se_ns",
               "sigma_se_ns")

    def __len__(self) -> int:
        return int(np.size(self.amplitude))

    @property
    def fwhm_ns(self) -> np.ndarray:
        """(K,) full width at half maximum, ns."""
        return FWHM_PER_SIGMA * self.sigma_ns

    @property
    def energy(self) -> np.ndarray:
        """(K,) area of each Gaussian, sample units x ns."""
        return self.amplitude * self.sigma_ns * np.sqrt(2.0 * np.pi)

    def model(self, time_ns) -> np.ndarray:
        """Evaluate baseline + sum of the Gaussians at ``time_ns`` (any shape, ns)."""
        return self.baseline + gaussian_sum(time_ns, self.amplitude, self.location_ns,
                                            self.sigma_ns)

    def to_records(self) -> np.ndarray:
        """The table as a NumPy structured array (one row per echo)."""
        dtype = [(name, "f8") for name in self.COLUMNS]
        out = np.empty(len(self), dtype=dtype)
        for name in self.COLUMNS:
            out[name] = getattr(self, name)
        return out

    @classmethod
    def empty(cls, **scalars) -> "Components":
        z = np.zeros(0)
        return cls(z, z.copy(), z.copy(), z.copy(), z.copy(), z.copy(), **scalars)


def gaussian_sum(t, amplitude, location, sigma) -> np.ndarray:
    """Sum of Gaussians ``sum_k A_k exp(-(t - mu_k)^2 / (2 sigma_k^2))``.

    Parameters
    ----------
    t : array_like, any shape
    amplitude, location, sigma : (K,) array_like

    Returns
    -------
    ndarray, shape of ``t``

    Examples
    --------
    >>> float(gaussian_sum(2.0, [3.0], [2.0], [1.0]))
    3.0
    """
    t = np.asarray(t, dtype=float)
    a = np.asarray(amplitude, dtype=float).reshape(-1)
    m = np.asarray(location, dtype=float).reshape(-1)
    s = np.asarray(sigma, dtype=float).reshape(-1)
    z = (t[..., None] - m) / s
    return np.sum(a * np.exp(-0.5 * z * z), axis=-1)


# ---------------------------------------------------------------- checks ---

def _as_waveform(samples, name: str = "samples") -> np.ndarray:
    try:
        y = np.asarray(samples, dtype=float)
    except (TypeError, ValueError) as err:
        raise InputError(f"{name} must be a 1-D array of numbers; got {type(samples).__name__}"
                         ) from err
    if y.ndim != 1:
        raise InputError(f"{name} must be 1-D (one waveform, samples in time order); got shape "
                         f"{y.shape}. Decompose waveforms one at a time (loop over rows).")
    if y.size < 4:
        raise InputError(f"{name} must have at least 4 samples; got {y.size}")
    if not np.all(np.isfinite(y)):
        raise InputError(f"{name} contains NaN or inf at indices "
                         f"{np.flatnonzero(~np.isfinite(y))[:5].tolist()}; remove padding or "
                         "fill gaps before decomposing")
    return y


def _positive(value, name: str) -> float:
    try:
        v = float(value)
    except (TypeError, ValueError) as err:
        raise InputError(f"{name} must be a positive number; got {value!r}") from err
    if not np.isfinite(v) or v <= 0:
        raise InputError(f"{name} must be a positive finite number; got {value!r}")
    return v


# ------------------------------------------------------------ estimation ---

def noise_level(samples) -> tuple[float, float]:
    """Robust baseline and noise standard deviation of a waveform.

    The baseline is the median of the lowest fifth of the samples (at least
    3); the noise is ``1.4826 MAD(diff(y)) / sqrt(2)``, floored at the
    quantisation noise ``q / sqrt(12)`` (``q`` the smallest step in the data).

    Parameters
    ----------
    samples : (n,) array_like

    Returns
    -------
    baseline, sigma : float

    Examples
    --------
    >>> b, s = noise_level([2, 2, 3, 2, 40, 90, 40, 2, 3, 2, 2, 3])
    >>> b
    2.0
    """
    y = _as_waveform(samples)
    k = max(3, y.size // 5)
    baseline = float(np.median(np.sort(y)[:k]))
    d = np.diff(y)
    sigma = 1.4826 * float(np.median(np.abs(d - np.median(d)))) / np.sqrt(2.0)
    steps = np.abs(d[d != 0])
    q = float(steps.min()) if steps.size else 1.0
    return baseline, max(sigma, q / np.sqrt(12.0))


def _runs(y: np.ndarray):
    """Start and end (inclusive) indices of runs of equal consecutive values."""
    change = np.flatnonzero(np.diff(y) != 0)
    starts = np.concatenate(([0], change + 1))
    ends = np.concatenate((change, [y.size - 1]))
    return starts, ends


def _half_width(y: np.ndarray, i0: int, i1: int, height: float, base: float, step: int):
    """Gaussian standard deviation seen from one flank of the peak run [i0, i1].

    Walks down the flank while it does not rise again, to the first sample
    under half height; inverts the Gaussian through that sample,
    ``sigma = d / sqrt(2 ln(h / y))`` (exact for a Gaussian, unlike linear
    interpolation of the half-maximum crossing on a coarse grid). None when
    the flank rises again before reaching half height.
    """
    h = height - base
    j = i1 if step > 0 else i0
    centre = 0.5 * (i0 + i1)
    prev = y[j]
    while 0 <= j + step < y.size:
        nxt = y[j + step]
        if nxt > prev:
            return None
        if nxt - base < 0.5 * h:
            v = nxt - base
            d = abs(j + step - centre)
            if v <= 0:  # fell to the baseline: interpolate the crossing linearly
                frac = (prev - base - 0.5 * h) / (prev - nxt) if prev != nxt else 0.0
                return abs(j + step * frac - centre) * 2.0 / FWHM_PER_SIGMA
            return d / np.sqrt(2.0 * np.log(h / v))
        prev = nxt
        j += step
    return None


def _detect(y: np.ndarray, base: float, threshold: float, terraces: bool):
    """Candidate echoes (location, height, sigma guess) in sample units."""
    starts, ends = _runs(y)
    vals = y[starts]
    out = []
    for r in range(1, len(starts) - 1):
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
        out.append((0.5 * (i0 + i1), height - base, float(np.mean(widths)) if widths else np.nan))
    return out


def detect_peaks(samples, *, dt_ns: float = 1.0, t0_ns: float = 0.0, min_amplitude=None,
                 baseline=None, smooth_ns: float = 0.0, terraces: bool = True) -> Components:
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

    Returns
    -------
    Components
        Guesses; amplitude is the sample height above the baseline, location
        the centre of the peak's run of equal samples, sigma from the half
        maximum crossings (NaN when neither flank reaches half height).
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
    cand = _detect(ys, base, thr, terraces)
    if not cand:
        return Components.empty(baseline=base, noise_sigma=sigma)
    loc, amp, sig = (np.array(c, dtype=float) for c in zip(*cand))
    nan = np.full(loc.size, np.nan)
    return Components(amp, t0_ns + loc * dt, sig * dt, nan, nan.copy(), nan.copy(),
                      baseline=base, noise_sigma=sigma)


# ------------------------------------------------------------- the fit ---

def _model_jac(p: np.ndarray, t: np.ndarray):
    k = (p.size - 1) // 3
    a, m, s = p[0:3 * k:3], p[1:3 * k:3], p[2:3 * k:3]
    z = (t[:, None] - m) / s
    e = np.exp(-0.5 * z * z)
    model = p[-1] + e @ a
    jac = np.empty((t.size, p.size))
    jac[:, 0:3 * k:3] = e
    ae = a * e
    jac[:, 1:3 * k:3] = ae * z / s
    jac[:, 2:3 * k:3] = ae * z * z / s
    jac[:, -1] = 1.0
    return model, jac


def _fit(y: np.ndarray, t: np.ndarray, amp, loc, sig, base, fit_baseline: bool,
         max_nfev: int):
    """Levenberg-Marquardt fit; returns (params, cov or None, rss)."""
    p0 = np.empty(3 * len(amp) + 1)
    p0[0:-1:3], p0[1:-1:3], p0[2:-1:3] = amp, loc, sig
    p0[-1] = base
    free = np.ones(p0.size, bool)
    free[-1] = fit_baseline
    full = p0.copy()
    k = len(amp)
    jac = np.empty((t.size, p0.size))
    jac[:, -1] = 1.0
    cache = {}

    def parts(q):
        key = q.tobytes()
        if cache.get("key") != key:
            full[free] = q
            a, m, s = full[0:3 * k:3], full[1:3 * k:3], full[2:3 * k:3]
            z = (t[:, None] - m) / s
            e = np.exp(-0.5 * z * z)
            cache.update(key=key, z=z, e=e, a=a.copy(), s=s.copy(), r=full[-1] + e @ a - y)
        return cache

    def f(q):
        return parts(q)["r"]

    def df(q):
        c = parts(q)
        z, e, a, s = c["z"], c["e"], c["a"], c["s"]
        ae = a * e
        jac[:, 0:3 * k:3] = e
        jac[:, 1:3 * k:3] = ae * z / s
        jac[:, 2:3 * k:3] = ae * z * z / s
        return jac[:, free] if not free.all() else jac

    with np.errstate(over="ignore", invalid="ignore", divide="ignore", under="ignore"):
        q, cov, info, _msg, _ier = optimize.leastsq(
            f, p0[free], Dfun=df,
            full_output=True, maxfev=max_nfev)
    full[free] = q
    full[2:-1:3] = np.abs(full[2:-1:3])
    r = info["fvec"]
    rss = float(r @ r)
    return full, free, cov, rss


def _split(p: np.ndarray):
    return p[0:-1:3].copy(), p[1:-1:3].copy(), p[2:-1:3].copy(), float(p[-1])


def _bic(rss: float, n: int, n_params: int) -> float:
    return n * np.log(max(rss, 1e-300) / n) + n_params * np.log(n)


def deconvolve(samples, impulse, *, iterations: int = 30, baseline=None) -> np.ndarray:
    """Richardson-Lucy deconvolution of a waveform by a system impulse response.

    Parameters
    ----------
    samples : (n,) array_like
        Received waveform (same sample spacing as ``impulse``).
    impulse : (m,) array_like
        Measured system response (e.g. the return from a hard flat target),
        baseline included or not: its own baseline (median of its lowest
        fifth) is removed, negatives clipped, and it is normalised to unit
        sum. Time zero of the result is the impulse's peak sample.
    iterations : int
        Richardson-Lucy iterations (more = sharper and noisier).
    baseline : float, optional
        Baseline of ``samples`` (default: estimated).

    Returns
    -------
    (n,) float64
        Deconvolved waveform above the baseline (non-negative). Its integral
        equals that of ``samples - baseline``.

    References
    ----------
    Lucy (1974) doi:10.1086/111605; Zhou et al. (2017)
    doi:10.1016/j.isprsjprs.2017.04.021.

    Examples
    --------
    >>> h = [0, 1, 3, 1, 0]
    >>> x = deconvolve(np.convolve([0, 0, 0, 10, 0, 0, 0, 0], h, mode="same"), h,
    ...                iterations=200, baseline=0)
    >>> int(np.argmax(x))
    3
    """
    y = _as_waveform(samples)
    h = _as_waveform(impulse, "impulse")
    if int(iterations) < 1:
        raise InputError(f"iterations must be >= 1; got {iterations!r}")
    hb, _ = noise_level(h)
    h = np.clip(h - hb, 0.0, None)
    if h.sum() <= 0:
        raise InputError("impulse has no signal above its baseline; pass the measured system "
                         "response (a return from a hard target)")
    h = h / h.sum()
    c = int(np.argmax(h))
    b = noise_level(y)[0] if baseline is None else float(baseline)
    d = np.clip(y - b, 0.0, None)
    total = d.sum()
    if total <= 0:
        return np.zeros_like(d)
    eps = 1e-12 * d.max()
    n = d.size
    x = np.full(n, total / n)
    hf = h[::-1]

    def conv(v, kern, centre):
        full = np.convolve(v, kern)
        return full[centre:centre + n]

    for _ in range(int(iterations)):
        est = conv(x, h, c)
        ratio = d / np.maximum(est, eps)
        x = x * conv(ratio, hf, h.size - 1 - c)
    return x


def decompose(samples, *, dt_ns: float = 1.0, t0_ns: float = 0.0, min_amplitude=None,
              smooth_ns: float = 1.0, terraces: bool = True, max_components: int = 12,
              add_components: bool = True, fit_baseline: bool = True, baseline=None,
              impulse=None, deconvolution_iterations: int = 30,
              max_nfev: int = 400) -> Components:
    """Gaussian decomposition of one waveform (see the module docstring).

    Parameters
    ----------
    samples : (n,) array_like
        One waveform, samples ``dt_ns`` apart (digitiser counts or volts).
    dt_ns : float
        Sample spacing, ns.
    t0_ns : float
        Time of the first sample, ns (locations are reported on this clock).
    min_amplitude : float, optional
        Detection threshold above the baseline, sample units. Default 4 noise
        standard deviations.
    smooth_ns : float
        Gaussian smoothing (standard deviation, ns) used for detection and for
        the residual search only; the fit always uses the raw samples.
    terraces : bool
        Detect runs of equal samples on flanks as weak echoes.
    max_components : int
        Upper bound on the number of echoes.
    add_components : bool
        Add echoes at residual maxima while the BIC decreases.
    fit_baseline : bool
        Fit the baseline (else hold it at ``baseline`` or the estimate).
    baseline : float, optional
        Baseline value (start value when fitted). Default: estimated.
    impulse : (m,) array_like, optional
        Measured system impulse response; when given the waveform is first
        deconvolved (:func:`deconvolve`) and the echoes are those of the
        deconvolved signal (time zero at the impulse peak, baseline 0).
    deconvolution_iterations : int
        Richardson-Lucy iterations.
    max_nfev : int
        Function evaluations per Levenberg-Marquardt run.

    Returns
    -------
    Components
        Echoes sorted by time, with standard errors.

    Raises
    ------
    InputError
        Samples not 1-D, not finite, fewer than 4; non-positive ``dt_ns``.

    Examples
    --------
    >>> t = np.arange(60.0)
    >>> y = 2 + gaussian_sum(t, [100, 40], [20, 31], [2.0, 2.5])
    >>> c = decompose(y)
    >>> np.round(c.location_ns, 3).tolist(), np.round(c.sigma_ns, 3).tolist()
    ([20.0, 31.0], [2.0, 2.5])
    """
    y = _as_waveform(samples)
    dt = _positive(dt_ns, "dt_ns")
    if int(max_components) < 1:
        raise InputError(f"max_components must be >= 1; got {max_components!r}")
    base0, sigma = noise_level(y)
    if baseline is not None:
        base0 = float(baseline)
    if impulse is not None:
        y = deconvolve(y, impulse, iterations=deconvolution_iterations, baseline=base0)
        base0, fit_baseline = 0.0, False
        sigma = noise_level(y)[1]
    thr = 4.0 * sigma if min_amplitude is None else float(min_amplitude)
    n = y.size
    t = np.arange(n, dtype=float)
    smooth = smooth_ns / dt
    ys = gaussian_filter1d(y, smooth) if smooth > 0 else y
    cand = _detect(ys, base0, thr, terraces)
    default_sig = max(1.0, 2.0 / dt)
    if not cand:
        return Components.empty(baseline=base0, noise_sigma=sigma,
                                rss=float(np.sum((y - base0) ** 2)))
    cand.sort(key=lambda c: -c[1])
    cand = cand[:int(max_components)]
    amp = np.array([c[1] for c in cand])
    loc = np.array([c[0] for c in cand])
    sig = np.array([c[2] if np.isfinite(c[2]) else default_sig for c in cand])
    sig = np.clip(sig, 0.5, n / 2.0)

    def fit(a, m, s, b):
        return _fit(y, t, a, m, s, b, fit_baseline, max_nfev)

    def prune(p, free, cov, rss):
        while True:
            a, m, s, b = _split(p)
            se = _standard_errors(p, free, cov, rss, n)
            se_a = se[0:-1:3]
            bad = ((a < thr) | (s < _MIN_SIGMA_SAMPLES) | (s > n) | (m < -0.5)
                   | (m > n - 0.5) | ~np.isfinite(a) | (np.isfinite(se_a) & (a < 2.0 * se_a)))
            if not bad.any():
                return p, free, cov, rss
            keep = ~bad
            if not keep.any():
                # a detected echo exists: keep the strongest well-formed one rather than none
                usable = (np.isfinite(a) & (a > 0) & (s >= _MIN_SIGMA_SAMPLES) & (s <= n)
                          & (m >= -0.5) & (m <= n - 0.5))
                if not usable.any():
                    return None
                keep[int(np.argmax(np.where(usable, a, -np.inf)))] = True
                return fit(a[keep], m[keep], s[keep], b)
            p, free, cov, rss = fit(a[keep], m[keep], s[keep], b)

    state = prune(*fit(amp, loc, sig, base0))
    if state is None and fit_baseline:
        # every echo was rejected after a free-baseline fit: retry with the baseline fixed
        return decompose(samples, dt_ns=dt_ns, t0_ns=t0_ns, min_amplitude=min_amplitude,
                         smooth_ns=smooth_ns, terraces=terraces, max_components=max_components,
                         add_components=add_components, fit_baseline=False, baseline=base0,
                         max_nfev=max_nfev)
    if state is None:
        return Components.empty(baseline=base0, noise_sigma=sigma,
                                rss=float(np.sum((y - base0) ** 2)))
    p, free, cov, rss = state
    if add_components:
        bic = _bic(rss, n, int(free.sum()))
        tried = np.zeros(n, bool)
        failures = 0
        while (p.size - 1) // 3 < int(max_components) and failures < 3:
            a, m, s, b = _split(p)
            model = _model_jac(p, t)[0]
            r = y - model
            rs = gaussian_filter1d(r, max(smooth, 1.0))
            rs[tried] = -np.inf
            j = int(np.argmax(rs))
            if rs[j] < thr:
                break
            s_new = float(np.median(s))
            trial = prune(*fit(np.append(a, max(r[j], rs[j])), np.append(m, float(j)),
                               np.append(s, s_new), b))
            ok = trial is not None
            if ok:
                bic_new = _bic(trial[3], n, int(trial[1].sum()))
                ok = bic_new < bic - 1e-9 and (trial[0].size - 1) // 3 > (p.size - 1) // 3
            if not ok:
                # this residual peak did not give a better model: try the next one
                tried[max(0, j - 2):j + 3] = True
                failures += 1
                continue
            p, free, cov, rss = trial
            bic = bic_new
            tried[:] = False
            failures = 0
    if fit_baseline and rss > 25.0 * sigma * sigma * n:
        # residual RMS above 5 noise sigma: LM wandered off with the baseline (seen on a
        # few NEON waveforms with long tails); retry with the baseline held at its robust
        # estimate and keep the better fit
        alt = decompose(samples, dt_ns=dt_ns, t0_ns=t0_ns, min_amplitude=min_amplitude,
                        smooth_ns=smooth_ns, terraces=terraces, max_components=max_components,
                        add_components=add_components, fit_baseline=False, baseline=base0,
                        max_nfev=max_nfev)
        if len(alt) and alt.rss < rss:
            return alt
    se = _standard_errors(p, free, cov, rss, n)
    a, m, s, b = _split(p)
    order = np.argsort(m)
    return Components(
        amplitude=a[order], location_ns=t0_ns + m[order] * dt, sigma_ns=s[order] * dt,
        amplitude_se=se[0:-1:3][order], location_se_ns=se[1:-1:3][order] * dt,
        sigma_se_ns=se[2:-1:3][order] * dt, baseline=b, baseline_se=float(se[-1]),
        noise_sigma=sigma, rss=rss)


def _standard_errors(p, free, cov, rss, n) -> np.ndarray:
    se = np.full(p.size, np.nan)
    dof = n - int(free.sum())
    if cov is None or dof <= 0:
        return se
    var = np.diag(cov) * rss / dof
    se[free] = np.sqrt(np.clip(var, 0.0, None))
    return se


def echo_positions(location_ns, *, origin, direction) -> np.ndarray:
    """3-D positions of echoes along a straight pulse.

    Parameters
    ----------
    location_ns : (K,) array_like
        Echo times, ns on the waveform clock.
    origin : (3,) array_like
        Position (m) that corresponds to time 0 of the waveform clock.
    direction : (3,) array_like
        Displacement per ns along the waveform (m/ns; for a two-way return
        waveform its length is c/2 = 0.1499 m/ns).

    Returns
    -------
    (K, 3) float64, metres

    Examples
    --------
    >>> echo_positions([0.0, 10.0], origin=[0, 0, 100], direction=[0, 0, -0.15]).tolist()
    [[0.0, 0.0, 100.0], [0.0, 0.0, 98.5]]
    """
    t = np.asarray(location_ns, dtype=float).reshape(-1, 1)
    o = np.asarray(origin, dtype=float).reshape(3)
    d = np.asarray(direction, dtype=float).reshape(3)
    return o + t * d

