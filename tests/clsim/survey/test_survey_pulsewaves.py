"""A survey's waveforms as PulseWaves (clsim survey --pulsewaves): read back with the reader checked on RIEGL's
own PulseWaves file, every sample's power within half a count, every segment where the simulator put it."""

from __future__ import annotations

import numpy as np
import pytest

from clsim.sensor import C_M_PER_NS
from clsim.survey import load_survey, run_survey, write_survey_pulsewaves
from clsim.waveforms.io.pulsewaves import read_pulsewaves, write_pulsewaves
from tests.clsim.survey.test_helios_files import make_job, scene_file  # noqa: F401 (fixture)
from voxlidar.errors import InputError


@pytest.fixture(scope="module")
def survey(scene_file, tmp_path_factory):  # noqa: F811
    out = tmp_path_factory.mktemp("pw")
    job = make_job(scene_file, first=0, count=60, photons=200, batch_size=30)
    run_survey(job, out, direct=True, progress=False)
    return job, load_survey(out), out


def test_survey_pulsewaves_round_trip(survey, tmp_path):
    job, wf, _ = survey
    pulses = job.pulses()
    pls, wvs, gain, offset = write_survey_pulsewaves(tmp_path / "s.pls", pulses, wf)
    back = read_pulsewaves(pls)
    assert len(back) == len(wf) and wvs.is_file()
    assert np.allclose(back.gps_time, pulses.time_s, atol=1e-8)
    assert np.allclose(back.anchor, pulses.position, atol=2e-4)
    for i in range(len(wf)):
        (seg,) = back.waves(i)
        n = int(wf.n_samples[i])
        assert len(seg.samples) == n
        assert np.all(np.abs(offset + gain * seg.samples - wf.waveform[i, :n]) <= 0.5 * gain * (1 + 1e-9))
        start, per_ns = back.segment_origin(seg)
        expect = pulses.position[i] + 0.5 * C_M_PER_NS * wf.t0_ns[i] * pulses.direction[i]
        assert np.allclose(start, expect, atol=2e-3), i
        assert np.allclose(per_ns, 0.5 * C_M_PER_NS * pulses.direction[i], rtol=1e-4)


def test_pulsewaves_limits_are_refused_in_one_line(tmp_path):
    kw = dict(gps_time=[0.0], origin=[[0.0, 0.0, 5000.0]], direction=[[0.0, 0.0, -1.0]], sample_units_ns=1.0)
    with pytest.raises(InputError, match="32,767"):  # a first sample 40,000 units away: past the 16-bit field
        write_pulsewaves(tmp_path / "far.pls", t0_ns=[40_000.0], samples=np.zeros((1, 10), int), **kw)
    with pytest.raises(InputError, match="digitiser counts"):
        write_pulsewaves(tmp_path / "neg.pls", t0_ns=[100.0], samples=-np.ones((1, 10), int), **kw)
    assert not any(tmp_path.iterdir())  # nothing written


def test_clsim_survey_writes_pulsewaves(scene_file, tmp_path, capsys):  # noqa: F811
    from clsim.cli import main

    rc = main(["survey", scene_file, "-o", str(tmp_path / "run"), "--pulses", "30", "--workers", "0", "--photons",
               "50", "--pulsewaves"])
    assert rc == 0, capsys.readouterr().err
    assert "PulseWaves" in capsys.readouterr().err
    assert len(read_pulsewaves(tmp_path / "run" / "survey.pls")) == 30
    rc = main(["decompose", str(tmp_path / "run" / "survey.pls"), "-o", str(tmp_path / "echoes.csv")])
    assert rc == 0 and (tmp_path / "echoes.csv").stat().st_size > 0
