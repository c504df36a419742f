"""Registration: rigid fit, targets, ICP, FPFH, failure on non-overlap, merged output.

Fast tests use procedural clouds with a known rigid transform; the slow ones
scan the synthetic tree (tlsvox.truth.synthetic + tlsvox.truth.scanner) at the VZ-400's
0.06 deg step and check the issue's accuracy figures against the true poses.
"""

from __future__ import annotations

import json

import numpy as np
import pytest

from tlsvox.errors import InputError
from tlsvox.register import (
    RegistrationError,
    coincidence,
    detect_targets,
    global_fpfh,
    match_targets,
    pose_error,
    read_transforms,
    register_pair,
    register_scans,
    rigid_fit,
    rotation_about_z,
    true_relative_transform,
    write_registered,
)
from tlsvox.scan import Scan

LAYOUT = np.array([[6.0, 2.0, 0.5], [-5.0, 4.0, 0.9], [2.0, -6.5, 0.4], [-3.0, -5.0, 1.3]])


def pose(x, y, z, yaw, tilt_deg=0.0):
    T = np.eye(4)
    a = np.deg2rad(tilt_deg)
    rx = np.array([[1, 0, 0], [0, np.cos(a), -np.sin(a)], [0, np.sin(a), np.cos(a)]])
    T[:3, :3] = rotation_about_z(yaw) @ rx
    T[:3, 3] = [x, y, z]
    return T


def _cyl(rng, base, axis, radius, length, n):
    axis = np.asarray(axis, float) / np.linalg.norm(axis)
    a = np.cross(axis, [1.0, 0, 0] if abs(axis[0]) < 0.9 else [0, 1.0, 0])
    a /= np.linalg.norm(a)
    b = np.cross(axis, a)
    t, ph = rng.uniform(0, length, n), rng.uniform(0, 2 * np.pi, n)
    return np.asarray(base) + t[:, None] * axis + radius * (np.cos(ph)[:, None] * a + np.sin(ph)[:, None] * b)


def toy_scan(seed, P, name, *, layout=LAYOUT, crown_seed=7, shift=(0.0, 0.0), noise=0.004,
             other_plot=False):
    """A procedural plot seen from pose ``P`` (world-from-scanner), in the scanner frame.

    Ground, a trunk with branches, a wall, a leaf crown (fixed by
    ``crown_seed``) and upright cylindrical targets (r 5 cm, h 10 cm) of
    which only the half facing the scanner is sampled, uniformly in the
    scanner's angle as a real scan grid would.  Every surface is sampled
    afresh per scan (different points, as two real scans).
    """
    rng = np.random.default_rng(seed)
    sx, sy = shift
    parts = []

    def add(p, db, mat):
        parts.append((p + [sx, sy, 0.0], np.full(len(p), db), np.full(len(p), mat)))

    add(np.column_stack([rng.uniform(-12, 12, 15000), rng.uniform(-12, 12, 15000), np.zeros(15000)]), -4.6, 3)
    # other_plot: a different stand (leaning thinner stem, other branches, no wall)
    lean, r_stem, phase = ((0.15, 0.0, 1.0), 0.18, 2.1) if other_plot else ((0, 0, 1), 0.25, 0.4)
    add(_cyl(rng, (0, 0, 0), lean, r_stem, 4.0, 5000), -3.7, 2)
    # other_plot: branches at other heights and angles (the same ones turned would overlap)
    z0, dz, rise = (1.7, 0.6, 0.4) if other_plot else (2.2, 0.35, 0.7)
    for k in range(3 if other_plot else 5):
        az = k * (2.0 if other_plot else 1.3) + phase
        add(_cyl(rng, (0, 0, z0 + dz * k), (np.cos(az), np.sin(az), rise), 0.07, 2.5, 1200), -3.7, 2)
    if not other_plot:
        add(np.column_stack([np.full(3000, 9.0), rng.uniform(-9, -3, 3000), rng.uniform(0, 2.5, 3000)]),
            -2.0, 3)
    crng = np.random.default_rng(crown_seed)
    centres = crng.normal(size=(2500, 3)) * [1.6, 1.6, 1.0] + [0, 0, 5.5]
    normals = crng.normal(size=(2500, 3))
    for _ in range(3):
        u = np.cross(normals, rng.normal(size=normals.shape))
        u /= np.linalg.norm(u, axis=1)[:, None]
        add(centres + 0.02 * u * rng.uniform(-1, 1, (len(u), 1)), -5.7, 1)
    origin = P[:3, 3] - [sx, sy, 0.0]
    for c in layout:
        view = c[:2] - origin[:2]
        phi0 = np.arctan2(-view[1], -view[0])  # facing the scanner
        s = rng.uniform(-1, 1, 300)  # uniform across the projected width
        phi = phi0 + np.arcsin(s)
        z = rng.uniform(-0.05, 0.05, 300)
        add(np.column_stack([c[0] + 0.05 * np.cos(phi), c[1] + 0.05 * np.sin(phi), c[2] + z]), 9.5, 4)
    xyz = np.concatenate([p[0] for p in parts])
    xyz = xyz + rng.normal(scale=noise, size=xyz.shape)
    local = (xyz - P[:3, 3]) @ P[:3, :3]
    return Scan(xyz=local, reflectance_db=np.concatenate([p[1] for p in parts]),
                truth_material=np.concatenate([p[2] for p in parts]), pose_true=P, name=name)


P_A = pose(-15.0, 3.0, 1.7, 20.0, tilt_deg=0.3)
P_B = pose(6.0, 8.0, 1.7, 200.0, tilt_deg=-0.2)


@pytest.fixture(scope="module")
def toy_pair():
    return toy_scan(1, P_A, "A"), toy_scan(2, P_B, "B")


def test_rigid_fit_recovers_known_transform(rng):
    src = rng.uniform(-10, 10, (50, 3))
    T = pose(3.0, -2.0, 0.5, 73.0, tilt_deg=12.0)
    dst = src @ T[:3, :3].T + T[:3, 3] + rng.normal(scale=0.002, size=(50, 3))
    rot, tr = pose_error(rigid_fit(src, dst), T)
    # 2 mm noise over a 20 m pattern: rotation ~1e-4 rad, translation ~1 mm
    assert rot < 0.01 and tr < 0.003
    # Umeyama with scale
    S = T.copy()
    S[:3, :3] *= 1.5
    Ts = rigid_fit(src, src @ S[:3, :3].T + S[:3, 3], with_scale=True)
    np.testing.assert_allclose(Ts, S, atol=1e-9)
    with pytest.raises(InputError, match="collinear"):
        rigid_fit(np.outer(np.arange(5.0), [1, 1, 0]), np.outer(np.arange(5.0), [1, 0, 0]))


def test_match_targets_with_outlier_and_missing_targets(rng):
    ref = rng.uniform(-10, 10, (6, 3))
    T = pose(20.0, -4.0, 0.1, 140.0, tilt_deg=0.5)
    # the source sees 5 of the 6 targets (noise 3 mm) plus one bright thing that is no target
    src_world = np.vstack([ref[[0, 2, 3, 4, 5]], [[30.0, 30.0, 2.0]]]) + rng.normal(scale=0.003, size=(6, 3))
    src = (src_world - T[:3, 3]) @ T[:3, :3]  # in the source's own frame: world = T src
    pairs, Tfit = match_targets(src, ref)
    assert pairs.tolist() == [[0, 0], [1, 2], [2, 3], [3, 4], [4, 5]]
    rot, tr = pose_error(Tfit, T)
    assert rot < 0.05 and tr < 0.01


def test_match_targets_refuses_a_symmetric_layout():
    square = np.array([[5.0, 0, 1], [0, 5.0, 1], [-5.0, 0, 1], [0, -5.0, 1]])
    # four equal sides: a quarter turn explains the targets as well as the truth
    assert match_targets(square, square + [1.0, 2.0, 0.0]) is None


def test_detect_targets_fits_cylinder_centres(toy_pair):
    A, _ = toy_pair
    centres = detect_targets(A)
    world = centres @ A.pose_true[:3, :3].T + A.pose_true[:3, 3]
    d = np.linalg.norm(world[:, None] - LAYOUT[None], axis=2)
    assert len(centres) == len(LAYOUT)
    # the centroid of a half cylinder lies r*pi/4 = 39 mm in front of the axis;
    # the fit must take that out (4 mm range noise, 300 points)
    assert d.min(axis=1).max() < 0.003
    flat = detect_targets(A, target_shape="flat")
    dflat = np.linalg.norm((flat @ A.pose_true[:3, :3].T + A.pose_true[:3, 3])[:, None] - LAYOUT[None], axis=2)
    assert dflat.min(axis=1).min() > 0.03
    with pytest.raises(InputError, match="target_shape"):
        detect_targets(A, target_shape="cone")


def test_register_with_targets_from_unknown_frames(toy_pair):
    A, B = toy_pair
    r = register_pair(B, A, method="targets")
    T_true = true_relative_transform(B, A)
    rot, tr = pose_error(r.transform, T_true)
    assert r.method == "targets" and len(r.target_pairs) == 4
    assert rot < 0.05 and tr < 0.005
    assert r.error_vs_truth["rotation_deg"] == pytest.approx(rot)
    assert r.fitness >= 0.25


def test_icp_from_a_perturbed_start(toy_pair):
    A, B = toy_pair
    T_true = true_relative_transform(B, A)
    start = T_true @ pose(0.3, -0.2, 0.05, 3.0)
    r = register_pair(B, A, method="icp", init=start)
    rot, tr = pose_error(r.transform, T_true)
    assert pose_error(start, T_true)[0] > 2.9
    assert rot < 0.2 and tr < 0.03


def test_no_overlap_is_a_clear_failure(toy_pair):
    A, _ = toy_pair
    other = _far_plot()
    with pytest.raises(RegistrationError) as info:
        register_pair(other, A, method="auto")
    msg = str(info.value)
    assert "fitness" in msg and "coincidence ratio" in msg
    # every FPFH peak was finished by ICP and refused, with its figures
    assert info.value.figures["candidates"]
    assert info.value.figures["coincidence"]["coincidence_ratio"] < 2.0


def _far_plot():
    """Another plot 200 m away: its own stem, branches, crown and target layout."""
    return toy_scan(3, pose(190.0, 10.0, 1.7, 80.0), "far", layout=LAYOUT[:, [1, 0, 2]] * [1.3, 0.7, 1],
                    crown_seed=99, shift=(200.0, 0.0), other_plot=True)


def test_fpfh_without_targets_is_accurate_and_repeatable(toy_pair):
    A, B = toy_pair
    T_true = true_relative_transform(B, A)
    r1 = register_pair(B, A, method="fpfh", seed=5)
    r2 = register_pair(B, A, method="fpfh", seed=5)
    rot, tr = pose_error(r1.transform, T_true)
    assert r1.method == "fpfh" and r1.coincidence["coincidence_ratio"] >= 2.0
    assert rot < 0.5 and tr < 0.05  # the goal without targets
    # seeded NumPy RANSAC, no threads: the same seed gives the same coarse transform, bit
    # for bit; Open3D's multithreaded ICP then sums in a varying order (last-bit differences)
    off_ground = [s.xyz[s.truth_material != 3] for s in (B, A)]
    np.testing.assert_array_equal(global_fpfh(*off_ground, seed=1), global_fpfh(*off_ground, seed=1))
    np.testing.assert_allclose(r1.transform, r2.transform, rtol=0, atol=1e-9)
    assert r1.hypothesis_groups == r2.hypothesis_groups


def test_coincidence_separates_right_from_wrong_alignment(toy_pair):
    A, B = toy_pair
    T_true = true_relative_transform(B, A)
    # half a turn about a vertical axis 1 m from the stem: crown on crown, stem beside stem
    W = np.eye(4)
    W[:3, :3] = rotation_about_z(180.0)
    W[:3, 3] = [2.0, 0.0, 0.0]
    T_wrong = np.linalg.inv(A.pose_true) @ W @ B.pose_true
    right, wrong = coincidence(B.xyz, A.xyz, T_true), coincidence(B.xyz, A.xyz, T_wrong)
    assert right["coincidence_ratio"] > 10.0 and wrong["coincidence_ratio"] < 2.0
    with pytest.raises(RegistrationError, match="by chance") as info:
        register_pair(B, A, method="icp", init=T_wrong, voxel_sizes=(0.08,))
    assert info.value.figures["coincidence"]["coincidence_ratio"] < 2.0


def test_register_scans_and_write_merged(toy_pair, tmp_path):
    A, B = toy_pair
    A.pose = None
    results = register_scans([A, B], method="targets")
    assert results[0] is None and np.allclose(A.pose, np.eye(4))
    las, js = write_registered(tmp_path / "merged.laz", [A, B], results=results)
    merged = Scan.read(las)
    assert len(merged) == len(A) + len(B)
    # the merged cloud is in A's frame: B's targets land on A's targets
    poses = read_transforms(js)
    rot, tr = pose_error(poses["B"], true_relative_transform(B, A))
    assert rot < 0.05 and tr < 0.005
    doc = json.loads(js.read_text())
    assert doc["scans"][1]["registration"]["method"] == "targets"
    assert {"fitness", "inlier_rmse_m", "transform"} <= set(doc["scans"][1]["registration"])


def test_bad_registration_input(toy_pair):
    A, B = toy_pair
    tiny = Scan(xyz=np.zeros((1, 3)), name="one")
    with pytest.raises(InputError, match="1 point"):
        register_pair(tiny, A)
    with pytest.raises(InputError, match="method"):
        register_pair(B, A, method="magic")
    with pytest.raises(InputError, match="init"):
        register_pair(B, A, method="icp")
    with pytest.raises(InputError, match="at least 2"):
        register_scans([A])


# -- the synthetic pair of the issue (slow: VZ-400 step 0.06 deg) --------------------

@pytest.fixture(scope="module")
def synthetic_pair():
    from tlsvox.truth.scanner import ScannerPreset, paper_scan_poses, simulate_scan
    from tlsvox.truth.synthetic import TreeParams, make_tree

    tree = make_tree(TreeParams(height=8.0, crown_base=2.0, crown_radius=3.0, total_leaf_area=60.0,
                                trunk_radius=0.15), seed=3)
    preset = ScannerPreset.riegl_vz400()
    return [simulate_scan(tree, pose=p, preset=preset, seed=k + 1, scan_id=k, name=f"s{k}", progress=False)
            for k, p in enumerate(paper_scan_poses(tree))]


def _perturbed(scan, T, name):
    """The same scan expressed in another (known) frame: xyz' = T^-1 xyz."""
    Ti = np.linalg.inv(T)
    return Scan(xyz=scan.xyz @ Ti[:3, :3].T + Ti[:3, 3], reflectance_db=scan.reflectance_db,
                truth_material=scan.truth_material, pose_true=scan.pose_true @ T, name=name)


@pytest.mark.slow
@pytest.mark.parametrize("method, max_rot_deg, max_trans_m", [("targets", 0.05, 0.005), ("fpfh", 0.5, 0.05)])
def test_synthetic_pair(synthetic_pair, method, max_rot_deg, max_trans_m):
    A, B = synthetic_pair
    Bp = _perturbed(B, pose(2.0, -1.0, 0.3, 25.0, tilt_deg=0.2), "s1-perturbed")
    r = register_pair(Bp, A, method=method)
    rot, tr = pose_error(r.transform, true_relative_transform(Bp, A))
    print(f"{method}: {rot:.4f} deg, {tr * 1000:.2f} mm, fitness {r.fitness:.3f}, groups {r.hypothesis_groups}")
    assert rot < max_rot_deg and tr < max_trans_m


@pytest.mark.slow
def test_synthetic_scans_without_overlap_fail(synthetic_pair):
    A, B = synthetic_pair
    # keep only what each scan sees of the crown's opposite halves (world x < -1 vs x > 1)
    def half(scan, sign, name):
        w = scan.xyz @ scan.pose_true[:3, :3].T + scan.pose_true[:3, 3]
        keep = (sign * w[:, 0] > 1.0) & (w[:, 2] > 0.3)
        return Scan(xyz=scan.xyz[keep], reflectance_db=scan.reflectance_db[keep],
                    pose_true=scan.pose_true, name=name)

    east, west = half(B, 1, "east"), half(A, -1, "west")
    # the crown's halves are alike: half a turn lays one on the other with a coarse
    # fitness of 0.6-0.8 (default tree); only the coincidence test tells it is wrong.
    # Seeded NumPy RANSAC: the same answer every run (it used to be flaky).
    messages = set()
    for _ in range(2):
        with pytest.raises(RegistrationError, match="fitness") as info:
            register_pair(east, west, method="auto")
        assert info.value.figures["coincidence"]["coincidence_ratio"] < 2.0
        messages.add(str(info.value).split("scored")[0])
    assert len(messages) == 1


def test_settings_group_the_options_and_repeat_a_registration(toy_pair, tmp_path):
    """register_pair's keyword arguments are the fields of RegisterSettings (four groups): the same transform
    from either, the run's settings recorded in its result and read back from a TOML file."""
    from tlsvox.register import RegisterSettings

    A, B = toy_pair
    first = register_pair(B, A, method="targets", target_tolerance_m=0.04)
    s = RegisterSettings.from_dict(first.to_dict()["settings"])
    assert s.coarse.method == "targets" and s.targets.target_tolerance_m == 0.04 and s.icp.voxel_sizes[-1] == 0.03
    s.write(tmp_path / "register.toml")
    again = register_pair(B, A, RegisterSettings.read(tmp_path / "register.toml"))
    assert np.array_equal(again.transform, first.transform) and again.settings == first.settings
    with pytest.raises(InputError, match=r"unknown register setting\(s\) \['voxel_size'\]"):
        register_pair(B, A, voxel_size=0.1)
    with pytest.raises(InputError, match="voxel_sizes"):
        register_pair(B, A, voxel_sizes=("a",))
