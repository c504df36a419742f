"""Readers: LAS/LAZ (real VZ-400i and ALS files), PLY/PCD/XYZI/PTS, and bad input."""

from __future__ import annotations

import numpy as np
import pytest

from tlsvox.errors import InputError, ScanFileError
from tlsvox.readers import ScanFormat, check_scan, read_any
from tlsvox.scan import Scan


@pytest.mark.realdata
def test_real_vz400i_scan_reads_without_reflectance(shared_data):
    path = shared_data / "tls-vz400i-scan" / "tls_scan.laz"
    scan = read_any(path)
    # documented in shared/data/README.md: 1,046,843 returns, no intensity
    assert len(scan) == 1_046_843
    assert scan.reflectance_db is None and scan.intensity is None
    assert np.all(scan.return_number >= 1)
    assert np.all(scan.return_number <= scan.number_of_returns)
    assert scan.number_of_returns.max() > 1  # a forest: multiple returns exist
    # scanner at the origin: ranges of a forest plot, metres
    r = np.linalg.norm(scan.xyz, axis=1)
    assert 0.5 < np.median(r) < 30.0
    with pytest.raises(InputError, match="neither reflectance"):
        read_any(path, require_reflectance=True)


@pytest.mark.realdata
def test_real_als_file_reads_with_intensity(shared_data):
    scan = read_any(shared_data / "als-mixedconifer" / "MixedConifer.laz", require_reflectance=True)
    assert len(scan) == 37_657
    assert scan.intensity is not None and scan.intensity.max() > 0
    ext = scan.xyz.max(axis=0) - scan.xyz.min(axis=0)
    assert 80 < ext[0] < 100 and 80 < ext[1] < 100  # a 90 x 90 m tile


def _tensor_cloud(xyz, **attrs):
    import open3d as o3d

    pc = o3d.t.geometry.PointCloud()
    pc.point.positions = o3d.core.Tensor(np.asarray(xyz, np.float64))
    for k, v in attrs.items():
        pc.point[k] = o3d.core.Tensor(np.asarray(v, np.float32).reshape(-1, 1))
    return pc


@pytest.mark.parametrize("suffix", ["ply", "pcd"])
def test_ply_pcd_keep_intensity_and_reflectance(tmp_path, rng, suffix):
    import open3d as o3d

    xyz = rng.uniform(-5, 5, (200, 3))
    inten = rng.uniform(1, 1000, 200)
    refl = rng.uniform(-15, -1, 200)
    path = tmp_path / f"a.{suffix}"
    o3d.t.io.write_point_cloud(str(path), _tensor_cloud(xyz, intensity=inten, reflectance=refl))
    scan = read_any(path)
    np.testing.assert_allclose(scan.xyz, xyz, atol=1e-6)
    np.testing.assert_allclose(scan.intensity, inten, rtol=1e-6)
    np.testing.assert_allclose(scan.reflectance_db, refl, rtol=1e-6)


@pytest.mark.parametrize("suffix", ["xyzi", "pts"])
def test_text_formats_keep_double_positions_and_intensity(tmp_path, suffix):
    xyz = np.array([[500000.123, 4100000.456, 12.789], [500001.5, 4100002.25, 13.0],
                    [500003.0, 4100001.0, 14.5]])
    inten = np.array([10.0, 20.0, 30.0])
    lines = [f"{x:.3f} {y:.3f} {z:.3f} {i:g}" for (x, y, z), i in zip(xyz, inten)]
    text = ("3\n" if suffix == "pts" else "") + "\n".join(lines) + "\n"
    path = tmp_path / f"a.{suffix}"
    path.write_text(text)
    scan = read_any(path)
    np.testing.assert_allclose(scan.xyz, xyz, atol=1e-6)  # float32 would lose the mm
    np.testing.assert_allclose(scan.intensity, inten)


def test_empty_files_fail_clearly(tmp_path):
    for name in ("e.ply", "e.laz", "e.xyz"):
        (tmp_path / name).write_bytes(b"")
        with pytest.raises(InputError, match="empty"):
            read_any(tmp_path / name)


def test_las_with_zero_points_fails(tmp_path):
    path = tmp_path / "none.las"
    Scan(xyz=np.zeros((0, 3)), name="none").write(path)
    with pytest.raises(InputError, match="no points"):
        read_any(path)


def test_nan_coordinates_fail(tmp_path):
    path = tmp_path / "n.xyz"
    path.write_text("1 2 3\n4 5 6\nnan 8 9\n")
    with pytest.raises(InputError, match="NaN"):
        read_any(path)


def test_single_point_scan_fails(tmp_path):
    path = tmp_path / "one.las"
    Scan(xyz=[[1.0, 2.0, 3.0]], reflectance_db=[-3.0], name="one").write(path)
    with pytest.raises(InputError, match="1 point"):
        read_any(path)
    with pytest.raises(InputError, match="1 point"):
        check_scan(Scan(xyz=[[0.0, 0.0, 0.0]]))


def test_las_without_reflectance_when_needed(tmp_path, rng):
    path = tmp_path / "plain.las"
    Scan(xyz=rng.normal(size=(50, 3)), name="plain").write(path)
    assert len(read_any(path)) == 50
    with pytest.raises(InputError, match="neither reflectance"):
        read_any(path, require_reflectance=True)


def test_unknown_format_and_missing_file(tmp_path):
    with pytest.raises(InputError, match="las, laz, ply"):
        read_any(tmp_path / "a.e57")
    with pytest.raises(InputError, match="las, laz, ply"):
        ScanFormat.parse("e57")
    with pytest.raises(ScanFileError):
        read_any(tmp_path / "missing.ply")


def test_files_are_read_by_content_not_by_name(tmp_path):
    """A LAS scan saved under another suffix is still read; a text file named .las is refused in one line."""
    import shutil

    from tlsvox.readers import read_any
    from tlsvox.scan import Scan
    from voxlidar.errors import InputError
    from voxlidar.safeio import file_kind

    rng = np.random.default_rng(0)
    Scan(xyz=rng.normal(size=(300, 3)), reflectance_db=rng.uniform(-20, 0, 300).astype(np.float32),
         name="s").write(tmp_path / "s.las")
    shutil.copy(tmp_path / "s.las", tmp_path / "s.dat")
    assert file_kind(tmp_path / "s.dat") == "las"
    a, b = read_any(tmp_path / "s.las"), read_any(tmp_path / "s.dat")
    assert np.array_equal(a.xyz, b.xyz)
    (tmp_path / "t.las").write_text("x y z\n1 2 3\n")
    with pytest.raises(InputError, match="is not a LAS/LAZ file: it is a text file"):
        read_any(tmp_path / "t.las")


def test_a_scene_is_read_by_content(tmp_path):
    from clsim.validation.testscenes import homogeneous_layer
    from voxlidar.errors import InputError
    from voxlidar.scene import Scene

    scene = homogeneous_layer(width=2.0, voxel_size=0.5)
    scene.save(tmp_path / "s.npz")
    (tmp_path / "s.npz").rename(tmp_path / "scene.data")
    assert Scene.load(tmp_path / "scene.data").n_voxels == scene.n_voxels
    (tmp_path / "v.npz").write_text("VOXEL SPACE\n")
    with pytest.raises(InputError, match="AMAPVox .vox file"):
        Scene.load(tmp_path / "v.npz")


def test_text_and_pcd_files_are_read_by_content(tmp_path, rng):
    """A PTS saved as .xyz, an XYZI saved as .pts and a PCD saved as .ply are read as what they hold."""
    import open3d as o3d

    from voxlidar.safeio import file_kind

    xyz = np.array([[1.5, 2.25, 3.0], [4.0, 5.0, 6.5], [7.0, 8.0, 9.25]])
    inten = np.array([10.0, 20.0, 30.0])
    rows = "\n".join(f"{x:g} {y:g} {z:g} {i:g}" for (x, y, z), i in zip(xyz, inten)) + "\n"
    (tmp_path / "a.xyz").write_text("3\n" + rows)  # really PTS
    (tmp_path / "b.pts").write_text(rows)  # really XYZI
    for name in ("a.xyz", "b.pts"):
        scan = read_any(tmp_path / name)
        np.testing.assert_allclose(scan.xyz, xyz)
        np.testing.assert_allclose(scan.intensity, inten)
    cloud = rng.uniform(-5, 5, (50, 3))
    o3d.t.io.write_point_cloud(str(tmp_path / "c.pcd"), _tensor_cloud(cloud))
    (tmp_path / "c.ply").write_bytes((tmp_path / "c.pcd").read_bytes())
    assert file_kind(tmp_path / "c.ply") == "pcd"
    np.testing.assert_allclose(read_any(tmp_path / "c.ply").xyz, cloud, atol=1e-6)
