"""The voxelize pipeline end to end: a turbid box of known LAD, bad input, the CLI,
and (slow) the synthetic oak scored against its mesh truth."""

from __future__ import annotations

import numpy as np
import pytest

from tlsvox.cli.voxelize import main as cli_main
from tlsvox.errors import InputError
from tlsvox.scan import PulseTable, Scan
from tlsvox.voxel.stages import score_lad, voxelize
from voxlidar.materials import Material
from voxlidar.scene import Scene

BOX_LO = np.array([-1.0, -1.0, 1.0])
BOX_HI = np.array([1.0, 1.0, 3.0])
LAD = 0.8  # m2/m3, spherical leaves: attenuation G * LAD = 0.4 per metre


def _box_scan(rng, position, yaw_deg, *, n_az=160, n_zen=120, scan_id=0):
    """Pulses from ``position`` over the box; leaf hits sampled from the turbid medium."""
    c = 0.5 * (BOX_LO + BOX_HI) - position
    az0, zen0 = np.arctan2(c[1], c[0]), np.arccos(c[2] / np.linalg.norm(c))
    az, zen = np.meshgrid(az0 + np.linspace(-0.45, 0.45, n_az), zen0 + np.linspace(-0.45, 0.45, n_zen))
    d = np.column_stack([np.sin(zen.ravel()) * np.cos(az.ravel()), np.sin(zen.ravel()) * np.sin(az.ravel()),
                         np.cos(zen.ravel())])
    with np.errstate(divide="ignore"):
        ta, tb = (BOX_LO - position) / d, (BOX_HI - position) / d
    t_in = np.max(np.minimum(ta, tb), axis=1)
    t_out = np.min(np.maximum(ta, tb), axis=1)
    x = t_in + rng.exponential(1.0 / (0.5 * LAD), len(d))
    hit = (t_out > t_in) & (x < t_out)
    y = np.deg2rad(yaw_deg)
    rot = np.array([[np.cos(y), -np.sin(y), 0], [np.sin(y), np.cos(y), 0], [0, 0, 1]])
    pose = np.eye(4)
    pose[:3, :3], pose[:3, 3] = rot, position
    d_scanner = d @ rot  # scanner frame = R^T world
    xyz = d_scanner[hit] * x[hit, None]
    return Scan(xyz=xyz, pulse_id=np.nonzero(hit)[0], truth_material=np.full(hit.sum(), Material.LEAF),
                return_number=np.ones(hit.sum()), number_of_returns=np.ones(hit.sum()), pose=pose,
                pulses=PulseTable(d_scanner, hit.astype(int)), scan_id=scan_id, name=f"box{scan_id}")


@pytest.fixture(scope="module")
def box_scans():
    rng = np.random.default_rng(2024)
    return [_box_scan(rng, np.array([-6.0, -1.0, 1.6]), 20.0, scan_id=0),
            _box_scan(rng, np.array([4.0, 5.0, 1.6]), -70.0, scan_id=1)]


def test_turbid_box_total_leaf_area(box_scans):
    res = voxelize(box_scans, voxel_size=0.5, leaf_angle="spherical", ground=None,
                   bounds=[BOX_LO, BOX_HI], progress=False)
    lad = res.lad
    assert not lad.occluded.any()
    true_area = LAD * np.prod(BOX_HI - BOX_LO)
    v = res.grid.voxel_volume
    area = lad.lad.sum() * v
    se = np.sqrt(np.sum(lad.lad_std**2)) * v
    assert abs(area - true_area) < 2 * se, (area, true_area, se)
    # each voxel within 3 of its standard errors (64 voxels: a 3-sigma miss has p ~ 0.17 overall)
    z = (lad.lad - LAD) / lad.lad_std
    assert np.all(np.abs(z) < 3.5), z.ravel()
    sc = score_lad(lad.lad, np.full(lad.lad.shape, LAD), voxel_volume=v)
    assert abs(sc["bias"]) < 2 * np.sqrt(np.mean(lad.lad_std**2) / lad.lad.size)
    s = res.scene
    assert isinstance(s, Scene) and s.leaf_angle.kind.value == "spherical"
    assert np.all(np.isfinite(s.lad)) and s.meta["beams"] == sum(len(b.pulses) for b in box_scans)


def test_no_pose_is_an_error(box_scans):
    a, b = box_scans
    nopose = Scan(xyz=b.xyz, pulse_id=b.pulse_id, pulses=b.pulses, name="b")
    with pytest.raises(InputError, match="'b' has no pose.*register"):
        voxelize([a, nopose], progress=False, ground=None)
    with pytest.raises(InputError, match="scanner_frame=True"):
        voxelize([nopose], progress=False, ground=None)


def test_mismatched_scans_are_errors(box_scans):
    a, b = box_scans
    far = Scan(xyz=b.xyz, pulse_id=b.pulse_id, pulses=b.pulses, pose=b.pose @ np.diag([1, 1, 1, 1.0]),
               name="far", truth_material=b.truth_material)
    far.pose[:3, 3] += [500.0, 0, 0]
    with pytest.raises(InputError, match="not co-registered"):
        voxelize([a, far], progress=False, ground=None)
    with pytest.raises(InputError, match="classes has 1 entries for 2 scans"):
        voxelize([a, b], classes=[np.zeros(len(a))], progress=False, ground=None)
    with pytest.raises(InputError, match="labels for its"):
        voxelize([a, b], classes=[np.zeros(3), np.zeros(len(b))], class_codes="material",
                 progress=False, ground=None)


def test_grid_too_large_reports_size(box_scans):
    with pytest.raises(InputError, match=r"need [0-9.]+ [KMG]iB .* only 1.0 KiB"):
        voxelize(box_scans, voxel_size=0.5, ground=None, max_bytes=1024, progress=False)


def test_bad_choices_list_valid_ones(box_scans):
    with pytest.raises(InputError, match="bcmle, voxlad"):
        voxelize(box_scans, estimator="mle", progress=False)
    with pytest.raises(InputError, match="count_stretch, voxlad"):
        voxelize(box_scans, wood="paper", progress=False)
    with pytest.raises(InputError, match="ground="):
        voxelize(box_scans, ground="flat", progress=False)


@pytest.fixture
def box_files(box_scans, tmp_path):
    """The box scans written as LAZ files (with their sidecars); their paths."""
    paths = []
    for s in box_scans:
        p = tmp_path / f"{s.name}.laz"
        s.write(p)
        paths.append(str(p))
    return paths


def test_cli_in_process(box_files, tmp_path, capsys):
    paths = box_files
    out = tmp_path / "scene.npz"
    vox = tmp_path / "scene.vox"
    rc = cli_main(paths + ["--voxel-size", "0.5", "--leaf-angle", "spherical", "--estimator", "bcmle",
                           "--ground", "none", "--bounds=-1,-1,1,1,1,3", "-o", str(out), "--vox", str(vox)])
    assert rc == 0
    scene = Scene.load(out)
    assert scene.total_leaf_area() == pytest.approx(LAD * 8.0, rel=0.1)
    assert vox.exists()
    assert '"estimator": "bcmle"' in capsys.readouterr().out
    with pytest.raises(SystemExit):
        cli_main(paths + ["--estimator", "mle", "-o", str(out)])
    with pytest.raises(SystemExit):  # argparse rejects 5 numbers
        cli_main([paths[0], "-o", str(tmp_path / "x.npz"), "--bounds=0,0,0,1,1"])
    # a library error becomes exit code 2 with the message, not a traceback
    rc = cli_main([str(tmp_path / "missing.laz"), "-o", str(tmp_path / "x.npz"), "-q"])
    assert rc == 2 and "does not exist" in capsys.readouterr().err


def test_cli_takes_poses_from_register_transforms(box_scans, tmp_path, capsys):
    """`tlsvox voxelize --transforms` (the JSON `tlsvox register` writes) replaces the pose
    sidecars: scans written with a wrong pose give the box's leaf area back only with it."""
    import copy
    import json

    paths, doc = [], {"format": "tlsvox-registration-1", "scans": []}
    for s in box_scans:
        wrong = copy.copy(s)
        wrong.pose = s.pose.copy()
        wrong.pose[:3, 3] += [0.0, 2.5, 0.0]  # 2.5 m off: misses the box
        p = tmp_path / f"{s.name}.laz"
        wrong.write(p)
        paths.append(str(p))
        doc["scans"].append({"name": s.name, "pose": s.pose.tolist()})
    tr = tmp_path / "merged.transforms.json"
    tr.write_text(json.dumps(doc))
    args = ["--voxel-size", "0.5", "--leaf-angle", "spherical", "--ground", "none", "--bounds=-1,-1,1,1,1,3", "-q"]
    rc = cli_main(paths + args + ["--transforms", str(tr), "-o", str(tmp_path / "good.npz")])
    assert rc == 0
    assert Scene.load(tmp_path / "good.npz").total_leaf_area() == pytest.approx(LAD * 8.0, rel=0.1)
    rc = cli_main(paths + args + ["-o", str(tmp_path / "bad.npz")])
    # the sidecars' wrong poses put every echo outside the box: an error, not a scene of empty voxels
    assert rc == 2 and "hold none of the" in capsys.readouterr().err
    assert not (tmp_path / "bad.npz").exists()
    doc["scans"] = doc["scans"][:1]
    tr.write_text(json.dumps(doc))
    rc = cli_main(paths + args + ["--transforms", str(tr), "-o", str(tmp_path / "x.npz")])
    assert rc == 2 and "no pose for scan(s) ['box1']" in capsys.readouterr().err
    assert not (tmp_path / "x.npz").exists()


@pytest.mark.slow
def test_synthetic_oak_two_scans_20cm():
    """The procedural oak, two simulated scans, 20 cm voxels, scored against the mesh.

    With 1/n echo weights the visible leaf area comes out within 5 %, but only
    because the wide beam's partial-hit bias (+43 % on the leaf box) cancels an
    underestimate that pencil beams show too (docs/voxelize.md, *Echo weights*).
    Weighted by the intercepted share, the wide beam gives the pencil beams' total.
    """
    from tlsvox.truth.scanner import ScannerPreset, paper_scan_poses, simulate_scan
    from tlsvox.truth.synthetic import make_tree

    tree = make_tree(seed=1)

    def scans_with(preset):
        out = []
        for i, pose in enumerate(paper_scan_poses(tree)):
            s = simulate_scan(tree, pose=pose, preset=preset, seed=10 + i, scan_id=i, progress=False)
            s.pose = s.pose_true  # registration is tested elsewhere
            out.append(s)
        return out

    def run(scans, rule):
        res = voxelize(scans, voxel_size=0.2, leaf_angle="uniform", estimator="bcmle", ground=0.0, progress=False,
                       echo_weights=rule)
        g = res.grid
        truth = tree.leaf_area_per_voxel(origin=g.lower, voxel_size=g.voxel_size, shape=g.shape) / g.voxel_volume
        return res, truth

    wide = scans_with(ScannerPreset.riegl_vz400())
    res, truth = run(wide, "uniform")
    g, occ = res.grid, res.lad.occluded
    visible = score_lad(np.where(occ, 0, res.lad.lad), np.where(occ, 0, truth), voxel_volume=g.voxel_volume)
    assert abs(visible["area_error"]) < 0.05, visible
    per_voxel = score_lad(res.lad.lad, truth, mask=~occ)
    assert abs(per_voxel["bias"]) < 0.05 * truth[~occ & (truth > 0)].mean()
    share, _ = run(wide, "fraction")
    pencil, _ = run(scans_with(ScannerPreset.riegl_vz400(n_subrays=1)), "uniform")
    a, b = share.scene.total_leaf_area(), pencil.scene.total_leaf_area()
    assert abs(a / b - 1) < 0.03, (a, b)  # measured with the demo's scan seeds (1, 2): 332.2 and 332.3 m2


def test_bounds_are_taken_as_given(box_scans):
    # a 1 m box at -0.3..0.7 is 2 x 2 x 2 voxels of 0.5 m starting at -0.3; snapped, it starts at -0.5
    bounds = [[-0.3, -0.3, 1.5], [0.7, 0.7, 2.5]]
    res = voxelize(box_scans, voxel_size=0.5, ground=None, bounds=bounds, progress=False)
    assert res.grid.origin == (-0.3, -0.3, 1.5) and res.grid.shape == (2, 2, 2)
    snapped = voxelize(box_scans, voxel_size=0.5, ground=None, bounds=bounds, snap=True, progress=False)
    assert snapped.grid.origin == (-0.5, -0.5, 1.5) and snapped.grid.shape == (3, 3, 2)
    # every output names the leaf angle model
    assert res.scene.meta["leaf_angle"] == {"name": "uniform"} == res.scene.leaf_angle.to_dict()


def test_cli_plan_layout_and_leaf_angle_note(box_files, tmp_path, capsys):
    paths = box_files
    out = tmp_path / "scene.npz"
    rc = cli_main(paths + ["--voxel-size", "0.1", "--ground", "none", "--plan", "-o", str(out), "-q"])
    text = capsys.readouterr().out
    assert rc == 0 and not out.exists()
    assert "hold echoes; dense layout" in text and "the dense layout needs" in text
    assert "undetected='model'" not in text
    rc = cli_main(paths + ["--voxel-size", "0.1", "--ground", "none", "--plan", "--undetected", "model",
                           "--detection-threshold-db", "-20", "-o", str(out),
                           "-q"])
    assert rc == 0 and "undetected='model'" in capsys.readouterr().out  # the correction's bytes are planned
    rc = cli_main(paths + ["--voxel-size", "0.25", "--ground", "none", "--layout", "sparse", "--leaf-azimuth",
                           "outward", "-o", str(out)])
    summary = capsys.readouterr().out
    assert rc == 0 and '"layout": "sparse"' in summary
    assert '"note": "the default; set it with --leaf-angle"' in summary and '"name": "uniform"' in summary
    scene = Scene.load(out)
    assert scene.meta["layout"] == "sparse" and scene.leaf_azimuth == "outward"


def test_leaf_angle_layers_reach_the_estimate(box_scans):
    """leaf_angle_layers: the same model in every layer gives the one-model run's leaf area (the
    tables are read where the beams' own G is exact); planophile leaves in the lower half change
    it there only; the layers are stated in the scene; bad layers get one line."""
    kw = dict(voxel_size=0.5, leaf_angle="spherical", ground=None, bounds=[BOX_LO, BOX_HI], progress=False)
    plain = voxelize(box_scans, **kw)
    mid = 0.5 * (BOX_LO[2] + BOX_HI[2])
    same = voxelize(box_scans, leaf_angle_layers=[(BOX_LO[2], mid, "spherical"), (mid, BOX_HI[2], "spherical")],
                    **kw)
    np.testing.assert_allclose(same.lad.lad, plain.lad.lad, rtol=1e-6, atol=1e-9)
    mixed = voxelize(box_scans, leaf_angle_layers=[(BOX_LO[2], mid, "planophile"), (mid, BOX_HI[2], "spherical")],
                     **kw)
    nz = plain.grid.shape[2]
    lower = plain.grid.lower[2] + (np.arange(nz) + 0.5) * 0.5 < mid
    np.testing.assert_allclose(mixed.lad.lad[:, :, ~lower], plain.lad.lad[:, :, ~lower], rtol=1e-6, atol=1e-9)
    assert np.abs(mixed.lad.lad[:, :, lower] - plain.lad.lad[:, :, lower]).max() > 0.05
    said = mixed.scene.meta["leaf_angle_layers"]
    assert said[0]["z_low"] is None and said[1]["z_low"] == pytest.approx(mid)
    assert said[0]["leaf_angle"]["name"] == "planophile" and plain.scene.meta["leaf_angle_layers"] is None
    # one model in every layer reads as that model alone (the per-layer tables within their
    # interpolation error): planophile leaves, azimuthally uniform and outward; the outward run has its
    # crown axis through a voxel centre, where the cosine to the outward direction is undefined and
    # the layer's azimuth-averaged G is read, as the one-model run reads the beam's own
    for azimuth in ("uniform", "outward"):
        kw_a = {**kw, "leaf_angle": "planophile", "leaf_azimuth": azimuth, "crown_center": (0.25, 0.25)}
        one = voxelize(box_scans, **kw_a)
        layered = voxelize(box_scans, leaf_angle_layers=[(BOX_LO[2], mid, "planophile"),
                                                         (mid, BOX_HI[2], "planophile")], **kw_a)
        np.testing.assert_allclose(layered.lad.lad, one.lad.lad, rtol=2e-3, atol=1e-9, err_msg=azimuth)
    for bad, what in (([(1.0, 2.0, "spherical"), (0.0, 1.0, "spherical")], "go up in height"),
                      ([(0.0, 1.0)], "is not \\(z_low, z_high, LeafAngle\\)"), ([], "is empty"),
                      ([(0.0, 1.0, "flat")], "spherical"), (3, "must be a LeafAngleMeasurement")):
        with pytest.raises(InputError, match=what):
            voxelize(box_scans, leaf_angle_layers=bad, **kw)
