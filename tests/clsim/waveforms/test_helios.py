"""HELIOS++ full-waveform text (``*_fullwave.txt``): read, decomposed from the shell, echoes placed on the beam.

The files are generated here in HELIOS++'s exact layout (index, origin, direction, min and max time, GPS
time, samples; 4 and 9 decimals), with Gaussian echoes at known one-way times, so the known answer is each
echo's time and the point ``origin + c t direction`` where HELIOS++ put its hit.
"""

from __future__ import annotations

import csv
import io

import numpy as np
import pytest

from clsim.cli.app import main
from clsim.errors import InputError
from clsim.waveforms.decompose import gaussian_sum
from clsim.waveforms.io.helios import C_M_PER_NS, HeliosFullwave, read_helios_fullwave, write_helios_fullwave


def _file(tmp_path, rng, count=30, bin_ns=1.0, n=80):
    """``count`` pulses from 400-420 m up, near nadir, one or two echoes (sigma 1.7 ns, HELIOS++'s default 4 ns
    pulse) each; returns the path and the true (pulse, one-way time, xyz) of every echo."""
    origin = np.column_stack([rng.uniform(-20, 20, count), rng.uniform(-20, 20, count), rng.uniform(400, 420, count)])
    d = np.column_stack([rng.normal(0, 0.02, count), rng.normal(0, 0.02, count), -np.ones(count)])
    d = np.round(d / np.linalg.norm(d, axis=1, keepdims=True), 4)  # HELIOS++ writes 4 decimals
    t_min = np.round(origin[:, 2] / C_M_PER_NS - 40.0, 4)
    samples, truth = [], []
    for i in range(count):
        t = t_min[i] + bin_ns * np.arange(n)
        times = [t_min[i] + rng.uniform(15, 30)] + ([t_min[i] + rng.uniform(45, 60)] if i % 2 else [])
        amps = rng.uniform(2e-4, 1e-3, len(times))
        samples.append(np.round(gaussian_sum(t, amps, times, [1.7] * len(times)), 9))
        dn = d[i] / np.linalg.norm(d[i])
        truth += [(i, tt, origin[i] + C_M_PER_NS * tt * dn) for tt in times]
    fw = HeliosFullwave(index=np.arange(100, 100 + count), origin=origin, direction=d, min_time_ns=t_min,
                        max_time_ns=t_min + (n - 1) * bin_ns, gps_time=np.arange(count) * 1e-4 + 5000.0,
                        samples=samples)
    path = write_helios_fullwave(tmp_path / "leg000_fullwave.txt", fw)
    return path, truth


def test_read_back_the_layout(tmp_path, rng):
    path, _ = _file(tmp_path, rng, count=5, bin_ns=0.5)
    fw = read_helios_fullwave(path)
    assert len(fw) == 5 and fw.index.tolist() == list(range(100, 105))
    assert np.allclose(fw.dt_ns, 0.5) and np.allclose(np.linalg.norm(fw.direction, axis=1), 1.0)
    first = path.read_text().splitlines()[0].split()
    assert first[0] == "100" and len(first[1].split(".")[1]) == 4 and len(first[9].split(".")[1]) == 9


def test_decomposed_from_the_shell_at_the_known_times_and_places(tmp_path, rng, capsys):
    path, truth = _file(tmp_path, rng)
    assert main(["waveforms", "info", str(path)]) == 0
    out = capsys.readouterr().out
    assert "HELIOS++ full waveform" in out and "waveforms: 30" in out
    fw = read_helios_fullwave(path)
    csv_out = tmp_path / "echoes.csv"
    assert main(["decompose", str(path), "-o", str(csv_out)]) == 0
    rows = list(csv.DictReader(io.StringIO(csv_out.read_text())))
    assert len(rows) == len(truth)  # noise-free waveforms: every echo, nothing else
    by_pulse = {}
    for r in rows:
        by_pulse.setdefault(int(r["waveform"]), []).append(r)
    for i, t_true, xyz in truth:
        r = min(by_pulse[i], key=lambda r: abs(fw.min_time_ns[i] + float(r["location_ns"]) - t_true))
        assert int(r["pulse_id"]) == 100 + i
        # times written with 4 decimals and samples with 9: within 0.01 ns, 3 mm along the beam
        assert abs(fw.min_time_ns[i] + float(r["location_ns"]) - t_true) < 0.01
        assert np.linalg.norm([float(r[k]) - v for k, v in zip("xyz", xyz)]) < 0.005


@pytest.mark.parametrize("line, says", [
    ("1 0 0 100 0 0 -1 300 304 12.5\n", "10 values"),
    ("1 0 0 100 0 0 -1 300 304 12.5 0 x 1\n", "'x', not a number"),
    ("1 0 0 100 0 0 -2 300 304 12.5 0 1 1\n", "not 1"),
    ("1 0 0 100 0 0 -1 304 300 12.5 0 1 1\n", "before min time"),
    ("1 0 0 nan 0 0 -1 300 304 12.5 0 1 1\n", "NaN"),
    ("1.5 0 0 100 0 0 -1 300 304 12.5 0 1 1\n", "not an integer"),
    ("\n\n", "no full-waveform lines"),
])
def test_bad_lines_named(line, says):
    with pytest.raises(InputError, match=says):
        read_helios_fullwave(io.StringIO(line))


def test_read_as_measured_pulses_for_a_replay(tmp_path, rng):
    """A HELIOS++ full-waveform file as the replay's measured pulses: each sample where HELIOS++ put it
    (origin + c t direction on its one-way time axis), the spacing doubled to the round trip, the file's
    beam origins kept; scan lines split at a GPS-time jump; the sensor defaults stated."""
    from clsim.replay import read_measured
    from clsim.replay._measured import HELIOS_DEFAULTS

    path, truth = _file(tmp_path, rng, count=12, bin_ns=0.5)
    fw = read_helios_fullwave(path)
    fw.gps_time[6:] += 1.0  # a second scan line
    path = write_helios_fullwave(tmp_path / "two_lines_fullwave.txt", fw)
    m = read_measured(path)
    assert m.samples.shape == (12, 80) and m.valid.all() and m.dt_ns == pytest.approx(1.0)
    for i in range(12):
        start, per_ns = fw.sample_geometry(i)
        assert np.allclose(m.bin0[i] + 7 * m.step[i], start + per_ns * 7 * 0.5, atol=1e-9)
        assert np.allclose(m.samples[i], fw.samples[i])
    assert np.allclose(m.origin, fw.origin) and m.line.tolist() == [0] * 6 + [1] * 6
    assert m.divergence_mrad == HELIOS_DEFAULTS["divergence_mrad"] and "states neither" in m.meta["sensor"]["defaults"]
    fw.max_time_ns[3] += 0.25  # one pulse on another sample clock
    with pytest.raises(InputError, match="one sample clock"):
        read_measured(write_helios_fullwave(tmp_path / "clocks_fullwave.txt", fw))
