"""``clsim survey``: a flight line over a scene, in-process, with the direct loop."""

from __future__ import annotations

import json

import numpy as np

from clsim.cli.app import main
from clsim.survey import load_survey
from clsim.survey.distributed import completed_batches
from clsim.validation import testscenes

ARGS = ["--sensor", "riegl-lms-q680i", "--altitude", "300", "--speed", "20", "--fov", "0.8", "--pulses", "12",
        "--photons", "200", "--batch-size", "5", "--workers", "0", "--no-las", "-q"]


def test_survey_runs_resumes_and_refuses_another_job(tmp_path, capsys):
    scene = testscenes.homogeneous_layer(width=4.0, thickness=1.0, voxel_size=0.5).save(tmp_path / "s.npz")
    out = tmp_path / "sv"
    assert main(["survey", str(scene), "-o", str(out), *ARGS]) == 0
    assert completed_batches(out) == {(0, 5), (5, 10), (10, 12)}
    wf = load_survey(out)
    assert wf.waveform.shape[0] == 12 and np.all(wf.energy > 0) and wf.bin_ns == 1.0 / 1.0
    # the default line crosses the scene along x at its middle y: the first pulse is over its west edge
    leg = json.loads((out / "survey.json").read_text())["legs"][0]
    assert leg["start"] == [-2.0, 0.0, 300.0] and leg["end"] == [2.0, 0.0, 300.0]
    before = sorted(p.stat().st_mtime_ns for p in (out / "batches").iterdir())
    assert main(["survey", str(scene), "-o", str(out), *[a for a in ARGS if a != "-q"]]) == 0
    assert "nothing to compute: all 3 batches are on disk" in capsys.readouterr().err
    assert sorted(p.stat().st_mtime_ns for p in (out / "batches").iterdir()) == before
    assert main(["survey", str(scene), "-o", str(out), *ARGS, "--seed", "2"]) == 2
    assert "holds another survey (differs in seed)" in capsys.readouterr().err
    assert main(["survey", str(scene), "-o", str(out), *ARGS, "--seed", "2", "--restart"]) == 0
    assert not np.array_equal(load_survey(out).waveform, wf.waveform)


def test_a_flagged_scene_is_said_and_refused_with_strict(tmp_path, capsys):
    """A scene written with quality warnings (tlsvox voxelize records them): clsim simulate and survey repeat
    each one when they load it, and with --strict refuse it before writing anything."""
    scene = testscenes.homogeneous_layer(width=4.0, thickness=1.0, voxel_size=0.5)
    scene.meta["warnings"] = ["scan 'merged' has no empty pulses: each of its 10 pulses left an echo"]
    path = scene.save(tmp_path / "flagged.npz")
    assert main(["simulate", str(path), "--photons", "2000", "-q", "-o", str(tmp_path / "w.npz")]) == 0
    assert "was written with a quality warning: scan 'merged' has no empty pulses" in capsys.readouterr().err
    assert main(["simulate", str(path), "--photons", "2000", "-q", "--strict", "-o", str(tmp_path / "w2.npz")]) == 2
    assert "--strict" in capsys.readouterr().err and not (tmp_path / "w2.npz").exists()
    assert main(["survey", str(path), "-o", str(tmp_path / "sv"), *ARGS, "--strict"]) == 2
    assert "no empty pulses" in capsys.readouterr().err and not (tmp_path / "sv").exists()
