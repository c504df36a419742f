"""Waveform metrics against analytic answers."""

from __future__ import annotations

import numpy as np
import pytest

from clsim.errors import InputError
from clsim.waveforms.metrics import (
    C_HALF_M_PER_NS,
    align_on_ground,
    canopy_ground_ratio,
    compare_waveforms,
    ground_peak_ns,
    pearson_r,
    relative_heights,
)


def g(t, a, m, s):
    return a * np.exp(-0.5 * ((t - m) / s) ** 2)


T = np.arange(0.0, 400.0, 0.1)


def test_ground_peak_subsample():
    t = np.arange(0.0, 100.0)
    w = g(t, 1.0, 20.0, 3.0) + g(t, 0.4, 71.37, 2.0)
    assert ground_peak_ns(t, w) == pytest.approx(71.37, abs=1e-9)  # exact for a Gaussian


def test_alignment_recovers_shift():
    ref = g(T, 1.0, 100.0, 4.0) + g(T, 0.8, 180.0, 2.0)
    sim = g(T, 1.0, 100.0 - 3.33, 4.0) + g(T, 0.8, 180.0 - 3.33, 2.0)
    aligned, shift = align_on_ground(T, sim, T, ref)
    assert shift == pytest.approx(3.33, abs=1e-3)
    res = compare_waveforms(T, 2.5 * sim, T, ref)
    assert res.pearson_r == pytest.approx(1.0, abs=1e-6)
    assert res.rmse < 1e-5


def test_pearson_of_shifted_gaussians_analytic():
    """Centred correlation of two equal Gaussians d apart on a window of length L:
    (s sqrt(pi) e^{-d^2/4s^2} - 2 pi s^2 / L) / (s sqrt(pi) - 2 pi s^2 / L)."""
    s, d = 3.0, 4.0
    length = T[-1] - T[0] + 0.1
    x, y = g(T, 1.0, 200.0, s), g(T, 1.0, 200.0 + d, s)
    expect = ((s * np.sqrt(np.pi) * np.exp(-d * d / (4 * s * s)) - 2 * np.pi * s * s / length)
              / (s * np.sqrt(np.pi) - 2 * np.pi * s * s / length))
    assert pearson_r(x, y) == pytest.approx(expect, abs=1e-6)


def test_canopy_ground_ratio_analytic():
    w = g(T, 1.0, 100.0, 6.0) + g(T, 3.0, 200.0, 2.0)
    assert canopy_ground_ratio(T, w) == pytest.approx((1.0 * 6.0) / (3.0 * 2.0), rel=1e-6)


def test_relative_heights_analytic():
    """Uniform canopy from 5 to 25 m (80 % of energy) over a narrow ground return (20 %):
    RH_p = 5 + (p - 20) / 80 * 20 m for p > 20."""
    dt = 0.01
    t = np.arange(0.0, 300.0, dt)
    tg = 250.0
    h = (tg - t) * C_HALF_M_PER_NS
    canopy = ((h >= 5.0) & (h <= 25.0)).astype(float)
    e_c = canopy.sum() * dt
    ground = g(t, 1.0, tg, 0.3)
    ground *= 0.25 * e_c / (ground.sum() * dt)
    rh = relative_heights(t, canopy + ground, ground_time_ns=tg)
    for p, val in rh.items():
        assert val == pytest.approx(5.0 + (p - 20.0) / 80.0 * 20.0, abs=0.02)  # 1.5 mm bins
    # ground found automatically gives the same answer
    auto = relative_heights(t, canopy + ground)
    for p in rh:
        assert auto[p] == pytest.approx(rh[p], abs=0.01)


def test_bad_input():
    with pytest.raises(InputError, match="time_ns has 3"):
        ground_peak_ns([0, 1, 2], [0, 1, 2, 3])
    with pytest.raises(InputError, match="increase"):
        ground_peak_ns([0, 2, 1], [0, 1, 0])
    with pytest.raises(InputError, match="normalize='area'"):
        compare_waveforms(T, g(T, 1, 50, 2), T, g(T, 1, 50, 2), normalize="area")
