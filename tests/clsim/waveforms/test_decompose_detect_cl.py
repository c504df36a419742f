"""The detection kernels (``clsim/kernels/decompose_detect.cl``) against the NumPy
detection of ``decompose_batch`` on the same waveforms: the same samples counted and
censored, the same candidates, and baselines, noise, widths and start values equal
within float32 rounding."""

from __future__ import annotations

import numpy as np
import pytest

from clsim.waveforms.decompose import decompose_batch, gaussian_sum
from clsim.waveforms.decompose._batch import _pad
from clsim.waveforms.decompose._batch_cl import device_fitter
from clsim.waveforms.decompose._batch_detect import _batch_pulse, _rice, candidates_numpy, noise_stats_numpy
from clsim.waveforms.decompose._matched import Pulse


def _mixed(rng):
    """Weak and strong echoes, two overlapping echoes (a shoulder), 8-bit clipped
    echoes, noise only, no-data zeros (a gap in the record) and ragged lengths."""
    t = np.arange(150.0)
    rows = []
    for k in range(40):
        rows.append(20.0 + gaussian_sum(t, [80.0, 2.0 * (3 + k % 10)], [35.0, 85.0], [2.5, 2.5])
                    + rng.normal(0.0, 2.0, t.size))
    for k in range(20):
        rows.append(12.0 + gaussian_sum(t, [120.0, 45.0], [60.0, 66.0 + 0.1 * k], [2.2, 3.0])
                    + rng.normal(0.0, 1.5, t.size))
    for k in range(20):
        clean = 10.0 + gaussian_sum(t[:80], [300.0, 60.0], [40.0, 55.0], [2.5, 3.0])
        rows.append(np.minimum(np.round(clean + rng.normal(0.0, 1.5, 80)), 255.0))
    for k in range(20):
        rows.append(20.0 + rng.normal(0.0, 2.0, 60 + 4 * k))
    for k in range(10):
        y = np.round(30.0 + gaussian_sum(t, [90.0], [50.0], [3.0]) + rng.normal(0.0, 1.0, t.size))
        y[100 + k:120 + k] = 0.0  # no-data fill between two digitised segments
        rows.append(y)
    return rows


@pytest.mark.parametrize("saturation", ["auto", 250.0, None])
def test_kernels_match_numpy_detection(cl_device_for_fits, saturation):
    """Masks and candidate sets identical; baseline and noise within 1e-5 relative;
    start amplitudes within 1e-4 relative, locations within 1e-3 sample, widths within
    1e-3 relative (the kernels run in float32, NumPy in float64)."""
    y, lengths = _pad(_mixed(np.random.default_rng(21)))
    ref = noise_stats_numpy(y, lengths, saturation)
    det = device_fitter(cl_device_for_fits).detector.bind(y, lengths)
    got = det.noise_stats(saturation)
    np.testing.assert_array_equal(got.use, ref.use)
    assert (got.cens is None) == (ref.cens is None)
    if ref.cens is not None:
        assert ref.cens.any()
        np.testing.assert_array_equal(got.cens, ref.cens)
    np.testing.assert_array_equal(got.n_valid, ref.n_valid)
    np.testing.assert_allclose(got.b, ref.b, rtol=1e-5)
    np.testing.assert_allclose(got.sigma, ref.sigma, rtol=1e-5)
    np.testing.assert_array_equal(np.isfinite(got.width), np.isfinite(ref.width))
    ok = np.isfinite(ref.width)
    assert ok.sum() > 50
    np.testing.assert_allclose(got.width[ok], ref.width[ok], rtol=1e-5)
    pl = Pulse.gaussian(_batch_pulse(ref.width))
    level = _rice(ref.n_valid, pl, 0.01) * ref.sigma / pl.norm
    a0, m0, s0, on0 = candidates_numpy(y, lengths, ref, pl, level, 8)
    a1, m1, s1, on1 = det.candidates(pl, level, 8)
    np.testing.assert_array_equal(on1, on0)
    assert on0.sum(axis=1).max() >= 2 and (on0.sum(axis=1) == 0).any()
    np.testing.assert_allclose(a1[on0], a0[on0], rtol=1e-4)
    np.testing.assert_allclose(m1[on0], m0[on0], atol=1e-3)
    np.testing.assert_allclose(s1[on0], s0[on0], rtol=1e-3)


def test_device_detection_decomposes_like_numpy(cl_device_for_fits):
    """The whole decomposition with detection and fits on the device and all in NumPy:
    the same echo count for at least 98 % of the mixed waveforms (float32 fits may
    settle a borderline BIC differently), locations within 0.05 standard error where
    the counts agree."""
    ys = _mixed(np.random.default_rng(22))
    one = decompose_batch(ys, device="numpy")
    two = decompose_batch(ys, device=cl_device_for_fits)
    same = one.counts == two.counts
    assert same.mean() >= 0.98, np.flatnonzero(~same)
    for i in np.flatnonzero(same)[:60]:
        a, b = one[i], two[i]
        if len(a):
            dz = np.abs(a.location_ns - b.location_ns) / a.location_se_ns
            assert np.all(dz < 0.05), (i, dz)


def test_many_components_fall_back_to_numpy_detection(cl_device_for_fits):
    """More candidates per waveform than the kernel keeps (32): NumPy detection, device
    fits; the known echoes are still found."""
    t = np.arange(400.0)
    m = np.arange(20.0, 390.0, 10.0)
    rng = np.random.default_rng(23)
    ys = 5.0 + gaussian_sum(t, np.full(m.size, 100.0), m, np.full(m.size, 1.5)) + rng.normal(
        0.0, 1.0, (3, t.size))
    table = decompose_batch(ys, max_components=40, device=cl_device_for_fits)
    assert np.all(table.counts == m.size), table.counts
    np.testing.assert_allclose(table[0].location_ns, m, atol=0.2)


def test_kernels_the_device_cannot_launch_are_fitted_by_numpy(cl_device_for_fits):
    """A fit kernel too large for the device (NVIDIA's OpenCL refuses k = 40 echoes:
    OUT_OF_HOST_MEMORY) falls back to the NumPy fit of the same rows: every kernel marked
    so here, the echo locations agree with the device's fits within 5 % of their standard errors."""
    ys = _mixed(np.random.default_rng(25))
    on_device = decompose_batch(ys, device=cl_device_for_fits)
    fitter = device_fitter(cl_device_for_fits)
    keys = {(k, fb) for k in range(1, 41) for fb in (False, True)}
    fitter.too_large |= keys
    try:
        on_host = decompose_batch(ys, device=cl_device_for_fits)
    finally:
        fitter.too_large -= keys
    same = on_device.counts == on_host.counts
    assert same.mean() >= 0.98, np.flatnonzero(~same)
    for i in np.flatnonzero(same):
        a, b = on_device[i], on_host[i]
        if len(a):
            dz = np.abs(a.location_ns - b.location_ns) / a.location_se_ns
            assert np.all(dz < 0.05), (i, dz)


def test_chunks_in_flight_give_the_same_table(cl_device_for_fits, monkeypatch):
    """Chunks decomposed two at a time in threads: the same table, bit for bit, as
    one chunk after the other (each chunk's work is its own)."""
    import clsim.waveforms.decompose._batch as batch

    ys = _mixed(np.random.default_rng(24)) * 2
    two = decompose_batch(ys, chunk=37, device=cl_device_for_fits)
    monkeypatch.setattr(batch, "_IN_FLIGHT", 1)
    one = decompose_batch(ys, chunk=37, device=cl_device_for_fits)
    np.testing.assert_array_equal(two.counts, one.counts)
    for col in ("amplitude", "location_ns", "sigma_ns", "amplitude_se"):
        np.testing.assert_array_equal(getattr(two, col), getattr(one, col))
    np.testing.assert_array_equal(two.baseline, one.baseline)
