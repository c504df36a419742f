"""Matched-filter echo detection with a controlled false-alarm rate.

The baseline-free waveform is correlated with the system pulse ``p`` (unit
peak), scaled so the output estimates the amplitude of a pulse-shaped echo at
every lag: ``f = (y - b) * p / ||p||^2``. For white noise of standard deviation
``sigma`` the output's noise is ``sigma / ||p||``, and a pulse-shaped echo of
amplitude ``A`` stands ``A ||p|| / sigma`` output sigmas above it, the largest
signal-to-noise ratio of any linear filter (North 1943; Turin 1960). For a
Gaussian pulse of ``s`` samples, ``||p||^2 = s sqrt(pi)``: with ``s = 2.5`` a
5-sigma echo stands 10.5 output sigmas high.

The threshold ``u`` (in output sigmas) is set from the expected number of
up-crossings of a stationary Gaussian process (Rice 1944), per noise-only
record of ``n`` samples::

    E[N_u] = n sqrt(lambda_2) / (2 pi) exp(-u^2 / 2)

with ``lambda_2 = sum(diff(g)^2)`` the variance of the derivative of the
filtered unit-variance noise (``g = p / ||p||``). Every excursion above ``u``
holds at least one local maximum and at high ``u`` exactly one, so solving
``E[N_u] = false_alarm`` gives the false-alarm rate per noise-only waveform.

References
----------
North, D. O. (1943/1963). An analysis of the factors which determine
    signal/noise discrimination in pulsed-carrier systems. Proc. IEEE 51(7),
    1016-1027. doi:10.1109/PROC.1963.2383
Turin, G. L. (1960). An introduction to matched filters. IRE Trans. Inf.
    Theory 6(3), 311-329. doi:10.1109/TIT.1960.1057571
Rice, S. O. (1944). Mathematical analysis of random noise. Bell Syst. Tech. J.
    23(3), 282-332. doi:10.1002/j.1538-7305.1944.tb00874.x
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.ndimage import correlate1d

from clsim.errors import InputError
from clsim.waveforms.decompose._checks import _as_waveform, _positive
from clsim.waveforms.decompose._model import FWHM_PER_SIGMA, Components
from clsim.waveforms.decompose._noise import noise_level, response_above_baseline
from voxlidar.choices import Choice

#: Default expected number of false echoes per noise-only waveform.
FALSE_ALARM = 0.01
#: Pulse width (Gaussian standard deviation, samples) when nothing measures it.
_FALLBACK_SIGMA = 2.0


@dataclass(frozen=True)
class Pulse:
    """A sampled system pulse (unit peak) for the matched filter.

    Attributes
    ----------
    shape : (m,) float64
        Pulse samples, peak 1.
    centre : int
        Index of the peak sample (lag 0 of the filter).
    sigma : float
        Gaussian-equivalent standard deviation (FWHM / 2.3548), samples.
    """

    shape: np.ndarray
    centre: int
    sigma: float

    @property
    def norm(self) -> float:
        """``||p||_2``: an echo of amplitude A stands ``A ||p|| / sigma`` high."""
        return float(np.sqrt(np.sum(self.shape ** 2)))

    @property
    def weights(self) -> np.ndarray:
        """The matched filter's correlation weights, ``p / ||p||^2`` (lag 0 at
        ``centre``): its output is in amplitude units (:func:`filter_output` and the
        device kernels use these)."""
        return self.shape / float(np.sum(self.shape * self.shape))

    @classmethod
    def gaussian(cls, sigma: float) -> Pulse:
        half = int(np.ceil(4.0 * sigma))
        x = np.arange(-half, half + 1, dtype=float)
        return cls(np.exp(-0.5 * (x / sigma) ** 2), half, float(sigma))

    @classmethod
    def measured(cls, samples) -> Pulse:
        """From a measured system response (baseline removed, cut at 1 % of its peak)."""
        h = response_above_baseline(samples, "pulse")
        h = h / h.max()
        c = int(np.argmax(h))
        above = np.flatnonzero(h >= 0.01)
        lo, hi = int(above[0]), int(above[-1])
        h = h[lo:hi + 1]
        c -= lo
        # Gaussian-equivalent width from the FWHM (interpolated half-maximum crossings)
        left = np.flatnonzero(h[:c + 1] < 0.5)
        right = np.flatnonzero(h[c:] < 0.5)
        xl = (left[-1] + (0.5 - h[left[-1]]) / (h[left[-1] + 1] - h[left[-1]])
              if left.size else 0.0)
        xr = (c + right[0] - 1 + (h[c + right[0] - 1] - 0.5)
              / (h[c + right[0] - 1] - h[c + right[0]]) if right.size else h.size - 1.0)
        return cls(h, c, max(float(xr - xl) / FWHM_PER_SIGMA, 0.5))


class Detection(str, Choice):
    """Echo detection of :func:`decompose`.

    ``matched``: matched filter with the system pulse, threshold from the
    false-alarm rate (:func:`detect_echoes`). ``amplitude``: local maxima of the
    smoothed samples ``min_amplitude`` above the baseline (the earlier rule).
    """

    MATCHED = "matched"
    AMPLITUDE = "amplitude"


def threshold(n_samples: int, pulse: Pulse, *, false_alarm: float = FALSE_ALARM) -> float:
    """Matched-filter threshold, in output noise sigmas, for a false-alarm rate.

    Parameters
    ----------
    n_samples : int
        Samples in the waveform.
    pulse : Pulse
    false_alarm : float
        Expected number of false echoes per noise-only waveform.

    Returns
    -------
    float
        ``u`` with ``n sqrt(lambda_2) / (2 pi) exp(-u^2/2) = false_alarm``
        (Rice 1944), at least 3.

    Examples
    --------
    >>> round(threshold(200, Pulse.gaussian(2.5), false_alarm=0.01), 2)
    3.69
    """
    g = pulse.shape / pulse.norm
    lam2 = float(np.sum(np.diff(g) ** 2))
    rate = n_samples * np.sqrt(lam2) / (2.0 * np.pi)
    return float(np.sqrt(2.0 * np.log(max(rate / false_alarm, 1.0)))) if rate > 0 else 3.0


def clipped_baseline(y: np.ndarray, sigma: float, start: float) -> float:
    """Mean of the samples within 2.5 sigma of the baseline, iterated from ``start``.

    The median of the lowest fifth (:func:`noise_level`) sits about 0.8 sigma
    below the mean of the noise; the matched filter sums ``||p||_1`` samples,
    so that bias would add ``0.8 sigma ||p||_1`` to its output. Five rounds of
    a symmetric 2.5-sigma window move it onto the noise mean (a truncated
    normal's mean is unbiased under a symmetric window).
    """
    b = float(start)
    for _ in range(5):
        near = np.abs(y - b) < 2.5 * sigma
        if near.sum() < 3:
            break
        b = float(np.mean(y[near]))
    return b


def filter_output(y: np.ndarray, pulse: Pulse) -> np.ndarray:
    """Matched-filter output in amplitude units: ``(y * p)[lag] / ||p||^2`` (zero padded).

    ``y`` is the baseline-free waveform, (n,) or (N, n) (filtered along the last axis).
    """
    p = pulse.shape
    # correlate1d centres the weights on index len // 2; shift so lag 0 is the pulse peak
    origin = pulse.centre - p.size // 2
    return correlate1d(y, pulse.weights, axis=-1, mode="constant", cval=0.0,
                       origin=origin)


def _local_maxima(f: np.ndarray, level: float) -> np.ndarray:
    """Indices of local maxima of ``f`` above ``level`` (plateaus: the first sample)."""
    if f.size < 3:
        return np.zeros(0, int)
    up = np.diff(f) > 0
    down = np.diff(f) <= 0
    peak = np.zeros(f.size, bool)
    peak[1:-1] = up[:-1] & down[1:]
    peak[0] = down[0]
    peak[-1] = up[-1]
    return np.flatnonzero(peak & (f > level))


def _subsample(f: np.ndarray, i: np.ndarray) -> np.ndarray:
    """Parabolic interpolation of the maxima at ``i``, samples."""
    lo = np.clip(i - 1, 0, f.size - 1)
    hi = np.clip(i + 1, 0, f.size - 1)
    den = f[lo] - 2.0 * f[i] + f[hi]
    with np.errstate(divide="ignore", invalid="ignore"):
        d = np.where(den < 0, 0.5 * (f[lo] - f[hi]) / den, 0.0)
    return i + np.clip(d, -0.5, 0.5)


def detect_echoes(samples, *, dt_ns: float = 1.0, t0_ns: float = 0.0, pulse=None,
                  pulse_sigma_ns=None, false_alarm: float = FALSE_ALARM,
                  baseline=None) -> Components:
    """Echoes found by a matched filter with the system pulse (see the module docstring).

    Parameters
    ----------
    samples : (n,) array_like
        One waveform, samples ``dt_ns`` apart.
    dt_ns, t0_ns : float
        Sample spacing and time of the first sample, ns.
    pulse : (m,) array_like, optional
        Measured system pulse (e.g. the return from a hard target, or the
        outgoing pulse), same sample spacing; its baseline is removed.
    pulse_sigma_ns : float, optional
        Else a Gaussian pulse of this standard deviation, ns. Default: the
        width of the strongest echo (:func:`detect_peaks`, 4 sigma), or 2
        samples when no echo rises 4 sigma.
    false_alarm : float
        Expected false echoes per noise-only waveform (white Gaussian noise).
    baseline : float, optional
        Default: the 2.5-sigma clipped mean (:func:`clipped_baseline`).

    Returns
    -------
    Components
        One row per local maximum of the filter output above the threshold:
        amplitude = filter output (amplitude of a pulse-shaped echo), location
        from parabolic interpolation, sigma = the pulse's. Standard errors NaN.

    Examples
    --------
    >>> from clsim.waveforms.decompose import gaussian_sum
    >>> rng = np.random.default_rng(0)
    >>> t = np.arange(150.0)
    >>> y = 10 + gaussian_sum(t, [5.0], [70.0], [2.5]) + rng.normal(0, 1, t.size)
    >>> c = detect_echoes(y, pulse_sigma_ns=2.5)
    >>> len(c), bool(abs(c.location_ns[0] - 70) < 1)
    (1, True)
    """
    y = _as_waveform(samples)
    dt = _positive(dt_ns, "dt_ns")
    fa = _positive(false_alarm, "false_alarm")
    b_low, sigma = noise_level(y)
    pl = resolve_pulse(y, b_low, sigma, pulse=pulse, pulse_sigma_ns=pulse_sigma_ns, dt=dt)
    base = clipped_baseline(y, sigma, b_low) if baseline is None else float(baseline)
    f = filter_output(y - base, pl)
    u = threshold(y.size, pl, false_alarm=fa)
    idx = _local_maxima(f, u * sigma / pl.norm)
    if idx.size == 0:
        return Components.empty(baseline=base, noise_sigma=sigma)
    loc = _subsample(f, idx)
    nan = np.full(idx.size, np.nan)
    return Components(f[idx], t0_ns + loc * dt, np.full(idx.size, pl.sigma * dt), nan,
                      nan.copy(), nan.copy(), baseline=base, noise_sigma=sigma)


def resolve_pulse(y, b_low, sigma, *, pulse, pulse_sigma_ns, dt) -> Pulse:
    """The :class:`Pulse` for ``pulse`` / ``pulse_sigma_ns`` / the strongest echo's width."""
    if pulse is not None:
        if pulse_sigma_ns is not None:
            raise InputError("give pulse (a measured response) or pulse_sigma_ns, not both")
        return pulse if isinstance(pulse, Pulse) else Pulse.measured(pulse)
    if pulse_sigma_ns is not None:
        return Pulse.gaussian(_positive(pulse_sigma_ns, "pulse_sigma_ns") / dt)
    from clsim.waveforms.decompose._detection import _detect

    cand = _detect(y, b_low, 4.0 * sigma, False, False)
    good = [c for c in cand if np.isfinite(c[2])]
    s = max(good, key=lambda c: c[1])[2] if good else _FALLBACK_SIGMA
    return Pulse.gaussian(float(np.clip(s, 0.7, max(0.7, y.size / 8.0))))
