"""clsim.survey.centre_line: one line over a box's middle, its swath spanning the box."""

from __future__ import annotations

import math

import numpy as np
import pytest

from clsim.errors import InputError
from clsim.survey import ScanPattern, centre_line, survey_pulses, typical_flight

PRESET = "riegl-lms-q680i"


def test_swath_spans_the_box_and_the_pulses_are_centred():
    lo, hi = (-7.0, -4.0, 0.0), (13.0, 6.0, 9.0)           # 20 m x 10 m, middle (3, 1)
    line = centre_line(lo, hi, PRESET, count=500)
    H, v = typical_flight(PRESET)
    assert line.flight == (H, v)
    # the swath at ground level, 2 H tan(fov / 2), is the box's depth (closed form)
    assert 2 * H * math.tan(math.radians(0.5 * line.fov_deg)) == pytest.approx(10.0, rel=1e-12)
    assert line.pattern.fov_deg == line.fov_deg
    preset = ScanPattern.preset(PRESET)
    assert line.pattern.pulse_rate_hz == preset.pulse_rate_hz and line.pattern.scan_rate_hz == preset.scan_rate_hz
    p = survey_pulses(line.trajectory, line.pattern, first=line.first, count=500)
    # the platform flies y = 1 at the preset's height; the 500 pulses straddle x = 3 within one pulse's travel
    assert np.allclose(p.position[:, 1:], [1.0, H])
    step = v / line.pattern.pulse_rate_hz
    assert 0.5 * (p.position[0, 0] + p.position[-1, 0]) == pytest.approx(3.0, abs=step)
    # every pulse's ground target lies within the box across track (the swath is the box's depth)
    assert np.all(np.abs(p.target[:, 1] - 1.0) <= 5.0 + 1e-9)


def test_fill_spreads_count_pulses_over_the_box():
    line = centre_line((0.0, 0.0), (50.0, 50.0), PRESET, count=2000, fill=True, line_spacing_m=2.0)
    H, v = line.flight
    assert line.pattern.pulse_rate_hz == pytest.approx(2000 * v / 50.0)
    assert line.pattern.scan_rate_hz == pytest.approx(v / 2.0)
    assert line.trajectory.legs[0].start[:2] == (0.0, 25.0) and line.trajectory.legs[0].end[:2] == (50.0, 25.0)
    assert line.first == 0
    assert len(survey_pulses(line.trajectory, line.pattern, count=2000)) == 2000


def test_a_long_count_lengthens_the_line():
    line = centre_line((0.0, 0.0), (4.0, 4.0), PRESET, count=100_000)
    H, v = line.flight
    assert line.trajectory.legs[0].length_m == pytest.approx(1.001 * 100_000 * v / line.pattern.pulse_rate_hz)
    assert line.first + 100_000 <= line.trajectory.duration_s * line.pattern.pulse_rate_hz


@pytest.mark.parametrize("kw, word", [(dict(lo=(0, 0), hi=(0, 5)), "hi > lo"),
                                      (dict(lo=(0, 0), hi=(5, float("nan"))), "hi > lo"),
                                      (dict(lo=(0,), hi=(5, 5)), "x and y"),
                                      (dict(count=0), "count"),
                                      (dict(line_spacing_m=0.0), "line_spacing_m")])
def test_bad_input_names_the_problem(kw, word):
    args = {**dict(lo=(0, 0), hi=(5, 5), count=10), **kw}
    with pytest.raises(InputError, match=word):
        centre_line(args.pop("lo"), args.pop("hi"), PRESET, **args)
