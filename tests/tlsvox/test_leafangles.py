"""Leaf angles measured from scans: helpers against exact answers, the measurement on a small tree."""

from __future__ import annotations

import numpy as np
import pytest

from tlsvox.errors import InputError
from tlsvox.leafangles import fit_beta, histogram_G, measure_leaf_angles
from voxlidar.leafangle import LeafAngle


@pytest.mark.parametrize("kind", ["uniform", "planophile", "erectophile"])
def test_histogram_G_matches_the_model(kind):
    la = LeafAngle(kind)
    edges = np.linspace(0, np.pi / 2, 91)
    prob = np.diff(la.cdf(edges))
    theta = np.radians([10.0, 35.0, 57.3, 80.0])
    np.testing.assert_allclose(histogram_G(edges, prob / np.diff(edges), theta), la.G(theta), rtol=2e-3)


@pytest.mark.parametrize("kind", ["uniform", "planophile", "erectophile"])
def test_fit_beta_keeps_mean_and_G(kind):
    la = LeafAngle(kind)
    edges = np.linspace(0, np.pi / 2, 19)
    fit = fit_beta(np.diff(la.cdf(edges)), edges)
    assert abs(np.degrees(fit.mean_angle() - la.mean_angle())) < 0.5
    theta = np.radians(np.linspace(20, 80, 7))
    np.testing.assert_allclose(fit.G(theta), la.G(theta), rtol=0.02)
    assert LeafAngle.from_dict(fit.to_dict()) == fit  # stored like any other model


def _scan_of(kind, *, noise):
    from tlsvox.truth.scanner import ScannerPreset, ScanPose, simulate_scan
    from tlsvox.truth.synthetic import make_leaf_slab

    slab = make_leaf_slab(lad=1.0, size=(1.5, 1.5, 1.0), leaf_angle=kind, origin=(0.0, -0.75, 2.0), seed=2,
                          leaf_length=0.08, leaf_width=0.04)
    preset = ScannerPreset.riegl_vz400(n_subrays=1, range_noise_m=noise, reflectance_noise_db=0.0)
    return slab, simulate_scan(slab, pose=ScanPose(position=(-4.0, 0.0, 1.0)), preset=preset, seed=1,
                               progress=False)


def test_noise_free_scan_recovers_the_mean_inclination():
    """Pencil beams, no range noise: plane fits plus 1/|cos a| weights give the slab's leaf angles."""
    for kind in ("planophile", "erectophile"):
        slab, scan = _scan_of(kind, noise=0.0)
        res = measure_leaf_angles([scan], layers=2, method="weighted")
        true = np.degrees(LeafAngle(kind).mean_angle())
        assert abs(np.degrees(res.crown.mean_inclination) - true) < 5.0, (kind, res.crown.mean_inclination)
        assert len(res.layers) == 2 and sum(lay.n_echoes for lay in res.layers) == res.crown.n_echoes
        doc = res.to_dict()
        assert doc["crown"]["leaf_angle"]["name"] == "beta" and len(doc["layers"]) == 2


def test_bad_input_names_the_parameter():
    slab, scan = _scan_of("uniform", noise=0.0)
    with pytest.raises(InputError, match="layers"):
        measure_leaf_angles([scan], layers=0)
    with pytest.raises(InputError, match="method"):
        measure_leaf_angles([scan], method="magic")
    with pytest.raises(InputError, match="no pose"):
        scan.pose_true = None
        measure_leaf_angles([scan])


def test_cli_voxelize_leaf_angle_measured(tmp_path, capsys):
    """`tlsvox voxelize --leaf-angle measured`: the fitted model drives G and the scene states it."""
    from tlsvox.cli.voxelize import main as cli_main
    from voxlidar.scene import Scene

    _, scan = _scan_of("erectophile", noise=0.0)
    scan.pose = scan.pose_true
    path = tmp_path / "slab.laz"
    scan.write(path)
    out = tmp_path / "scene.npz"
    rc = cli_main([str(path), "--voxel-size", "0.5", "--ground", "none", "--leaf-angle", "measured",
                   "--leaf-angle-layers", "2", "-o", str(out)])
    text = capsys.readouterr().out
    assert rc == 0 and '"measured"' in text
    scene = Scene.load(out)
    assert scene.leaf_angle.kind.value == "beta"
    measured = scene.meta["leaf_angle_measured"]
    assert len(measured["layers"]) == 2 and measured["crown"]["leaf_angle"] == scene.leaf_angle.to_dict()
    assert abs(measured["crown"]["mean_inclination_deg"] - np.degrees(LeafAngle("erectophile").mean_angle())) < 5
    rc = cli_main([str(path), "--leaf-angle", "measured", "--leaf-angle-layers", "0", "-o",
                   str(tmp_path / "x.npz"), "-q"])
    err = capsys.readouterr().err
    assert rc == 2 and "--leaf-angle-layers" in err and len(err.strip().splitlines()) == 1
    assert not (tmp_path / "x.npz").exists()
