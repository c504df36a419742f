"""Simulator.run_pulses: many pulses over one scene, each bit for bit what Simulator.run gives it."""

from __future__ import annotations

import numpy as np
import pytest

from clsim.digitize import convolve_fine, pulse_kernel
from clsim.errors import InputError
from clsim.sensor import Sensor
from clsim.survey import ScanPattern, Trajectory, survey_pulses
from clsim.transport.result import PulseWaveforms
from clsim.transport.setup import prepare_scene
from clsim.validation import testscenes

BASE = Sensor.preset("riegl-lms-q680i")


def scene():
    s = testscenes.homogeneous_layer(width=6.0, thickness=1.5, lad=1.0, voxel_size=0.5, base_height=3.0)
    return testscenes.set_optics(s, BASE.wavelength_nm, leaf=(0.45, 0.40), ground=(0.3, 0.0), bark=(0.45, 0.0))


def pulses(n=6):
    """Palmer circles from 250 m: every pulse its own off-nadir angle, azimuth and height."""
    tr = Trajectory.line((-2.0, 0.0), (2.0, 0.0), altitude_m=250.0, speed_mps=40.0)
    pat = ScanPattern(kind="palmer", pulse_rate_hz=400.0, scan_rate_hz=37.0, fov_deg=1.0, along_fov_deg=0.6)
    return survey_pulses(tr, pat, BASE, count=n, seed=11)


@pytest.mark.parametrize("batches", [1, 4])
def test_each_pulse_is_bit_identical_to_run(sim, batches):
    sc, p = scene(), pulses()
    assert len(set(np.round(p.azimuth_deg, 6))) == len(p)          # the pulses differ in geometry
    wf = sim.run_pulses(sc, p, BASE, photons=400, batches=batches, max_order=2)
    assert isinstance(wf, PulseWaveforms) and len(wf) == len(p)
    assert np.array_equal(wf.index, p.index)
    assert wf.bin_ns == 1.0 / BASE.sampling_ghz
    for i in range(len(p)):
        res = sim.run(sc, p.sensor(i, BASE), photons=400, seed=int(p.seed[i]), target=p.target[i],
                      batches=batches, max_order=2)
        n = wf.n_samples[i]
        assert n == res.time_ns.size
        assert np.array_equal(wf.waveform[i, :n].view(np.uint64), res.waveform.view(np.uint64))
        assert np.all(wf.waveform[i, n:] == 0.0)
        assert wf.t0_ns[i] == res.time_ns[0]
        assert wf.energy[i] == pytest.approx(res.energy()[0], rel=1e-12)
        assert res.waveform.max() > 0                            # something came back


def test_seed_and_batching_independence(sim):
    """A pulse's waveform is the same whether it runs alone or with others."""
    sc, p = scene(), pulses(5)
    setup = prepare_scene(sc, wavelength_nm=BASE.wavelength_nm)
    whole = sim.run_pulses(sc, p, BASE, photons=300, scene_setup=setup)
    parts = PulseWaveforms.concat([sim.run_pulses(sc, q, BASE, photons=300, scene_setup=setup)
                                   for q in (p[:2], p[2:3], p[3:])])
    for name in PulseWaveforms.ARRAYS:
        assert np.array_equal(getattr(whole, name), getattr(parts, name)), name
    other = sim.run_pulses(sc, survey_pulses(*_geometry(), BASE, count=5, seed=12), BASE, photons=300)
    assert not np.array_equal(other.waveform, whole.waveform)    # another seed, other photons


def _geometry():
    tr = Trajectory.line((-2.0, 0.0), (2.0, 0.0), altitude_m=250.0, speed_mps=40.0)
    return tr, ScanPattern(kind="palmer", pulse_rate_hz=400.0, scan_rate_hz=37.0, fov_deg=1.0, along_fov_deg=0.6)


def test_bad_inputs(sim):
    sc, p = scene(), pulses(2)
    with pytest.raises(InputError, match="pulses must be clsim.survey.Pulses"):
        sim.run_pulses(sc, [1, 2], BASE, photons=10)
    with pytest.raises(InputError, match="scene_setup was prepared for another"):
        sim.run_pulses(sc, p, BASE, photons=10, scene_setup=prepare_scene(scene(), wavelength_nm=1064.0))
    with pytest.raises(InputError, match="photons"):
        sim.run_pulses(sc, p, BASE, photons=0)


def test_pulse_waveforms_save_load_concat(tmp_path):
    a = PulseWaveforms.from_rows([3, 4], [np.arange(3.0), np.arange(5.0)], t0_ns=[1.0, 2.0], bin_ns=0.5,
                                 energy=[0.1, 0.2])
    assert a.waveform.shape == (2, 5) and a.n_samples.tolist() == [3, 5] and a.waveform[0, 3:].tolist() == [0, 0]
    b = PulseWaveforms.load(a.save(tmp_path / "a.npz"))
    for name in PulseWaveforms.ARRAYS:
        assert np.array_equal(getattr(a, name), getattr(b, name))
    c = PulseWaveforms.concat([a, PulseWaveforms.from_rows([5], [np.ones(7)], t0_ns=[0.0], bin_ns=0.5, energy=[1])])
    assert c.waveform.shape == (3, 7) and c.index.tolist() == [3, 4, 5] and c.waveform[1, 5:].tolist() == [0, 0]
    with pytest.raises(InputError, match="different spacings"):
        PulseWaveforms.concat([a, PulseWaveforms.from_rows([5], [np.ones(2)], t0_ns=[0.0], bin_ns=1.0, energy=[1])])
    (tmp_path / "bad.npz").write_bytes(b"not a zip")
    with pytest.raises(InputError, match="not a batch of pulse waveforms"):
        PulseWaveforms.load(tmp_path / "bad.npz")


def test_convolve_fine_span_is_the_full_convolution_bit_for_bit():
    """convolve_fine convolves only the nonzero span: each sample must equal np.convolve's exactly."""
    rng = np.random.default_rng(0)
    for trial in range(400):
        n = int(rng.integers(1, 2500))
        row = np.zeros(n)
        kind = trial % 4
        if kind == 0:                                            # one return
            k, w = int(rng.integers(0, n)), int(rng.integers(1, 200))
            row[k:k + w] = rng.random(len(row[k:k + w]))
        elif kind == 1:                                          # scattered bins
            row[:] = rng.random(n) * (rng.random(n) < 0.01)
        elif kind == 2:                                          # both ends
            row[0], row[-1] = 1.0, rng.random()
        else:                                                    # dense
            row[:] = rng.random(n)
        kern, lag0 = pulse_kernel(float(rng.choice([0.01, 0.05, 0.2])), float(rng.uniform(0.5, 8.0)))
        if trial % 3 == 0:
            lag0 = int(rng.integers(0, len(kern)))
        full = np.convolve(row, kern)[lag0:lag0 + n]
        got = convolve_fine(np.stack([row, np.zeros(n)]), kern, lag0)
        assert np.array_equal(got[0].view(np.uint64), full.view(np.uint64)), trial
        assert np.array_equal(got[1].view(np.uint64), np.zeros(n).view(np.uint64))


def test_run_over_a_prepared_scene_is_bit_identical(sim):
    """Simulator.run(scene_setup=...): the scene uploaded once for many runs, every result
    bit for bit the plain run's; a second prepared scene replaces the kept copies."""
    sc = scene()
    kw = dict(photons=500, max_order=2, batches=4)
    first = prepare_scene(sc, wavelength_nm=BASE.wavelength_nm)
    for seed in (3, 4):
        plain = sim.run(sc, BASE, seed=seed, **kw)
        kept = sim.run(sc, BASE, seed=seed, scene_setup=first, **kw)
        assert np.array_equal(plain.waveform.view(np.uint64), kept.waveform.view(np.uint64))
        assert np.array_equal(plain.fine, kept.fine)
    other = prepare_scene(sc, wavelength_nm=BASE.wavelength_nm, leaf_off=True)
    off = sim.run(sc, BASE, seed=5, leaf_off=True, scene_setup=other, **kw)
    assert sim._uploaded[0][0] is other.bricks
    assert np.array_equal(off.waveform, sim.run(sc, BASE, seed=5, leaf_off=True, **kw).waveform)
    with pytest.raises(InputError, match="scene_setup was prepared for another"):
        sim.run(sc, BASE, seed=6, scene_setup=other, **kw)  # leaves on, set-up made leaf-off
