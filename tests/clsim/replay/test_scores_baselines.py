"""Per-pulse scores and the two baselines against known answers."""

from __future__ import annotations

import numpy as np
import pytest

from clsim.replay import MeasuredPulses, Prepared, blair_hofton, nearest_pulse, score_pulse, summarize


def _two_peaks(t, a=1.0, b=0.5, mu=(20.0, 50.0), s=3.0):
    return 100 * (a * np.exp(-0.5 * ((t - mu[0]) / s) ** 2) + b * np.exp(-0.5 * ((t - mu[1]) / s) ** 2))


def test_identical_waveforms_score_perfectly():
    t = np.arange(80.0)
    y = _two_peaks(t)
    s = score_pulse(y, y)
    assert s["r"] == pytest.approx(1.0) and s["r_best"] == pytest.approx(1.0) and s["lag_ns"] == 0
    assert s["energy_ratio"] == pytest.approx(1.0)
    for p in (25, 50, 75, 98):
        assert s[f"rh{p}"] == pytest.approx(s[f"rh{p}_measured"])
    # ground: the lower peak at 50 ns; canopy cover: canopy energy over total = 1 / 1.5 (mirror method)
    assert s["cover_measured"] == pytest.approx(1.0 / 1.5, abs=1e-3)


def test_a_late_and_brighter_prediction_is_found_late_and_brighter():
    t = np.arange(80.0)
    y = _two_peaks(t)
    pred = 1.3 * _two_peaks(t, mu=(22.0, 52.0))
    s = score_pulse(y, pred)
    assert s["r"] < 0.9 and s["r_best"] == pytest.approx(1.0, abs=1e-6) and s["lag_ns"] == 2.0
    assert s["energy_ratio"] == pytest.approx(1.3, rel=1e-3)
    # 2 ns later is 0.30 m lower: every height reads 0.30 m less against the same ground
    c_half = 0.299792458 / 2 / 1.000293
    assert s["rh50"] - s["rh50_measured"] == pytest.approx(-2 * c_half, abs=0.01)
    summary = summarize([s, score_pulse(y, y)])
    assert summary["pulses"] == 2 and summary["energy_ratio_q75"] > summary["energy_ratio_q25"]


def _parallel_pulses():
    """Four vertical records 0.3 m apart in x over the same canopy, each sample 0.15 m lower."""
    n, width = 4, 60
    t = np.arange(width, dtype=float)
    x = 0.3 * np.arange(n)
    signal = np.stack([_two_peaks(t, b=0.5 + 0.2 * i, mu=(20.0 + i, 45.0)) for i in range(n)])
    step = np.tile([0.0, 0.0, -0.15], (n, 1))
    bin0 = np.c_[x, np.zeros(n), np.full(n, 20.0)]
    bin0[2, 2] += 0.15 * 3  # pulse 2 starts 3 samples higher: its record is shifted
    signal[2] = np.r_[np.zeros(3), signal[2][:-3]]
    pulses = MeasuredPulses(samples=signal + 10, valid=np.ones_like(signal, bool), dt_ns=1.0, bin0=bin0, step=step,
                            origin=bin0 + [0, 0, 1000.0], line=np.zeros(n, int))
    h = np.exp(-0.5 * ((np.arange(21) - 10) / 3.0) ** 2)
    return Prepared(pulses=pulses, signal=signal, mask=np.ones_like(signal, bool), noise=np.ones(n), shape=h / h.sum(),
                    shape_peak=10.0, echo_pulse=np.zeros(0, int), echo_sample=np.zeros(0), echo_energy=np.zeros(0),
                    echo_sigma=np.zeros(0), echo_xyz=np.zeros((0, 3)))


def test_nearest_pulse_moves_the_neighbour_to_the_same_heights():
    p = _parallel_pulses()
    # pulse 1's nearest training pulse among 0, 2, 3 is 0 or 2 (0.3 m); 2 lies 3 samples higher
    got = nearest_pulse(p, 3, np.array([0, 2]))
    want = p.signal[2][3:]  # pulse 2's samples at pulse 3's heights
    assert np.allclose(got[: want.size], want, atol=1e-9)


def test_blair_hofton_from_one_coincident_pulse_rebuilds_its_echoes():
    p = _parallel_pulses()
    # echoes of pulse 0: its two Gaussians' energies at their peaks (the template is the same Gaussian)
    e = 100 * 3.0 * np.sqrt(2 * np.pi) * np.array([1.0, 0.5])
    p.echo_pulse = np.array([0, 0])
    p.echo_sample = np.array([20.0, 45.0])
    p.echo_energy = e
    p.echo_xyz = p.pulses.bin0[0] + p.echo_sample[:, None] * p.pulses.step[0]
    # a test pulse on the same axis as pulse 0 (pulse 0 itself, trained on itself): its own waveform back
    got = blair_hofton(p, 0, np.array([0]), sigma_m=0.3)
    assert np.allclose(got, p.signal[0], atol=0.02 * p.signal[0].max())
    # the footprint weights: a test pulse 0.3 m away gets the same shape (weights normalised by the pulses')
    got1 = blair_hofton(p, 1, np.array([0]), sigma_m=0.3)
    assert np.allclose(got1, p.signal[0], atol=0.02 * p.signal[0].max())
