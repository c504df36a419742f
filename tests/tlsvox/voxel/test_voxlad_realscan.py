"""The real RIEGL VZ-400i scan (../shared/data) voxelised at 20 cm end to end.

The file holds points only: the pulses that left no echo are rebuilt from the
scan's angular grid (data README: 0.048 deg x 0.622 deg, 2082 x 580 lines,
zenith 30-130.024 deg, roll/pitch/yaw 1.026, 0.746, -110.019 deg).
"""

from __future__ import annotations

import numpy as np
import pytest

from tlsvox.scan import AngularGrid, Scan
from tlsvox.voxel.pulses import group_pulses, reconstruct_empty_pulses, rotation_from_rpy
from tlsvox.voxel.stages import voxelize

GRID = AngularGrid(30.0, 0.048, 2082, 0.0, 0.622, 580)
RPY = (1.026, 0.746, -110.019)

pytestmark = pytest.mark.realdata


@pytest.fixture(scope="module")
def real_scan(shared_data):
    path = shared_data / "tls-vz400i-scan" / "tls_scan.laz"
    if not path.exists():
        pytest.skip(f"{path} is absent")
    return Scan.read(path)


def test_socs_rotation_matches_the_grid(real_scan):
    """With the documented roll/pitch/yaw the smallest zenith is the grid's 30 deg."""
    first = real_scan.return_number == 1
    d = real_scan.xyz[first] / np.linalg.norm(real_scan.xyz[first], axis=1)[:, None]
    zen = np.degrees(np.arccos(np.clip(d @ rotation_from_rpy(*RPY)[:, 2], -1, 1)))
    assert zen.min() == pytest.approx(30.0, abs=0.01)
    zen_file = np.degrees(np.arccos(d[:, 2]))
    assert zen_file.min() < 29.5  # the tilt is real: without it the limit is off by > 0.5 deg


def test_empty_pulses_rebuilt_on_the_grid(real_scan):
    groups = group_pulses(real_scan)
    first = int(np.count_nonzero(real_scan.return_number == 1))
    assert first <= len(groups.direction) <= first * 1.01  # few orphan later echoes
    rec = reconstruct_empty_pulses(groups.direction, GRID, socs_rotation=rotation_from_rpy(*RPY))
    assert rec.line_fit > 0.98
    assert rec.n_lines == pytest.approx(GRID.n_azimuth, abs=3)
    # every pulse of the grid accounted for, within 3% (two wrap-around lines, jitter)
    assert rec.pulses_total == pytest.approx(GRID.n_pulses, rel=0.03)
    assert abs(rec.azimuth_step_deg - GRID.azimuth_step_deg) < 0.005


def test_real_scan_voxelised_at_20cm(real_scan):
    res = voxelize([real_scan], voxel_size=0.2, scanner_frame=True, angular_grid=GRID,
                   socs_rotation=rotation_from_rpy(*RPY), ground="ransac", leaf_angle="spherical",
                   progress=False)
    s = res.scene
    assert np.all(np.isfinite(s.lad)) and np.all(s.lad >= 0)
    assert res.stats.n_beams == pytest.approx(GRID.n_pulses, rel=0.03)
    # the scanner stands about 1.2-1.8 m above a near-level ground
    assert -2.0 < res.ground.z_center < -1.0 and res.ground.tilt_deg < 10
    # nothing was seen above the highest echo: no plant area up there
    top = real_scan.xyz[:, 2].max()
    z_top = res.grid.lower[2] + (s.ijk[:, 2] + 1) * s.voxel_size
    assert np.all(s.lad[z_top > top + 0.4] == 0)
    # a voxel 1.5 m beside the scanner head is crossed by thousands of beams; the one
    # straight above it by none (the scan starts at 30 deg zenith)
    side = res.grid.index_of([[1.5, 0.0, 0.0]])[0]
    above = res.grid.index_of([[0.0, 0.0, 1.5]])[0]
    assert res.stats.field("count")[tuple(side)] > 1000
    assert res.stats.field("count")[tuple(above)] == 0 and res.lad.occluded[tuple(above)]
    # a plausible forest: total plant area index over the scanned disc between 0.5 and 15
    lad = res.lad.lad
    area = lad.sum() * res.grid.voxel_volume
    ground_area = np.pi * 8.0**2
    assert 0.5 < area / ground_area < 15
    assert res.lad.occluded.mean() < 0.9
    assert s.meta["scans"][0]["line_fit"] > 0.99  # the right grid fits its lines: no warning
    assert not any("scan lines" in w for w in s.meta["warnings"])


def test_a_wrong_angular_grid_is_flagged(real_scan):
    """An azimuth step 10x too small rebuilds the empty pulses on lines that do not exist:
    the line fit drops and the quality gate says so (it used to pass silently)."""
    from tlsvox.voxel.stages import quality_warnings

    groups = group_pulses(real_scan)
    wrong = AngularGrid(30.0, 0.048, 2082, 0.0, 0.0622, 5800)
    rec = reconstruct_empty_pulses(groups.direction, wrong, socs_rotation=rotation_from_rpy(*RPY))
    good = reconstruct_empty_pulses(groups.direction, GRID, socs_rotation=rotation_from_rpy(*RPY))
    assert rec.line_fit < 0.9 < good.line_fit
    warned = quality_warnings(np.ones(3), np.zeros(3, bool), [{"scan": "tls", "line_fit": rec.line_fit}])
    assert len(warned) == 1 and "scan lines" in warned[0] and "--angular-grid" in warned[0]
    assert quality_warnings(np.ones(3), np.zeros(3, bool), [{"scan": "tls", "line_fit": good.line_fit}]) == []


def test_the_documented_command_without_its_angular_grid(shared_data, tmp_path, capsys):
    """docs/voxelize.md's one command: the scan as a cloud without pulses from 0,0,0, with its profile
    picture.  The step read from the cloud is the documented one within 1 %; the empty pulses counted
    per angular cell and the plant area agree with the angular grid's reconstruction within 10 %
    (measured: +9.2 % and -2.8 %, docs/bench/merged.md), and the run names how it got them."""
    import json

    from tlsvox.cli.app import main
    from voxlidar import Scene

    path = shared_data / "tls-vz400i-scan" / "tls_scan.laz"
    if not path.exists():
        pytest.skip(f"{path} is absent")
    picture = tmp_path / "plot_profile.png"
    assert main(["voxelize", str(path), "--scan-positions", "0,0,0", "--voxel-size", "0.2", "--leaf-angle",
                 "spherical", "-o", str(tmp_path / "plot.npz"), "--profile", str(picture),
                 "--profile-radius", "8"]) == 0
    summary = json.loads(capsys.readouterr().out)
    assert picture.stat().st_size > 10_000
    merged = Scene.load(tmp_path / "plot.npz").meta["merged"][0]
    zstep, astep = (float(v) for v in merged["expected_from"].split("step ")[1].split(" deg")[0].split(" x "))
    assert zstep == pytest.approx(0.048, rel=0.01) and astep == pytest.approx(0.622, rel=0.01)
    reference = voxelize([Scan.read(path)], voxel_size=0.2, scanner_frame=True, angular_grid=GRID,
                         socs_rotation=rotation_from_rpy(*RPY), leaf_angle="spherical", progress=False)
    assert merged["empty_pulses"] == pytest.approx(reference.scene.meta["scans"][0]["empty"], rel=0.10)
    assert summary["leaf_area_m2"] == pytest.approx(reference.scene.total_leaf_area(), rel=0.10)
