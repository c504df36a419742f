"""Template decomposition: echoes as shifted copies of the system's own (non-Gaussian) pulse."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from clsim.errors import InputError
from clsim.waveforms.decompose._template import decompose_template, template_from_returns


def _template():
    """A skewed pulse with a long tail, as real systems' are (peak at sample 6)."""
    t = np.arange(40.0)
    h = (t / 6.0) ** 2 * np.exp(2.0 - t / 3.0)
    return h / h.max()


def _waveforms(rng, n=60, width=120, noise=1.0):
    h = _template()
    truth = []
    rows = []
    for i in range(n):
        k = 1 + i % 2
        locs = rng.uniform(20, 80, 1) if k == 1 else np.array([30.0, 30.0 + rng.uniform(18, 30)])
        amps = rng.uniform(40, 80, k)
        y = np.full(width, 10.0) + rng.normal(0, noise, width)
        for a, m in zip(amps, locs):
            y += a * np.interp(np.arange(width) - m + 6.0, np.arange(h.size), h, left=0, right=0)
        rows.append(y)
        truth.append((locs, amps * h.sum()))
    return rows, truth


def test_template_echoes_are_the_targets_not_the_tail(rng):
    rows, truth = _waveforms(rng)
    echoes = decompose_template(rows, _template())
    counts = echoes.counts
    want = np.array([len(t[0]) for t in truth])
    assert np.mean(counts == want) >= 0.95, (counts, want)
    for i, (locs, energy) in enumerate(truth):
        if counts[i] != len(locs):
            continue
        sel = echoes.waveform == i
        assert np.allclose(echoes.location_ns[sel], locs, atol=0.5)
        assert np.allclose(echoes.energy[sel], energy, rtol=0.06)
    # a Gaussian decomposition of the same waveforms fits the tail with extra echoes
    from clsim.waveforms.decompose import decompose_batch

    gauss = decompose_batch(rows, device="numpy")
    assert gauss.counts.mean() > want.mean() + 0.3


def test_noise_alone_gives_few_false_echoes(rng):
    rows = [10.0 + rng.normal(0, 1.0, 120) for _ in range(200)]
    echoes = decompose_template(rows, _template(), false_alarm=0.01)
    assert echoes.counts.mean() <= 0.05


def test_template_from_returns_recovers_the_pulse(rng):
    h = _template()
    rows, _ = _waveforms(rng, n=80)
    est = template_from_returns(rows, width=20)
    got = est[20 - 6:]  # its peak at index 20, the template's at 6
    assert np.abs(got - h[: got.size]).max() < 0.05


def test_bad_templates_and_options():
    with pytest.raises(InputError, match="no positive"):
        decompose_template([np.ones(20)], np.zeros(10))
    with pytest.raises(InputError, match="false_alarm"):
        decompose_template([np.ones(20)], _template(), false_alarm=2)
    with pytest.raises(InputError, match="strong single returns"):
        template_from_returns([np.ones(30)])


def test_min_relative_drops_what_is_weaker_than_a_share_of_the_strongest(rng):
    h = _template()
    y = np.full(150, 10.0) + rng.normal(0, 0.2, 150)
    for a, m in ((100.0, 30.0), (3.0, 100.0)):  # a weak bump far behind the main echo
        y += a * np.interp(np.arange(150) - m + 6.0, np.arange(h.size), h, left=0, right=0)
    every = decompose_template([y], h)
    assert np.any(np.abs(every.location_ns - 100.0) < 1.0)  # the weak echo is significant (SNR about 25)
    kept = decompose_template([y], h, min_relative=0.05)
    assert kept.counts[0] == 1 and abs(kept.location_ns[0] - 30.0) < 0.5
    with pytest.raises(InputError, match="min_relative"):
        decompose_template([y], h, min_relative=1.5)


def test_quantised_records_are_not_decomposed_into_their_steps(rng):
    h = _template()
    # an 8-bit record: a slow baseline wander of one or two steps behind a strong echo
    y = 12.0 + np.round(0.8 * np.sin(np.arange(200) / 9.0))
    y += np.round(90 * np.interp(np.arange(200) - 30 + 6.0, np.arange(h.size), h, left=0, right=0))
    assert decompose_template([y], h).counts[0] <= 2


def _receiver():
    """A receiver's response: a spread main lobe and a tail at a few per cent of it (peak at lag 8)."""
    k = np.arange(40.0)
    r = np.exp(-0.5 * ((k - 8.0) / 1.2) ** 2)
    return r + np.where(k > 11, 0.05 * np.exp(-(k - 11) / 12.0), 0.0)


def _shot(rng, at, amp=200.0, n=60):
    """One shot: a recorded outgoing pulse (Gaussian, 2 ns sigma) and its single return at sample ``at``."""
    t = np.arange(28.0)
    out = 2.0 + 190.0 * np.exp(-0.5 * ((t - 11.0 + rng.uniform(-0.3, 0.3)) / 1.9) ** 2)
    echo = np.convolve(out - 2.0, _receiver())
    y = np.full(n, 2.0)
    shift = int(at) - int(np.argmax(echo))
    a, b = max(0, shift), min(n, shift + echo.size)
    y[a:b] += amp * echo[a - shift: b - shift] / echo.max()
    return np.round(out + rng.normal(0, 0.5, out.size)), np.round(y + rng.normal(0, 0.5, n))


def test_receiver_response_makes_the_return_one_echo(rng):
    from clsim.waveforms.decompose._template import echo_template, receiver_response

    shots = [_shot(rng, at) for at in (17, 20, 24, 30)]
    r = receiver_response([o for o, _ in shots[1:]], [y for _, y in shots[1:]])
    assert r.shape == (40,) and r.min() >= 0
    # the fitted response has the tail: its share beyond 4 samples after the peak as the truth's (~15 %)
    # within a third (the outgoing pulses' jitter and 0.5-count noise blur the main lobe)
    peak, true = int(np.argmax(r)), _receiver()
    want = true[int(np.argmax(true)) + 4:].sum() / true.sum()
    assert abs(r[peak + 4:].sum() / r.sum() - want) < want / 3
    out, y = shots[0]
    held = decompose_template([y], echo_template(out, r))
    assert held.counts[0] == 1
    assert abs(held.location_ns[0] - 17.0) <= 1.0
    # the outgoing pulse alone as the template fits the tail with extra echoes
    assert decompose_template([y], np.clip(out - 2.0, 0, None)).counts[0] > 1


def test_receiver_response_needs_pairs():
    from clsim.waveforms.decompose._template import receiver_response

    with pytest.raises(InputError, match="pairs"):
        receiver_response([np.ones(10)], [])


RIEGL = Path(__file__).resolve().parents[3].parent / "shared" / "data" / "riegl-pulsewaves" / "140823_183115_1_clipped_test.pls"


@pytest.mark.skipif(not RIEGL.is_file(), reason=f"the RIEGL PulseWaves sample is not at {RIEGL}")
def test_riegl_returns_are_one_echo_each_with_the_receiver_held_out():
    """The file's two returns each show one peak; each is decomposed with the other's receiver response."""
    from clsim.waveforms.decompose._template import echo_template, receiver_response
    from clsim.waveforms.io import read_pulsewaves

    pw = read_pulsewaves(RIEGL)
    out = {s.pulse: s.samples for s in pw.segments if s.kind == "outgoing"}
    ret = {s.pulse: s.samples for s in pw.segments if s.kind == "returning"}
    assert len(ret) == 2
    for j in ret:
        others = [i for i in ret if i != j]
        r = receiver_response([out[i] for i in others], [ret[i] for i in others])
        echoes = decompose_template([ret[j]], echo_template(out[j], r))
        assert echoes.counts[0] == 1, j
        assert decompose_template([ret[j]], out[j]).counts[0] > 1  # the outgoing pulse alone: the tail is echoes
