"""Merged point clouds without pulses (tlsvox.voxel.merged, tlsvox voxelize --scan-positions).

The known answers: a scanner lattice's own steps; the gaps cut out of a full lattice; the same
scans voxelised with their pulse tables (the merged cloud must give the same leaf area within the
smear of its estimated gaps over an 8 x 8-step cell); a plane's area for the occupancy count.
"""

from __future__ import annotations

import json

import laspy
import numpy as np
import pytest

from tlsvox.errors import InputError
from tlsvox.voxel.merged import (
    AngularStep,
    assign_points,
    crossings_per_area,
    empty_pulses,
    estimate_step,
    merge_scans,
    merged_warnings,
    occupancy_lad,
    parse_positions,
    split_by_positions,
)


def lattice(z0, z1, dz, a0, a1, da, *, jitter=0.0, rng=None):
    """Unit vectors of a scanner lattice (zenith z0..z1 step dz, azimuth a0..a1 step da, degrees)."""
    zz, aa = np.meshgrid(np.arange(z0, z1, dz), np.arange(a0, a1, da), indexing="ij")
    zz, aa = zz.ravel(), aa.ravel()
    if jitter:
        zz = zz + rng.normal(0, jitter, zz.shape)
        aa = aa + rng.normal(0, jitter, aa.shape)
    z, a = np.radians(zz), np.radians(aa)
    return np.column_stack([np.sin(z) * np.cos(a), np.sin(z) * np.sin(a), np.cos(z)])


@pytest.mark.parametrize("dz,da", [(0.06, 0.06), (0.048, 0.622)])
def test_step_estimated_from_a_jittered_lattice(rng, dz, da):
    """The steps of a lattice whose directions carry twice the scatter of coordinates rounded to 1 mm at
    15 m (0.002 deg): within 1 %."""
    u = lattice(60, 100, dz, 10, 10 + 800 * da, da, jitter=0.002, rng=rng)
    step = estimate_step(u)
    assert step.zenith_deg == pytest.approx(dz, rel=0.01) and step.azimuth_deg == pytest.approx(da, rel=0.01)


@pytest.mark.parametrize("given", [True, False])
def test_empty_pulses_count_the_gaps_cut_out(rng, given):
    """A full 0.1-deg lattice with 30 % of its pulses removed in patches: the estimate puts back as many
    (within 2 %: the cells at the span's edges), each in the cell it was cut from."""
    u = lattice(70, 110, 0.1, 0, 40, 0.1)
    zen = np.degrees(np.arccos(u[:, 2]))
    az = np.degrees(np.arctan2(u[:, 1], u[:, 0]))
    patch = (np.sin(np.radians(zen) * 9) * np.sin(np.radians(az) * 11)) > 0.45
    drop = patch & (rng.random(len(u)) < 0.9)
    new, info = empty_pulses(u[~drop], AngularStep(0.1, 0.1) if given else None)
    assert info["empty_pulses"] == pytest.approx(drop.sum(), rel=0.02)
    assert info["coverage_p90"] == pytest.approx(1.0, abs=0.02)
    nz = np.degrees(np.arccos(new[:, 2]))
    na = np.degrees(np.arctan2(new[:, 1], new[:, 0]))
    assert nz.min() > 69.1 and nz.max() < 110.9 and na.min() > -0.9 and na.max() < 40.9
    # where the gaps were cut: each empty pulse within one 8-step cell (0.8 deg) of a removed pulse
    from scipy.spatial import cKDTree

    d, _ = cKDTree(np.column_stack([zen[drop], az[drop]])).query(np.column_stack([nz, na]))
    assert np.percentile(d, 99) < 0.8 * np.sqrt(2)


def test_positions_parsed_and_bad_ones_named(tmp_path):
    assert parse_positions("0,0,1.5; 10,-2,1.6").tolist() == [[0, 0, 1.5], [10, -2, 1.6]]
    f = tmp_path / "pos.txt"
    f.write_text("# x y z\n1 2 3\n4,5,6  # second\n")
    assert parse_positions(f).tolist() == [[1, 2, 3], [4, 5, 6]]
    f.write_text("1 2\n")
    with pytest.raises(InputError, match="line 1 .* has 2 numbers"):
        parse_positions(f)
    with pytest.raises(InputError, match="three numbers"):
        parse_positions("1,2;3,4,5")
    with pytest.raises(InputError, match="same point"):
        parse_positions("1,2,3;1,2,3")


def test_points_assigned_by_source_id_or_nearest():
    pos = np.array([[0.0, 0, 0], [10, 0, 0]])
    pts = np.array([[1.0, 0, 0], [9, 0, 0], [6, 0, 0]])
    idx, how = assign_points(pts, pos, source_id=[5, 5, 3])
    assert idx.tolist() == [1, 1, 0] and "source id" in how
    idx, how = assign_points(pts, pos, source_id=[5, 5, 3], rule="nearest")
    assert idx.tolist() == [0, 1, 1] and "nearest" in how
    idx, how = assign_points(pts, pos, source_id=[1, 1, 1])  # one id for two positions: nearest
    assert idx.tolist() == [0, 1, 1]
    with pytest.raises(InputError, match="3 distinct source ids .* for 2 scan positions"):
        assign_points(pts, pos, source_id=[1, 2, 3], rule="source-id")


def test_crossings_per_area():
    assert crossings_per_area("spherical") == pytest.approx(1.5, abs=2e-3)
    assert crossings_per_area("horizontal") == pytest.approx(1.0)
    assert crossings_per_area("vertical") == pytest.approx(4 / np.pi)


def test_occupancy_gives_a_tilted_planes_area(rng):
    """Points dense on 2 x 2 m planes tilted 40 deg, facing four azimuths: the cells they occupy times
    the cell's face area over the plane's crossings (cos t + sin t (|cos phi| + |sin phi|)) give each
    plane's 4 m2 within 5 % (slivers of cells holding no point) when the points are dense (25 a cm2),
    and much less when the cell is finer than their spacing (the case the scene's warning names)."""
    from tlsvox.voxel.grid import VoxelGrid

    t = np.radians(40)
    grid = VoxelGrid(origin=(0.0, 0.0, 0.0), voxel_size=0.5, shape=(12, 12, 12))
    for phi in np.radians([0, 30, 45, 90, 135]):
        uv = rng.uniform(-1, 1, (1_000_000, 2))
        e1 = np.array([np.cos(t) * np.cos(phi), np.cos(t) * np.sin(phi), -np.sin(t)])
        e2 = np.array([-np.sin(phi), np.cos(phi), 0.0])
        pts = np.array([3.0, 3, 3]) + uv[:, :1] * e1 + uv[:, 1:] * e2
        crossings = np.cos(t) + np.sin(t) * (abs(np.cos(phi)) + abs(np.sin(phi)))
        for cell, n, lo, hi in ((0.04, len(pts), 0.95, 1.05), (0.01, 20_000, 0.0, 0.7)):
            area = occupancy_lad(pts[:n], grid, cell=cell, leaf_angle="horizontal").sum() * grid.voxel_volume
            assert lo < area / crossings / 4.0 < hi, (np.degrees(phi), cell, area / crossings)


@pytest.fixture(scope="module")
def small_tree_scans():
    from tlsvox.truth.scanner import ScannerPreset, paper_scan_poses, simulate_scan
    from tlsvox.truth.synthetic import TreeParams, make_tree

    tree = make_tree(TreeParams(total_leaf_area=80.0, height=8.0, crown_radius=3.0), seed=1)
    preset = ScannerPreset.riegl_vz400(zenith_step_deg=0.12, azimuth_step_deg=0.12)
    scans = []
    for i, pose in enumerate(paper_scan_poses(tree)):
        s = simulate_scan(tree, pose=pose, preset=preset, seed=10 + i, scan_id=i, progress=False)
        s.pose = s.pose_true
        scans.append(s)
    return tree, scans


def _stripped(scans):
    from tlsvox.scan import Scan

    return [Scan(s.world_xyz(), return_number=s.return_number, number_of_returns=s.number_of_returns,
                 truth_material=s.truth_material, scan_id=s.scan_id, name=s.name) for s in scans]


def test_merged_cloud_gives_the_full_pipelines_leaf_area(small_tree_scans):
    """The small tree's two scans merged, pulses and poses dropped, split back by source and by
    nearest position: the leaf area of the full-pulse pipeline (79.4 of 80 m2) within 3 % by source
    (step given or estimated), within 8 % by nearest position (points seen from the far position
    traced from the near one)."""
    from tlsvox.voxel.stages import voxelize

    tree, scans = small_tree_scans
    kw = dict(voxel_size=0.2, leaf_angle="uniform", echo_weights="uniform", ground=0.0, progress=False)
    full = voxelize(scans, **kw).scene.total_leaf_area()
    merged, source = merge_scans(_stripped(scans))
    positions = np.array([s.pose_true[:3, 3] for s in scans])
    for step in (0.12, None):
        parts = split_by_positions(merged, positions, source_id=source, step=step)
        assert [p.meta["merged"]["coverage_p90"] for p in parts] == pytest.approx([1.0, 1.0], abs=0.05)
        assert not merged_warnings(parts)
        assert voxelize(parts, **kw).scene.total_leaf_area() == pytest.approx(full, rel=0.03)
    parts = split_by_positions(merged, positions, step=0.12)
    assert "nearest" in parts[0].meta["merged"]["assigned"]
    assert voxelize(parts, **kw).scene.total_leaf_area() == pytest.approx(full, rel=0.08)
    thinned, _ = merge_scans([s for s in _stripped(scans)])
    keep = np.random.default_rng(0).random(len(thinned)) < 0.5
    half = type(thinned)(thinned.xyz[keep], return_number=thinned.return_number[keep],
                         number_of_returns=thinned.number_of_returns[keep], truth_material=thinned.truth_material[keep])
    said = merged_warnings(split_by_positions(half, positions, source_id=source[keep], step=0.12))
    assert said and "thinned" in said[0]


def _write_las(path, scans, *, with_ids=True):
    xyz = np.vstack([s.world_xyz() for s in scans])
    header = laspy.LasHeader(point_format=6, version="1.4")
    header.scales = np.full(3, 1e-3)
    header.offsets = np.floor(xyz.min(axis=0))
    las = laspy.LasData(header)
    las.x, las.y, las.z = xyz.T
    las.return_number = np.concatenate([s.return_number for s in scans])
    las.number_of_returns = np.concatenate([s.number_of_returns for s in scans])
    if with_ids:
        las.point_source_id = np.concatenate([np.full(len(s), 3 + s.scan_id) for s in scans])
    las.write(str(path))
    return path


def test_cli_merged_cloud_with_positions_and_without(tmp_path, small_tree_scans, capsys):
    """From the shell: a merged LAS with positions (beams rebuilt, stated in the summary and the scene),
    an XYZ file with positions unknown (occupancy, labelled); misuse refused in one line."""
    from tlsvox.cli.app import main
    from voxlidar.scene import Scene

    _, scans = small_tree_scans
    las = _write_las(tmp_path / "merged.las", scans)
    pos = tmp_path / "positions.txt"
    pos.write_text("\n".join(" ".join(f"{v:.4f}" for v in s.pose_true[:3, 3]) for s in scans) + "\n")
    assert main(["voxelize", str(las), "--scan-positions", str(pos), "--voxel-size", "0.2", "-o",
                 str(tmp_path / "a.npz")]) == 0
    summary = json.loads(capsys.readouterr().out)
    assert [m["points"] for m in summary["merged"]] == [len(s) for s in scans]
    scene = Scene.load(tmp_path / "a.npz")
    assert [m["assigned"].startswith("by source id") for m in scene.meta["merged"]] == [True, True]
    assert all(m["empty_pulses"] > 0 for m in scene.meta["merged"]) and scene.total_leaf_area() > 0
    xyz = tmp_path / "merged.xyz"
    np.savetxt(xyz, np.vstack([s.world_xyz() for s in scans]), fmt="%.3f")
    assert main(["voxelize", str(xyz), "--scan-positions", "unknown", "--voxel-size", "0.2", "-q", "-o",
                 str(tmp_path / "b.npz")]) == 0
    occ = Scene.load(tmp_path / "b.npz")
    assert occ.meta["estimator"] == "occupancy" and "occlusion not corrected" in occ.meta["occupancy"]["note"]
    first = ",".join(f"{v:.4f}" for v in scans[0].pose_true[:3, 3])
    for argv, says in (
            ([str(las), "--angular-step", "0.1"], "--angular-step is for merged clouds"),
            ([str(las), "--scan-positions", str(pos), "--scanner-frame"], "--scanner-frame does not go with"),
            ([str(xyz), "--scan-positions", "unknown", "--estimator", "voxlad"], "--estimator needs beams"),
            ([str(xyz), "--scan-positions", "unknown", "--angular-step", "0.1"], "--angular-step needs beams"),
            ([str(las), "--scan-positions", str(pos), "--occupancy-cell", "0.02"], "--occupancy-cell is for"),
            ([str(las), "--scan-positions", "0,0,0;1,2"], "three numbers"),
            ([str(las), "--scan-positions=" + first + ";500,500,0", "--assign", "nearest"],
             "scan position 1 .* has 0 points"),
            ([str(las), "--scan-positions", "0,0,0;500,500,0"],
             "scan position 0 .* no regular scan pattern .* where the scanner stood")):
        capsys.readouterr()
        assert main(["voxelize", *argv, "-q", "-o", str(tmp_path / "c.npz")]) == 2
        err = capsys.readouterr().err
        assert len(err.strip().splitlines()) == 1 and "Traceback" not in err
        import re

        assert re.search(says, err), err
    assert not (tmp_path / "c.npz").exists()
