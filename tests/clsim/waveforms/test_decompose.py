"""Gaussian decomposition: synthetic truth (with calibrated standard errors),
deconvolution, the peer's expectations, all NEON waveforms, bad input."""

from __future__ import annotations

import importlib.util
from pathlib import Path

import numpy as np
import pytest

from clsim.errors import InputError
from clsim.waveforms.decompose import decompose, deconvolve, detect_peaks, echo_positions, gaussian_sum

ROOT = Path(__file__).resolve().parents[3]


def _bench():
    spec = importlib.util.spec_from_file_location("bench_decompose",
                                                  ROOT / "benchmarks" / "bench_decompose.py")
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    return mod


TRUE = dict(a=np.array([120.0, 45.0, 80.0]), m=np.array([30.0, 41.5, 70.0]),
            s=np.array([2.2, 3.0, 2.5]), b=12.0)


def _synthetic(rng, noise=2.0, n=110):
    t = np.arange(n, dtype=float)
    y = TRUE["b"] + gaussian_sum(t, TRUE["a"], TRUE["m"], TRUE["s"])
    return y + rng.normal(0.0, noise, n)


def test_recovers_known_components_within_standard_errors(rng):
    c = decompose(_synthetic(rng))
    assert len(c) == 3
    for got, se, true in ((c.amplitude, c.amplitude_se, TRUE["a"]),
                          (c.location_ns, c.location_se_ns, TRUE["m"]),
                          (c.sigma_ns, c.sigma_se_ns, TRUE["s"])):
        z = np.abs(got - true) / se
        assert np.all(z < 4.0), z
    assert abs(c.baseline - TRUE["b"]) < 4 * c.baseline_se


def test_standard_errors_match_monte_carlo_scatter():
    """Reported SEs equal the scatter of estimates over noise realisations.

    200 realisations: the sample standard deviation of an estimate has a
    relative standard error of 1/sqrt(2*199) = 5 %; we allow 20 %.
    """
    rng = np.random.default_rng(7)
    est, ses = [], []
    for _ in range(200):
        c = decompose(_synthetic(rng))
        assert len(c) == 3
        est.append(np.concatenate([c.amplitude, c.location_ns, c.sigma_ns]))
        ses.append(np.concatenate([c.amplitude_se, c.location_se_ns, c.sigma_se_ns]))
    ratio = np.std(est, axis=0, ddof=1) / np.mean(ses, axis=0)
    assert np.all(np.abs(ratio - 1.0) < 0.2), ratio
    bias = np.mean(est, axis=0) - np.concatenate([TRUE["a"], TRUE["m"], TRUE["s"]])
    assert np.all(np.abs(bias) < 4 * np.std(est, axis=0) / np.sqrt(200)), bias


def test_dt_and_t0_scale_the_clock(rng):
    y = _synthetic(rng)
    for kw, half in (({}, {}), ({"detection": "amplitude"}, {"detection": "amplitude", "smooth_ns": 0.5})):
        a = decompose(y, **kw)
        b = decompose(y, dt_ns=0.5, t0_ns=100.0, **half)
        np.testing.assert_allclose(b.location_ns, 100.0 + 0.5 * a.location_ns)
        np.testing.assert_allclose(b.sigma_ns, 0.5 * a.sigma_ns)


def test_noise_only_gives_no_echo():
    rng = np.random.default_rng(3)
    c = decompose(50.0 + rng.normal(0.0, 1.5, 200))
    assert len(c) == 0


def _impulse(n=40):
    """An asymmetric system response: a Gaussian convolved with an exponential tail."""
    t = np.arange(n, dtype=float)
    g = np.exp(-0.5 * ((t - 8.0) / 1.5) ** 2)
    e = np.exp(-t / 4.0)
    h = np.convolve(g, e)[:n]
    return h / h.max()


def test_deconvolution_restores_the_echo_times():
    """Two 1-ns echoes blurred by an asymmetric impulse: RL deconvolution puts them
    back at their times (impulse peak = time zero) within 0.3 ns; fitting the blurred
    waveform directly is biased by the tail."""
    rng = np.random.default_rng(11)
    n = 120
    t = np.arange(n, dtype=float)
    truth_m = np.array([40.0, 52.0])
    x = gaussian_sum(t, [100.0, 70.0], truth_m, [1.0, 1.0])
    h = _impulse()
    hn = h / h.sum()
    c0 = int(np.argmax(hn))
    blurred = np.convolve(x, hn)[c0:c0 + n]
    y = 5.0 + blurred + rng.normal(0.0, 0.5, n)
    plain = decompose(y)
    dec = decompose(y, impulse=5.0 + h * 100, deconvolution_iterations=60)
    main = np.sort(np.argsort(-dec.amplitude)[:2])
    assert np.all(np.abs(dec.location_ns[main] - truth_m) < 0.3), dec.location_ns
    # RL leaves small ringing echoes; they stay below 6 % of the main echo
    others = np.setdiff1d(np.arange(len(dec)), main)
    assert np.all(dec.amplitude[others] < 0.06 * dec.amplitude.max())
    # without deconvolution the strongest echo is pulled late by the impulse tail
    strongest = plain.location_ns[np.argmax(plain.amplitude)]
    assert strongest - truth_m[0] > 0.5
    # deconvolution keeps the energy
    d = deconvolve(y, 5.0 + h * 100, iterations=60, baseline=5.0)
    assert d.sum() == pytest.approx(np.clip(y - 5.0, 0, None).sum(), rel=1e-9)


def test_echo_positions_along_the_pulse():
    p = echo_positions([10.0], origin=[1.0, 2.0, 300.0], direction=[0.0, 0.01, -0.1495])
    np.testing.assert_allclose(p, [[1.0, 2.1, 298.505]])


def test_clipped_echo_recovered_from_its_flanks():
    """An 8-bit echo of height 300 clipped at 255: censoring the clipped samples
    recovers the height without bias and with calibrated standard errors; fitting
    them as values (saturation=None) is biased low by tens of counts."""
    rng = np.random.default_rng(21)
    t = np.arange(80.0)
    z, bias_plain = [], []
    for _ in range(100):
        y = np.minimum(np.round(10.0 + gaussian_sum(t, [300.0, 60.0], [40.0, 55.0], [2.5, 3.0])
                                + rng.normal(0.0, 1.5, t.size)), 255.0)
        c = decompose(y)
        assert len(c) == 2
        z.append((c.amplitude[0] - 300.0) / c.amplitude_se[0])
        np.testing.assert_allclose(decompose(y, saturation=255).amplitude, c.amplitude)
        bias_plain.append(decompose(y, saturation=None).amplitude[0] - 300.0)
    # mean of 100 unit normals: SE 0.1; scatter of z: 1 within 25 %
    assert abs(np.mean(z)) < 0.4 and 0.75 < np.std(z) < 1.25, (np.mean(z), np.std(z))
    assert np.mean(bias_plain) < -20.0


def test_echo_cut_by_the_record_end():
    rng = np.random.default_rng(1)
    t = np.arange(31.0)
    y = 5.0 + gaussian_sum(t, [100.0], [31.0], [3.0]) + rng.normal(0.0, 1.0, t.size)
    c = decompose(y)
    assert len(c) == 1
    assert abs(c.location_ns[0] - 31.0) < 4 * c.location_se_ns[0]
    assert abs(c.amplitude[0] - 100.0) < 4 * c.amplitude_se[0]
    assert detect_peaks(y, edges=True).location_ns[-1] == 30.0


@pytest.mark.parametrize("separation_sigma, count", [(1.5, 1), (2.5, 2), (3.0, 2)])
def test_echoes_are_added_only_when_resolved(separation_sigma, count):
    """Two echoes (150 and 100 counts, sigma 2.5, noise 1) closer than Sparrow's
    limit (2 sigma) are one feature and are reported as one echo every time (the
    BIC alone added the second in 3 of 20 realisations at 1.5 sigma); beyond it,
    both are reported every time."""
    rng = np.random.default_rng(2)
    t = np.arange(100.0)
    truth = 3.0 + gaussian_sum(t, [150.0, 100.0], [40.0, 40.0 + 2.5 * separation_sigma],
                               [2.5, 2.5])
    for _ in range(20):
        assert len(decompose(truth + rng.normal(0.0, 1.0, t.size))) == count


def test_no_data_zeros_are_left_out():
    """A record with a baseline of 200 counts and a run of zero samples (no-data fill
    between two digitised segments): the zeros are not fitted as signal."""
    rng = np.random.default_rng(4)
    t = np.arange(120.0)
    clean = 200.0 + gaussian_sum(t, [150.0, 60.0], [30.0, 90.0], [3.0, 4.0])
    y = np.round(clean + rng.normal(0.0, 2.0, t.size))
    y[60:70] = 0.0
    c = decompose(y)
    assert len(c) == 2
    for got, se, true in ((c.amplitude, c.amplitude_se, [150.0, 60.0]),
                          (c.location_ns, c.location_se_ns, [30.0, 90.0])):
        assert np.all(np.abs(got - true) < 4 * se), (got, se)
    assert abs(c.baseline - 200.0) < 4 * c.baseline_se


def test_bad_saturation():
    with pytest.raises(InputError, match="saturation"):
        decompose(np.ones(10), saturation="clip")
    with pytest.raises(InputError, match="saturation"):
        decompose(np.ones(10), saturation=-1.0)
    with pytest.raises(InputError, match="saturation"):
        decompose(np.ones(10), saturation=True)


@pytest.mark.realdata
def test_peer_expectations_pass_rate(shared_data):
    bench = _bench()
    res = bench.score_peer(shared_data / "riegl-pulsewaves" / "adapt_gaussianfitter_tests.json")
    for r in res["rows"]:
        if not r["passed"]:
            print(f"FAIL {r['name']}: {'; '.join(r['fails'])}")
    print(f"pass rate {res['n_pass']}/{res['n']} = {res['rate']:.1%}, assertions "
          f"{res['assert_rate']:.1%}")
    assert res["n"] == 69
    # measured 42/69 tests (60.9 %) and 80.4 % of assertions (a NaN estimate counts as a
    # failure); the goal of 90 % is not reached, see docs/waveforms.md
    assert res["rate"] >= 0.58
    assert res["assert_rate"] >= 0.78


@pytest.mark.realdata
def test_all_neon_waveforms_decompose(shared_data):
    bench = _bench()
    waves = bench.load_neon(shared_data)
    assert len(waves) == 500
    poor = []
    for i, w in enumerate(waves):
        c = decompose(w)
        assert len(c) >= 1, i
        for col in c.COLUMNS[:3]:
            assert np.all(np.isfinite(getattr(c, col))), (i, col)
        # the fit explains the signal: residual RMS far below the signal amplitude (over
        # the samples with data: 8 records hold runs of zeros, no-data fill between two
        # digitised segments, which decompose leaves out)
        data = w != 0
        resid = (w - c.model(np.arange(w.size, dtype=float)))[data]
        if np.sqrt(np.mean(resid ** 2)) >= 0.1 * (w.max() - c.baseline):
            poor.append(i)
    print(f"poorly fitted (residual RMS >= 10 % of the signal): {poor}")
    # measured: none of 500 (before the no-data zeros were left out: 4, the records
    # 103, 183, 413, 415 with such gaps); see docs/waveforms.md
    assert len(poor) <= 2


def test_detect_peaks_plateau_and_terrace():
    y = [1, 1, 2, 20, 40, 40, 20, 12, 12, 12, 5, 1, 1]
    c = detect_peaks(y, baseline=0.0, min_amplitude=10)
    assert c.location_ns.tolist() == [4.5, 8.0]
    assert c.amplitude.tolist() == [40.0, 12.0]


@pytest.mark.parametrize("bad, match", [
    (np.zeros((3, 10)), "1-D"),
    ([1.0, 2.0], "at least 4"),
    ([1.0, np.nan, 2.0, 3.0, 4.0], "NaN"),
])
def test_bad_samples(bad, match):
    with pytest.raises(InputError, match=match):
        decompose(bad)


def test_bad_dt():
    with pytest.raises(InputError, match="dt_ns"):
        decompose(np.ones(10), dt_ns=0)


# ------------------------------------------------ matched-filter detection ---

WEAK = dict(n=150, baseline=20.0, noise=2.0, strong=(80.0, 35.0), weak_at=85.0, sigma=2.5)


def _weak_echo(rng, k_sigma):
    """A strong echo (40 noise sigma) at 35 ns and a weak one of ``k_sigma`` noise
    sigma at 85 ns, both sigma 2.5 ns, white noise 2 counts (k_sigma 0: noise and the
    strong echo only)."""
    t = np.arange(WEAK["n"], dtype=float)
    y = WEAK["baseline"] + gaussian_sum(t, [WEAK["strong"][0], k_sigma * WEAK["noise"]],
                                        [WEAK["strong"][1], WEAK["weak_at"]],
                                        [WEAK["sigma"]] * 2)
    return y + rng.normal(0.0, WEAK["noise"], t.size)


@pytest.mark.parametrize("k_sigma", [3, 5, 8, 12])
def test_weak_echo_found_by_the_matched_filter(k_sigma):
    """100 realisations: the weak echo is reported (an echo within one pulse sigma of
    its time) at least 85 % of the time at every level (measured: 98 % at 3 sigma,
    100 % above; binomial SE at 85 % is 3.6 %), and where found its location lies
    within 4 standard errors of the truth."""
    rng = np.random.default_rng(100 + k_sigma)
    found, z = 0, []
    for _ in range(100):
        c = decompose(_weak_echo(rng, k_sigma))
        d = np.abs(c.location_ns - WEAK["weak_at"])
        if d.min() < WEAK["sigma"]:
            found += 1
            j = int(np.argmin(d))
            z.append(d[j] / c.location_se_ns[j])
    assert found >= 85, found
    assert np.mean(np.asarray(z) < 4.0) >= 0.97, z


def test_weak_echo_missed_by_the_amplitude_rule():
    """The earlier rule (4 sigma on the smoothed samples) finds a 3-sigma echo rarely:
    what the matched filter adds (measured 5 % of 300)."""
    rng = np.random.default_rng(9)
    found = sum(np.any(np.abs(decompose(_weak_echo(rng, 3), detection="amplitude")
                              .location_ns - WEAK["weak_at"]) < WEAK["sigma"])
                for _ in range(50))
    assert found <= 10, found


def test_false_echoes_per_noise_only_waveform():
    """1000 noise-only waveforms (150 samples, white noise): at most 0.05 false echoes
    per waveform (default false_alarm 0.01; measured 0.016, Poisson SE 0.004)."""
    rng = np.random.default_rng(8)
    n_false = sum(len(decompose(WEAK["baseline"] + rng.normal(0.0, WEAK["noise"], WEAK["n"])))
                  for _ in range(1000))
    assert n_false / 1000 <= 0.05, n_false


def test_threshold_gives_the_false_alarm_rate():
    """Rice's formula: asking detect_echoes for 0.3 false echoes per waveform on 2000
    noise-only waveforms (known pulse) gives 0.3 within 25 % (Poisson SE of 600
    counts: 4 %; the rest is the estimated noise sigma and baseline)."""
    from clsim.waveforms.decompose import detect_echoes

    rng = np.random.default_rng(6)
    n = sum(len(detect_echoes(20.0 + rng.normal(0.0, 2.0, 150), pulse_sigma_ns=2.5,
                              false_alarm=0.3)) for _ in range(2000))
    assert abs(n / 2000 / 0.3 - 1.0) < 0.25, n / 2000


def test_matched_filter_with_a_measured_pulse():
    """The matched filter with an asymmetric measured pulse (peak = lag 0) puts a
    weak echo (5 sigma) of that shape at the time of its peak within 1 sample."""
    from clsim.waveforms.decompose import detect_echoes

    rng = np.random.default_rng(10)
    h = _impulse()
    hits = 0
    for _ in range(50):
        y = np.full(150, 10.0)
        y[70 - int(np.argmax(h)):70 - int(np.argmax(h)) + h.size] += 10.0 * h
        c = detect_echoes(y + rng.normal(0.0, 2.0, 150), pulse=5.0 + 100.0 * h)
        hits += np.any(np.abs(c.location_ns - 70.0) < 1.0)
    assert hits >= 45, hits


def test_bad_detection_options():
    with pytest.raises(InputError, match="detection"):
        decompose(np.ones(10), detection="mf")
    with pytest.raises(InputError, match="min_amplitude"):
        decompose(np.ones(10), detection="matched", min_amplitude=3.0)
