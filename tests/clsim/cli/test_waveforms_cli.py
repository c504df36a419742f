"""CLI sub-commands, called in-process through an argparse parser built with register()."""

from __future__ import annotations

import csv
import io
import json

import numpy as np
import pytest

from clsim.cli.app import main
from tlsvox.register.georegister import rotation_error_deg, transform_points, yaw_matrix


def run(argv):
    """The ``clsim`` command in-process: its exit code."""
    return main([str(a) for a in argv])


@pytest.mark.realdata
def test_info_las_and_pulsewaves(shared_data, capsys):
    assert run(["waveforms", "info", str(shared_data / "leica-fwf-las13" / "fwf.las")]) == 0
    out = capsys.readouterr().out
    assert "packets: 2250" in out and "[13, 12, 13, 13, 14, 13, 13, 17, 42, 67" in out
    pls = shared_data / "riegl-pulsewaves" / "140823_183115_1_clipped_test.pls"
    assert run(["waveforms", "info", str(pls)]) == 0
    out = capsys.readouterr().out
    assert "pulses: 4" in out and "outgoing: [28, 28, 28, 28]" in out
    assert "returning: [60, 60]" in out


@pytest.mark.realdata
def test_decompose_pulsewaves_with_plot(shared_data, tmp_path):
    pls = shared_data / "riegl-pulsewaves" / "140823_183115_1_clipped_test.pls"
    out, png = tmp_path / "echoes.csv", tmp_path / "fit.png"
    assert run(["decompose", str(pls), "-o", str(out), "--plot", str(png)]) == 0
    rows = list(csv.DictReader(io.StringIO(out.read_text())))
    assert {r["waveform"] for r in rows} == {"0", "1"}
    # echoes lie on the terrain of the header's bounding box (z 2084.6-2093.6 m)
    z = np.array([float(r["z"]) for r in rows])
    assert np.all((z > 2080) & (z < 2100))
    assert png.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"


@pytest.mark.realdata
def test_decompose_neon_csv_with_geolocation(shared_data, tmp_path):
    d = shared_data / "neon-harvard-waveforms"
    out = tmp_path / "neon.csv"
    assert run(["decompose", str(d / "return.csv"), "-o", str(out), "--limit", "5",
                "--geolocation", str(d / "geolocation.csv")]) == 0
    rows = list(csv.DictReader(io.StringIO(out.read_text())))
    assert {r["waveform"] for r in rows} == {str(i) for i in range(5)}
    # first echo of pulse 0 is near the NEON first-return position (z 334.69 m)
    first = [r for r in rows if r["waveform"] == "0"][0]
    assert abs(float(first["z"]) - 334.69) < 1.5


@pytest.mark.realdata
def test_decompose_batch_matches_single(shared_data, tmp_path, capsys):
    """--batch on 40 NEON waveforms: the same first-return height as the per-waveform
    run for every pulse (within 1.5 m, as above), and bad combinations refused."""
    d = shared_data / "neon-harvard-waveforms"
    outs = {}
    for flag in ([], ["--batch"]):
        out = tmp_path / f"neon{len(flag)}.csv"
        assert run(["decompose", str(d / "return.csv"), "-o", str(out), "--limit", "40",
                    "--geolocation", str(d / "geolocation.csv")] + flag) == 0
        rows = list(csv.DictReader(io.StringIO(out.read_text())))
        outs[len(flag)] = {w: float([r for r in rows if r["waveform"] == w][0]["z"])
                           for w in {r["waveform"] for r in rows}}
    assert outs[0].keys() == outs[1].keys() and len(outs[0]) == 40
    assert abs(outs[1]["0"] - 334.69) < 1.5
    diff = np.array([outs[0][w] - outs[1][w] for w in outs[0]])
    assert np.mean(np.abs(diff) < 1.5) >= 0.9, diff
    assert run(["decompose", str(d / "return.csv"), "-o", str(tmp_path / "x.csv"), "--batch",
                "--min-amplitude", "10"]) == 2
    assert "batch" in capsys.readouterr().err
    assert run(["decompose", str(d / "return.csv"), "-o", str(tmp_path / "x.csv"),
                "--device", "numpy"]) == 2
    assert "--device chooses where --batch fits" in capsys.readouterr().err


@pytest.mark.realdata
def test_decompose_batch_device_numpy(shared_data, tmp_path):
    """--batch --device numpy (the NumPy fits) and --batch (an OpenCL device when one
    builds the kernel): the same echo count and first-echo time for 40 NEON pulses
    in at least 38 (the device fits in float32 may take another branch of the model
    selection on a few) and the first-echo times within 0.1 ns where the counts agree."""
    d = shared_data / "neon-harvard-waveforms"
    got = {}
    for dev in ([], ["--device", "numpy"]):
        out = tmp_path / f"neon{len(dev)}.csv"
        assert run(["decompose", str(d / "return.csv"), "-o", str(out), "--limit", "40",
                    "--batch"] + dev) == 0
        rows = list(csv.DictReader(io.StringIO(out.read_text())))
        got[len(dev)] = {w: [float(r["location_ns"]) for r in rows if r["waveform"] == w]
                         for w in {r["waveform"] for r in rows}}
    same = [w for w in got[0] if len(got[0][w]) == len(got[2].get(w, []))]
    assert len(same) >= 38, len(same)
    dt = np.array([min(got[0][w]) - min(got[2][w]) for w in same])
    assert np.all(np.abs(dt) < 0.1), dt


def test_decompose_rejects_unknown_type(tmp_path, capsys):
    f = tmp_path / "x.dat"
    f.write_text("1,2,3")
    assert run(["decompose", str(f), "-o", str(tmp_path / "o.csv")]) == 2
    assert "unknown waveform file type" in capsys.readouterr().err


def test_georegister_cli(tmp_path):
    rng = np.random.default_rng(5)
    # an asymmetric structure: tilted ground, two posts, a box
    g = rng.uniform(-10, 10, (6000, 2))
    ground = np.column_stack([g, 0.05 * g[:, 0] + 0.3 * np.sin(g[:, 1] / 2)])
    post = np.column_stack([rng.normal(2, 0.1, 1500), rng.normal(-3, 0.1, 1500),
                            rng.uniform(0, 6, 1500)])
    box = rng.uniform([-6, 3, 0], [-3, 5, 2.5], (1500, 3))
    target = np.vstack([ground, post, box]) + [1000.0, 2000.0, 50.0]
    truth = yaw_matrix(10.0)
    truth[:3, 3] = [1000.0, 2000.0, 50.0]
    source = transform_points(np.linalg.inv(truth), target) + rng.normal(0, 0.003, target.shape)
    np.save(tmp_path / "tls.npy", source)
    np.save(tmp_path / "als.npy", target[::3])
    out = tmp_path / "t.json"
    assert run(["georegister", str(tmp_path / "tls.npy"), str(tmp_path / "als.npy"), "-o",
                str(out), "--init", "1000.5,1999.5,50.2,4", "--yaw-range", "10",
                "--voxel-size", "0.1", "--output-cloud", str(tmp_path / "moved.npy")]) == 0
    res = np.array(json.loads(out.read_text())["transform"])
    assert rotation_error_deg(res, truth) < 0.2
    assert np.linalg.norm(res[:3, 3] - truth[:3, 3]) < 0.05
    assert np.load(tmp_path / "moved.npy").shape == source.shape


@pytest.mark.realdata
def test_decompose_names_each_pulse_and_its_gps_time(shared_data, tmp_path):
    """Every echo row carries its waveform packet and the GPS time of the pulse (the packet's first point)."""
    from clsim.waveforms.io import read_las_waveforms

    src = shared_data / "leica-fwf-las13" / "fwf.las"
    out = tmp_path / "echoes.csv"
    assert run(["decompose", str(src), "-o", str(out), "--limit", "20", "--plot", str(tmp_path / "fit.png")]) == 0
    rows = list(csv.DictReader(io.StringIO(out.read_text())))
    w = read_las_waveforms(src)
    first = {}
    for i, p in enumerate(w.packet):
        if p >= 0 and int(p) not in first:
            first[int(p)] = i
    assert {int(r["pulse_id"]) for r in rows} <= set(range(20))
    for r in rows:
        assert float(r["gps_time"]) == pytest.approx(w.gps_time[first[int(r["pulse_id"])]], abs=1e-6)
        # volts from the packet's descriptor: gain x counts above the baseline, offset + gain x baseline
        d = w.descriptor_of_point(first[int(r["pulse_id"])])
        assert float(r["amplitude_v"]) == pytest.approx(d.gain * float(r["amplitude"]), rel=1e-5)
        assert float(r["baseline_v"]) == pytest.approx(d.offset + d.gain * float(r["baseline"]), rel=1e-5, abs=1e-9)
    assert (tmp_path / "fit.png").stat().st_size > 1000


@pytest.mark.realdata
def test_decompose_with_the_instruments_pulse_as_template(shared_data, tmp_path, capsys):
    from clsim.waveforms.decompose._template import decompose_template

    d = shared_data / "neon-harvard-waveforms"
    out = tmp_path / "t.csv"
    assert run(["decompose", d / "return.csv", "-o", out, "--limit", "20", "--geolocation", d / "geolocation.csv",
                "--template", d / "system_impulse.csv"]) == 0
    rows = list(csv.DictReader(io.StringIO(out.read_text())))
    assert set(rows[0]) >= {"location_ns", "energy", "extent_ns", "snr", "z"}
    # the rows are decompose_template's echoes of the same records, in order
    waves = []
    for line in (d / "return.csv").read_text().splitlines()[1:21]:
        v = np.array([float(x) for x in line.split(",")])
        waves.append(v[: np.flatnonzero(v)[-1] + 1])
    impulse = np.array([float(r.split(",")[0]) for r in (d / "system_impulse.csv").read_text().splitlines()[1:]])
    want = decompose_template(waves, impulse - np.median(np.sort(impulse)[: impulse.size // 5]))  # baseline off
    assert np.allclose([float(r["location_ns"]) for r in rows], want.location_ns, atol=1e-4)
    first = [r for r in rows if r["waveform"] == "0"][0]
    assert abs(float(first["z"]) - 334.69) < 1.5  # NEON's first-return position of pulse 0
    # the options that belong to the Gaussian fit are refused with --template, one line
    assert run(["decompose", d / "return.csv", "-o", tmp_path / "x.csv", "--template", "returns", "--batch"]) == 2
    assert "drop --batch" in capsys.readouterr().err
    assert run(["decompose", d / "return.csv", "-o", tmp_path / "x.csv", "--min-relative", "0.05"]) == 2
    assert "--min-relative needs --template" in capsys.readouterr().err
    assert not (tmp_path / "x.csv").exists()
