"""Gaussian decomposition of full waveforms.

A received waveform is modelled as a constant baseline plus a sum of Gaussian
echoes (Hofton et al. 2000; Wagner et al. 2006)

.. math::  y(t) = b + \\sum_k A_k \\exp\\left(-\\frac{(t-\\mu_k)^2}{2\\sigma_k^2}\\right)

The steps, each an option of :func:`decompose`:

1. Baseline ``b`` and noise standard deviation are estimated robustly (lowest
   fifth of the samples; median absolute first difference). Exact zeros more
   than 4 noise sigma below the baseline are no-data fill (the gap between
   two digitised segments of a NEON record) and are left out of the fit.
2. Optional deconvolution with a measured system impulse response
   (Richardson-Lucy; Zhou et al. 2017 used it on the same NEON waveforms).
3. Candidate echoes: local maxima of the (optionally Gaussian-smoothed)
   waveform plus "terraces" (runs of equal samples on a rising or falling
   flank, the trace of a weak echo riding on a strong one in 8-bit data)
   plus echoes cut by the ends of the record, kept when they rise
   ``min_amplitude`` above the baseline. Initial width: the full width at half
   maximum between the linearly interpolated half-maximum crossings of the two
   flanks (Hofton et al. 2000); a flank that a neighbouring echo stops before
   half height gives the Gaussian through its valley sample instead.
4. Levenberg-Marquardt least squares (MINPACK ``lmder`` through
   :func:`scipy.optimize.leastsq`) with the analytic Jacobian; location,
   width, amplitude of every echo and the baseline are free. Start values:
   the detected locations and widths, with amplitudes and baseline from the
   linear least-squares fit at those locations and widths. Clipped
   (saturated) samples are censored: they count only where the model falls
   below them (Tobin 1958), so the unclipped flanks set height and width.
5. Component count: echoes that are not significant (amplitude under the
   detection threshold or under two standard errors) or not resolvable
   (sigma under 0.3 sample) are dropped and the fit repeated; then an echo is
   added at the largest smoothed residual when, fitted alone to the residual,
   it is resolved from every echo already there by Sparrow's criterion (the
   pair's sum shows two features: four inflection points), and kept after the
   refit of all echoes only if the Bayesian information criterion decreases
   (Schwarz 1978). The search stops at the first rejected residual peak.
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
Sparrow, C. M. (1916). On spectroscopic resolving power. ApJ 44, 76.
    doi:10.1086/142271
Tobin, J. (1958). Estimation of relationships for limited dependent
    variables. Econometrica 26(1), 24-36. doi:10.2307/1907382
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
# LM stops when the relative change of the RSS or of the parameters is under 1e-6:
# a millionth of a parameter, far below any standard error of 8-16 bit waveforms
_LM_TOL = 1e-6


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


# ------------------------------------------------------------- the fit ---

def _fit(y: np.ndarray, t: np.ndarray, amp, loc, sig, base, fit_baseline: bool,
         max_nfev: int, censored=None):
    """Levenberg-Marquardt fit; returns (params, free mask, cov or None, rss).

    ``censored`` (boolean mask or None) marks saturated samples: their true
    value is at least the recorded one, so they contribute a residual only
    where the model falls below them (one-sided, Tobit-like least squares).
    The Jacobian is built in column-major layout (``col_deriv``) so MINPACK
    uses it without a copy.
    """
    k = len(amp)
    # internal layout [a_1..a_k, mu_1..mu_k, sigma_1..sigma_k, b]: contiguous slices
    q0 = np.concatenate([np.asarray(amp, float), np.asarray(loc, float),
                         np.asarray(sig, float), [float(base)]])
    nf = q0.size if fit_baseline else q0.size - 1
    y_b = y if fit_baseline else y - float(base)
    jac = np.empty((nf, t.size))
    if fit_baseline:
        jac[-1] = 1.0
    last = {"key": None}

    def f(q):
        a, m, s = q[:k], q[k:2 * k], q[2 * k:3 * k]
        z = t - m[:, None]  # (k, n), scaled in place
        z /= s[:, None]
        e = np.square(z)
        e *= -0.5
        np.exp(e, out=e)
        r = a @ e
        r -= y_b
        if fit_baseline:
            r += q[3 * k]
        if censored is not None:
            r[censored] = np.minimum(r[censored], 0.0)
        last.update(key=q.tobytes(), z=z, e=e, a_s=a / s, r=r)
        return r

    def df(q):
        # MINPACK asks for the Jacobian at the last point where it evaluated f
        if q.tobytes() != last["key"]:
            f(q)
        z, e = last["z"], last["e"]
        jac[:k] = e
        dm = jac[k:2 * k]
        np.multiply(e, last["a_s"][:, None], out=dm)
        dm *= z
        np.multiply(dm, z, out=jac[2 * k:3 * k])
        if censored is not None:
            jac[:, censored & (last["r"] >= 0.0)] = 0.0
        return jac

    with np.errstate(over="ignore", invalid="ignore", divide="ignore", under="ignore"):
        q, cov, info, _msg, _ier = optimize.leastsq(
            f, q0[:nf], Dfun=df, col_deriv=True, full_output=True, maxfev=max_nfev,
            ftol=_LM_TOL, xtol=_LM_TOL)
    # back to the public layout [a_1, mu_1, sigma_1, ..., b]
    order = np.append(np.arange(3 * k).reshape(3, k).T.reshape(-1), 3 * k)
    qf = q0.copy()
    qf[:nf] = q
    full = qf[order]
    full[2:-1:3] = np.abs(full[2:-1:3])
    free = np.zeros(full.size, bool)
    free[:full.size if fit_baseline else full.size - 1] = True
    if cov is not None:
        sel = order[:nf] if fit_baseline else order[:-1]
        cov = cov[np.ix_(sel, sel)]
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
              impulse=None, deconvolution_iterations: int = 30, saturation="auto",
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
        Add echoes at residual maxima while the BIC decreases; a new echo must
        be resolved from the others where it appears (Sparrow's criterion).
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
    saturation : "auto", float or None
        Clipped samples are censored: the true value is at least the recorded
        one, so they count in the fit only where the model falls below them
        (the unsaturated flanks then set the echo's height and width).
        ``"auto"``: a run of 3 or more equal samples at the record maximum
        (a Gaussian echo sampled at 1 ns cannot give three equal top samples
        unless it is clipped or wider than the quantisation allows);
        a number: the digitiser's full-scale value (samples at or above it are
        clipped); None: no censoring.
    max_nfev : int
        Function evaluations per Levenberg-Marquardt run.

    Returns
    -------
    Components
        Echoes sorted by time, with standard errors.

    Raises
    ------
    InputError
        Samples not 1-D, not finite, fewer than 4; non-positive ``dt_ns``;
        ``saturation`` neither "auto", None nor a positive number.

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
    cand = _detect(ys, base0, thr, terraces, True)
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
    opts = dict(y=y, valid=valid, thr=thr, smooth=smooth, k_max=k_max, censored=censored,
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


def _linear_start(y, amp, loc, sig, base, fit_baseline, valid, censored):
    """Start amplitudes (and baseline) by linear least squares at the guessed locations
    and widths: sample heights include the tails of overlapping echoes, the linear
    solution does not. Falls back to the heights when an amplitude comes out <= 0."""
    use = np.ones(y.size, bool)
    if valid is not None:
        use &= valid
    if censored is not None:
        use &= ~censored
    t = np.flatnonzero(use).astype(float)
    z = (t[:, None] - loc) / sig
    design = np.exp(-0.5 * z * z)
    target = y[use]
    if fit_baseline:
        design = np.column_stack([design, np.ones(t.size)])
    else:
        target = target - base
    if t.size <= design.shape[1]:
        return amp, base
    coef = np.linalg.lstsq(design, target, rcond=None)[0]
    a = coef[:amp.size]
    if not np.all(a > 0):
        return amp, base
    return a, (float(coef[-1]) if fit_baseline else base)


def _gaps(y: np.ndarray):
    """Mask of samples with data (False: no-data zeros), or None when there is no gap.

    Exact zeros are no-data fill when the rest of the record has its baseline more
    than 4 noise standard deviations above zero (noise cannot reach them).
    """
    zero = y == 0.0
    if not zero.any() or zero.sum() > y.size - 4:
        return None
    b, s = noise_level(y[~zero])
    return ~zero if b > 4.0 * s else None


def _saturated(y: np.ndarray, saturation):
    """Mask of clipped samples, or None (see ``saturation`` in :func:`decompose`)."""
    if saturation is None:
        return None
    if isinstance(saturation, bool):
        raise InputError(f"saturation must be 'auto', None or the digitiser's full-scale "
                         f"value (a number); got {saturation!r}")
    if isinstance(saturation, str):
        if saturation != "auto":
            raise InputError(f"saturation must be 'auto', None or the digitiser's full-scale "
                             f"value (a number); got {saturation!r}")
        top = y.max()
        starts, ends = _runs(y)
        at_top = (y[starts] == top) & (ends - starts + 1 >= 3)
        if not at_top.any():
            return None
        mask = np.zeros(y.size, bool)
        for i0, i1 in zip(starts[at_top], ends[at_top]):
            mask[i0:i1 + 1] = True
        return mask
    level = _positive(saturation, "saturation")
    mask = y >= level
    return mask if mask.any() else None


def _resolved(m: np.ndarray, s: np.ndarray, a: np.ndarray, j: int) -> bool:
    """Whether echo ``j`` is resolved from each other echo (Sparrow's criterion).

    Two echoes are resolved when their sum shows two features, two maxima or a
    maximum and a shoulder: four inflection points instead of the single
    Gaussian's two. For two equal Gaussians this happens beyond a separation
    of 2 sigma (where the sum's curvature at the midpoint changes sign).
    """
    for i in range(m.size):
        if i == j:
            continue
        lo = min(m[i] - 3 * s[i], m[j] - 3 * s[j])
        hi = max(m[i] + 3 * s[i], m[j] + 3 * s[j])
        x = np.linspace(lo, hi, 400)
        curv = 0.0
        for k in (i, j):
            z = (x - m[k]) / s[k]
            curv = curv + a[k] * (z * z - 1.0) * np.exp(-0.5 * z * z) / s[k] ** 2
        if np.count_nonzero(np.diff(np.sign(curv)) != 0) < 4:
            return False
    return True


def _order_and_fit(amp, loc, sig, base, *, y, valid, thr, smooth, k_max, censored,
                   add_components, max_nfev, fit_baseline):
    """Fit, prune insignificant echoes, add resolved echoes at residual peaks (BIC).

    ``valid`` (mask or None) selects the samples fitted; ``y`` has its gaps filled.
    Returns (params, free, cov, rss) or None when no echo survives.
    """
    t = np.arange(y.size, dtype=float)
    if valid is None:
        y_fit, t_fit, cens_fit = y, t, censored
    else:
        y_fit, t_fit = y[valid], t[valid]
        cens_fit = None if censored is None else censored[valid]
    n = y_fit.size

    def fit(a, m, s, b):
        return _fit(y_fit, t_fit, a, m, s, b, fit_baseline, max_nfev, cens_fit)

    def prune(p, free, cov, rss):
        while True:
            a, m, s, b = _split(p)
            se = _standard_errors(p, free, cov, rss, n)
            se_a = se[0:-1:3]
            # significant: fitted height at least the detection threshold and two
            # standard errors; resolvable: sigma >= 0.3 sample; peak inside the record
            # or at most one sigma beyond its ends (an echo cut by the record)
            bad = ((a < thr) | (s < _MIN_SIGMA_SAMPLES) | (s > t.size) | (m < -s)
                   | (m > t.size - 1 + s) | ~np.isfinite(a)
                   | (np.isfinite(se_a) & (a < 2.0 * se_a)))
            if not bad.any():
                return p, free, cov, rss
            keep = ~bad
            if not keep.any():
                # a detected echo exists: keep the strongest well-formed one rather than none
                usable = (np.isfinite(a) & (a > 0) & (s >= _MIN_SIGMA_SAMPLES) & (s <= t.size)
                          & (m >= -s) & (m <= t.size - 1 + s))
                if not usable.any():
                    return None
                keep[int(np.argmax(np.where(usable, a, -np.inf)))] = True
                return fit(a[keep], m[keep], s[keep], b)
            p, free, cov, rss = fit(a[keep], m[keep], s[keep], b)

    state = prune(*fit(amp, loc, sig, base))
    if state is None or not add_components:
        return state
    p, free, cov, rss = state
    n_eff = n - (0 if cens_fit is None else int(cens_fit.sum()))
    bic = _bic(rss, n_eff, int(free.sum()))
    # residual peaks are tried from the highest down. One that is not resolved from the
    # echoes already there is passed over (it is the pulse's departure from a Gaussian,
    # e.g. the tail of the system response, not a target); the search stops at the first
    # resolved one that does not lower the BIC (a lower residual peak is even less likely
    # to)
    skipped = np.zeros(y.size, bool)
    while (p.size - 1) // 3 < k_max:
        a, m, s, b = _split(p)
        r = y - b - gaussian_sum(t, a, m, s)
        if censored is not None:
            r[censored] = 0.0
        if valid is not None:
            r[~valid] = 0.0
        rs = gaussian_filter1d(r, max(smooth, 1.0))
        rs[skipped] = -np.inf
        j = int(np.argmax(rs))
        if rs[j] < thr:
            break
        # one Gaussian fitted to the residual, the other echoes held
        hw = [w for w in (_half_width(rs, j, j, rs[j], 0.0, -1),
                          _half_width(rs, j, j, rs[j], 0.0, +1)) if w is not None]
        s0 = max(float(np.mean(hw)) / np.sqrt(2.0 * np.log(2.0)), 0.5) if hw else float(
            np.median(s))
        lone = _fit(r if valid is None else r[valid], t_fit, [max(r[j], rs[j])], [float(j)],
                    [s0], 0.0, False, max_nfev, cens_fit)[0]
        if not _resolved(np.append(m, lone[1]), np.append(s, lone[2]),
                         np.append(a, lone[0]), a.size):
            # pass over this residual feature: mask it to its half-maximum width
            lo = j - (hw[0] if hw else 2.0)
            hi = j + (hw[-1] if hw else 2.0)
            skipped[max(0, int(np.floor(lo))):int(np.ceil(hi)) + 1] = True
            continue
        trial = prune(*fit(np.append(a, lone[0]), np.append(m, lone[1]),
                           np.append(s, lone[2]), b))
        if trial is None or (trial[0].size - 1) // 3 <= (p.size - 1) // 3:
            break
        bic_new = _bic(trial[3], n_eff, int(trial[1].sum()))
        if bic_new >= bic:
            break
        p, free, cov, rss = trial
        bic = bic_new
        skipped[:] = False
    return p, free, cov, rss


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

