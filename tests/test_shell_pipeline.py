"""The documented shell pipeline connects: what `tlsvox classify` writes, `tlsvox voxelize` reads."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from tlsvox.cli.app import main as tlsvox_main


@pytest.fixture(scope="module")
def scanned_box(tmp_path_factory):
    pytest.importorskip("open3d")
    from tlsvox.truth.scanner import ScannerPreset, ScanPose, simulate_scan
    from tlsvox.truth.synthetic import make_leaf_slab

    d = tmp_path_factory.mktemp("box")
    box = make_leaf_slab(lad=1.0, size=(1.0, 1.0, 1.0), origin=(-0.5, -0.5, 1.0), seed=3)
    preset = ScannerPreset.riegl_vz400(zenith_step_deg=0.5, azimuth_step_deg=0.5, n_subrays=1)
    for i, x in enumerate((-5.0, 5.0)):
        scan = simulate_scan(box, pose=ScanPose(position=(x, 0.0, 1.7), yaw_deg=0.0 if x < 0 else 180.0),
                             preset=preset, seed=i, scan_id=i + 1, progress=False)
        scan.pose = scan.pose_true
        scan.write(d / f"s{i + 1}.laz")
    return d, box


def test_classify_output_feeds_voxelize(scanned_box, tmp_path):
    from tlsvox.scan import Scan
    from voxlidar.scene import Scene

    d, box = scanned_box
    cls = tmp_path / "cls"
    assert tlsvox_main(["classify", str(d / "s1.laz"), str(d / "s2.laz"), "-o", str(cls), "--no-ground"]) == 0
    c1 = Scan.read(cls / "s1.classified.laz")
    assert c1.classification is not None and c1.pulses is not None and c1.pose is not None
    args = ["--voxel-size", "0.5", "--ground", "none", "-q", "--bounds=-1,-1,0.5,1,1,2.5"]
    assert tlsvox_main(["voxelize", str(cls / "s1.classified.laz"), str(cls / "s2.classified.laz"),
                        "-o", str(tmp_path / "cls.npz"), *args]) == 0
    assert tlsvox_main(["voxelize", str(d / "s1.laz"), str(d / "s2.laz"), "-o", str(tmp_path / "truth.npz"),
                        *args]) == 0
    by_class = Scene.load(tmp_path / "cls.npz").total_leaf_area()
    by_truth = Scene.load(tmp_path / "truth.npz").total_leaf_area()
    assert by_truth == pytest.approx(box.leaf_area(), rel=0.35)  # the synthetic truth labels
    assert by_class > 0
    # the labels in the file, not the simulated truth beside them, decide what voxelize counts:
    # the truth written as PointClass codes gives the truth's result exactly, all noise none
    codes = np.array([7, 5, 64, 2, 65], np.uint8)  # Material NONE, LEAF, BARK, GROUND, TARGET
    for label, fill in (("astruth", None), ("noise", 7)):
        for name in ("s1", "s2"):
            s = Scan.read(cls / f"{name}.classified.laz")
            lab = codes[s.truth_material] if fill is None else np.full(len(s), fill, np.uint8)
            dataclasses.replace(s, classification=lab).write(tmp_path / f"{name}.{label}.laz")
        assert tlsvox_main(["voxelize", str(tmp_path / f"s1.{label}.laz"), str(tmp_path / f"s2.{label}.laz"),
                            "-o", str(tmp_path / f"{label}.npz"), *args]) == 0
    assert Scene.load(tmp_path / "astruth.npz").total_leaf_area() == pytest.approx(by_truth, rel=1e-9)
    assert Scene.load(tmp_path / "noise.npz").total_leaf_area() == 0.0


def test_classified_scans_take_poses_from_register_transforms(scanned_box, tmp_path):
    """The README's chain: register -> classify -> voxelize --transforms.  A classified scan
    keeps its scan name, which is how the transforms file names its pose."""
    import json

    from tlsvox.scan import Scan
    from voxlidar.scene import Scene

    d, _ = scanned_box
    raw = tmp_path / "raw"
    raw.mkdir()
    poses = {}
    for name in ("s1", "s2"):  # scans as `tlsvox scan` writes them: the true pose only
        s = Scan.read(d / f"{name}.laz")
        poses[s.name] = s.pose_true.tolist()
        s.pose = None
        s.write(raw / f"{name}.laz")
    transforms = tmp_path / "merged.transforms.json"  # the shape `tlsvox register` writes
    transforms.write_text(json.dumps({"scans": [{"name": n, "pose": p} for n, p in poses.items()]}))
    cls = tmp_path / "cls"
    assert tlsvox_main(["classify", str(raw / "s1.laz"), str(raw / "s2.laz"), "-o", str(cls), "--no-ground"]) == 0
    assert Scan.read(cls / "s1.classified.laz").name in poses
    out = tmp_path / "scene.npz"
    assert tlsvox_main(["voxelize", str(cls / "s1.classified.laz"), str(cls / "s2.classified.laz"),
                        "--transforms", str(transforms), "-o", str(out), "--voxel-size", "0.5",
                        "--ground", "none", "-q", "--bounds=-1,-1,0.5,1,1,2.5"]) == 0
    assert Scene.load(out).total_leaf_area() > 0
