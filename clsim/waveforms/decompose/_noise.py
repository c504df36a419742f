"""Baseline and noise of a waveform; no-data gaps and clipped samples."""

from __future__ import annotations

import numpy as np

from clsim.errors import InputError
from clsim.waveforms.decompose._checks import _as_waveform, _positive


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


def response_above_baseline(samples, name: str) -> np.ndarray:
    """A measured system response with its baseline (:func:`noise_level`) removed and
    negative samples clipped; an InputError when nothing is left above the baseline."""
    h = _as_waveform(samples, name)
    h = np.clip(h - noise_level(h)[0], 0.0, None)
    if h.max() <= 0:
        raise InputError(f"{name} has no signal above its baseline; pass the measured system "
                         "response (a return from a hard target)")
    return h


def _runs(y: np.ndarray):
    """Start and end (inclusive) indices of runs of equal consecutive values."""
    change = np.flatnonzero(np.diff(y) != 0)
    starts = np.concatenate(([0], change + 1))
    ends = np.concatenate((change, [y.size - 1]))
    return starts, ends


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

