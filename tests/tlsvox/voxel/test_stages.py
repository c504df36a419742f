"""The voxel stage as separate stages, its grouped settings, and a run repeated from its output.

The turbid box of ``test_voxlad`` (LAD 0.8 m2/m3, spherical leaves) through each stage on its own,
then the whole run repeated from the settings its scene records (in Python, from a TOML file and
from the scene file itself on the command line): the same LAD to the last bit.
"""

from __future__ import annotations

import numpy as np
import pytest

from tests.tlsvox.voxel.test_voxlad import BOX_HI, BOX_LO, LAD, box_scans  # noqa: F401  (fixture)
from tlsvox.cli.voxelize import main as cli_main
from tlsvox.errors import InputError
from tlsvox.ground import GroundPlane
from tlsvox.scan import PulseTable, Scan
from tlsvox.voxel import stages
from tlsvox.voxel.settings import VoxelizeSettings
from tlsvox.voxel.trace import EchoKind, Tracer
from voxlidar.materials import Material
from voxlidar.scene import Scene

BOX = dict(voxel_size=0.5, leaf_angle="spherical", ground=None, bounds=(tuple(BOX_LO), tuple(BOX_HI)))


def test_settings_round_trip_and_refuse_unknown_names(tmp_path):
    s = VoxelizeSettings.from_kwargs(voxel_size=0.25, fill="layer", ground=1.5, leaf_shape=[0.06, 0.03],
                                     angular_grid=dict(zenith_start_deg=30.0, zenith_step_deg=0.05, n_zenith=10,
                                                       azimuth_start_deg=0.0, azimuth_step_deg=0.1, n_azimuth=20))
    assert (s.grid.voxel_size, s.model.fill, s.ground.ground, s.undetected.leaf_shape) == (0.25, "layer", 1.5,
                                                                                          (0.06, 0.03))
    assert VoxelizeSettings.from_dict(s.to_dict()) == s
    s.write(tmp_path / "run.toml")
    assert VoxelizeSettings.read(tmp_path / "run.toml") == s
    none = VoxelizeSettings.from_kwargs(ground=None, leaf_size=None)  # TOML has no null: written "none"
    none.write(tmp_path / "none.toml")
    assert VoxelizeSettings.read(tmp_path / "none.toml") == none and none.ground.ground is None
    with pytest.raises(InputError, match=r"unknown voxelize setting\(s\) \['voxel_sise'\]"):
        VoxelizeSettings.from_kwargs(voxel_sise=0.2)
    with pytest.raises(InputError, match=r"unknown field\(s\) \['estimater'\] in voxelize settings \[model\]"):
        VoxelizeSettings.from_dict({"model": {"estimater": "bcmle"}})
    (tmp_path / "bad.toml").write_text("[grid\nvoxel_size = 0.2\n")
    with pytest.raises(InputError, match="is not a TOML file"):
        VoxelizeSettings.read(tmp_path / "bad.toml")


def test_world_echoes_stage(box_scans):  # noqa: F811
    s = VoxelizeSettings.from_kwargs(**BOX)
    e = stages.world_echoes(box_scans, None, s)
    assert len(e.world) == 2 and all(np.all(k == EchoKind.LEAF) for k in e.kinds)  # truth material: leaves
    inside = np.all((e.world[0] > BOX_LO - 1e-9) & (e.world[0] < BOX_HI + 1e-9), axis=1)
    assert inside.all()  # the box's echoes, put in the world by each scan's pose
    posed = Scan(xyz=box_scans[0].xyz, pulse_id=box_scans[0].pulse_id, pulses=box_scans[0].pulses, name="loose")
    with pytest.raises(InputError, match="has no pose"):
        stages.world_echoes([posed], None, s)


def _ground_scan(rng, z0=0.3, n=4000):
    """Nadir-free pulses onto a flat ground at z0 and a few leaves above it, in the world frame."""
    xy = rng.uniform(-4, 4, (n, 2))
    ground = np.column_stack([xy, z0 + rng.normal(0, 0.01, n)])
    leaves = np.column_stack([rng.uniform(-1, 1, (300, 2)), rng.uniform(1.5, 3.0, 300)])
    origin = np.array([0.0, -8.0, 1.5])
    xyz = np.vstack([ground, leaves])
    d = xyz - origin
    d /= np.linalg.norm(d, axis=1)[:, None]
    pose = np.eye(4)
    pose[:3, 3] = origin
    mat = np.r_[np.full(n, Material.GROUND), np.full(300, Material.LEAF)]
    return Scan(xyz=xyz - origin, pulse_id=np.arange(len(xyz)), truth_material=mat, pose=pose,
                pulses=PulseTable(d, np.ones(len(xyz), int)), name="ground")


def test_ground_stage_fits_given_and_marks_ground_echoes():
    scan = _ground_scan(np.random.default_rng(3))
    s = VoxelizeSettings.from_kwargs(ground="ransac")
    e = stages.world_echoes([scan], [np.r_[np.full(4000, Material.LEAF), np.full(300, Material.LEAF)]],
                            VoxelizeSettings.from_kwargs(class_codes="material"))
    plane = stages.scene_ground(e, s)
    # fitted to the lowest echoes: within three of the ground's 1 cm noise below its mean height
    assert -0.03 < plane.z_center - 0.3 < 0.005 and plane.tilt_deg < 1.0
    # every ground echo, labelled leaf, now stops beams as ground; the leaves above stay leaves
    assert np.all(e.kinds[0][:4000] == EchoKind.OTHER) and np.all(e.kinds[0][4000:] == EchoKind.LEAF)
    given = stages.scene_ground(stages.world_echoes([scan], None, s), VoxelizeSettings.from_kwargs(ground=0.3))
    assert given.z_center == 0.3
    as_plane = GroundPlane.horizontal(0.25)
    via_settings = VoxelizeSettings.from_kwargs(ground=as_plane)  # recorded as a table, rebuilt by the stage
    assert stages.scene_ground(stages.world_echoes([scan], None, s), via_settings).z_center == 0.25
    assert stages.scene_ground(e, VoxelizeSettings.from_kwargs(ground=None)) is None


def test_grid_stage(box_scans):  # noqa: F811
    s = VoxelizeSettings.from_kwargs(**BOX)
    e = stages.world_echoes(box_scans, None, s)
    grid = stages.make_grid(e, None, s)
    assert np.allclose(grid.lower, BOX_LO) and tuple(grid.shape) == (4, 4, 4)
    free = stages.make_grid(e, None, VoxelizeSettings.from_kwargs(voxel_size=0.5))  # the echoes' box
    assert np.all(free.lower <= e.world[0].min(axis=0) + 1e-9) and np.all(free.upper >= e.world[0].max(axis=0))
    with pytest.raises(InputError, match="hold none of the"):
        stages.make_grid(e, None, VoxelizeSettings.from_kwargs(voxel_size=0.5, bounds=((5, 5, 5), (6, 6, 6))))


def test_beams_trace_estimate_stages_recover_the_box(box_scans):  # noqa: F811
    """Stages 5-7 by hand: the box's leaf area within 2 standard errors of the truth (as test_voxlad)."""
    s = VoxelizeSettings.from_kwargs(**BOX)
    e = stages.world_echoes(box_scans, None, s)
    checks = stages.check_settings(e.scans, s)
    grid = stages.make_grid(e, None, s)
    projection = stages.leaf_projection(e, grid, checks.leaf_angle, checks.azimuth)
    parts, infos = stages.make_beams(e, checks.leaf_angle, s)
    assert len(parts) == 2 and [i["echo_weights"] for i in infos] == ["uniform", "uniform"]
    beams = parts[0].concat(parts)
    run = stages.TraceRun.start(grid, beams, Tracer(), stages.Layout.AUTO, checks, projection, 2, s)
    stats, _ = run.sums(beams)
    lad = stages.estimate(stats, checks.estimator, checks.fill, s)
    area, se = lad.lad.sum() * grid.voxel_volume, np.sqrt(np.sum(lad.lad_std ** 2)) * grid.voxel_volume
    assert abs(area - LAD * np.prod(BOX_HI - BOX_LO)) < 2 * se
    scene, _ = stages.build_scene(grid, stats, lad, None, infos, checks, projection, run.plan,
                                  {"rule": "ignore"}, s)
    assert scene.meta["settings"] == s.to_dict()
    assert np.isclose(scene.total_leaf_area(), area)


def test_run_repeats_from_its_recorded_settings(box_scans):  # noqa: F811
    first = stages.voxelize(box_scans, progress=False, **BOX)
    again = stages.voxelize(box_scans, VoxelizeSettings.from_dict(first.scene.meta["settings"]), progress=False)
    assert np.array_equal(first.scene.lad, again.scene.lad) and np.array_equal(first.scene.ijk, again.scene.ijk)
    other = stages.voxelize(box_scans, VoxelizeSettings.from_dict(first.scene.meta["settings"]), voxel_size=1.0,
                            progress=False)  # a keyword replaces one field
    assert other.scene.voxel_size == 1.0 and other.scene.meta["settings"]["model"]["leaf_angle"] == "spherical"


def test_cli_config_and_write_config(box_scans, tmp_path, capsys):  # noqa: F811
    paths = []
    for sc in box_scans:
        paths.append(str(sc.write(tmp_path / f"{sc.name}.laz")))
    bounds = ",".join(f"{v:g}" for v in (*BOX_LO, *BOX_HI))
    assert cli_main([*paths, "-o", str(tmp_path / "a.npz"), "--voxel-size", "0.5", "--leaf-angle", "spherical",
                     "--ground", "none", "--bounds", bounds, "--write-config", str(tmp_path / "a.toml"), "-q"]) == 0
    a = Scene.load(tmp_path / "a.npz")
    text = (tmp_path / "a.toml").read_text()
    assert "[grid]\nvoxel_size = 0.5" in text and 'leaf_angle = "spherical"' in text
    for config in ("a.toml", "a.npz"):  # the TOML file, or the scene itself
        out = tmp_path / f"from-{config}.npz"
        assert cli_main([*paths, "-o", str(out), "--config", str(tmp_path / config), "-q"]) == 0
        b = Scene.load(out)
        assert np.array_equal(a.lad, b.lad) and b.meta["settings"] == a.meta["settings"]
    assert cli_main([*paths, "-o", str(tmp_path / "c.npz"), "--config", str(tmp_path / "a.toml"), "--voxel-size",
                     "1", "-q"]) == 0  # the command line wins
    assert Scene.load(tmp_path / "c.npz").voxel_size == 1.0
    (tmp_path / "bad.toml").write_text("[grids]\nvoxel_size = 0.5\n")
    capsys.readouterr()
    assert cli_main([*paths, "-o", str(tmp_path / "d.npz"), "--config", str(tmp_path / "bad.toml"), "-q"]) == 2
    assert "unknown voxelize settings group(s) ['grids']" in capsys.readouterr().err
    assert not (tmp_path / "d.npz").exists()
