"""A clsim survey job as HELIOS++ files (clsim.survey.helios): the same pulses, and HELIOS++'s own schemas.

HELIOS++'s XML schemas are GPL files of its repository, not copied here: the schema test reads them from a
checkout (``$VOXLIDAR_HELIOS_SRC``, a work tree or a git directory; default the mirror beside the project,
``../.mirror/3dgeo-heidelberg+helios/repo``) and skips with the reason when there is none.
"""

from __future__ import annotations

import json
import os
import subprocess
import xml.etree.ElementTree as ET
from pathlib import Path

import numpy as np
import pytest

from clsim.sensor import Sensor
from clsim.survey import ScanPattern, Trajectory
from clsim.survey.distributed import SurveyJob
from clsim.survey.helios import OPTICS, write_helios_survey
from clsim.validation import testscenes
from tlsvox.voxel.amapvox import read_vox

ROOT = Path(__file__).resolve().parents[3]
SCHEMAS = "python/pyhelios/util/xsd"


@pytest.fixture(scope="module")
def scene_file(tmp_path_factory):
    s = testscenes.homogeneous_layer(width=6.0, thickness=1.5, lad=1.0, voxel_size=0.5, base_height=3.0)
    return str(s.save(tmp_path_factory.mktemp("scene") / "layer.npz"))


def make_job(scene_file, kind="polygon", **kw):
    tr = Trajectory.line((-20.0, 0.0), (20.0, 0.0), altitude_m=300.0, speed_mps=50.0)
    pat = ScanPattern(kind=kind, pulse_rate_hz=10_000.0, scan_rate_hz=50.0, fov_deg=20.0)
    return SurveyJob(**{**dict(scene_path=scene_file, trajectory=tr, pattern=pat, sensor=Sensor.preset("riegl-lms-q680i"),
                               photons=10, first=1_000, count=4_000, seed=3), **kw})


def waypoints(survey: Path):
    legs = ET.parse(survey).getroot().find("survey").findall("leg")
    out = []
    for leg in legs:
        ps, ss = leg.find("platformSettings"), leg.find("scannerSettings")
        out.append((np.array([float(ps.get(k)) for k in "xyz"]), float(ps.get("movePerSec_m")), ss.get("active")))
    return out


def test_the_helios_survey_flies_the_jobs_pulses(scene_file, tmp_path):
    job = make_job(scene_file)
    files = write_helios_survey(job, tmp_path / "helios")
    (start, speed, on), (end, _, off) = waypoints(files.survey)
    rate = job.pattern.pulse_rate_hz
    # HELIOS++ fires from the first waypoint at the pulse rate until the platform reaches the second
    at = job.trajectory.at([job.first / rate, (job.first + job.count) / rate])[0]
    assert np.allclose(start, at[0], atol=1e-6) and np.allclose(end, at[1], atol=1e-6)
    assert on == "true" and off == "false"
    fired = np.linalg.norm(end - start) / speed * rate
    assert fired == pytest.approx(job.count, abs=1e-6)
    settings = ET.parse(files.survey).getroot().find("scannerSettings")
    assert float(settings.get("pulseFreq_hz")) == rate and float(settings.get("scanAngle_deg")) == 10.0
    scanner = ET.parse(files.scanner).getroot().find("scanner")
    assert scanner.get("optics") == "rotating"
    assert float(scanner.get("beamDivergence_rad")) == pytest.approx(0.5e-3 * job.sensor.divergence_mrad)  # a half-angle
    info = json.loads(files.job.read_text())
    assert (info["first"], info["count"]) == (job.first, job.count) and (files.first, files.count) == (1_000, 4_000)
    # the voxels as HELIOS++ reads them: AMAPVox's columns first, the scene's LAD in PadBVTotal
    header = files.vox.read_text().splitlines()[5].split()
    assert header[:7] == ["i", "j", "k", "PadBVTotal", "angleMean", "bsEntering", "bsIntercepted"]
    assert header[15] == "attenuationBiasCorrection"
    back = read_vox(files.vox)
    from voxlidar.scene import Scene

    orig = Scene.load(scene_file)
    assert np.allclose(back.dense("lad"), orig.dense("lad"))
    # the ground lies under the whole swath at the job's ground height
    v = np.array([[float(x) for x in ln.split()[1:]] for ln in files.ground.read_text().splitlines()
                  if ln.startswith("v ")])
    assert np.allclose(v[:, 2], job.ground_z)
    half_swath = 300.0 * np.tan(np.radians(10.0))
    assert v[:, 1].min() < -half_swath and v[:, 1].max() > half_swath


@pytest.mark.parametrize("kind", sorted(OPTICS))
def test_each_scan_pattern_has_its_deflector(scene_file, tmp_path, kind):
    files = write_helios_survey(make_job(scene_file, kind=kind), tmp_path / kind)
    assert ET.parse(files.scanner).getroot().find("scanner").get("optics") == OPTICS[kind]


def test_a_job_across_two_legs_gets_a_waypoint_pair_per_leg(scene_file, tmp_path):
    tr = Trajectory.lawnmower((-20.0, -5.0), length_m=40.0, spacing_m=10.0, lines=2, altitude_m=300.0, speed_mps=50.0)
    job = make_job(scene_file, trajectory=tr, first=0, count=None)
    files = write_helios_survey(job, tmp_path / "two")
    pts = waypoints(files.survey)
    assert [p[2] for p in pts] == ["true", "false", "true", "false"]
    rate = job.pattern.pulse_rate_hz
    fired = sum(np.linalg.norm(b[0] - a[0]) / a[1] * rate for a, b in (pts[:2], pts[2:]))
    assert fired == pytest.approx(job.count, abs=2)


def test_a_plot_of_trees_goes_as_one_voxel_grid(tmp_path):
    from clsim.scenes import PlotScene

    tree = testscenes.homogeneous_layer(width=2.0, thickness=1.0, lad=1.0, voxel_size=0.5, base_height=1.0)
    plot = PlotScene(12.0, voxel_size=0.5, origin_xy=(-6.0, -6.0))
    plot.add_tree(tree, -3.0, 0.0)
    plot.add_tree(tree, 3.0, 0.0)
    path = plot.save(tmp_path / "plot.npz")
    files = write_helios_survey(make_job(str(path)), tmp_path / "h")
    assert read_vox(files.vox).total_leaf_area() == pytest.approx(plot.total_leaf_area(), rel=1e-6)


def helios_schemas(dest: Path) -> Path | None:
    """HELIOS++'s four XSDs copied into ``dest`` from a checkout (None when none is at hand)."""
    src = Path(os.environ.get("VOXLIDAR_HELIOS_SRC", ROOT.parent / ".mirror" / "3dgeo-heidelberg+helios" / "repo"))
    names = ("survey", "scene", "scanner", "platform")
    if (src / SCHEMAS).is_dir():
        for n in names:
            (dest / f"{n}.xsd").write_bytes((src / SCHEMAS / f"{n}.xsd").read_bytes())
        return dest
    if (src / "HEAD").is_file():  # a bare or mirrored git directory
        for n in names:
            r = subprocess.run(["git", f"--git-dir={src}", "show", f"HEAD:{SCHEMAS}/{n}.xsd"], capture_output=True)
            if r.returncode:
                return None
            (dest / f"{n}.xsd").write_bytes(r.stdout)
        return dest
    return None


def test_the_files_parse_against_helios_schemas(scene_file, tmp_path):
    xmlschema = pytest.importorskip("xmlschema")
    schemas = helios_schemas(tmp_path)
    if schemas is None:
        pytest.skip("no HELIOS++ checkout with its schemas (set VOXLIDAR_HELIOS_SRC to a work tree or git dir)")
    for kind in sorted(OPTICS):
        files = write_helios_survey(make_job(scene_file, kind=kind), tmp_path / kind)
        for name, path in (("survey", files.survey), ("scene", files.scene), ("scanner", files.scanner),
                           ("platform", files.platform)):
            xmlschema.XMLSchema(str(schemas / f"{name}.xsd")).validate(str(path))


def test_clsim_survey_writes_both_runs(scene_file, tmp_path, capsys):
    from clsim.cli import main

    rc = main(["survey", scene_file, "-o", str(tmp_path / "run"), "--pulses", "40", "--workers", "0", "--photons",
               "50", "-q", "--helios", str(tmp_path / "helios")])
    assert rc == 0, capsys.readouterr().err
    assert (tmp_path / "run" / "survey.las").is_file() and (tmp_path / "helios" / "survey.xml").is_file()
    info = json.loads((tmp_path / "helios" / "helios_job.json").read_text())
    assert info["count"] == 40 and "pulse k is this run's pulse 0 + k" in capsys.readouterr().err
