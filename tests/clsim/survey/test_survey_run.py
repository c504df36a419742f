"""clsim.survey.distributed: a survey's pulses in batches, in a loop or on Dask, resumable.

Every test compares waveforms bit for bit: each pulse has its own seed, so the
output may not depend on the batching, the number of workers, or on a run
having been stopped and resumed.
"""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest

from clsim.errors import InputError
from clsim.sensor import Sensor
from clsim.survey import ScanPattern, SurveyJob, Trajectory, load_survey, run_survey
from clsim.survey.distributed import batch_path, completed_batches, projected_rate
from clsim.transport.result import PulseWaveforms
from clsim.validation import testscenes

ROOT = Path(__file__).resolve().parents[3]
BASE = Sensor.preset("riegl-lms-q680i")


@pytest.fixture(scope="module")
def scene_file(tmp_path_factory):
    s = testscenes.homogeneous_layer(width=6.0, thickness=1.5, lad=1.0, voxel_size=0.5, base_height=3.0)
    return str(s.save(tmp_path_factory.mktemp("scene") / "layer.npz"))


def make_job(scene_file, **kw):
    tr = Trajectory.line((-2.0, 0.0), (2.0, 0.0), altitude_m=250.0, speed_mps=40.0)
    pat = ScanPattern(kind="palmer", pulse_rate_hz=400.0, scan_rate_hz=37.0, fov_deg=1.0)
    return SurveyJob(**{**dict(scene_path=scene_file, trajectory=tr, pattern=pat, sensor=BASE, photons=300,
                               count=30, batch_size=7, seed=5, max_order=2), **kw})


def same(a: PulseWaveforms, b: PulseWaveforms) -> bool:
    return all(np.array_equal(np.asarray(getattr(a, k)).view(np.uint8), np.asarray(getattr(b, k)).view(np.uint8))
               for k in PulseWaveforms.ARRAYS)


def test_direct_loop_output_does_not_depend_on_batching(scene_file, tmp_path, sim):
    job = make_job(scene_file)
    assert job.ranges() == [(0, 7), (7, 14), (14, 21), (21, 28), (28, 30)]
    run = run_survey(job, tmp_path / "a", direct=True, progress=False, simulator=sim)
    assert (run.n_batches, run.computed, run.skipped, run.pulses, run.finished) == (5, 5, 0, 30, True)
    a = load_survey(tmp_path / "a")
    run_survey(make_job(scene_file, batch_size=30), tmp_path / "b", direct=True, progress=False, simulator=sim)
    b = load_survey(tmp_path / "b")
    whole = sim.run_pulses(*_load(scene_file), job.pulses(), BASE, photons=300, max_order=2)
    assert same(a, b) and same(a, whole)
    assert a.index.tolist() == list(range(30)) and np.all(a.energy > 0)


def _load(path):
    from voxlidar.scene import Scene

    return (Scene.load(path),)


def test_stopped_run_resumes_to_the_same_output(scene_file, tmp_path, sim):
    job = make_job(scene_file)
    run_survey(job, tmp_path / "full", direct=True, progress=False, simulator=sim)
    first = run_survey(job, tmp_path / "cut", direct=True, progress=False, simulator=sim, stop_after=2)
    assert (first.computed, first.finished) == (2, False)
    assert completed_batches(tmp_path / "cut") == {(0, 7), (7, 14)}
    with pytest.raises(InputError, match="3 of 5 batches missing"):
        load_survey(tmp_path / "cut")
    before = batch_path(tmp_path / "cut", 0, 7).stat().st_mtime_ns
    rest = run_survey(job, tmp_path / "cut", direct=True, progress=False, simulator=sim)
    assert (rest.skipped, rest.computed, rest.finished) == (2, 3, True)
    assert batch_path(tmp_path / "cut", 0, 7).stat().st_mtime_ns == before   # kept, not recomputed
    assert same(load_survey(tmp_path / "cut"), load_survey(tmp_path / "full"))


def test_folder_of_another_survey_is_refused(scene_file, tmp_path, sim):
    run_survey(make_job(scene_file, count=7), tmp_path / "o", direct=True, progress=False, simulator=sim)
    with pytest.raises(InputError, match=r"holds another survey \(differs in photons, seed\)"):
        run_survey(make_job(scene_file, count=7, seed=6, photons=10), tmp_path / "o", direct=True, progress=False)


def test_bad_jobs(scene_file, tmp_path):
    with pytest.raises(InputError, match="does not exist"):
        make_job(str(tmp_path / "nothing.npz"))
    with pytest.raises(InputError, match="do not fit the trajectory"):
        make_job(scene_file, count=10**6)
    with pytest.raises(InputError, match="batch_size must be an integer >= 1"):
        make_job(scene_file, batch_size=0)
    (tmp_path / "file").write_text("x")
    with pytest.raises(InputError, match="is a file"):
        run_survey(make_job(scene_file), tmp_path / "file", direct=True)


def test_projected_rate():
    assert projected_rate(4, 100.0, 0.01, 10) == 400.0          # workers limit
    assert projected_rate(100, 100.0, 0.01, 10) == 1000.0       # the scheduler limits: 10 pulses / 0.01 s


def _dask_job(scene_file):
    pytest.importorskip("dask.distributed")
    return make_job(scene_file, device=os.environ.get("VOXLIDAR_DEVICE"))


def test_two_dask_workers_match_the_direct_loop(scene_file, tmp_path):
    """Bit-identical over a local cluster of 2 worker processes, which also resumes a run
    that the direct loop stopped."""
    job = _dask_job(scene_file)
    run_survey(job, tmp_path / "direct", direct=True, progress=False, las=tmp_path / "direct" / "s.las")
    run_survey(job, tmp_path / "two", direct=True, progress=False, stop_after=1)
    two = run_survey(job, tmp_path / "two", workers=2, in_flight=1, progress=False, las=tmp_path / "two" / "s.las")
    assert (two.workers, two.skipped, two.computed, two.finished) == (2, 1, 4, True)
    assert same(load_survey(tmp_path / "two"), load_survey(tmp_path / "direct"))
    # the LAS streamed by the driver as the workers' batches came in, in whatever order: the same bytes
    assert (tmp_path / "two" / "s.las").read_bytes() == (tmp_path / "direct" / "s.las").read_bytes()


@pytest.mark.slow
def test_one_dask_worker_matches_the_direct_loop(scene_file, tmp_path):
    job = _dask_job(scene_file)
    run_survey(job, tmp_path / "direct", direct=True, progress=False)
    one = run_survey(job, tmp_path / "one", workers=1, progress=False)
    assert (one.workers, one.computed, one.finished) == (1, 5, True)
    assert same(load_survey(tmp_path / "one"), load_survey(tmp_path / "direct"))


@pytest.mark.slow
def test_killed_process_resumes_to_the_same_output(scene_file, tmp_path):
    """``clsim survey`` killed (SIGKILL) after its first batches; the same command again finishes it,
    its LAS (streamed batch by batch) the same bytes as an uninterrupted run's."""
    args = [sys.executable, "-m", "clsim.cli", "survey", scene_file, "--sensor", "riegl-lms-q680i",
            "--start=-2,0", "--end", "2,0", "--altitude", "250", "--speed", "10", "--pulse-rate", "400",
            "--scan-rate", "37", "--fov", "1", "--pulses", "100", "--photons", "10000", "--batch-size", "4", "--seed", "5",
            "--workers", "0", "-q"]
    env = dict(os.environ, PYTHONPATH=os.pathsep.join([str(ROOT), os.environ.get("PYTHONPATH", "")]))
    proc = subprocess.Popen(args + ["-o", str(tmp_path / "killed")], env=env, cwd=tmp_path)
    deadline = time.monotonic() + 120
    try:
        while len(completed_batches(tmp_path / "killed")) < 2 and proc.poll() is None:
            assert time.monotonic() < deadline, "no batch written in 120 s"
            time.sleep(0.01)
    finally:
        proc.send_signal(signal.SIGKILL)
        proc.wait()
    n_before = len(completed_batches(tmp_path / "killed"))
    assert 2 <= n_before < 25, n_before                           # stopped midway
    subprocess.run(args + ["-o", str(tmp_path / "killed")], env=env, cwd=tmp_path, check=True)
    subprocess.run(args + ["-o", str(tmp_path / "whole")], env=env, cwd=tmp_path, check=True)
    assert not list((tmp_path / "killed" / "batches").glob(".*"))  # no temporary file left
    assert same(load_survey(tmp_path / "killed"), load_survey(tmp_path / "whole"))
    assert not [p for p in (tmp_path / "killed").iterdir() if p.name.startswith(".")]  # no partial LAS left
    for name in ("survey.las", "survey.wdp"):
        assert (tmp_path / "killed" / name).read_bytes() == (tmp_path / "whole" / name).read_bytes()


def test_a_plot_of_many_trees_flies_from_its_file(tmp_path, sim):
    """A PlotScene file is a survey scene: the loop over it equals run_pulses over the plot in memory."""
    from clsim.scenes import PlotScene, make_plot

    plot = make_plot(20.0, 4, seed=3, voxel_size=0.5, n_models=2, min_spacing_m=6.0)
    path = plot.save(tmp_path / "plot.npz")
    cx, cy = plot.origin_xy + 0.5 * np.array([plot.width_m, plot.length_m])
    tr = Trajectory.line((cx - 3.0, cy), (cx + 3.0, cy), altitude_m=250.0, speed_mps=40.0)
    pat = ScanPattern(kind="mirror", pulse_rate_hz=300.0, scan_rate_hz=20.0, fov_deg=2.0)
    job = SurveyJob(scene_path=str(path), trajectory=tr, pattern=pat, sensor=BASE, photons=200, count=12,
                    batch_size=5, seed=2, max_order=2)
    assert job.ground_z == pytest.approx(plot.ground_z)
    run_survey(job, tmp_path / "out", direct=True, progress=False, simulator=sim)
    got = load_survey(tmp_path / "out")
    whole = sim.run_pulses(PlotScene.load(path), job.pulses(), BASE, photons=200, max_order=2)
    assert same(got, whole) and np.all(got.energy > 0)


def test_survey_plot_example_runs_end_to_end(tmp_path, capsys):
    """examples/survey_plot.py in a plain loop: the plot, the batches, the LAS and its four pictures;
    run again, every batch is already on disk (resume)."""
    import runpy

    example = runpy.run_path(str(ROOT / "examples" / "survey_plot.py"))
    args = [str(tmp_path), "--pulses", "600", "--photons", "50", "--workers", "0"]
    assert example["main"](args) == 0
    assert "600 pulses, 1 batches computed" in capsys.readouterr().out
    names = sorted(p.name for p in tmp_path.iterdir())
    assert names == ["plot.npz", "survey", "survey.las", "survey.wdp", "survey_plot_canopy.png",
                     "survey_plot_footprints.png", "survey_plot_points.png", "survey_plot_radargram.png"]
    assert example["main"](args) == 0
    assert "0 batches computed, 1 already on disk" in capsys.readouterr().out


def test_deterministic_first_order_survey(scene_file, tmp_path, sim):
    """--first-order deterministic: the same waveforms whatever the batching (each pulse keeps its
    own window), resumed to the same bits, and recorded in survey.json (a Monte Carlo survey's
    survey.json is unchanged, so old folders still resume)."""
    job = make_job(scene_file, first_order="deterministic", max_order=1, photons=1)
    run_survey(job, tmp_path / "a", direct=True, progress=False, simulator=sim)
    run_survey(make_job(scene_file, first_order="deterministic", max_order=1, photons=1, batch_size=30),
               tmp_path / "b", direct=True, progress=False, simulator=sim)
    a, b = load_survey(tmp_path / "a"), load_survey(tmp_path / "b")
    assert same(a, b) and np.all(a.energy > 0)
    import json

    saved = json.loads((tmp_path / "a" / "survey.json").read_text())
    assert saved["first_order"] == "deterministic" and saved["beam_samples"] == 19
    assert "first_order" not in make_job(scene_file).to_dict()
    with pytest.raises(InputError, match="first_order"):
        make_job(scene_file, first_order="photons")
    with pytest.raises(InputError, match="beam_samples"):
        make_job(scene_file, first_order="deterministic", beam_samples=0)
