"""tlsvox.voxel.wood.qsm: cylinders fitted to wood echoes, and the solid wood voxels they fill."""

from __future__ import annotations

import numpy as np
import pytest

from tlsvox.errors import InputError
from tlsvox.voxel.wood.qsm import CylinderModel, apply_cylinders, fit_cylinders
from tlsvox.voxel.wood.solid import cylinder_cells


def cylinder_points(a, b, r, n, rng, *, noise=0.003, arc=(0.0, 2 * np.pi)):
    """``n`` points on the side of the cylinder a-b (radius r) within the arc, with Gaussian noise."""
    from tlsvox.truth._mesh import orthonormal

    a, b = np.asarray(a, float), np.asarray(b, float)
    d = (b - a) / np.linalg.norm(b - a)
    e1, e2 = (v[0] for v in orthonormal(d[None]))
    phi = rng.uniform(*arc, n)
    t = rng.uniform(0, 1, n)
    p = a + t[:, None] * (b - a) + r * (np.cos(phi)[:, None] * e1 + np.sin(phi)[:, None] * e2)
    return p + rng.normal(0, noise, p.shape)


def test_half_seen_tilted_cylinder_is_recovered():
    # a scanner sees half of a trunk: 3 mm range noise, 4000 points on 2 m. The fit's standard error is
    # about noise * sqrt(2 / n) (0.07 mm); 1 mm (a third of the noise) fails a biased fit, not the noise
    rng = np.random.default_rng(1)
    a, b, r = np.array([1.0, 2.0, 0.0]), np.array([1.3, 2.1, 2.0]), 0.18
    m = fit_cylinders(cylinder_points(a, b, r, 4000, rng, arc=(0.3, 0.3 + np.pi)))
    assert len(m) >= 2
    assert np.all(np.abs(m.cylinders[:, 6] - r) < 1e-3), m.cylinders[:, 6]
    u = (b - a) / np.linalg.norm(b - a)
    for c in m.cylinders:
        v = (c[3:6] - c[:3]) / np.linalg.norm(c[3:6] - c[:3])
        assert np.degrees(np.arccos(abs(u @ v))) < 1.0
        for end in (c[:3], c[3:6]):  # on the true axis
            x = end - a
            assert np.linalg.norm(x - (x @ u) * u) < 2e-3
    # the pieces span the stem from end to end (within a slice)
    t = np.concatenate([(m.cylinders[:, :3] - a) @ u, (m.cylinders[:, 3:6] - a) @ u])
    assert t.min() < 0.2 and t.max() > np.linalg.norm(b - a) - 0.2


def test_fork_both_branches_and_no_cylinder_in_a_leaf_clump():
    rng = np.random.default_rng(2)
    stem = cylinder_points([0, 0, 0], [0, 0, 3], 0.15, 6000, rng)
    branch = cylinder_points([0, 0, 2.0], [1.5, 0, 3.5], 0.07, 3000, rng)
    clump = rng.normal([-1.5, 1.5, 3.0], 0.25, (1500, 3))  # leaf echoes taken for wood
    m = fit_cylinders(np.vstack([stem, branch, clump]))
    mid = 0.5 * (m.cylinders[:, :3] + m.cylinders[:, 3:6])
    on_stem = np.hypot(mid[:, 0], mid[:, 1]) < 0.05
    d = np.array([1.0, 0, 1.0]) / np.sqrt(2)
    x = mid - [0, 0, 2.0]
    on_branch = (np.linalg.norm(x - (x @ d)[:, None] * d, axis=1) < 0.05) & ~on_stem
    assert on_stem.sum() >= 3 and on_branch.sum() >= 2
    assert np.all(np.abs(m.cylinders[on_stem, 6] - 0.15) < 3e-3)
    assert np.all(np.abs(m.cylinders[on_branch, 6] - 0.07) < 3e-3)
    assert not np.any(np.linalg.norm(mid - [-1.5, 1.5, 3.0], axis=1) < 1.0)  # nothing in the clump
    assert on_stem.sum() + on_branch.sum() == len(m)


def test_fit_refuses_bad_options_and_takes_too_few_points():
    with pytest.raises(InputError, match="spacing"):
        fit_cylinders(np.zeros((100, 3)), spacing=0)
    with pytest.raises(InputError, match="link"):
        fit_cylinders(np.zeros((100, 3)), spacing=0.05, link=0.05)
    with pytest.raises(InputError, match="NaN"):
        fit_cylinders(np.full((100, 3), np.nan))
    assert len(fit_cylinders(np.zeros((3, 3)))) == 0


def test_apply_fills_solid_cells_drops_explained_bark_and_keeps_the_rest():
    from voxlidar.scene import Scene

    h, shape = 0.1, (20, 20, 30)
    origin = np.zeros(3)
    cyl = np.array([[1.0, 1.0, 0.5, 1.0, 1.0, 1.5, 0.25], [1.0, 1.0, 1.5, 1.0, 1.0, 2.5, 0.25]])  # stacked pieces
    model = CylinderModel(cyl, np.array([100, 100]), np.array([0.004, 0.004]), np.array([180.0, 180.0]),
                          np.array([0, 0]))
    rng = np.random.default_rng(3)
    bark = cylinder_points(cyl[0, :3], cyl[1, 3:6], 0.25, 4000, rng, noise=0.002)
    twig = np.array([1.15, 1.25, 1.05]) + rng.normal(0, 0.005, (50, 3))  # something else, 4 cm off the surface
    wood = np.vstack([bark, twig])
    # the turbid scene: wood in every voxel holding a wood echo
    ijk = np.unique(np.floor(wood / h).astype(int), axis=0)
    scene = Scene(origin=origin, voxel_size=h, shape=shape, ijk=ijk, lad=np.zeros(len(ijk)),
                  wood=np.full(len(ijk), 0.5))
    out, info = apply_cylinders(scene, model, wood)
    flat, axis, _ = cylinder_cells(cyl, origin=origin, voxel_size=h, shape=shape)
    keys = np.ravel_multi_index(out.ijk.T, shape)
    assert np.array_equal(np.sort(keys[out.wood_solid]), flat)
    assert info["solid_voxels"] == len(flat) and info["new_voxels"] > 0
    assert np.allclose(out.wood_axis[out.wood_solid], [0, 0, 1])
    # the caps: at the top and bottom ends only, none at the joint of the two pieces
    z = out.ijk[out.wood_solid, 2]
    cap = out.wood_cap[out.wood_solid]
    assert cap[z == 5].mean() > 0.2 and cap[z == 24].mean() > 0.2
    assert np.all(cap[(z >= 12) & (z <= 17)] < 1e-12)  # side normals only (rounding)
    # the bark beside the core: every echo explained -> no turbid wood left; the twig's voxel keeps its share
    twig_key = np.ravel_multi_index(tuple(np.floor(twig[0] / h).astype(int)), shape)
    row = np.flatnonzero(keys == twig_key)[0]
    assert not out.wood_solid[row] and 0.0 < out.wood[row] < 0.5  # its bark echoes explained, the twig not
    shell = ~out.wood_solid & (keys != twig_key) & np.isin(keys, np.ravel_multi_index(ijk.T, shape))
    assert np.all(out.wood[shell] == 0.0)
    assert np.array_equal(scene.wood, np.full(len(ijk), 0.5))  # the input is not changed
    # thinner than half a voxel: nothing to fill
    thin = CylinderModel(cyl * [1, 1, 1, 1, 1, 1, 0.1], model.support, model.sigma, model.coverage_deg, model.chain)
    same, info = apply_cylinders(scene, thin, wood)
    assert same is scene and info["solid_voxels"] == 0


def test_cli_voxelize_qsm_fills_the_scanned_trunk(tmp_path, capsys):
    # one scan of a bare upright trunk (its near half, bark by truth material): with --qsm the trunk's
    # cells are solid wood, and the summary says what was fitted; without it, none are
    import json

    from tlsvox.cli.app import main as tlsvox_main
    from tlsvox.scan import PulseTable, Scan
    from voxlidar.materials import Material
    from voxlidar.scene import Scene

    rng = np.random.default_rng(4)
    axis_xy, r = np.array([3.0, 0.0]), 0.2
    phi = rng.uniform(0.55 * np.pi, 1.45 * np.pi, 20000)  # the side facing a scanner at the origin
    z = rng.uniform(0.5, 2.5, len(phi))
    pts = np.column_stack([axis_xy[0] + r * np.cos(phi), r * np.sin(phi), z - 1.5])  # scanner frame: 1.5 m up
    pts += rng.normal(0, 0.002, pts.shape)
    miss = rng.normal(size=(2000, 3))
    miss[:, 2] = np.abs(miss[:, 2]) + 0.5
    d = np.vstack([pts / np.linalg.norm(pts, axis=1, keepdims=True), miss / np.linalg.norm(miss, axis=1,
                                                                                               keepdims=True)])
    pose = np.eye(4)
    pose[2, 3] = 1.5
    scan = Scan(xyz=pts, pulse_id=np.arange(len(pts)), truth_material=np.full(len(pts), Material.BARK),
                pose=pose, pulses=PulseTable(d, np.r_[np.ones(len(pts), int), np.zeros(len(miss), int)]))
    scan.write(tmp_path / "trunk.laz")
    common = ["voxelize", str(tmp_path / "trunk.laz"), "--voxel-size", "0.1", "--ground", "none"]
    assert tlsvox_main([*common, "-o", str(tmp_path / "solid.npz"), "--qsm"]) == 0
    summary = json.loads(capsys.readouterr().out)
    assert tlsvox_main([*common, "-o", str(tmp_path / "turbid.npz"), "-q"]) == 0
    solid, turbid = Scene.load(tmp_path / "solid.npz"), Scene.load(tmp_path / "turbid.npz")
    truth = np.array([[3.0, 0.0, 0.5, 3.0, 0.0, 2.5, r]])
    flat, _, _ = cylinder_cells(truth, origin=solid.origin, voxel_size=0.1, shape=solid.shape)
    got = np.ravel_multi_index(solid.ijk[solid.wood_solid].T, solid.shape)
    # the fitted trunk's cells against the true trunk's: only cells whose centre lies within 5 mm of the
    # true surface (sides or ends) may differ (the fit's radius, axis and ends err by far less: 20,000
    # points with 2 mm noise)
    ijk = np.argwhere(np.ones(solid.shape, bool))
    c = solid.origin + (ijk + 0.5) * 0.1
    rho = np.hypot(c[:, 0] - 3.0, c[:, 1])
    edge = ((np.abs(rho - r) < 0.005) & (c[:, 2] > 0.495) & (c[:, 2] < 2.505)) | (
        (rho < r + 0.005) & ((np.abs(c[:, 2] - 0.5) < 0.005) | (np.abs(c[:, 2] - 2.5) < 0.005)))
    differ = np.setxor1d(got, flat)
    assert np.all(np.isin(differ, np.ravel_multi_index(ijk[edge].T, solid.shape))), len(differ)
    assert len(flat) > 100
    assert not np.any(turbid.wood_solid)
    assert solid.meta["qsm"]["cylinders"] >= 1 and summary["qsm"]["solid_voxels"] == len(got)


def test_cli_qsm_relabels_leaf_echoes_on_the_bark_in_memory_only(tmp_path, capsys):
    # a classified scan of a bare trunk in which one echo in five is labelled leaf (bark the classifier
    # missed) and a clump of leaf echoes 30 cm off the trunk: with --qsm the trunk's leaf-labelled echoes
    # count as wood (all of them up to the tail of the range noise: they lie on its surface) and the clump's do
    # not; --qsm-keep-labels keeps them; the file's labels are never changed
    import json

    from tlsvox.classify import PointClass
    from tlsvox.cli.app import main as tlsvox_main
    from tlsvox.scan import CLASSIFY_MARK, PulseTable, Scan

    rng = np.random.default_rng(5)
    r = 0.2
    phi = rng.uniform(0.55 * np.pi, 1.45 * np.pi, 20000)
    z = rng.uniform(0.5, 2.5, len(phi))
    trunk = np.column_stack([3.0 + r * np.cos(phi), r * np.sin(phi), z - 1.5])
    trunk += rng.normal(0, 0.002, trunk.shape)
    clump = np.array([2.5, 0.0, 0.0]) + rng.normal(0, 0.03, (500, 3))
    # leaves 3-5 cm off the bark, on the scanner's side (well outside the 1 cm band): they stay leaves
    phi2 = rng.uniform(0.8 * np.pi, 1.2 * np.pi, 300)
    rho2 = r + rng.uniform(0.03, 0.05, len(phi2))
    near = np.column_stack([3.0 + rho2 * np.cos(phi2), rho2 * np.sin(phi2), rng.uniform(-0.8, 0.8, len(phi2))])
    pts = np.vstack([trunk, clump, near])
    labels = np.full(len(pts), PointClass.WOOD, np.uint8)
    missed = rng.random(len(trunk)) < 0.2
    labels[:len(trunk)][missed] = PointClass.LEAF
    labels[len(trunk):] = PointClass.LEAF
    d = pts / np.linalg.norm(pts, axis=1, keepdims=True)
    pose = np.eye(4)
    pose[2, 3] = 1.5
    scan = Scan(xyz=pts, pulse_id=np.arange(len(pts)), classification=labels, pose=pose,
                pulses=PulseTable(d, np.ones(len(pts), int)), meta={"classes": CLASSIFY_MARK})
    scan.write(tmp_path / "trunk.laz")
    common = ["voxelize", str(tmp_path / "trunk.laz"), "--voxel-size", "0.1", "--ground", "none", "--qsm"]
    assert tlsvox_main([*common, "-o", str(tmp_path / "a.npz")]) == 0
    moved = json.loads(capsys.readouterr().out)["qsm"]["leaf_echoes_relabelled_wood"]
    assert 0.995 * missed.sum() <= moved <= missed.sum()  # 1 cm is 5 sigma of the 2 mm range noise
    assert tlsvox_main([*common, "-o", str(tmp_path / "b.npz"), "--qsm-keep-labels"]) == 0
    assert json.loads(capsys.readouterr().out)["qsm"]["leaf_echoes_relabelled_wood"] == 0
    assert np.array_equal(Scan.read(tmp_path / "trunk.laz").classification, labels)
    # the relabelled echoes are wood to the estimator: the trunk's missed bark no longer makes leaf area
    from voxlidar.scene import Scene

    a, b = Scene.load(tmp_path / "a.npz"), Scene.load(tmp_path / "b.npz")
    assert a.total_leaf_area() < 0.8 * b.total_leaf_area(), (a.total_leaf_area(), b.total_leaf_area())
    # echo by echo: exactly the trunk's leaf-labelled echoes within the band, none of the clump or the near leaves
    from tlsvox.voxel.wood.qsm import bark_echoes, fit_cylinders, wood_points

    read = Scan.read(tmp_path / "trunk.laz")
    read.pose = pose
    bark = bark_echoes([read], fit_cylinders(wood_points([read])))[0]
    assert not bark[len(trunk):].any() and np.all(bark[:len(trunk)] <= missed)


def test_cli_qsm_with_no_wood_echoes_warns_and_writes(tmp_path, capsys):
    # a classified scan of leaves only: nothing to fit, nothing relabelled, the scene written with the warning
    import json

    from tlsvox.classify import PointClass
    from tlsvox.cli.app import main as tlsvox_main
    from tlsvox.scan import CLASSIFY_MARK, PulseTable, Scan
    from tlsvox.voxel.wood.qsm import bark_echoes, fit_cylinders

    pts = np.array([2.5, 0.0, 0.0]) + np.random.default_rng(6).normal(0, 0.2, (2000, 3))
    scan = Scan(xyz=pts, pulse_id=np.arange(len(pts)), classification=np.full(len(pts), PointClass.LEAF, np.uint8),
                pose=np.eye(4), pulses=PulseTable(pts / np.linalg.norm(pts, axis=1, keepdims=True),
                                                  np.ones(len(pts), int)), meta={"classes": CLASSIFY_MARK})
    empty = fit_cylinders(np.zeros((0, 3)))
    assert len(empty) == 0 and not bark_echoes([scan], empty)[0].any()
    scan.write(tmp_path / "leaves.laz")
    common = ["voxelize", str(tmp_path / "leaves.laz"), "--voxel-size", "0.2", "--ground", "none"]
    assert tlsvox_main([*common, "-o", str(tmp_path / "a.npz"), "--qsm"]) == 0
    out = capsys.readouterr()
    assert json.loads(out.out)["qsm"]["leaf_echoes_relabelled_wood"] == 0 and "no wood echoes" in out.err
    assert tlsvox_main([*common, "-o", str(tmp_path / "b.npz"), "--qsm-keep-labels"]) == 2
    assert "needs --qsm" in capsys.readouterr().err


def test_owner_matches_the_direct_test_of_every_cylinder():
    # owner() looks each cylinder up in a slice of the points sorted by x: the same first owner as testing
    # every point against every cylinder (ends overshot by the tolerance, thin and thick, tilted cylinders)
    rng = np.random.default_rng(8)
    n = 40
    a = rng.uniform(-1, 1, (n, 3))
    d = rng.normal(size=(n, 3))
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    b = a + d * rng.uniform(0.1, 0.6, (n, 1))
    cyl = np.hstack([a, b, rng.uniform(0.01, 0.2, (n, 1))])
    model = CylinderModel(cyl, np.full(n, 50), rng.uniform(0.001, 0.01, n), np.full(n, 180.0), np.arange(n))
    pts = rng.uniform(-1.3, 1.3, (200_000, 3))
    for kw in ({}, {"surface": True, "floor": 0.01}, {"tolerance": 0.05}):
        want = np.full(len(pts), -1)
        for i, (c, s) in enumerate(zip(cyl, model.sigma)):
            tol = kw.get("tolerance", max(3 * s, kw.get("floor", 0.02)))
            length = np.linalg.norm(c[3:6] - c[:3])
            u = (c[3:6] - c[:3]) / length
            x = pts - c[:3]
            t = x @ u
            rad = np.linalg.norm(x - t[:, None] * u, axis=1)
            hit = (t > -tol) & (t < length + tol) & (rad < c[6] + tol) & (want < 0)
            if kw.get("surface"):
                hit &= rad > c[6] - tol
            want[hit] = i
        got = model.owner(pts, **kw)
        assert (want >= 0).sum() > 1000 and np.array_equal(got, want)
    assert np.array_equal(model.explained(pts), model.owner(pts) >= 0)
