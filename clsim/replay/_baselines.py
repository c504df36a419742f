"""The two baselines a replay is scored beside, from training pulses only.

- :func:`blair_hofton`: the standard method of waveform simulators from ALS
  data (Blair & Hofton 1999; the GEDI simulator, Hancock et al. 2019): every
  training echo near the test beam, weighted by the footprint's Gaussian at
  its distance from the beam axis and by its energy, placed at its range on
  the test beam and convolved with the system pulse.  ``kind="samples"``
  takes every training sample above three noise sigma as the point instead
  (its value already holds the pulse, so it is not convolved again).  The sum
  is divided by the footprint weight of the training pulses themselves, so
  that a test pulse between training pulses gets their weighted mean.
- :func:`nearest_pulse`: the measured training pulse whose beam passes
  nearest, moved onto the test beam (each of its samples to the test sample at
  the same height): a ceiling no forward model is expected to pass.

Both work on :class:`~clsim.replay._echoes.Prepared` records and return
predictions on each test record's samples, in the file's counts.
"""

from __future__ import annotations

import numpy as np

__all__ = ["beam_distance", "blair_hofton", "nearest_pulse", "project"]


def project(prepared, i: int, points) -> tuple[np.ndarray, np.ndarray]:
    """Sample index along test pulse ``i`` of ``points`` (P, 3), and their distance from its axis, metres."""
    p = prepared.pulses
    rel = np.asarray(points, dtype=np.float64) - p.bin0[i]
    s = p.step[i]
    k = rel @ s / float(s @ s)
    perp = rel - k[:, None] * s
    return k, np.linalg.norm(perp, axis=1)


def beam_distance(prepared, i: int, others) -> np.ndarray:
    """(J,) distance, metres, of the beams ``others`` from test beam ``i`` at the middle of its record."""
    p = prepared.pulses
    mid = p.bin0[i] + 0.5 * p.n_samples[i] * p.step[i]
    rel = mid - p.bin0[others]
    s = p.step[others]
    k = np.einsum("ij,ij->i", rel, s) / np.einsum("ij,ij->i", s, s)
    return np.linalg.norm(rel - k[:, None] * s, axis=1)


def _place(length: int, at, values, shape, peak) -> np.ndarray:
    """Sum of ``values`` times the pulse ``shape`` (peak at ``peak``) centred at samples ``at``."""
    out = np.zeros(length)
    idx = np.arange(length)
    grid = np.arange(shape.size)
    for a, v in zip(at, values):
        out += v * np.interp(idx - a + peak, grid, shape, left=0.0, right=0.0)
    return out


def _weights(d, sigma):
    return np.exp(-0.5 * (d / sigma) ** 2)


def blair_hofton(prepared, test: int, train, *, sigma_m: float, kind: str = "echoes") -> np.ndarray:
    """Predicted waveform of pulse ``test`` from the pulses ``train`` (see the module docstring).

    Parameters
    ----------
    prepared : Prepared
    test : int
    train : (J,) int array
    sigma_m : float, metres
        Standard deviation of the footprint's Gaussian.
    kind : {"echoes", "samples"}

    Returns
    -------
    (S,) float64, counts on the test record's samples
    """
    train = np.asarray(train)
    length = prepared.signal.shape[1]
    wj = _weights(beam_distance(prepared, test, train), sigma_m)
    norm = wj.sum()
    if not norm > 1e-12:  # no training beam within reach: the nearest one's weight
        wj = np.zeros_like(wj)
        wj[np.argmin(beam_distance(prepared, test, train))] = 1.0
        norm = 1.0
    if kind == "echoes":
        sel = np.isin(prepared.echo_pulse, train)
        k, d = project(prepared, test, prepared.echo_xyz[sel])
        w = _weights(d, sigma_m) * prepared.echo_energy[sel]
        near = w > 1e-6 * max(w.max(initial=0.0), 1e-300)
        return _place(length, k[near], w[near] / norm, prepared.shape, prepared.shape_peak)
    out = np.zeros(length)
    p = prepared.pulses
    for j, wt in zip(train, wj):
        if wt < 1e-6 * wj.max():
            continue
        y = prepared.signal[j]
        above = np.flatnonzero(prepared.mask[j] & (y > 3.0 * prepared.noise[j]))
        if not above.size:
            continue
        pts = p.bin0[j] + above[:, None] * p.step[j]
        k, d = project(prepared, test, pts)
        w = _weights(d, sigma_m) * y[above] / norm
        lo = np.floor(k).astype(int)
        f = k - lo
        for a, b in ((lo, w * (1 - f)), (lo + 1, w * f)):
            ok = (a >= 0) & (a < length)
            np.add.at(out, a[ok], b[ok])
    return out


def nearest_pulse(prepared, test: int, train) -> np.ndarray:
    """The training record whose beam passes nearest pulse ``test``, on the test record's samples.

    Each test sample takes the nearest pulse's value at the same height
    (linear interpolation between its samples; 0 outside its record).
    """
    train = np.asarray(train)
    j = int(train[np.argmin(beam_distance(prepared, test, train))])
    p = prepared.pulses
    length = prepared.signal.shape[1]
    z_test = p.bin0[test, 2] + np.arange(length) * p.step[test, 2]
    kj = (z_test - p.bin0[j, 2]) / p.step[j, 2]
    n = int(p.n_samples[j])
    return np.interp(kj, np.arange(n), prepared.signal[j, :n], left=0.0, right=0.0)
