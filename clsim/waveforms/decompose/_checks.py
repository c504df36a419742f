"""Input checks where a waveform enters the decomposition."""

from __future__ import annotations

import numpy as np

from clsim.errors import InputError


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

