"""The TLS scanner simulator against known answers."""

import numpy as np
import pytest
from scipy.optimize import least_squares

from tlsvox import InputError, LeafAngle, Material, Optics
from tlsvox.scan import AngularGrid, Scan
from tlsvox.truth.scanner import ScannerPreset, ScanPose, simulate_scan, subray_pattern
from tlsvox.truth.synthetic import SyntheticTree, TreeParams, make_leaf_slab, make_tree, make_wall

OPTICS = {Material.BARK: Optics(0.42), Material.LEAF: Optics(0.27, 0.34), Material.GROUND: Optics(0.3),
          Material.TARGET: Optics(0.9, retro_gain=10.0)}


def _grid_around_x(half_deg, step):
    n = int(round(2 * half_deg / step)) + 1
    return AngularGrid(90.0 - half_deg, step, n, -half_deg, step, n)


def test_subray_pattern_is_a_gaussian_quadrature():
    # equal-power sub-rays at the RMS radius of their annulus keep the beam's
    # second moment E[r^2] = 1/2 (I ~ exp(-2 r^2)) but for the centre disc's
    # share: E[s | disc] / n with s exponential(rate 2) truncated at P = 1/n
    for n in (7, 19, 37):
        r, a = subray_pattern(n)
        assert len(r) == n
        b = -0.5 * np.log(1 - 1 / n)
        disc = (0.5 - (b + 0.5) * np.exp(-2 * b)) / (1 - np.exp(-2 * b))
        assert np.mean(r**2) == pytest.approx(0.5 - disc / n, abs=1e-12)
        assert abs(np.mean(r * np.cos(a))) < 1e-12  # centred


def test_wall_reflectance_and_range_at_normal_incidence():
    wall = make_wall(center=(15.0, 0.0, 0.0), normal=(-1, 0, 0), half_size=3.0, material=Material.BARK)
    preset = ScannerPreset(reflectance_noise_db=0.0)
    scan = simulate_scan(wall, pose=ScanPose(position=(0, 0, 0)), preset=preset, optics=OPTICS,
                         window=_grid_around_x(0.3, 0.05), seed=1, progress=False)
    assert len(scan) == len(scan.pulses)  # one echo per pulse
    d = scan.pulses.direction[scan.pulse_id]
    cos_inc = d[:, 0]  # wall normal is -x
    # apparent reflectance = rho * cos(incidence), within 1 %
    np.testing.assert_allclose(scan.reflectance / cos_inc, 0.42, rtol=0.01)
    # range: 15 m / cos, unbiased within 3 standard errors, spread = the 5 mm noise
    err = np.linalg.norm(scan.xyz, axis=1) - 15.0 / cos_inc
    assert abs(err.mean()) < 3 * 0.005 / np.sqrt(len(err)) + 2e-4  # + beam-footprint geometry
    assert 0.004 < err.std() < 0.006


def test_beam_centred_on_an_edge_reads_about_half():
    # a wall occupying y > 0 only: every pulse of the column at azimuth 0 has its
    # beam centre on the edge
    wall = SyntheticTree(vertices=np.array([[15, 0, -3], [15, 6, -3], [15, 6, 3], [15, 0, 3]], float),
                         triangles=np.array([[0, 1, 2], [0, 2, 3]]), material=np.full(2, Material.BARK, np.uint8),
                         ground_z=None)
    preset = ScannerPreset(reflectance_noise_db=0.0, min_reflectance_db=-40.0)
    grid = AngularGrid(85.0, 0.05, 201, 0.0, 0.06, 1)
    scan = simulate_scan(wall, pose=ScanPose(position=(0, 0, 0)), preset=preset, optics=OPTICS,
                         window=grid, seed=2, progress=False)
    cos_inc = scan.pulses.direction[scan.pulse_id][:, 0]
    ratio = scan.reflectance / (0.42 * cos_inc)
    # 7 sub-rays: the ring contributes 3/7 on average, the centre ray 0 or 1/7
    assert 0.35 < ratio.mean() < 0.65
    # and a beam fully on the wall reads 1 (sanity of the normalisation)
    full = simulate_scan(wall, pose=ScanPose(position=(0, -1, 0)), preset=preset, optics=OPTICS,
                         window=AngularGrid(90.0, 0.05, 1, 4.0, 0.05, 1), seed=2, progress=False)
    assert full.reflectance[0] / (0.42 * full.pulses.direction[0, 0]) == pytest.approx(1.0, rel=0.01)


def test_gap_fraction_through_a_leaf_slab_is_beer_lambert():
    lad, thick = 1.0, 1.0
    slab = make_leaf_slab(lad=lad, size=(thick, 5.0, 5.0), origin=(5.0, -2.5, -2.5), leaf_angle="spherical",
                          seed=4)
    preset = ScannerPreset(n_subrays=1, min_reflectance_db=-80.0, reflectance_noise_db=0.0, range_noise_m=0.0)
    grid = _grid_around_x(15.0, 1.0)
    scan = simulate_scan(slab, pose=ScanPose(position=(0, 0, 0)), preset=preset, optics=OPTICS, window=grid,
                         seed=0, progress=False)
    d = scan.pulses.direction.astype(float)
    path = thick / d[:, 0]
    expected = np.exp(-LeafAngle("spherical").G(np.arccos(d[:, 0])) * lad * path)
    gap = scan.pulses.n_echoes == 0
    # binomial standard error; rays 1 deg apart are ~9 cm apart at the slab,
    # longer than a leaf, so pulses are nearly independent
    se = np.sqrt(np.sum(expected * (1 - expected))) / len(gap)
    assert abs(gap.mean() - expected.mean()) < 3 * se, (gap.mean(), expected.mean(), se)


@pytest.fixture(scope="module")
def small_scan(tmp_path_factory):
    tree = make_tree(TreeParams(height=6.0, crown_base=1.5, crown_radius=2.0, trunk_radius=0.12,
                                total_leaf_area=10.0, n_scaffolds=4, branch_levels=2, target_distance=4.0), seed=1)
    pose = ScanPose(position=(0.5, -9.0, 1.7), yaw_deg=33.0, pitch_deg=0.6, roll_deg=-0.4)
    scan = simulate_scan(tree, pose=pose, seed=7, scan_id=3, name="small", progress=False)
    return tree, scan


def test_scan_keeps_no_return_pulses_and_materials(small_scan):
    tree, scan = small_scan
    assert np.any(scan.pulses.n_echoes == 0)
    assert np.any(scan.pulses.n_echoes > 1)
    assert int(scan.pulses.n_echoes.sum()) == len(scan)
    found = set(np.unique(scan.truth_material).tolist())
    assert {Material.LEAF, Material.BARK, Material.GROUND, Material.TARGET} <= found
    # the echo count of each point agrees with its pulse
    np.testing.assert_array_equal(scan.number_of_returns, scan.pulses.n_echoes[scan.pulse_id])
    assert np.all(scan.return_number <= scan.number_of_returns)


def _fit_cylinder_axis(xy, radius, guess):
    res = least_squares(lambda c: np.linalg.norm(xy - c, axis=1) - radius, guess)
    return res.x


def test_true_pose_puts_targets_in_place(small_scan):
    tree, scan = small_scan
    world = scan.world_xyz(scan.pose_true)
    tgt = world[scan.truth_material == Material.TARGET]
    seen = 0
    for centre in tree.targets:
        pts = tgt[np.linalg.norm(tgt - centre, axis=1) < 0.3]
        if len(pts) < 10:
            continue  # hidden behind the trunk from this position
        seen += 1
        towards = scan.pose_true[:3, 3][:2] - pts[:, :2].mean(axis=0)
        guess = pts[:, :2].mean(axis=0) - 0.5 * tree.params.target_radius * towards / np.linalg.norm(towards)
        xy = _fit_cylinder_axis(pts[:, :2], tree.params.target_radius, guess)
        est = np.r_[xy, pts[:, 2].mean()]
        assert np.linalg.norm(est - centre) < 0.01, (est, centre)
    assert seen >= 3


def test_same_seed_same_scan(small_scan):
    tree, scan = small_scan
    again = simulate_scan(tree, pose=scan.pose_true, seed=7, scan_id=3, name="small", progress=False)
    np.testing.assert_array_equal(again.xyz, scan.xyz)
    np.testing.assert_array_equal(again.reflectance_db, scan.reflectance_db)


def test_las_round_trip_keeps_every_field(small_scan, tmp_path):
    _, scan = small_scan
    path = scan.write(tmp_path / "small.laz")
    back = Scan.read(path)
    np.testing.assert_allclose(back.xyz, scan.xyz, atol=0.6e-4)  # 0.1 mm LAS scale
    for name in ("reflectance_db", "pulse_id", "truth_material", "return_number", "number_of_returns"):
        np.testing.assert_array_equal(getattr(back, name), getattr(scan, name), err_msg=name)
    np.testing.assert_array_equal(back.pose_true, scan.pose_true)
    assert back.scan_id == scan.scan_id and back.name == scan.name
    np.testing.assert_array_equal(back.pulses.direction, scan.pulses.direction)
    np.testing.assert_array_equal(back.pulses.n_echoes, scan.pulses.n_echoes)
    assert back.pulses.grid == scan.pulses.grid
    assert back.meta["preset"]["name"] == "riegl-vz400"


def test_bad_input_names_the_parameter():
    with pytest.raises(InputError, match="zenith_step_deg"):
        ScannerPreset(zenith_step_deg=-0.06)
    with pytest.raises(InputError, match="reflectance"):
        Optics(1.2)
    with pytest.raises(InputError, match="empty"):
        empty = SyntheticTree(vertices=np.zeros((0, 3)), triangles=np.zeros((0, 3), int), material=np.zeros(0, np.uint8))
        simulate_scan(empty, pose=ScanPose(), progress=False)
    tree = make_tree(TreeParams(height=6.0, crown_base=1.5, crown_radius=2.0, total_leaf_area=1.0,
                                n_scaffolds=3, branch_levels=1), seed=0)
    with pytest.raises(InputError, match="inside a trunk"):
        simulate_scan(tree, pose=ScanPose(position=(0.0, 0.0, 1.0)), progress=False)
    with pytest.raises(InputError, match="n_subrays"):
        ScannerPreset(n_subrays=5)
