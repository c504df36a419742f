"""Richardson-Lucy deconvolution by a measured system impulse response."""

from __future__ import annotations

import numpy as np

from clsim.errors import InputError
from clsim.waveforms.decompose._checks import _as_waveform
from clsim.waveforms.decompose._noise import noise_level, response_above_baseline


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
    if int(iterations) < 1:
        raise InputError(f"iterations must be >= 1; got {iterations!r}")
    h = response_above_baseline(impulse, "impulse")
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

