"""LAD estimated on a coarser grid and put on the fine one (``voxelize(lad_voxel_size=...)``)."""

from __future__ import annotations

import json

import numpy as np
import pytest

from tests.tlsvox.voxel.test_voxlad import BOX_HI, BOX_LO, LAD, box_scans  # noqa: F401  (fixture)
from tlsvox.errors import InputError
from tlsvox.voxel.coarse import _cap, opaque_lad, ratio_of
from tlsvox.voxel.plan import MemoryPlan
from tlsvox.voxel.stages import voxelize

KW = dict(leaf_angle="spherical", ground=None, progress=False, bounds=[BOX_LO, BOX_HI])


def _parent_area(scene, k):
    """Leaf area (m2) per coarse voxel key, from a fine scene."""
    parent = scene.ijk // k
    keys, inv = np.unique(np.ravel_multi_index(parent.T, tuple(-(-np.array(scene.shape) // k))),
                          return_inverse=True)
    return keys, np.bincount(inv, weights=scene.lad * scene.voxel_size**3)


def test_ratio_must_be_a_whole_multiple():
    assert ratio_of(0.02, 0.1) == 5 and ratio_of(0.05, 0.2) == 4
    for bad in (0.03, 0.02, 0.01, -0.1, float("nan")):
        with pytest.raises(InputError, match="lad_voxel_size"):
            ratio_of(0.02, bad)


def test_even_placement_keeps_the_coarse_estimate(box_scans):  # noqa: F811
    # 0.1 m voxels with n_min = 12 leave about half the box occluded, so the fine estimate alone loses
    # leaf area; estimated on 0.5 m voxels (every one seen) and put on the 0.1 m grid, each fine voxel
    # holds its coarse voxel's LAD and the box's leaf area is the coarse run's: the truth within 2 of
    # its standard errors
    fine_only = voxelize(box_scans, voxel_size=0.1, n_min=12, **KW)
    res = voxelize(box_scans, voxel_size=0.1, n_min=12, lad_voxel_size=0.5, **KW)
    direct = voxelize(box_scans, voxel_size=0.5, n_min=12, **KW)
    s, c = res.scene, res.coarse.scene
    assert s.voxel_size == pytest.approx(0.1) and c.voxel_size == pytest.approx(0.5)
    np.testing.assert_allclose(res.coarse.grid.lower, res.grid.lower)
    # the coarse run is the direct 0.5 m run (same grid, same beams)
    np.testing.assert_array_equal(c.ijk, direct.scene.ijk)
    np.testing.assert_array_equal(c.lad, direct.scene.lad)
    parent = np.ravel_multi_index((s.ijk // 5).T, c.shape)
    lookup = dict(zip(np.ravel_multi_index(c.ijk.T, c.shape), c.lad))
    np.testing.assert_array_equal(s.lad, [lookup[p] for p in parent])
    assert s.n_voxels == 125 * int((c.lad > 0).sum())
    area, coarse_area = s.total_leaf_area(), c.total_leaf_area()
    assert area == pytest.approx(coarse_area, rel=1e-12)
    true_area = LAD * np.prod(BOX_HI - BOX_LO)
    se = np.sqrt(np.sum(res.coarse.lad.lad_std**2)) * 0.5**3
    assert abs(area - true_area) < 2 * se, (area, true_area, se)
    assert fine_only.scene.occluded.mean() > 0.3
    assert fine_only.scene.total_leaf_area() < true_area - 3 * se  # what the fine grid alone gives
    meta = s.meta["lad_voxel_size"]
    assert meta["size"] == pytest.approx(0.5) and meta["ratio"] == 5 and meta["placement"] == "even"
    assert meta["leaf_area_fine"] == pytest.approx(meta["leaf_area_coarse"], rel=1e-12)
    assert s.leaf_angle.kind.value == "spherical"


def test_echo_placement_keeps_each_coarse_voxels_area(box_scans):  # noqa: F811
    res = voxelize(box_scans, voxel_size=0.1, n_min=12, lad_voxel_size=0.5, lad_placement="echoes", **KW)
    s, c = res.scene, res.coarse.scene
    keys, area = _parent_area(s, 5)
    ckeys = np.ravel_multi_index(c.ijk.T, c.shape)
    has = c.lad > 0
    np.testing.assert_array_equal(keys, np.sort(ckeys[has]))
    order = np.argsort(ckeys[has])
    np.testing.assert_allclose(area, (c.lad[has] * 0.5**3)[order], rtol=1e-9)
    # leaf area only where the fine run has leaf echoes (every coarse voxel of the box holds some)
    leaf_w = res.stats.field("leaf_w")
    held = leaf_w[tuple(s.ijk.T)] > 0 if not res.stats.sparse else None
    if held is not None:
        assert held.all()
    assert np.all(s.lad <= opaque_lad(0.1) + 1e-9)
    assert s.meta["lad_voxel_size"]["placement"] == "echoes"


def test_cap_moves_the_excess_to_siblings_and_keeps_the_sum():
    lad = np.array([30.0, 5.0, 5.0, 12.0, 11.0, 1.0])
    group = np.array([0, 0, 0, 1, 1, 2])
    out, left = _cap(lad, group, 3, 10.0)
    assert np.all(out <= 10.0 + 1e-12)
    np.testing.assert_allclose(np.bincount(group, weights=out) + left, np.bincount(group, weights=lad))
    # group 0: 20 over the cap, siblings take 5 each up to the cap, 10 left over; group 1: both at the cap
    np.testing.assert_allclose(out, [10.0, 10.0, 10.0, 10.0, 10.0, 1.0])
    np.testing.assert_allclose(left, [10.0, 3.0, 0.0])


def test_bad_options_are_one_line_errors(box_scans):  # noqa: F811
    with pytest.raises(InputError, match="whole multiple"):
        voxelize(box_scans, voxel_size=0.2, lad_voxel_size=0.5, **KW)
    with pytest.raises(InputError, match="lad_placement='nearest'"):
        voxelize(box_scans, voxel_size=0.25, lad_voxel_size=0.5, lad_placement="nearest", **KW)
    with pytest.raises(InputError, match="needs lad_voxel_size"):
        voxelize(box_scans, voxel_size=0.25, lad_placement="echoes", **KW)
    with pytest.raises(InputError, match="must be a number"):
        ratio_of(0.1, "ten")
    # a generator of scans serves both runs
    res = voxelize((s for s in box_scans), voxel_size=0.25, lad_voxel_size=0.5, **KW)
    assert res.scene.total_leaf_area() > 0


def test_plan_only_gives_the_larger_runs_plan(box_scans):  # noqa: F811
    plan = voxelize(box_scans, voxel_size=0.1, lad_voxel_size=0.3, plan_only=True, **KW)
    coarse = voxelize(box_scans, voxel_size=0.3, plan_only=True, **KW)
    cg = coarse.grid
    fine = voxelize(box_scans, voxel_size=0.1, plan_only=True, **{**KW, "bounds": [cg.lower, cg.upper]})
    assert isinstance(plan, MemoryPlan) and fine.grid.shape == tuple(3 * n for n in cg.shape)
    assert plan.need == max(coarse.need, fine.need)
    # the plan names the grid the run writes, not only the larger run's (issue 37: "a grid of 0.1 m")
    text = plan.describe()
    assert text.startswith(f"the scene's grid {' x '.join(map(str, fine.grid.shape))} of 0.1 m")
    assert f"LAD estimated on {' x '.join(map(str, cg.shape))} of 0.3 m" in text


@pytest.mark.parametrize("placement", ["even", "echoes"])
def test_coarse_voxels_past_the_bounds_are_kept_whole(box_scans, placement):  # noqa: F811
    # 0.3 m voxels do not divide the 2 m box: the coarse grid ends past it, and the fine grid covers
    # its voxels whole, so the fine scene holds exactly the coarse run's leaf area, one row per voxel,
    # and the coarse run's occluded voxels (k^3 fine ones each, evenly placed)
    res = voxelize(box_scans, voxel_size=0.1, lad_voxel_size=0.3, lad_placement=placement, n_min=96, **KW)
    s, c = res.scene, res.coarse.scene
    assert res.grid.shape == tuple(3 * n for n in res.coarse.grid.shape)
    np.testing.assert_allclose(res.grid.upper, res.coarse.grid.upper)
    assert s.total_leaf_area() == pytest.approx(c.total_leaf_area(), rel=1e-12)
    assert len(np.unique(res.grid.flat(s.ijk))) == s.n_voxels
    assert c.occluded.any()
    if placement == "even":
        assert int(s.occluded.sum()) == 27 * int(c.occluded.sum())


def test_echo_placement_caps_and_merges(box_scans, monkeypatch):  # noqa: F811
    # a cap far below the box's LAD forces every path of the cap: excess to siblings, then the rest of a
    # fully capped coarse voxel spread over all its children (some of which hold echoes): one row per
    # voxel, the coarse voxel's leaf area kept
    import tlsvox.voxel.coarse as coarse

    monkeypatch.setattr(coarse, "opaque_lad", lambda h: 1.0)
    res = voxelize(box_scans, voxel_size=0.1, lad_voxel_size=0.5, lad_placement="echoes", **KW)
    s = res.scene
    assert s.meta["lad_voxel_size"]["opaque_spread"] > 0
    assert len(np.unique(res.grid.flat(s.ijk))) == s.n_voxels
    assert s.total_leaf_area() == pytest.approx(res.coarse.scene.total_leaf_area(), rel=1e-9)


def test_cli_lad_voxel_size(box_scans, tmp_path, capsys):  # noqa: F811
    from tlsvox.cli.app import main as tlsvox_main
    from voxlidar.scene import Scene

    paths = []
    for s in box_scans:
        paths.append(str(tmp_path / f"{s.name}.laz"))
        s.write(paths[-1])
    common = ["voxelize", *paths, "--voxel-size", "0.1", "--ground", "none", "--leaf-angle", "spherical",
              "--bounds=" + ",".join(str(v) for v in [*BOX_LO, *BOX_HI])]
    assert tlsvox_main([*common, "-o", str(tmp_path / "a.npz"), "--lad-voxel-size", "0.5"]) == 0
    summary = json.loads(capsys.readouterr().out)
    assert summary["lad_voxel_size"]["size"] == pytest.approx(0.5)
    assert summary["lad_voxel_size"]["placement"] == "even"
    assert "coarse grid" in summary["lad_voxel_size"]["flags"]  # the summary's flags are the coarse voxels'
    scene = Scene.load(tmp_path / "a.npz")
    assert scene.voxel_size == pytest.approx(0.1) and scene.meta["lad_voxel_size"]["ratio"] == 5
    assert tlsvox_main([*common, "-o", str(tmp_path / "b.npz"), "--lad-voxel-size", "0.25"]) == 2
    assert "whole multiple" in capsys.readouterr().err
    assert tlsvox_main([*common, "-o", str(tmp_path / "c.npz"), "--lad-placement", "echoes"]) == 2
    assert "needs --lad-voxel-size" in capsys.readouterr().err
    assert not (tmp_path / "b.npz").exists() and not (tmp_path / "c.npz").exists()


def test_voxels_narrower_than_two_leaves_warn_with_the_fix(box_scans):  # noqa: F811
    small = voxelize(box_scans, voxel_size=0.05, **KW)
    said = [w for w in small.scene.meta["warnings"] if "narrower than two leaves" in w]
    assert len(said) == 1 and "lad_voxel_size=0.1" in said[0] and "--lad-voxel-size 0.1" in said[0]
    fixed = voxelize(box_scans, voxel_size=0.05, lad_voxel_size=0.25, **KW)
    assert not any("narrower than two leaves" in w for w in fixed.scene.meta["warnings"])
    assert not any("narrower" in w for w in voxelize(box_scans, voxel_size=0.1, **KW).scene.meta["warnings"])
    assert not any("narrower" in w for w in voxelize(box_scans, voxel_size=0.05, leaf_size=None,
                                                     **KW).scene.meta["warnings"])
