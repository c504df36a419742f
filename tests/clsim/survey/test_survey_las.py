"""Survey LAS 1.4 output: the round trip of waveforms and returns, geometry, pictures, bad input.

The waveforms are synthetic echoes of known range (Gaussians of the sensor's
pulse width at the ground and, on every other pulse, at a canopy 12 m above
it), so the returns have a known answer.
"""

from __future__ import annotations

import runpy
from pathlib import Path

import laspy
import numpy as np
import pytest

from clsim import Sensor
from clsim.errors import InputError
from clsim.sensor import C_M_PER_NS as C
from clsim.survey import (
    ScanPattern,
    SurveyLas,
    Trajectory,
    plot_point_cloud,
    plot_radargram,
    read_survey_las,
    survey_pulses,
    write_survey_las,
)
from clsim.waveforms.io import read_las_waveforms
from voxlidar.errors import VoxlidarError

PNG = b"\x89PNG\r\n\x1a\n"
SENSOR = Sensor.preset("riegl-lms-q680i")
CANOPY_M = 12.0           # canopy echo this far (m, along the beam) before the ground
#: Coordinates are stored in 1 mm steps (0.5 mm per axis, 0.87 mm in 3-D); the
#: fitted location of a noise-free echo quantised to 16 bits is better than
#: 0.002 ns (0.3 mm of range).  Sum, rounded up:
POS_TOL_M = 1.5e-3


def make_pulses(n=240, seed=4):
    pat = ScanPattern(kind="mirror", pulse_rate_hz=4000.0, scan_rate_hz=20.0, fov_deg=40.0)
    tr = Trajectory.line((0.0, 0.0), (30.0, 0.0), altitude_m=300.0, speed_mps=50.0)
    return survey_pulses(tr, pat, SENSOR, count=n, seed=seed)


def echoes(pulses, bin_ns, empty_every=0):
    """Waveforms with a ground echo and, on even pulses, a canopy echo; the truth."""
    n = len(pulses)
    n_bins = int(np.ceil(2.0 * 35.0 / C / bin_ns))            # 35 m of range
    t0 = 2.0 * (pulses.range_m - 25.0) / C + 0.37           # records start 25 m before the ground
    t = t0[:, None] + bin_ns * np.arange(n_bins)
    sig = SENSOR.pulse_sigma_ns
    tg = 2.0 * pulses.range_m / C
    tc = 2.0 * (pulses.range_m - CANOPY_M) / C
    canopy = np.arange(n) % 2 == 0
    w = 1e-6 * np.exp(-0.5 * ((t - tg[:, None]) / sig) ** 2)
    w += np.where(canopy, 4e-7, 0.0)[:, None] * np.exp(-0.5 * ((t - tc[:, None]) / sig) ** 2)
    if empty_every:
        w[::empty_every] = 0.0
    return w, t0, canopy


def _write(bin_ns, folder):
    pulses = make_pulses()
    w, t0, canopy = echoes(pulses, bin_ns)
    las, wdp = write_survey_las(folder / "line.las", pulses, w, t0_ns=t0, bin_ns=bin_ns,
                                sensor=SENSOR, gps_time_offset_s=1.0e6, device="numpy")
    return dict(pulses=pulses, w=w, t0=t0, canopy=canopy, las=las, wdp=wdp, bin_ns=bin_ns)


@pytest.fixture(scope="module", params=[1.0, 1.0 / 1.8], ids=["1GHz", "1.8GHz"])
def written(request, tmp_path_factory):
    """1 GHz (1000 ps) and 1.8 GHz (555.6 ps: the descriptor's spacing rounds to 556)."""
    return _write(request.param, tmp_path_factory.mktemp("las"))


@pytest.fixture(scope="module")
def written_1ghz(tmp_path_factory):
    return _write(1.0, tmp_path_factory.mktemp("las1"))


def test_files_are_las14_format9_with_external_packets(written):
    assert written["las"].is_file() and written["wdp"].is_file()
    f = laspy.read(written["las"])
    assert (str(f.header.version), f.header.point_format.id) == ("1.4", 9)
    assert f.header.global_encoding.waveform_data_packets_external
    assert not f.header.global_encoding.waveform_data_packets_internal
    assert f.header.system_identifier.startswith("clsim riegl-lms-q680i")
    assert not list(written["las"].parent.glob(".*"))               # no temporary left


def test_waveforms_read_back_within_half_a_count(written):
    lw = read_las_waveforms(written["las"])
    (d,) = lw.descriptors.values()
    w = written["w"]
    assert d.bits_per_sample == 16 and d.n_samples == w.shape[1]
    assert d.spacing_ps == round(written["bin_ns"] * 1000)
    assert d.offset == 0.0 and d.gain == pytest.approx(w.max() / 65535, rel=1e-12)
    assert lw.n_packets == len(w)                                   # one packet per pulse
    err = np.abs(lw.volts()[:, :d.n_samples] - w)
    assert err.max() <= 0.5 * d.gain * (1 + 1e-9)                   # the stated quantisation


def test_packets_in_the_wdp_are_where_laspy_says(written):
    """Independent read: each point's offset/size in the .wdp gives its pulse's samples."""
    f = laspy.read(written["las"])
    blob = np.fromfile(written["wdp"], dtype=np.uint8)
    offs = np.asarray(f.wavepacket_offset, dtype=np.int64)
    size = int(f.wavepacket_size[0])
    assert (np.asarray(f.wavepacket_size) == size).all() and size == 2 * written["w"].shape[1]
    raw = blob[offs[:, None] + np.arange(size)].copy().view("<u2")
    gain = written["w"].max() / 65535
    pulse = np.asarray(f.pulse_index, dtype=np.int64) - written["pulses"].index[0]
    np.testing.assert_array_equal(raw, np.rint(written["w"][pulse] / gain).astype(np.uint16))


def test_returns_are_the_known_echoes(written):
    p, canopy = written["pulses"], written["canopy"]
    f = laspy.read(written["las"])
    pulse = np.asarray(f.pulse_index, dtype=np.int64) - p.index[0]
    assert np.bincount(pulse, minlength=len(p)).tolist() == np.where(canopy, 2, 1).tolist()
    rn = np.asarray(f.return_number)
    nr = np.asarray(f.number_of_returns)
    assert (nr == np.where(canopy[pulse], 2, 1)).all()
    # in time order: the canopy first, the ground last
    rng = np.where((rn == 1) & canopy[pulse], p.range_m[pulse] - CANOPY_M, p.range_m[pulse])
    truth = p.position[pulse] + rng[:, None] * p.direction[pulse]
    xyz = np.column_stack([f.x, f.y, f.z])
    assert np.abs(xyz - truth).max() < POS_TOL_M
    np.testing.assert_array_equal(np.asarray(f.gps_time), 1.0e6 + p.time_s[pulse])
    assert np.abs(np.asarray(f.scan_angle) * 0.006 - p.scan_angle_deg[pulse]).max() <= 0.003
    assert (np.asarray(f.point_source_id) == p.leg[pulse] + 1).all()
    assert not np.asarray(f.synthetic).any() and not np.asarray(f.withheld).any()
    amp = np.where((rn == 1) & canopy[pulse], 4e-7, 1e-6)
    np.testing.assert_allclose(np.asarray(f.amplitude), amp, rtol=1e-3)
    np.testing.assert_allclose(np.asarray(f.echo_width_ns), SENSOR.pulse_sigma_ns, rtol=1e-2)
    gain = written["w"].max() / 65535
    # the amplitude in digitiser counts, clipped to 16 bits (a fitted peak exceeds the sampled one)
    counts = np.minimum(np.rint(np.asarray(f.amplitude, dtype=np.float64) / gain), 65535)
    assert np.abs(np.asarray(f.intensity) - counts).max() <= 1.0     # float32 amplitude


def test_samples_lie_on_the_beam_at_c_t_over_2(written):
    """Sample j of a pulse lies at position + c (t0 + j bin) / 2 * direction, through the
    project's reader (LasWaveforms.sample_positions: P + (L - t) x_t) for every point."""
    p, t0, b = written["pulses"], written["t0"], written["bin_ns"]
    lw = read_las_waveforms(written["las"])
    f = laspy.read(written["las"])
    pulse = np.asarray(f.pulse_index, dtype=np.int64) - p.index[0]
    j = np.arange(written["w"].shape[1])
    worst = 0.0
    for i in range(len(lw)):
        k = pulse[i]
        truth = p.position[k] + (0.5 * C * (t0[k] + j * b))[:, None] * p.direction[k]
        worst = max(worst, float(np.abs(lw.sample_positions(i) - truth).max()))
    assert worst < 1e-3                      # 1 mm coordinate steps; float32 x_t adds < 0.01 mm
    s = read_survey_las(written["las"])
    for k in (0, 1, len(p) - 1):
        truth = p.position[k] + (0.5 * C * (t0[k] + j * b))[:, None] * p.direction[k]
        assert np.abs(s.sample_positions(k) - truth).max() < 1e-3


def test_read_survey_las_gives_pulses_and_returns(written):
    s = read_survey_las(written["las"])
    p = written["pulses"]
    assert isinstance(s, SurveyLas) and s.n_pulses == len(p)
    np.testing.assert_array_equal(s.pulse_index, p.index)
    np.testing.assert_array_equal(s.pulse_gps_time, 1.0e6 + p.time_s)
    assert np.abs(s.waveforms - written["w"]).max() <= 0.5 * s.gain * (1 + 1e-9)
    np.testing.assert_allclose(s.step, 0.5 * C * written["bin_ns"] * p.direction, atol=1e-7)
    assert s.returns.all() and len(s.xyz) == int(np.where(written["canopy"], 2, 1).sum())


def test_pulses_without_a_return_keep_their_waveform(tmp_path):
    p = make_pulses(60)
    w, t0, _ = echoes(p, 1.0, empty_every=5)                       # pulses 0, 5, ... silent
    w[5, 100] = 1e-9                                                # one tiny sample: a peak, no echo
    las, _ = write_survey_las(tmp_path / "a.las", p, w, t0_ns=t0, bin_ns=1.0, sensor=SENSOR,
                              min_amplitude=1e-8, device="numpy")
    s = read_survey_las(las)
    assert s.n_pulses == 60
    silent = np.arange(0, 60, 5)
    stand = np.flatnonzero(s.withheld)
    np.testing.assert_array_equal(s.pulse[stand], silent)
    assert s.synthetic[stand].all() and (s.number_of_returns[stand] == 1).all()
    assert (s.intensity[stand] == 0).all()
    # at the strongest sample (the first of an all-zero record)
    for k, pt in zip(silent, stand):
        j = 100 if k == 5 else 0
        assert np.abs(s.xyz[pt] - s.sample_positions(k)[j]).max() < 1e-3
    assert not s.withheld[~np.isin(s.pulse, silent)].any()
    las2, _ = write_survey_las(tmp_path / "b.las", p, w, t0_ns=t0, bin_ns=1.0, sensor=SENSOR,
                               min_amplitude=1e-8, empty="drop", device="numpy")
    d = read_survey_las(las2)
    assert d.n_pulses == 48 and not d.withheld.any()
    np.testing.assert_array_equal(d.pulse_index, np.setdiff1d(p.index, p.index[silent]))
    np.testing.assert_array_equal(d.waveforms, s.waveforms[~np.isin(np.arange(60), silent)])


def test_waveform_only_file_and_8_bits(tmp_path):
    p = make_pulses(30)
    w, t0, _ = echoes(p, 1.0)
    las, _ = write_survey_las(tmp_path / "w.las", p, w, t0_ns=t0, bin_ns=1.0, sensor=SENSOR,
                              returns=False, bits=8)
    s = read_survey_las(las)
    assert len(s.xyz) == 30 and s.synthetic.all() and not s.withheld.any()
    assert s.raw.dtype == np.uint8 and s.gain == pytest.approx(w.max() / 255)
    assert np.abs(s.waveforms - w).max() <= 0.5 * s.gain * (1 + 1e-9)
    peak = np.argmax(s.raw, axis=1)
    for k in range(30):
        assert np.abs(s.xyz[k] - s.sample_positions(k)[peak[k]]).max() < 1e-3


def test_stated_gain_and_offset_are_written(tmp_path):
    p = make_pulses(20)
    w, t0, _ = echoes(p, 1.0)
    las, _ = write_survey_las(tmp_path / "g.las", p, w - 1e-7, t0_ns=t0, bin_ns=1.0,
                              sensor=SENSOR, gain=1e-10, offset=-2e-7, device="numpy")
    s = read_survey_las(las)
    assert (s.gain, s.offset) == (1e-10, -2e-7)
    assert np.abs(s.waveforms - (w - 1e-7)).max() <= 0.5e-10 * (1 + 1e-6)


def test_the_file_does_not_depend_on_the_chunking(tmp_path):
    """Chunks of 7 and of all pulses, float64 and float32 input of the same values: the
    same bytes (the sensor's pulse is the matched filter of every chunk)."""
    p = make_pulses(50)
    w, t0, _ = echoes(p, 1.0)
    w = (w + np.random.default_rng(2).normal(0.0, 1e-8, w.shape)).astype(np.float32)
    outs = []
    for k, (chunk, arr) in enumerate([(7, w), (1000, w.astype(np.float64))]):
        las, wdp = write_survey_las(tmp_path / f"c{k}.las", p, arr, t0_ns=t0, bin_ns=1.0,
                                    sensor=SENSOR, chunk=chunk, device="numpy")
        outs.append((las.read_bytes(), wdp.read_bytes()))
    assert outs[0] == outs[1]


def test_a_failed_write_leaves_no_file(tmp_path, monkeypatch):
    p = make_pulses(10)
    w, t0, _ = echoes(p, 1.0)

    def boom(self, *a, **k):
        raise OSError("disk full")

    monkeypatch.setattr(laspy.LasWriter, "write_points", boom)
    with pytest.raises(OSError, match="disk full"):
        write_survey_las(tmp_path / "x.las", p, w, t0_ns=t0, bin_ns=1.0, sensor=SENSOR,
                         device="numpy")
    assert list(tmp_path.iterdir()) == []


def _bad():
    p = make_pulses(10)
    w, t0, _ = echoes(p, 1.0)
    ok = dict(t0_ns=t0, bin_ns=1.0, sensor=SENSOR)
    nan = w.copy()
    nan[3, 4] = np.nan
    return {
        "laz suffix": (("x.laz", p, w), ok, ".las"),
        "rows": (("x.las", p, w[:5]), ok, "one row per pulse"),
        "t0 shape": (("x.las", p, w), {**ok, "t0_ns": t0[:3]}, "t0_ns"),
        "bin_ns 0": (("x.las", p, w), {**ok, "bin_ns": 0.0}, "bin_ns"),
        "bits 12": (("x.las", p, w), {**ok, "bits": 12}, "8, 16 or 32"),
        "gain 0": (("x.las", p, w), {**ok, "gain": 0.0}, "gain"),
        "NaN": (("x.las", p, nan), ok, "NaN"),
        "empty kind": (("x.las", p, w), {**ok, "empty": "keep"}, "empty"),
        "max_returns": (("x.las", p, w), {**ok, "max_returns": 16}, "1-15"),
        "not pulses": (("x.las", p.target, w), ok, "Pulses"),
        "not a sensor": (("x.las", p, w), {**ok, "sensor": "riegl"}, "Sensor"),
    }


@pytest.mark.parametrize("case", list(_bad()))
def test_bad_input_is_one_line(case, tmp_path):
    (name, pulses, w), kw, words = _bad()[case]
    with pytest.raises(InputError) as err:
        write_survey_las(tmp_path / name, pulses, w, **kw)
    assert words in str(err.value) and "\n" not in str(err.value)
    assert list(tmp_path.iterdir()) == []


# -- pictures -----------------------------------------------------------------
def test_radargram_and_point_cloud_write_pictures(written_1ghz, tmp_path):
    las = written_1ghz["las"]
    s = read_survey_las(las)
    a = plot_radargram(las, tmp_path / "r.png", max_scan_angle_deg=None)
    b = plot_radargram(s, tmp_path / "r_log.png", max_scan_angle_deg=5.0, log=True)
    c = plot_point_cloud(las, tmp_path / "pc_rn.png", color="return")
    for out in (a, b, c):
        assert out.read_bytes()[:8] == PNG
    with pytest.raises(VoxlidarError, match="picture format"):
        plot_radargram(s, tmp_path / "r.txt")
    with pytest.raises(InputError, match="nadir"):
        plot_radargram(s, tmp_path / "r2.png", max_scan_angle_deg=-1.0)
    with pytest.raises(InputError, match="height' or 'return"):
        plot_point_cloud(s, tmp_path / "pc2.png", color="intensity")


def test_example_round_trip_prints_its_errors(tmp_path, capsys):
    example = runpy.run_path(str(Path(__file__).parents[3] / "examples" / "survey_las.py"))
    s = example["main"](tmp_path, length_m=12.0)
    out = capsys.readouterr().out
    assert "waveforms read back" in out and "first-sample positions" in out
    assert s.n_pulses > 4000
    assert sorted(p.name for p in tmp_path.iterdir()) == [
        "line.las", "line.wdp", "survey_point_cloud.png", "survey_radargram.png"]


# -- noise, the OpenCL fits, the simulator's own waveforms ---------------------
def test_noisy_echoes_with_the_default_device(tmp_path):
    """Noise of 1 % of the ground echo; the fits on the default device (OpenCL when one
    builds the kernel, else NumPy). Every true echo is found within 5 standard errors of
    location (Cramér-Rao for a Gaussian echo: sigma_t = (noise / A) sqrt(2 sigma dt / sqrt(pi)),
    0.014 ns for the ground, 0.035 ns for the canopy); extra returns (false alarms, 0.01 per
    waveform expected: 2.4 here) are at most 10 (Poisson(2.4) exceeds 10 with p < 1e-4)."""
    p = make_pulses()
    w, t0, canopy = echoes(p, 1.0)
    noise = 1e-8
    w = w + np.random.default_rng(5).normal(0.0, noise, w.shape)
    las, _ = write_survey_las(tmp_path / "n.las", p, w, t0_ns=t0, bin_ns=1.0, sensor=SENSOR)
    s = read_survey_las(las)
    found = 0
    sig_t = lambda a: noise / a * np.sqrt(2 * SENSOR.pulse_sigma_ns / np.sqrt(np.pi))  # noqa: E731
    for k in range(len(p)):
        mine = s.xyz[s.pulse == k]
        truths = [(p.range_m[k], 1e-6)] + ([(p.range_m[k] - CANOPY_M, 4e-7)] if canopy[k] else [])
        for r, a in truths:
            gap = np.linalg.norm(mine - (p.position[k] + r * p.direction[k]), axis=1).min()
            found += gap < 5 * 0.5 * C * sig_t(a) + POS_TOL_M
    n_true = int(np.where(canopy, 2, 1).sum())
    assert found == n_true
    assert n_true <= len(s.xyz) <= n_true + 10


def test_simulated_ground_returns_lie_on_the_ground(tmp_path):
    """The NumPy reference simulator's waveforms over a flat ground (z = 0): each pulse's
    one return lies on the ground. Tolerance 5 mm: the footprint (0.31 m across, 15 deg
    incidence) spreads the echo over +-4 cm of range, symmetric about the beam axis to
    0.04 mm; 2000 photons leave its centroid about 0.5 mm uncertain."""
    from clsim import ReferenceSimulator
    from clsim.validation import testscenes

    scene = testscenes.ground_only(width=40.0, voxel_size=2.0)
    tr = Trajectory.line((-5.0, 0.0), (5.0, 0.0), altitude_m=300.0, speed_mps=50.0)
    pat = ScanPattern(kind="palmer", pulse_rate_hz=10_000.0, scan_rate_hz=20.0, fov_deg=30.0)
    p = survey_pulses(tr, pat, first=7, count=5, seed=11)
    base = Sensor.preset("ahab-chiroptera-i", fov_mrad=3.0)
    runs = [ReferenceSimulator().run(scene, p.sensor(i, base), photons=2000, seed=int(p.seed[i]),
                                     target=p.target[i], max_order=1) for i in range(len(p))]
    n = min(len(r.waveform) for r in runs)
    w = np.array([r.waveform[:n] for r in runs])
    t0 = np.array([r.time_ns[0] for r in runs])
    las, _ = write_survey_las(tmp_path / "sim.las", p, w, t0_ns=t0, bin_ns=1.0 / base.sampling_ghz,
                              sensor=base, device="numpy")
    s = read_survey_las(las)
    assert s.n_pulses == 5 and s.returns.all() and len(s.xyz) == 5
    assert np.abs(s.xyz[:, 2]).max() < 5e-3
    np.testing.assert_allclose(s.xyz[:, :2], p.target[:, :2], atol=5e-3)
