"""tlsvox.pipeline.scene_from_scans: scans of a synthetic tree -> a georeferenced scene, in one call."""

from __future__ import annotations

import numpy as np
import pytest

from tlsvox.errors import InputError
from tlsvox.pipeline import scene_from_scans
from tlsvox.register import pose_error


@pytest.fixture(scope="module")
def tree_and_scans():
    from tlsvox.truth.scanner import ScannerPreset, paper_scan_poses, simulate_scan
    from tlsvox.truth.synthetic import TreeParams, make_tree

    tree = make_tree(TreeParams(height=8.0, crown_base=2.0, crown_radius=3.0, total_leaf_area=60.0,
                                trunk_radius=0.15, leaf_angle="uniform"), seed=3)
    preset = ScannerPreset.riegl_vz400(zenith_step_deg=0.12, azimuth_step_deg=0.12)
    scans = [simulate_scan(tree, pose=p, preset=preset, seed=2 + i, scan_id=i, name=f"s{i}", progress=False)
             for i, p in enumerate(paper_scan_poses(tree))]
    return tree, scans


@pytest.fixture(scope="module")
def pipeline_result(tree_and_scans):
    return scene_from_scans(tree_and_scans[1], voxel_size=0.2, progress=False)


def test_pipeline_registers_georeferences_and_voxelises(tree_and_scans, pipeline_result):
    from tlsvox.voxel.stages import voxelize

    tree, scans = tree_and_scans
    res = pipeline_result
    # registration: the second scan's pose against its true pose (known transform);
    # the reference scan takes its true pose (georeference="true")
    assert np.array_equal(scans[0].pose, scans[0].pose_true)
    rot_deg, trans_m = pose_error(scans[1].pose, scans[1].pose_true)
    assert rot_deg < 0.2 and trans_m < 0.03, (rot_deg, trans_m)
    # the scene sits in the world frame: its grid holds (nearly) all of the true leaf area
    sc = res.scene
    inside = tree.leaf_area_per_voxel(origin=sc.origin, voxel_size=sc.voxel_size, shape=sc.shape).sum()
    assert inside > 0.99 * tree.params.total_leaf_area, inside
    # the one call adds nothing and loses nothing: voxelize with the same poses and classes
    direct = voxelize(scans, voxel_size=0.2, classes=[c.labels for c in res.classifications],
                      class_codes="pointclass", leaf_angle="uniform", leaf_azimuth="outward", estimator="bcmle",
                      progress=False)
    assert np.array_equal(direct.lad.lad, res.voxelized.lad.lad)
    assert set(res.timings) == {"register", "classify", "voxelize", "qsm"}
    summary = res.summary()
    assert len(summary["registration"]) == 2 and len(summary["classification"]) == 2


def test_pipeline_fits_the_trunk_and_fills_it_solid(tree_and_scans, pipeline_result):
    # the trunk's fitted cylinders against the tree's own: the mesh's trunk is an octagonal prism, so its
    # surface lies between the inscribed radius r cos(22.5 deg) and r; a fit to it must too (range noise and
    # registration error, a few mm, average out over thousands of echoes), its axis within that band's
    # width (r (1 - cos 22.5 deg) = 1.1 cm here) of the true axis, along it within 2 degrees
    from tlsvox.voxel.wood.solid import cylinder_cells

    tree, scans = tree_and_scans
    res = pipeline_result
    true = tree.cylinders[0]  # the trunk, 0 .. crown_base, upright
    r, top = true[6], true[5]
    cyl = res.cylinders.cylinders
    mid = 0.5 * (cyl[:, :3] + cyl[:, 3:6])
    trunk = (mid[:, 2] < top - 0.3) & (np.hypot(mid[:, 0], mid[:, 1]) < r)
    assert trunk.sum() >= 2
    band = r * (1 - np.cos(np.pi / 8))
    assert np.all((cyl[trunk, 6] > r - band) & (cyl[trunk, 6] <= r)), cyl[trunk, 6]
    for c in cyl[trunk]:
        u = (c[3:6] - c[:3]) / np.linalg.norm(c[3:6] - c[:3])
        assert np.degrees(np.arccos(abs(u[2]))) < 2.0
        assert np.hypot(*mid[trunk][0, :2]) < band
    assert cyl[trunk][:, [2, 5]].min() < 0.3 and cyl[trunk][:, [2, 5]].max() > top - 0.3
    # the scene's solid voxels hold the fitted cylinders' cells, and the scene without them is the turbid one
    sc = res.scene
    assert sc.wood_solid.sum() == res.scene.meta["qsm"]["solid_voxels"] > 0
    flat, _, _ = cylinder_cells(cyl[cyl[:, 6] >= 0.1], origin=sc.origin, voxel_size=0.2, shape=sc.shape)
    assert np.array_equal(np.sort(np.ravel_multi_index(sc.ijk[sc.wood_solid].T, sc.shape)), flat)
    assert not np.any(res.voxelized.scene.wood_solid)


@pytest.mark.slow
def test_pipeline_without_qsm_keeps_the_turbid_wood(tree_and_scans, pipeline_result):
    plain = scene_from_scans(tree_and_scans[1], voxel_size=0.2, progress=False, qsm=False)
    assert plain.cylinders is None and "qsm" not in plain.timings
    assert not np.any(plain.scene.wood_solid)
    # the classifier's labels, as they were: the qsm run moved only leaf echoes to wood, and counted them
    from tlsvox.classify import PointClass

    for a, b in zip(plain.classifications, pipeline_result.classifications):
        moved = a.labels != b.labels
        assert a.on_cylinders == 0 and moved.sum() == b.on_cylinders > 0
        assert np.all(a.labels[moved] == PointClass.LEAF) and np.all(b.labels[moved] == PointClass.WOOD)


def test_pipeline_relabels_bark_on_the_fitted_cylinders(tree_and_scans, pipeline_result):
    # leaf-classed echoes on a fitted cylinder's bark are relabelled wood: against the scans' truth
    # materials, what moved is mostly bark. Moving an echo lowers the leaf area's bias when it is bark
    # more often than leaf (break-even 50 %); the band of 3 sigma (5-20 mm) around a branch holds few
    # leaves, so at least three in four must be bark. The leaf class's precision rises, its recall stays
    from tlsvox.classify import PointClass, score
    from voxlidar.materials import Material

    _, scans = tree_and_scans
    moved_bark = moved = 0
    for c in pipeline_result.classifications:
        assert c.counts["leaf"] == int(np.count_nonzero(c.labels == PointClass.LEAF))
    plain = _classifier_labels(scans)
    for s, before, c in zip(scans, plain, pipeline_result.classifications):
        m = (before == PointClass.LEAF) & (c.labels == PointClass.WOOD)
        moved += int(m.sum())
        moved_bark += int(np.count_nonzero(s.truth_material[m] == Material.BARK))
        old, new = score(before, s.truth_material), score(c.labels, s.truth_material)
        assert new.precision["leaf"] > old.precision["leaf"]
        assert new.recall["leaf"] > old.recall["leaf"] - 0.005  # the few leaves within 3 sigma of a branch
        assert new.recall["wood"] > old.recall["wood"]
    assert moved > 100 and moved_bark / moved > 0.75, (moved_bark, moved)


def _classifier_labels(scans):
    from tlsvox.classify import classify_scan

    return [classify_scan(s, refine=True).labels for s in scans]  # as scene_from_scans classifies


def test_pipeline_refuses_what_it_cannot_do(tree_and_scans):
    _, scans = tree_and_scans
    with pytest.raises(InputError, match="empty"):
        scene_from_scans([])
    with pytest.raises(InputError, match="georeference"):
        scene_from_scans(scans, georeference="gnss")


def test_calibrated_fill_with_one_scan_is_refused_before_any_work():
    """Said at entry, before registration, classification and the cylinder fit run."""
    with pytest.raises(InputError, match="two or more scans, got 1"):
        scene_from_scans([object()], voxelize_kwargs={"fill": "calibrated"})
