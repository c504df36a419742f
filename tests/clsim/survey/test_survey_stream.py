"""A survey's LAS written batch by batch as the batches finish (clsim.survey._las_feed).

The streamed file must be the very bytes of the file written at once from the
same waveforms with the same settings, and a stopped run resumed must end with
the very bytes of an uninterrupted one.
"""

from __future__ import annotations

import numpy as np
import pytest

from clsim.errors import InputError
from clsim.survey import ScanPattern, Trajectory, load_survey, read_survey_las, run_survey
from clsim.survey._las_feed import echoes_path, las_layout
from clsim.survey._las_writer import SurveyLasWriter
from clsim.survey.las import write_survey_las
from tests.clsim.survey.test_survey_run import BASE, make_job, scene_file  # noqa: F401  (fixture)


@pytest.mark.parametrize("first_order", ["mc", "deterministic"])
def test_streamed_las_is_the_file_written_at_once(scene_file, tmp_path, sim, first_order):  # noqa: F811
    job = make_job(scene_file, first_order=first_order, bin_ns=0.25 if first_order == "deterministic" else 0.05)
    run = run_survey(job, tmp_path / "s", direct=True, progress=False, simulator=sim, las=tmp_path / "s" / "a.las")
    las, wdp = run.las
    assert run.finished and run.las_points > 0 and run.las_clipped == 0
    lay = las_layout(job)
    wf = load_survey(tmp_path / "s")
    assert wf.n_samples.max() <= lay.n_samples              # the layout's window holds every record
    full = np.zeros((len(wf), lay.n_samples))
    full[:, :wf.waveform.shape[1]] = wf.waveform
    las2, wdp2 = write_survey_las(tmp_path / "b.las", job.pulses(), full, t0_ns=wf.t0_ns, bin_ns=wf.bin_ns,
                                  sensor=BASE, gain=lay.gain, offset=0.0, offsets=lay.offsets)
    assert las.read_bytes() == las2.read_bytes() and wdp.read_bytes() == wdp2.read_bytes()
    back = read_survey_las(las)
    assert back.n_pulses == 30 and back.pulse_index.tolist() == list(range(30))
    # the gain leaves the strongest sample well under the top count, and keeps it to 1/2 count
    assert full.max() < 0.5 * lay.gain * 65535
    assert np.abs(back.waveforms - full).max() <= 0.5 * lay.gain * (1 + 1e-9)
    assert not [p for p in (tmp_path / "s").iterdir() if p.name.startswith(".")]


def test_stopped_run_resumes_to_the_same_las(scene_file, tmp_path, sim):  # noqa: F811
    job = make_job(scene_file)
    whole = run_survey(job, tmp_path / "whole", direct=True, progress=False, simulator=sim,
                       las=tmp_path / "whole" / "survey.las")
    out = tmp_path / "part"
    part = run_survey(job, out, direct=True, progress=False, simulator=sim, stop_after=2, las=out / "survey.las")
    assert part.las is None and not part.finished
    assert sorted(p.name for p in out.iterdir()) == ["batches", "survey.json"]    # no partial LAS left
    assert echoes_path(out, 0, 7).is_file() and echoes_path(out, 7, 14).is_file()
    done = run_survey(job, out, direct=True, progress=False, simulator=sim, las=out / "survey.las")
    assert (done.skipped, done.computed) == (2, 3)
    for name in ("survey.las", "survey.wdp"):
        assert (out / name).read_bytes() == (tmp_path / "whole" / name).read_bytes()
    # a third run computes nothing and rebuilds the same file from the kept echoes
    (out / "survey.las").unlink()
    again = run_survey(job, out, direct=True, progress=False, simulator=sim, las=out / "survey.las")
    assert again.computed == 0 and (out / "survey.las").read_bytes() == (tmp_path / "whole" / "survey.las").read_bytes()
    assert whole.las_points == done.las_points == again.las_points


def test_echoes_found_with_other_settings_are_not_reused(scene_file, tmp_path, sim):  # noqa: F811
    """A cached batch's echoes carry their settings: another pulse width finds them again."""
    job = make_job(scene_file, count=7)
    run_survey(job, tmp_path, direct=True, progress=False, simulator=sim, las=tmp_path / "a.las")
    from clsim.survey._las_writer import Echoes

    lay = las_layout(job)
    w = SurveyLasWriter(tmp_path / "x.las", BASE.replace(pulse_fwhm_ns=5.0), n_samples=lay.n_samples,
                        bin_ns=1.0 / BASE.sampling_ghz, gain=lay.gain, offsets=lay.offsets)
    try:
        assert Echoes.load(echoes_path(tmp_path, 0, 7), w.echo_key()) is None
    finally:
        w.abort()
    assert not (tmp_path / "x.las").exists()


def test_writer_refuses_a_wider_batch(tmp_path):
    from clsim.survey import survey_pulses

    tr = Trajectory.line((-2.0, 0.0), (2.0, 0.0), altitude_m=250.0, speed_mps=40.0)
    p = survey_pulses(tr, ScanPattern(pulse_rate_hz=400.0, scan_rate_hz=37.0, fov_deg=1.0), BASE, count=3)
    w = SurveyLasWriter(tmp_path / "x.las", BASE, n_samples=8, bin_ns=1.0, gain=1e-6, offsets=(0, 0, 0))
    with pytest.raises(InputError, match="<= 8"):
        w.append(p, np.zeros((3, 9)), 0.0)
    w.abort()
    assert list(tmp_path.iterdir()) == []
