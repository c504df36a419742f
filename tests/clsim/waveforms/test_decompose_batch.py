"""Batched decomposition (``decompose_batch``) against known answers: the same
synthetic truths as the single-waveform tests, many realisations in one call."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.ndimage import gaussian_filter1d

from clsim.errors import DeviceError, InputError
from clsim.waveforms.decompose import EchoTable, decompose, decompose_batch, gaussian_sum
from clsim.waveforms.decompose._batch_cl import device_fitter
from clsim.waveforms.decompose._batch_fit import fit_group
from clsim.waveforms.decompose._matched import Pulse, filter_output

TRUE = dict(a=np.array([120.0, 45.0, 80.0]), m=np.array([30.0, 41.5, 70.0]),
            s=np.array([2.2, 3.0, 2.5]), b=12.0)


def _three(rng, count, noise=2.0, n=110):
    t = np.arange(n, dtype=float)
    clean = TRUE["b"] + gaussian_sum(t, TRUE["a"], TRUE["m"], TRUE["s"])
    return clean + rng.normal(0.0, noise, (count, n))


def test_known_components_and_calibrated_errors(decompose_device):
    """200 realisations of three known echoes: every waveform gives 3 echoes; the
    scatter of each estimate equals its mean reported standard error within 20 %
    (sampling SE of a standard deviation from 200 draws: 5 %); no bias beyond
    4 standard errors of the mean."""
    table = decompose_batch(_three(np.random.default_rng(7), 200), device=decompose_device)
    assert np.all(table.counts == 3), np.bincount(table.counts)
    for col, se_col, true in (("amplitude", "amplitude_se", TRUE["a"]),
                              ("location_ns", "location_se_ns", TRUE["m"]),
                              ("sigma_ns", "sigma_se_ns", TRUE["s"])):
        est = getattr(table, col).reshape(200, 3)
        se = getattr(table, se_col).reshape(200, 3)
        ratio = est.std(axis=0, ddof=1) / se.mean(axis=0)
        assert np.all(np.abs(ratio - 1.0) < 0.2), (col, ratio)
        bias = est.mean(axis=0) - true
        assert np.all(np.abs(bias) < 4 * est.std(axis=0) / np.sqrt(200)), (col, bias)


def test_batch_agrees_with_single(decompose_device):
    """Same waveforms, same echo count: a batch of many and each waveform alone (its own pulse width) reach
    the same minimum (locations within 0.2 standard error)."""
    ys = _three(np.random.default_rng(3), 30)
    table = decompose_batch(ys, device=decompose_device)
    for i, y in enumerate(ys):
        one, many = decompose(y, device=decompose_device), table[i]
        assert len(one) == len(many) == 3
        dz = np.abs(one.location_ns - many.location_ns) / one.location_se_ns
        assert np.all(dz < 0.2), dz


def test_single_call_is_a_batch_of_one(decompose_device):
    """The contract: decompose(w) is decompose_batch([w])[0], field for field, on every device, with the same
    defaults; the amplitude rule's own options are refused with matched detection."""
    import inspect

    rng = np.random.default_rng(11)
    ys = list(_three(rng, 6)) + list(_weak(rng, 5.0, 4)) + [rng.normal(10.0, 2.0, 90)]
    for y in ys:
        one, batch = decompose(y, dt_ns=0.5, t0_ns=7.0, device=decompose_device), decompose_batch(
            [y], dt_ns=0.5, t0_ns=7.0, device=decompose_device)[0]
        for col in EchoTable.COLUMNS:
            assert np.array_equal(getattr(one, col), getattr(batch, col), equal_nan=True), col
        assert np.array_equal([one.baseline, one.baseline_se, one.noise_sigma, one.rss],
                              [batch.baseline, batch.baseline_se, batch.noise_sigma, batch.rss], equal_nan=True)
    single, many = (inspect.signature(f).parameters for f in (decompose, decompose_batch))
    for name in ("dt_ns", "t0_ns", "pulse", "pulse_sigma_ns", "false_alarm", "saturation", "max_components",
                 "add_components", "device"):
        assert single[name].default == many[name].default, name
    for bad in ({"smooth_ns": 0.5}, {"terraces": False}, {"fit_baseline": False}, {"baseline": 3.0},
                {"max_nfev": 100}):
        with pytest.raises(InputError, match="belong.*to detection='amplitude'"):
            decompose(ys[0], **bad)
    assert len(decompose(ys[0], detection="amplitude", smooth_ns=0.5, max_nfev=100)) == 3


def _weak(rng, k_sigma, count):
    t = np.arange(150.0)
    clean = 20.0 + gaussian_sum(t, [80.0, 2.0 * k_sigma], [35.0, 85.0], [2.5, 2.5])
    return clean + rng.normal(0.0, 2.0, (count, t.size))


@pytest.mark.parametrize("k_sigma", [3, 5, 8, 12])
def test_weak_echo_found(k_sigma, decompose_device):
    """A weak echo (k noise sigma, 2.5 ns wide) after a strong one: found (an echo
    within 2.5 ns) in at least 85 % of 300 realisations."""
    table = decompose_batch(_weak(np.random.default_rng(20 + k_sigma), k_sigma, 300),
                            device=decompose_device)
    near = np.abs(table.location_ns - 85.0) < 2.5
    found = np.unique(table.waveform[near]).size
    assert found >= 255, found


def test_false_echoes_per_noise_only_waveform(decompose_device):
    """3000 noise-only waveforms: at most 0.05 false echoes per waveform (design
    0.01; Poisson SE of the measured rate about 0.002)."""
    rng = np.random.default_rng(11)
    table = decompose_batch(20.0 + rng.normal(0.0, 2.0, (3000, 150)), pulse_sigma_ns=2.5,
                            device=decompose_device)
    assert table.n_echoes / 3000 <= 0.05, table.n_echoes


@pytest.mark.parametrize("separation_sigma, count", [(1.5, 1), (2.5, 2), (3.0, 2)])
def test_two_echoes_at_decreasing_separation(separation_sigma, count, decompose_device):
    """150 and 100 counts, sigma 2.5, noise 1: below Sparrow's limit one echo, beyond
    it two, in at least 19 of 20 realisations."""
    rng = np.random.default_rng(2)
    t = np.arange(100.0)
    truth = 3.0 + gaussian_sum(t, [150.0, 100.0], [40.0, 40.0 + 2.5 * separation_sigma],
                               [2.5, 2.5])
    table = decompose_batch(truth + rng.normal(0.0, 1.0, (20, t.size)), device=decompose_device)
    assert np.sum(table.counts == count) >= 19, table.counts


def test_clipped_echo_unbiased(decompose_device):
    """An 8-bit echo of 300 counts clipped at 255: censored, its height comes back
    unbiased (mean z-score over 100 realisations within 0.4 of 0)."""
    rng = np.random.default_rng(21)
    t = np.arange(80.0)
    clean = 10.0 + gaussian_sum(t, [300.0, 60.0], [40.0, 55.0], [2.5, 3.0])
    ys = np.minimum(np.round(clean + rng.normal(0.0, 1.5, (100, t.size))), 255.0)
    table = decompose_batch(ys, device=decompose_device)
    assert np.all(table.counts == 2)
    main = table.amplitude.reshape(100, 2)[:, 0]
    z = (main - 300.0) / table.amplitude_se.reshape(100, 2)[:, 0]
    assert abs(np.mean(z)) < 0.4 and 0.7 < np.std(z) < 1.3, (np.mean(z), np.std(z))


def test_no_data_zeros_and_ragged_lengths(decompose_device):
    """Waveforms of different lengths, one with a run of no-data zeros: the zeros are
    left out and both echoes are recovered within 4 standard errors."""
    rng = np.random.default_rng(4)
    t = np.arange(120.0)
    clean = 200.0 + gaussian_sum(t, [150.0, 60.0], [30.0, 90.0], [3.0, 4.0])
    y = np.round(clean + rng.normal(0.0, 2.0, t.size))
    y[60:70] = 0.0
    table = decompose_batch([y, y[:50]], t0_ns=[0.0, 100.0], device=decompose_device)
    assert table.counts.tolist() == [2, 1]
    c = table[0]
    assert np.all(np.abs(c.amplitude - [150.0, 60.0]) < 4 * c.amplitude_se)
    assert np.all(np.abs(c.location_ns - [30.0, 90.0]) < 4 * c.location_se_ns)
    assert abs(table[1].location_ns[0] - 130.0) < 4 * table[1].location_se_ns[0]


def test_table_records_and_csv(tmp_path):
    ys = _three(np.random.default_rng(5), 3)
    table = decompose_batch(ys, dt_ns=0.5)
    rec = table.to_records()
    assert rec.shape == (9,) and rec["waveform"].tolist() == [0, 0, 0, 1, 1, 1, 2, 2, 2]
    np.testing.assert_allclose(table[1].location_ns, 0.5 * decompose_batch(ys).location_ns[3:6])
    table.save_csv(tmp_path / "echoes.csv")
    back = np.genfromtxt(tmp_path / "echoes.csv", delimiter=",", names=True)
    np.testing.assert_allclose(back["location_ns"], rec["location_ns"], rtol=1e-8)
    stacked = EchoTable.from_components([table[i] for i in range(3)])
    np.testing.assert_array_equal(stacked.amplitude, table.amplitude)


def test_table_components_equal_indexing():
    """``components()`` gives ``table[i]`` for every waveform, those without an echo
    (noise only) included."""
    rng = np.random.default_rng(6)
    ys = np.concatenate([_three(rng, 3), 12.0 + rng.normal(0.0, 2.0, (2, 110))])[[0, 3, 1, 4, 2]]
    table = decompose_batch(ys)
    assert table.counts.tolist() == [3, 0, 3, 0, 3]
    every = table.components()
    assert len(every) == len(table)
    for i, c in enumerate(every):
        ref = table[i]
        for col in EchoTable.COLUMNS:
            np.testing.assert_array_equal(getattr(c, col), getattr(ref, col))
        assert (c.baseline, c.noise_sigma, c.rss) == (ref.baseline, ref.noise_sigma, ref.rss)


@pytest.mark.parametrize("bad, match", [
    ([], "empty"),
    ([np.ones(3)], "at least 4"),
    ([np.array([1.0, np.nan, 2.0, 3.0])], "NaN"),
])
def test_bad_input(bad, match):
    with pytest.raises(InputError, match=match):
        decompose_batch(bad)


def test_bad_options():
    with pytest.raises(InputError, match="dt_ns"):
        decompose_batch(np.ones((2, 10)), dt_ns=0)
    with pytest.raises(InputError, match="not both"):
        decompose_batch(np.ones((2, 10)), pulse=np.ones(5), pulse_sigma_ns=2.0)
    with pytest.raises(InputError, match="saturation"):
        decompose_batch(np.ones((2, 10)), saturation="clip")


def test_device_fits_match_numpy(cl_device_for_fits):
    """One group of 500 fits of two echoes from rough starts, on the device and in
    NumPy: the same minimum (parameters within 0.02 standard error, RSS within 1e-4
    relative; the device sums in float32) in about as many iterations."""
    rng = np.random.default_rng(8)
    t = np.arange(150.0)
    y = 20.0 + gaussian_sum(t, [80.0, 10.0], [35.0, 85.0], [2.5, 2.5]) + rng.normal(0.0, 2.0,
                                                                                  (500, 150))
    use = np.ones(y.shape, bool)
    noise = np.full(500, 2.0)
    start = (np.tile([70.0, 8.0], (500, 1)), np.tile([35.5, 84.3], (500, 1)),
             np.tile([2.8, 2.0], (500, 1)), np.full(500, 19.0))
    ref = fit_group(y, use, *start, noise=noise)
    got = device_fitter(cl_device_for_fits).bind(y, use, None, noise).fit(np.arange(500), *start)
    for name, col in (("a", 0), ("m", 2), ("s", 4)):
        dz = np.abs(getattr(got, name) - getattr(ref, name)) / ref.se[:, col:col + 2]
        assert np.all(dz < 0.02), (name, dz.max(axis=0))
    np.testing.assert_allclose(got.rss, ref.rss, rtol=1e-4)
    np.testing.assert_allclose(got.se, ref.se, rtol=0.05)
    assert abs(got.n_iter.mean() - ref.n_iter.mean()) < 0.5, (got.n_iter.mean(), ref.n_iter.mean())


@pytest.mark.parametrize("blocks", [1, 2, 3, 4, 5])
def test_device_fits_every_block_of_the_span(blocks, cl_device_for_fits):
    """The kernel sums two blocks of 8 samples per pass; a counted span of an odd
    number of blocks ends on a block alone. An echo whose tails reach the span's first
    and last samples (2 sigma from its peak), counted over 8 x ``blocks`` samples that
    start and end inside a longer row: the device fits the NumPy fits' minimum over the
    same samples (parameters within 0.02 standard error, RSS within 1e-4 relative, as
    in ``test_device_fits_match_numpy``); a block left out or one read beyond the span
    would change the RSS by the squared noise of its samples (1/blocks of it or more)."""
    rng = np.random.default_rng(20 + blocks)
    n, lo, g = 64, 8, 300
    span = 8 * blocks
    t = np.arange(n, dtype=float)
    m0, s0 = lo + (span - 1) / 2.0, span / 4.0
    y = 10.0 + gaussian_sum(t, [90.0], [m0], [s0]) + rng.normal(0.0, 2.0, (g, n))
    use = np.zeros(y.shape, bool)
    use[:, lo:lo + span] = True
    noise = np.full(g, 2.0)
    start = (np.full((g, 1), 80.0), np.full((g, 1), m0 + 0.3), np.full((g, 1), 1.1 * s0),
             np.full(g, 9.0))
    ref = fit_group(y, use, *start, noise=noise)
    got = device_fitter(cl_device_for_fits).bind(y, use, None, noise).fit(np.arange(g), *start)
    np.testing.assert_array_equal(got.n_eff, span)
    for name, col in (("a", 0), ("m", 1), ("s", 2), ("b", 3)):
        dz = np.abs(getattr(got, name).reshape(g) - getattr(ref, name).reshape(g)) / ref.se[:, col]
        assert np.all(dz < 0.02), (name, dz.max())
    np.testing.assert_allclose(got.rss, ref.rss, rtol=1e-4)


def test_device_standard_errors_float32_inverse(cl_device_for_fits):
    """The standard errors inverted in float32 (devices without double) agree with the
    double inverse of the same fits within 1e-4 relative (the matrix is scaled to a
    unit diagonal first); with the baseline held its error is NaN."""
    from clsim.waveforms.decompose._batch_cl import DeviceFitter

    rng = np.random.default_rng(12)
    t = np.arange(120.0)
    y = 15.0 + gaussian_sum(t, [90.0, 30.0, 25.0], [30.0, 60.0, 66.0], [2.5, 3.0, 2.5])
    y = y + rng.normal(0.0, 2.0, (200, t.size))
    use = np.ones(y.shape, bool)
    noise = np.full(200, 2.0)
    start = (np.tile([80.0, 25.0, 20.0], (200, 1)), np.tile([30.4, 59.5, 66.5], (200, 1)),
             np.tile([2.2, 3.3, 2.2], (200, 1)), np.full(200, 14.0))
    info = device_fitter(cl_device_for_fits).info
    if "cl_khr_fp64" not in info.device.extensions:
        pytest.skip(f"{info.device.name} has no double: both builds would be float32")
    got = {}
    for se_float in (False, True):
        bound = DeviceFitter(info, se_float=se_float).bind(y, use, None, noise)
        got[se_float] = (bound.fit(np.arange(200), *start),
                         bound.fit(np.arange(200), *start, fit_baseline=False))
    for held in (0, 1):
        dbl, flt = got[False][held], got[True][held]
        np.testing.assert_array_equal(dbl.a, flt.a)
        assert np.all(np.isfinite(dbl.se[:, :9])) and np.all(dbl.se[:, :9] > 0)
        np.testing.assert_allclose(flt.se, dbl.se, rtol=1e-4)
    assert np.all(np.isnan(got[True][1].se[:, 9])) and np.all(np.isfinite(got[True][0].se[:, 9]))


def test_device_residual_and_its_filters(cl_device_for_fits):
    """The device fits return the residual at the fit (zero where a sample does not
    count) and that residual through the matched filter and the Gaussian of sigma 1,
    as the host's ``filter_output`` and ``gaussian_filter1d`` give them at the samples
    that count (float32 sums: within 1e-5 of the largest value), also for records
    whose counted samples start and end inside the row."""
    rng = np.random.default_rng(10)
    t = np.arange(150.0)
    y = 20.0 + gaussian_sum(t, [80.0, 30.0], [40.0, 60.0], [2.5, 3.0]) + rng.normal(
        0.0, 2.0, (50, 150))
    use = np.ones(y.shape, bool)
    use[::2, :13] = False
    use[1::3, 131:] = False
    pulse = Pulse.gaussian(2.5)
    bound = device_fitter(cl_device_for_fits).bind(y, use, None, np.full(50, 2.0))
    bound.set_pulse(pulse)
    got = bound.fit(np.arange(50), np.tile([70.0, 25.0], (50, 1)),
                    np.tile([40.5, 59.0], (50, 1)), np.tile([2.5, 3.2], (50, 1)),
                    np.full(50, 19.0))
    model = np.array([b + gaussian_sum(t, a, m, s) for a, m, s, b in
                      zip(got.a, got.m, got.s, got.b)])
    r = np.where(use, y - model, 0.0)
    np.testing.assert_allclose(got.resid, r, atol=1e-5 * np.abs(y).max())
    res = got.resid.astype(float)
    for c, ref in enumerate((filter_output(res, pulse),
                             gaussian_filter1d(res, 1.0, axis=1, mode="constant"))):
        np.testing.assert_allclose(got.filtered[:, c][use], ref[use],
                                   atol=1e-5 * np.abs(ref).max())


def test_device_round_of_groups_matches_each_group_alone(cl_device_for_fits):
    """One round of three groups (1, 2 and 3 echoes, in the order 2, 1, 3; one upload
    of rows and starts, a launch per group at its offsets into them and into the
    shared result buffer) gives every group exactly the fits, standard errors and
    residuals it gets fitted alone (the same kernel on the same inputs)."""
    ys = _three(np.random.default_rng(12), 30)
    use = np.ones(ys.shape, bool)
    bound = device_fitter(cl_device_for_fits).bind(ys, use, None, np.full(30, 2.0))
    bound.set_pulse(Pulse.gaussian(2.5))
    groups = []
    for k, rows in ((2, np.arange(0, 12)), (1, np.arange(12, 19)), (3, np.arange(19, 30))):
        g = rows.size
        groups.append((rows, np.tile(0.9 * TRUE["a"][:k], (g, 1)),
                       np.tile(TRUE["m"][:k] + 0.4, (g, 1)), np.tile(TRUE["s"][:k] * 1.1, (g, 1)),
                       np.full(g, 11.0)))
    together = bound.fit_groups(groups, linear=True)
    for group, got in zip(groups, together):
        alone = bound.fit_groups([group], linear=True)[0]
        for name in ("a", "m", "s", "b", "rss", "se", "n_eff", "n_iter", "resid", "filtered"):
            np.testing.assert_array_equal(getattr(got, name), getattr(alone, name), name)
    assert [g.a.shape[1] for g in together] == [2, 1, 3]


def test_device_and_numpy_agree(cl_device_for_fits):
    """The whole batched decomposition on the device and in NumPy: the same echo count
    for every waveform and locations within 0.05 standard error."""
    ys = _three(np.random.default_rng(9), 100)
    one = decompose_batch(ys, device="numpy")
    two = decompose_batch(ys, device=cl_device_for_fits)
    np.testing.assert_array_equal(one.counts, two.counts)
    dz = np.abs(one.location_ns - two.location_ns) / one.location_se_ns
    assert np.all(dz < 0.05), dz.max()


def test_unknown_device():
    with pytest.raises(DeviceError, match="no-such-device"):
        decompose_batch(np.ones((2, 10)), device="no-such-device")


def _mixed(rng, count):
    """Waveforms of ragged lengths (40-150 samples) with 0-3 echoes of varied widths."""
    out = []
    for _ in range(count):
        n = int(rng.integers(40, 151))
        t = np.arange(n, dtype=float)
        k = int(rng.integers(0, 4))
        y = 10.0 + gaussian_sum(t, rng.uniform(15, 120, k), rng.uniform(8, n - 8, k), rng.uniform(1.5, 4.0, k))
        out.append(y + rng.normal(0.0, 1.5, n))
    return out


def _rows(table, order=None):
    """Each waveform's echoes and baseline, in the original order of the waveforms."""
    idx = range(len(table)) if order is None else np.argsort(order)
    return [((table[i].location_ns, table[i].location_se_ns), (table[i].amplitude, table[i].amplitude_se),
             (table[i].sigma_ns, table[i].sigma_se_ns), (table.baseline[i], table.baseline_se[i])) for i in idx]


def test_results_independent_of_chunk_and_order(decompose_device):
    """One waveform's echoes depend on itself and the call's shared pulse, not on its
    chunk or the order of the input: chunk 240 (one chunk), 17 and 1, and the input
    reversed, give the same number of echoes in every waveform, and each estimate
    within 1 % of its own standard error (a group of fits iterates until all its rows
    converge, so an ill-conditioned pair of echoes may stop a little further on)."""
    ys = _mixed(np.random.default_rng(11), 240)
    ref = _rows(decompose_batch(ys, device=decompose_device, chunk=240))
    assert sum(len(r[0][0]) for r in ref) > 200
    order = np.arange(len(ys))[::-1]
    for table, o in ((decompose_batch(ys, device=decompose_device, chunk=17), None),
                     (decompose_batch(ys[:60], device=decompose_device, chunk=1, pulse_sigma_ns=2.4), "pulse"),
                     (decompose_batch([ys[i] for i in order], device=decompose_device, chunk=23), order)):
        if isinstance(o, str):
            one = _rows(decompose_batch(ys[:60], device=decompose_device, chunk=60, pulse_sigma_ns=2.4))
            got = _rows(table)
        else:
            one, got = ref, _rows(table, o)
        for i, (a, b) in enumerate(zip(one, got)):
            assert len(a[0][0]) == len(b[0][0]), (i, a[0][0], b[0][0])
            for (x, se), (y, _) in zip(a, b):
                tol = np.where(np.isfinite(se), 0.01 * np.asarray(se), 0.0) + 1e-9  # no SE (no echo): equal
                assert np.all(np.abs(np.asarray(x) - y) <= tol), (i, x, y, se)
