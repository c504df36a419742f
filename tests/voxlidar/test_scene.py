"""Scene NPZ save/load and AMAPVox .vox import/export round trips."""

from __future__ import annotations

import numpy as np
import pytest

from tlsvox.errors import InputError
from tlsvox.voxel.amapvox import read_vox, write_vox
from voxlidar.leaf_orientation import LeafAngle
from voxlidar.scene import Scene


@pytest.fixture
def scene(rng):
    shape = (6, 5, 4)
    ijk = np.argwhere(rng.random(shape) < 0.4)
    m = len(ijk)
    occluded = rng.random(m) < 0.2
    lad = np.where(occluded, 0.0, rng.gamma(2.0, 0.7, m))
    lad[occluded & (rng.random(m) < 0.5)] = 0.9  # some occluded voxels filled
    return Scene(origin=(10.2, -3.4, 0.6), voxel_size=0.2, shape=shape, ijk=ijk, lad=lad,
                 wood=rng.random(m) * (rng.random(m) < 0.3), wood_kind="probability", occluded=occluded,
                 lad_std=lad * 0.1, leaf_angle=LeafAngle("beta", mu=2.8, nu=1.2), leaf_azimuth="outward",
                 crown_center=(10.8, -2.9), ground_z=0.6, meta={"estimator": "bcmle"})


def _same(a: Scene, b: Scene):
    assert a.shape == b.shape and a.voxel_size == pytest.approx(b.voxel_size)
    np.testing.assert_allclose(a.origin, b.origin, atol=1e-6)
    for name in ("lad", "wood", "occluded", "lad_std"):
        np.testing.assert_allclose(a.dense(name), b.dense(name), rtol=1e-7, atol=1e-9, err_msg=name)
    assert a.leaf_angle == b.leaf_angle
    assert a.leaf_azimuth == b.leaf_azimuth and a.wood_kind == b.wood_kind
    assert a.ground_z == pytest.approx(b.ground_z)
    np.testing.assert_allclose(a.crown_center, b.crown_center)


def test_npz_round_trip(scene, tmp_path):
    path = scene.save(tmp_path / "s.npz")
    back = Scene.load(path)
    _same(scene, back)
    assert back.meta == scene.meta
    np.testing.assert_array_equal(back.ijk, scene.ijk)
    assert back.total_leaf_area() == pytest.approx(scene.total_leaf_area(), rel=1e-12)


def test_vox_round_trip(scene, tmp_path):
    path = write_vox(scene, tmp_path / "s.vox")
    text = path.read_text().splitlines()
    assert text[0] == "VOXEL SPACE"
    assert text[3] == "#split: 6 5 4"
    assert text[6].startswith("i j k PadBVTotal")
    assert len(text) == 7 + 6 * 5 * 4  # every voxel of the grid, AMAPVox style
    back = read_vox(path)
    _same(scene, back)


def test_vox_keeps_bark_directions_and_optics(scene, rng, tmp_path):
    """Directional bark (wood_beta, wood_axis) and the materials' optics survive a .vox round trip."""
    m = len(scene.ijk)
    axis = rng.normal(size=(m, 3))
    scene.wood_axis = axis / np.linalg.norm(axis, axis=1, keepdims=True)
    scene.wood_beta = np.where(scene.wood > 0, rng.random(m), 0.0)
    scene.materials = {**scene.materials, "bark": {"1064": [0.41, 0.0]}}
    back = read_vox(write_vox(scene, tmp_path / "d.vox"))
    _same(scene, back)
    np.testing.assert_allclose(back.dense("wood_beta"), scene.dense("wood_beta"), rtol=1e-8)
    woody = scene.wood_beta > 0
    lookup = {tuple(v): a for v, a in zip(back.ijk, back.wood_axis)}
    got = np.array([lookup[tuple(v)] for v in scene.ijk[woody]])
    np.testing.assert_allclose(got, scene.wood_axis[woody], atol=1e-8)
    assert back.materials == scene.materials


def test_vox_keeps_solid_wood(scene, tmp_path):
    """Solid voxels (wood_solid, wood_cap) survive a .vox round trip."""
    solid = scene.wood > 0
    scene.wood_solid = solid
    scene.wood_cap = np.where(solid, 0.25, 0.0)
    scene.__post_init__()
    back = read_vox(write_vox(scene, tmp_path / "s.vox"))
    np.testing.assert_array_equal(back.dense("wood_solid"), scene.dense("wood_solid"))
    np.testing.assert_allclose(back.dense("wood_cap"), scene.dense("wood_cap"))
    assert back.wood_directional


def test_vox_without_bark_directions_has_the_plain_columns(scene, tmp_path):
    header = write_vox(scene, tmp_path / "p.vox").read_text().splitlines()[6]
    assert header == "i j k PadBVTotal wood occluded lad_std"


def test_vox_occluded_unfilled_is_nan(scene, tmp_path):
    path = write_vox(scene, tmp_path / "s.vox")
    rows = np.loadtxt(path, skiprows=7)
    dense_occ = scene.dense("occluded").ravel()
    dense_lad = scene.dense("lad").ravel()
    assert np.all(np.isnan(rows[dense_occ & (dense_lad == 0), 3]))
    assert np.all(np.isfinite(rows[~dense_occ, 3]))


def test_reads_plain_amapvox_layout(tmp_path):
    """A file as AMAPVox writes it: other columns, NaN PAD, #res on the #type line."""
    lines = ["VOXEL SPACE", "#min_corner: 0.0 0.0 0.0", "#max_corner: 1.0 1.0 0.5", "#split: 2 2 1",
             "#type: TLS #res: 0.5 #MAX_PAD: 5.0",
             "i j k PadBVTotal angleMean bsEntering bsIntercepted nbSampling transmittance",
             "0 0 0 1.25 45 10 2 10 0.8", "0 1 0 NaN 45 0 0 0 NaN", "1 0 0 0 45 10 0 10 1", "1 1 0 3.5 45 10 5 10 0.5"]
    p = tmp_path / "a.vox"
    p.write_text("\n".join(lines) + "\n")
    s = read_vox(p)
    assert s.shape == (2, 2, 1) and s.voxel_size == 0.5
    assert s.dense("lad")[:, :, 0].tolist() == [[1.25, 0.0], [0.0, 3.5]]
    assert s.dense("occluded")[0, 1, 0] and not s.dense("occluded")[1, 1, 0]


def test_bad_vox_files(tmp_path):
    p = tmp_path / "bad.vox"
    p.write_text("hello\n")
    with pytest.raises(InputError, match="VOXEL SPACE"):
        read_vox(p)
    p.write_text("VOXEL SPACE\n#min_corner: 0 0 0\n#split: 1 1 1\ni j k PadBVTotal\n0 0 0 1\n")
    with pytest.raises(InputError, match="max_corner"):
        read_vox(p)
    with pytest.raises(InputError, match="does not exist"):
        read_vox(tmp_path / "none.vox")
    with pytest.raises(InputError, match="Scene"):
        write_vox("scene.npz", tmp_path / "x.vox")


def test_npz_write_is_atomic(scene, tmp_path, monkeypatch):
    """A failure while writing leaves the previous file intact."""
    path = scene.save(tmp_path / "s.npz")
    before = path.read_bytes()

    def boom(*a, **k):
        raise RuntimeError("disk full")

    monkeypatch.setattr(np, "savez_compressed", boom)
    with pytest.raises(RuntimeError):
        scene.save(path)
    assert path.read_bytes() == before
    assert [f.name for f in tmp_path.iterdir()] == ["s.npz"]


def test_vox_refuses_a_grid_it_would_list_in_gigabytes(tmp_path):
    """A .vox lists every voxel as text: a 2 cm grid over a tree would be ~10 GB; one line says so instead."""
    from tlsvox.voxel.amapvox import VOX_MAX_VOXELS

    scene = Scene(origin=(0, 0, 0), voxel_size=0.02, shape=(300, 300, 300), ijk=[[1, 2, 3]], lad=[1.0])
    assert 300**3 > VOX_MAX_VOXELS
    with pytest.raises(InputError, match="lists every voxel of the grid: 300 x 300 x 300"):
        write_vox(scene, tmp_path / "big.vox")
    assert not (tmp_path / "big.vox").exists()


def test_wood_directions_round_trip_and_default(scene, tmp_path):
    """Bark axes and anisotropy survive save/load; a scene without them is isotropic
    (beta 0, axis +z) and writes no such keys, so old files read as before."""
    assert not scene.wood_directional and np.all(scene.wood_beta == 0)
    np.testing.assert_array_equal(scene.wood_axis, np.tile([0.0, 0.0, 1.0], (scene.n_voxels, 1)))
    with np.load(scene.save(tmp_path / "iso.npz")) as z:
        assert "wood_axis" not in z and "wood_beta" not in z
    rng = np.random.default_rng(4)
    axis = rng.normal(size=(scene.n_voxels, 3))
    scene.wood_axis = axis * 3.0  # any length: stored as unit vectors
    scene.wood_beta = rng.uniform(0, 1, scene.n_voxels)
    scene.__post_init__()
    np.testing.assert_allclose(np.linalg.norm(scene.wood_axis, axis=1), 1.0)
    back = Scene.load(scene.save(tmp_path / "dir.npz"))
    assert back.wood_directional
    np.testing.assert_allclose(back.wood_axis, scene.wood_axis, rtol=1e-12)
    np.testing.assert_allclose(back.wood_beta, scene.wood_beta, rtol=1e-12)


@pytest.mark.parametrize("kw, word", [
    (dict(wood_beta=[1.5]), "wood_beta must lie in"),
    (dict(wood_beta=[0.5, 0.5]), "wood_beta must have one value per voxel"),
    (dict(wood_beta=[0.5], wood_axis=[[0.0, 0.0, 0.0]]), "zero-length"),
    (dict(wood_axis=[0.0, 0.0, 1.0, 0.0]), r"wood_axis must be one 3-vector per voxel"),
    (dict(wood_axis=[[np.nan, 0.0, 1.0]]), "NaN"),
    (dict(wood_solid=[True], wood_cap=[-0.1]), "wood_cap must lie in"),
    (dict(wood_solid=[True], wood_axis=[[0.0, 0.0, 0.0]]), "zero-length"),
])
def test_bad_wood_directions(kw, word):
    with pytest.raises(InputError, match=word):
        Scene(origin=(0, 0, 0), voxel_size=1.0, shape=(1, 1, 1), ijk=[[0, 0, 0]], lad=[0.0], wood=[0.3], **kw)
