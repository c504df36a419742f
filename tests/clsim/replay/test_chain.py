"""The paper's chain with a known answer: a simulated airborne survey over a leaf slab, read back as a measurement.

``clsim survey`` over the exact twin of a leaf slab above a ground writes LAS 1.4 waveform packets; that file
is then treated as measured: ``tlsvox voxelize`` makes a scene from its pulses (the slab's LAD is the
answer), and ``clsim replay --scene`` replays it over the twin (the survey's own waveforms are the answer).
"""

from __future__ import annotations

import json

import numpy as np
import pytest

LAD, TOP, BOTTOM, HALF = 1.0, 6.0, 4.0, 3.0  # the slab: 6 x 6 x 2 m of LAD 1 over a ground at z = 0


@pytest.fixture(scope="module")
def flown(tmp_path_factory):
    """The twin and two surveys of it: the hot spot on (the return through the gap it went down) and off."""
    pytest.importorskip("open3d")
    from clsim.cli.app import main
    from tlsvox.truth.synthetic import make_leaf_slab

    d = tmp_path_factory.mktemp("chain")
    slab = make_leaf_slab(lad=LAD, size=(2 * HALF, 2 * HALF, TOP - BOTTOM), origin=(-HALF, -HALF, BOTTOM), seed=3,
                          ground=True)
    twin = slab.truth_scene(0.25)
    twin.save(d / "twin.npz")
    # a slow, narrow line over the slab: 4 kHz, 40 lines/s, +-0.75 deg at 300 m (an 8 m swath)
    line = ["--start=-5,0", "--end", "5,0", "--altitude", "300", "--speed", "60", "--pulse-rate", "4000",
            "--scan-rate", "40", "--fov", "1.5", "--pulses", "600", "--photons", "500", "--workers", "0", "-q"]
    for name, extra in (("hotspot", ["--hotspot"]), ("turbid", [])):
        assert main(["survey", str(d / "twin.npz"), "-o", str(d / name), *line, *extra]) == 0
    return d, twin


def summary_of(out):
    return json.loads((out / "summary.json").read_text())


def _layers(scene):
    """Median LAD of each 0.5 m layer of the slab's inner 4 x 4 m (away from its edges), top first."""
    c = scene.centers()
    inner = (np.abs(c[:, 0]) < HALF - 1) & (np.abs(c[:, 1]) < HALF - 1) & ~scene.occluded
    out = []
    for z in np.arange(TOP - 0.25, BOTTOM, -0.5):
        sel = inner & (np.abs(c[:, 2] - z) < 0.01)
        out.append(float(np.median(scene.lad[sel])) if sel.any() else 0.0)
    return np.array(out)


@pytest.mark.parametrize("survey, flags", [("hotspot", []), ("turbid", ["--no-hotspot"])])
def test_voxelize_the_survey_file_gives_the_slab_back(flown, tmp_path, survey, flags):
    from tlsvox.cli.app import main
    from voxlidar.scene import Scene

    d, twin = flown
    out = tmp_path / "air.npz"
    assert main(["voxelize", str(d / survey / "survey.las"), "--voxel-size", "0.5", "--ground", "ransac", "-q",
                 "-o", str(out), *flags]) == 0
    scene = Scene.load(out)
    assert scene.ground_z == pytest.approx(0.0, abs=0.1)
    assert scene.meta["airborne"]["full_hits"]["rule"].startswith("vegetation and ground")
    # measured: 0.90-1.11 (hot spot), 0.86-1.10 (turbid) per layer with 500 photons per pulse and about 8 pulses per
    # m2; a layer's median off by more than 20 % is a wrong weight, not noise
    assert np.allclose(_layers(scene), LAD, rtol=0.2), _layers(scene)
    # the whole slab (measured +6 % and +4 %): the pulses cover it but for its edges, pooled over 0.23 m
    assert scene.total_leaf_area() == pytest.approx(twin.total_leaf_area(), rel=0.15)


def test_the_wrong_return_path_doubles_the_lad(flown, tmp_path):
    """Two-way attenuated returns read as one-way: each layer's share looks twice as large."""
    from tlsvox.cli.app import main
    from voxlidar.scene import Scene

    d, _ = flown
    out = tmp_path / "air.npz"
    assert main(["voxelize", str(d / "turbid" / "survey.las"), "--voxel-size", "0.5", "--ground", "ransac", "-q",
                 "-o", str(out)]) == 0
    assert np.all(_layers(Scene.load(out)) > 1.5 * LAD)


def test_replay_over_the_exact_twin_reproduces_the_survey(flown, tmp_path, capsys):
    from clsim.cli.app import main

    d, _ = flown
    out = tmp_path / "replay"
    assert main(["replay", str(d / "hotspot" / "survey.las"), "-o", str(out), "--scene", str(d / "twin.npz"),
                 "--scheme", "interleaved", "--methods", "simulation,nearest", "--photons", "500", "--no-plots",
                 "-q"]) == 0
    assert "riegl-lms-q680i" in json.dumps(summary_of(out)["sensor"])
    summary = json.loads((out / "summary.json").read_text())
    sim = summary["schemes"]["interleaved"]["summary"]["simulation"]["all"]
    # the same simulator over the same scene, the sensor read from the file (its flight fitted, its divergence
    # and wavelength from the preset it names): measured r 1.000, energy IQR 0.99-1.01, RH50 bias -0.03 m
    assert sim["r_median"] > 0.99
    assert 0.95 < sim["energy_ratio_q25"] and sim["energy_ratio_q75"] < 1.05
    assert abs(sim["rh50_bias"]) < 0.15 and abs(sim["rh98_bias"]) < 0.15


def test_airborne_files_refuse_scan_options(flown, tmp_path, capsys):
    from tlsvox.cli.app import main

    d, _ = flown
    las = str(d / "hotspot" / "survey.las")
    assert main(["voxelize", las, "--scanner-frame", "--fill", "layer", "-o", str(tmp_path / "a.npz")]) == 2
    err = capsys.readouterr().err
    assert "--scanner-frame, --fill" in err and "airborne" in err and "Traceback" not in err
    assert main(["voxelize", las, las, "-o", str(tmp_path / "a.npz")]) == 2
    assert "one airborne file" in capsys.readouterr().err
    assert not (tmp_path / "a.npz").exists()
