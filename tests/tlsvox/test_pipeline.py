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


def test_pipeline_registers_georeferences_and_voxelises(tree_and_scans):
    from tlsvox.voxel.voxlad import voxelize

    tree, scans = tree_and_scans
    res = scene_from_scans(scans, voxel_size=0.2, progress=False)
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
    assert set(res.timings) == {"register", "classify", "voxelize"}
    summary = res.summary()
    assert len(summary["registration"]) == 2 and len(summary["classification"]) == 2


def test_pipeline_refuses_what_it_cannot_do(tree_and_scans):
    _, scans = tree_and_scans
    with pytest.raises(InputError, match="empty"):
        scene_from_scans([])
    with pytest.raises(InputError, match="georeference"):
        scene_from_scans(scans, georeference="gnss")
