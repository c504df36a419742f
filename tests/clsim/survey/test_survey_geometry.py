"""Survey geometry against known answers: swath widths, line spacings, the
Palmer ellipse, pulse counts, targets on the ground, seeds that batching
cannot change, and one-line errors."""

from __future__ import annotations

import math
import re
import time
from importlib import resources
from pathlib import Path

import numpy as np
import pytest

from clsim import InputError, Sensor, list_presets
from clsim.survey import Leg, ScanPattern, Trajectory, plot_footprints, survey_pulses, typical_flight
from voxlidar.errors import VoxlidarError

H = 500.0           # flying height, m
V = 50.0            # speed, m/s


def line(length=200.0, heading_deg=0.0, altitude=H, speed=V):
    h = math.radians(heading_deg)
    return Trajectory.line((0.0, 0.0), (length * math.cos(h), length * math.sin(h)),
                           altitude_m=altitude, speed_mps=speed)


def pattern(kind, **kw):
    base = dict(kind=kind, pulse_rate_hz=10_000.0, scan_rate_hz=20.0, fov_deg=60.0)
    return ScanPattern(**{**base, **kw})


# -- swath, lines, ellipse -----------------------------------------------------------
@pytest.mark.parametrize("kind", ["mirror", "polygon"])
def test_swath_width_is_2H_tan_half_fov(kind):
    p = survey_pulses(line(), pattern(kind), count=2000)
    width = p.target[:, 1].max() - p.target[:, 1].min()
    expect = 2 * H * math.tan(math.radians(30.0))
    # the mirror reaches both edges; the polygon's last pulse of a line is one angular step short
    step = 60.0 * 20.0 / 10_000.0
    short = 0.0 if kind == "mirror" else H * (math.tan(math.radians(30)) - math.tan(math.radians(30 - step)))
    assert width == pytest.approx(expect - short, abs=1e-9)
    # every footprint lies H tan(scan angle) from the nadir track, + to the right
    offset = -(p.target[:, 1] - p.position[:, 1])          # heading +x: right is -y
    np.testing.assert_allclose(offset, H * np.tan(np.radians(p.scan_angle_deg)), atol=1e-9)


def test_polygon_lines_are_parallel_and_speed_over_scan_rate_apart():
    pat = pattern("polygon")
    per_line = int(pat.pulse_rate_hz / pat.scan_rate_hz)   # 500 pulses a line
    p = survey_pulses(line(), pat, count=5 * per_line)
    xy = p.target[:, :2].reshape(5, per_line, 2)
    np.testing.assert_allclose(np.diff(xy[:, :, 0], axis=0), V / pat.scan_rate_hz, atol=1e-9)
    np.testing.assert_allclose(np.diff(xy[:, :, 1], axis=0), 0.0, atol=1e-9)
    assert np.all(np.diff(p.scan_angle_deg.reshape(5, per_line), axis=1) > 0)   # all left to right


def test_mirror_zigzag_turns_at_the_edges():
    pat = pattern("mirror")
    per_line = int(pat.pulse_rate_hz / pat.scan_rate_hz)
    p = survey_pulses(line(), pat, count=6 * per_line + 1)
    a = p.scan_angle_deg
    k = np.arange(7) * per_line                            # the turning pulses
    np.testing.assert_allclose(a[k], np.where(np.arange(7) % 2 == 0, -30.0, 30.0), atol=1e-9)
    d = np.sign(np.diff(a)).reshape(6, per_line)
    assert np.all(d[0::2] > 0) and np.all(d[1::2] < 0)     # even lines to the right, odd back
    # same-edge turning points are 2 v / scan rate apart along track, alternate edges v / rate
    np.testing.assert_allclose(np.diff(p.target[k[0::2], 0]), 2 * V / pat.scan_rate_hz, atol=1e-9)
    np.testing.assert_allclose(np.diff(p.target[k, 0]), V / pat.scan_rate_hz, atol=1e-9)


def test_palmer_circle_radius_and_constant_off_nadir():
    p = survey_pulses(line(heading_deg=37.0), pattern("palmer", fov_deg=30.0), count=3000)
    r = np.hypot(*(p.target[:, :2] - p.position[:, :2]).T)
    np.testing.assert_allclose(r, H * math.tan(math.radians(15.0)), rtol=1e-12)
    np.testing.assert_allclose(p.off_nadir_deg, 15.0, atol=1e-9)


def test_palmer_ellipse_axes_along_and_across_track():
    heading = 120.0
    p = survey_pulses(line(heading_deg=heading), pattern("palmer", fov_deg=40.0, along_fov_deg=28.0),
                      count=3000)
    h = math.radians(heading)
    rel = p.target[:, :2] - p.position[:, :2]
    along = rel @ [math.cos(h), math.sin(h)]
    across = rel @ [math.sin(h), -math.cos(h)]
    a, b = H * math.tan(math.radians(14.0)), H * math.tan(math.radians(20.0))
    np.testing.assert_allclose((along / a) ** 2 + (across / b) ** 2, 1.0, rtol=1e-12)
    assert along.max() == pytest.approx(a, rel=1e-4) and across.max() == pytest.approx(b, rel=1e-4)


# -- counts, directions, targets ------------------------------------------------------
def test_pulse_count_is_rate_times_duration():
    tr, pat = line(), pattern("polygon")
    assert len(survey_pulses(tr, pat, start_s=0.25, duration_s=1.5)) == 15_000
    assert len(survey_pulses(tr, pat)) == round(tr.duration_s * pat.pulse_rate_hz) == 40_000
    p = survey_pulses(tr, pat, start_s=0.25, duration_s=0.001)
    np.testing.assert_allclose(p.time_s, 0.25 + np.arange(10) / 10_000.0, rtol=0, atol=1e-12)


@pytest.mark.parametrize("kind", ["mirror", "polygon", "palmer"])
def test_directions_are_unit_and_targets_on_the_flat_ground(kind):
    p = survey_pulses(line(heading_deg=200.0), pattern(kind), count=4000, ground=12.5)
    np.testing.assert_allclose(np.linalg.norm(p.direction, axis=1), 1.0, atol=1e-14)
    assert np.all(p.target[:, 2] == 12.5)
    np.testing.assert_allclose(p.position + p.range_m[:, None] * p.direction, p.target, atol=1e-9)
    np.testing.assert_allclose(p.footprint_m, 2 * p.range_m * math.tan(Sensor().divergence_mrad * 1e-3))


def test_targets_on_a_dem():
    def dem(x, y):
        return 3.0 + 0.05 * x + 2.0 * np.sin(y / 15.0)

    p = survey_pulses(line(), pattern("mirror"), count=3000, ground=dem, z_range=(-3.0, 20.0))
    np.testing.assert_allclose(p.target[:, 2], dem(p.target[:, 0], p.target[:, 1]), atol=1e-6)
    np.testing.assert_allclose(p.position + p.range_m[:, None] * p.direction, p.target, atol=1e-9)
    with pytest.raises(InputError, match="z_range"):
        survey_pulses(line(), pattern("mirror"), count=10, ground=dem)


@pytest.mark.parametrize("kind", ["mirror", "polygon", "palmer"])
def test_pulse_sensor_places_the_simulator_where_the_platform_is(kind):
    p = survey_pulses(line(heading_deg=75.0), pattern(kind), count=500, ground=4.0)
    base = Sensor.preset("ahab-chiroptera-i")
    for i in (0, 123, 499):
        s = p.sensor(i, base)
        np.testing.assert_allclose(s.beam_axis(), p.direction[i], atol=1e-12)
        np.testing.assert_allclose(s.position(p.target[i]), p.position[i], atol=1e-8)
        assert s.range_m == pytest.approx(p.range_m[i], rel=1e-12)


def test_seeds_and_pulses_do_not_depend_on_batching():
    tr, pat = line(), pattern("palmer")
    full = survey_pulses(tr, pat, count=5000, seed=2**64 - 3)
    assert full.seed[0] == 2**64 - 3 and full.seed[3] == 0          # base seed + index, mod 2**64
    part = survey_pulses(tr, pat, first=1234, count=777, seed=2**64 - 3)
    by_time = survey_pulses(tr, pat, start_s=1234 / 10_000, duration_s=777 / 10_000, seed=2**64 - 3)
    batches = list(full.batches(999))
    for name in ("index", "seed", "time_s", "position", "direction", "target", "off_nadir_deg", "azimuth_deg"):
        assert np.array_equal(getattr(part, name), getattr(full, name)[1234:2011]), name
        assert np.array_equal(getattr(by_time, name), getattr(full, name)[1234:2011]), name
        assert np.array_equal(np.concatenate([getattr(b, name) for b in batches]), getattr(full, name)), name


def test_lawnmower_legs_follow_each_other():
    tr = Trajectory.lawnmower((0.0, 0.0), length_m=100.0, spacing_m=40.0, lines=3, heading_deg=90.0,
                              altitude_m=H, speed_mps=V)
    assert tr.duration_s == pytest.approx(6.0)
    pos, heading, leg = tr.at([0.0, 1.0, 2.5, 5.0])
    np.testing.assert_allclose(pos, [[0, 0, H], [0, 50, H], [40, 75, H], [80, 50, H]], atol=1e-12)
    np.testing.assert_allclose(heading, [90, 90, 270, 90])
    assert leg.tolist() == [0, 0, 1, 2]
    p = survey_pulses(tr, pattern("polygon"))
    assert len(p) == 60_000 and set(np.unique(p.leg)) == {0, 1, 2}


def test_hundred_thousand_pulses_well_under_a_second():
    tr = line(length=1000.0)
    pat = pattern("palmer", pulse_rate_hz=100_000.0)
    survey_pulses(tr, pat, count=1000)
    t0 = time.perf_counter()
    p = survey_pulses(tr, pat, count=100_000)
    assert len(p) == 100_000 and time.perf_counter() - t0 < 0.5


# -- presets ------------------------------------------------------------------
@pytest.mark.parametrize("name", list_presets())
def test_presets_have_survey_numbers_with_sources(name):
    pat, flight = ScanPattern.preset(name), typical_flight(name)
    assert pat.pulse_rate_hz > 0 and flight.altitude_m > 0 and flight.speed_mps > 0
    text = (resources.files("clsim") / "presets" / f"{name}.toml").read_text()
    for row in text.splitlines():
        if re.match(r"^\s*\w+\s*=", row):                   # every number and name says where it comes from
            assert "#" in row or row.split("=")[0].strip() in ("name", "description"), row


def test_riegl_preset_is_the_data_sheet():
    s, pat = Sensor.preset("riegl-lms-q680i"), ScanPattern.preset("riegl-lms-q680i")
    assert (pat.kind.value, pat.fov_deg, pat.scan_rate_hz) == ("polygon", 60.0, 200.0)
    assert s.divergence_mrad == 0.25 and s.wavelength_nm == 1550.0


# -- pictures -----------------------------------------------------------------
def test_plot_footprints_writes_a_picture(tmp_path):
    p = survey_pulses(line(), pattern("mirror"), count=3000)
    out = plot_footprints(p, tmp_path / "fp.png", title="mirror")
    assert out.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    with pytest.raises(VoxlidarError, match="picture format"):
        plot_footprints(p, tmp_path / "fp.txt")


# -- bad input ----------------------------------------------------------------
BAD = {
    "negative speed": (lambda: Leg((0, 0, 100), (10, 0, 100), -5.0), "speed_mps"),
    "zero speed": (lambda: Trajectory.line((0, 0), (1, 0), altitude_m=100.0, speed_mps=0.0), "speed_mps"),
    "below the ground": (lambda: Leg((0, 0, -1), (10, 0, 100), 5.0), "altitude"),
    "vertical leg": (lambda: Leg((0, 0, 100), (0, 0, 200), 5.0), "heading"),
    "no legs": (lambda: Trajectory([]), "Leg"),
    "zero pulse rate": (lambda: pattern("polygon", pulse_rate_hz=0.0), "pulse_rate_hz"),
    "negative scan rate": (lambda: pattern("mirror", scan_rate_hz=-1.0), "scan_rate_hz"),
    "fov over 180": (lambda: pattern("mirror", fov_deg=200.0), "fov_deg"),
    "fov of 180": (lambda: pattern("polygon", fov_deg=180.0), "fov_deg"),
    "palmer fov 0": (lambda: pattern("palmer", fov_deg=0.0), "fov_deg"),
    "along fov for a mirror": (lambda: pattern("mirror", along_fov_deg=20.0), "along_fov_deg"),
    "fov not a number": (lambda: pattern("mirror", fov_deg="wide"), "fov_deg"),
    "unknown kind": (lambda: pattern("galvo"), "mirror, polygon, palmer"),
    "too many pulses": (lambda: survey_pulses(line(), pattern("mirror"), count=10**6), "fewer pulses"),
    "negative count": (lambda: survey_pulses(line(), pattern("mirror"), count=-1), "count"),
    "both selections": (lambda: survey_pulses(line(), pattern("mirror"), first=0, start_s=0.0), "not both"),
    "ground above platform": (lambda: survey_pulses(line(), pattern("mirror"), count=5, ground=600.0), "above"),
    "negative seed": (lambda: survey_pulses(line(), pattern("mirror"), count=5, seed=-1), "seed"),
    "no survey table": (lambda: ScanPattern.preset("nope"), "unknown"),
    "bad z_range": (lambda: survey_pulses(line(), pattern("mirror"), count=5, ground=np.hypot, z_range=(5, 1)),
                    "z_range"),
    "DEM over the platform": (lambda: survey_pulses(line(), pattern("mirror"), count=5, ground=np.hypot,
                                                    z_range=(0, 900)), "above the DEM"),
    "DEM outside z_range": (lambda: survey_pulses(line(), pattern("mirror"), count=5,
                                                  ground=lambda x, y: x * 0 - 50.0, z_range=(0, 10)), "widen"),
    "ground not a number": (lambda: survey_pulses(line(), pattern("mirror"), count=5, ground="flat"), "ground"),
    "sensor not a Sensor": (lambda: survey_pulses(line(), pattern("mirror"), "ahab", count=5), "Sensor"),
}


@pytest.mark.parametrize("case", BAD)
def test_bad_input_is_one_line_input_error(case):
    make, words = BAD[case]
    with pytest.raises(InputError) as err:
        make()
    assert words in str(err.value) and "\n" not in str(err.value)


def test_preset_file_without_survey_table(tmp_path):
    f = tmp_path / "mine.toml"
    f.write_text('name = "mine"\n')
    with pytest.raises(InputError, match=r"no \[survey\] table"):
        ScanPattern.preset(f)
    assert Sensor.preset(f).name == "mine"


def test_example_prints_the_closed_forms(tmp_path, capsys):
    import runpy

    example = runpy.run_path(str(Path(__file__).parents[3] / "examples" / "survey_footprints.py"))
    example["main"](tmp_path)
    out = capsys.readouterr().out
    assert "2 H tan(fov/2) = 692.82 m" in out and "ellipse semi-axes 99.73, 145.59 m" in out
    assert sorted(p.name for p in tmp_path.iterdir()) == [f"survey_footprints_{k}.png"
                                                          for k in ("mirror", "palmer", "polygon")]


def test_survey_pulses_run_through_the_simulator_oracle():
    """The NumPy oracle places the sensor at the platform and returns the
    Lambertian ground's A/R^2 rho cos(theta)/pi for each pulse of a Palmer scan."""
    from clsim import ReferenceSimulator
    from clsim.validation import testscenes

    scene = testscenes.ground_only(width=40.0, voxel_size=2.0)
    p = survey_pulses(line(), pattern("palmer", fov_deg=30.0), first=7, count=2, seed=11)
    base = Sensor.preset("ahab-chiroptera-i", fov_mrad=3.0)
    rho, _ = scene.optics("ground", base.wavelength_nm)
    for i in range(len(p)):
        res = ReferenceSimulator().run(scene, p.sensor(i, base), photons=1000, seed=int(p.seed[i]),
                                       target=p.target[i], max_order=1)
        np.testing.assert_allclose(res.settings["sensor_position"], p.position[i], atol=1e-8)
        e, se = res.energy(kind="ground")
        expect = base.aperture_area_m2 / p.range_m[i] ** 2 * rho / np.pi * math.cos(math.radians(15.0))
        assert abs(e - expect) < 5 * se + 1e-5 * expect
