"""Leaf angles measured from scans: helpers against exact answers, the measurement on a small tree."""

from __future__ import annotations

import numpy as np
import pytest

from tlsvox.errors import InputError
from tlsvox.leafangles import fit_beta, histogram_G, measure_leaf_angles
from voxlidar.leaf_orientation import LeafAngle


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
    with pytest.raises(InputError, match="azimuth"):
        measure_leaf_angles([scan], azimuth="sideways")
    with pytest.raises(InputError, match="no pose"):
        scan.pose_true = None
        measure_leaf_angles([scan])


def test_cli_voxelize_leaf_angle_measured(tmp_path, capsys):
    """`tlsvox voxelize --leaf-angle measured --leaf-angle-by-layer`: the fitted models drive G (the
    whole crown's is the scene's, each layer's in its voxels) and the scene states them."""
    from tlsvox.cli.voxelize import main as cli_main
    from voxlidar.scene import Scene

    _, scan = _scan_of("erectophile", noise=0.0)
    scan.pose = scan.pose_true
    path = tmp_path / "slab.laz"
    scan.write(path)
    out = tmp_path / "scene.npz"
    rc = cli_main([str(path), "--voxel-size", "0.5", "--ground", "none", "--leaf-angle", "measured",
                   "--leaf-angle-layers", "2", "--leaf-angle-by-layer", "-o", str(out)])
    text = capsys.readouterr().out
    assert rc == 0 and '"measured"' in text
    scene = Scene.load(out)
    assert scene.leaf_angle.kind.value == "beta"
    measured = scene.meta["leaf_angle_measured"]
    assert len(measured["layers"]) == 2 and measured["crown"]["leaf_angle"] == scene.leaf_angle.to_dict()
    assert abs(measured["crown"]["mean_inclination_deg"] - np.degrees(LeafAngle("erectophile").mean_angle())) < 5
    by_layer = scene.meta["leaf_angle_layers"]
    assert [lay["leaf_angle"] for lay in by_layer] == [lay["leaf_angle"] for lay in measured["layers"]]
    assert by_layer[0]["z_low"] is None and by_layer[1]["z_low"] == pytest.approx(measured["layers"][1]["z_range_m"][0])
    rc = cli_main([str(path), "--leaf-angle", "spherical", "--leaf-angle-by-layer", "-o", str(tmp_path / "y.npz")])
    err = capsys.readouterr().err
    assert rc == 2 and "needs --leaf-angle measured" in err and len(err.strip().splitlines()) == 1
    assert not (tmp_path / "y.npz").exists()
    rc = cli_main([str(path), "--leaf-angle", "measured", "--leaf-angle-layers", "0", "-o",
                   str(tmp_path / "x.npz"), "-q"])
    err = capsys.readouterr().err
    assert rc == 2 and "--leaf-angle-layers" in err and len(err.strip().splitlines()) == 1
    assert not (tmp_path / "x.npz").exists()


def test_cli_refuses_a_scan_without_a_pose_before_measuring(tmp_path, capsys, monkeypatch):
    """A simulated scan not yet registered (a true pose, no pose) is refused at once, not after the
    measurement has run on its true pose (half a minute on a real crown)."""
    import tlsvox.leafangles
    from tlsvox.cli.voxelize import main as cli_main

    _, scan = _scan_of("uniform", noise=0.0)
    assert scan.pose is None and scan.pose_true is not None
    path = tmp_path / "slab.laz"
    scan.write(path)

    def never(*args, **kwargs):
        raise AssertionError("measured before the pose was checked")

    monkeypatch.setattr(tlsvox.leafangles, "measure_leaf_angles", never)
    rc = cli_main([str(path), "--leaf-angle", "measured", "-q", "-o", str(tmp_path / "x.npz")])
    err = capsys.readouterr().err
    assert rc == 2 and "no pose" in err and "--scanner-frame" in err and len(err.strip().splitlines()) == 1
    assert not (tmp_path / "x.npz").exists()


def test_em_recovers_the_distribution_and_the_mixes_from_rows_of_different_kernels():
    """The crown inverts the rows of every scan, layer and zenith group together: one distribution, an
    occlusion mix per row set and an azimuth mix explain them all (exact rows, so only the EM's convergence
    limits the match)."""
    from tlsvox.leafangles._histogram import _em

    rng = np.random.default_rng(0)
    n_mod, n_lev, n_bins, n_col = 2, 3, 8, 40
    p_true = rng.dirichlet(np.ones(n_bins))
    mixes = [rng.dirichlet(np.ones(n_lev)) for _ in range(2)]
    az_true = np.array([0.15, 0.85])
    rows = []
    for g, scale in enumerate((1.0, 30.0, 500.0, 7.0)):  # rows of very different leaf areas
        K = rng.random((n_mod, n_lev, n_bins, n_col)) ** 4
        x = az_true[:, None, None] * mixes[g % 2][None, :, None] * p_true[None, None, :]
        rows.append((0, g % 2, 0, scale * np.einsum("alb,albc->c", x, K), K))
    p, mix, az = _em(rows, (1, 2, 1), 3000)
    np.testing.assert_allclose(p[0], p_true, atol=5e-3)
    np.testing.assert_allclose(az[0], az_true, atol=0.02)
    for m, m_true in zip(mix, mixes):
        np.testing.assert_allclose(m, m_true, atol=0.03)
    rows.append((0, 0, 0, np.ones(n_col), np.zeros((n_mod, n_lev, n_bins, n_col))))  # a row without a kernel
    assert all(np.isfinite(v).all() for v in _em(rows, (1, 2, 1), 10))


def test_trunk_center_from_two_sides_of_a_noisy_trunk():
    """The trunk's axis from the two arcs two scanners see, with branch echoes around: within 1 cm."""
    from tlsvox.leafangles import trunk_center

    rng = np.random.default_rng(1)
    centre, rad = np.array([0.4, -0.2]), 0.24
    ang = np.concatenate([rng.uniform(-1.2, 1.2, 800), rng.uniform(np.pi - 1.0, np.pi + 1.0, 600)])
    z = rng.uniform(0.0, 2.0, len(ang))
    pts = np.column_stack([centre[0] + rad * np.cos(ang), centre[1] + rad * np.sin(ang), z])
    pts[:, :2] += rng.normal(0.0, 0.005, (len(pts), 2))
    branches = np.column_stack([rng.uniform(-1.5, 1.5, (100, 2)), rng.uniform(0.4, 1.2, 100)])
    c, r = trunk_center(np.concatenate([pts, branches]))
    assert np.linalg.norm(c - centre) < 0.01 and abs(r - rad) < 0.01, (c, r)
    assert trunk_center(pts[:10])[0] is None  # too few echoes: no centre

VZ400_BEAM = (0.0035, 0.000175, 7)  # exit radius m, half divergence rad, sub-rays


def _grid_plane(spacing=0.005, n=11):
    g = (np.arange(n) - n // 2) * spacing
    x, y = np.meshgrid(g, g)
    return np.column_stack([x.ravel(), y.ravel(), np.zeros(x.size)])


def test_edge_on_fits_are_dropped():
    """A fit whose normal is nearer edge-on to its beam than |cos a| = cap is dropped; facing ones kept."""
    from tlsvox.leafangles._planes import _fit_scan

    xyz = _grid_plane()
    kw = dict(radius=0.012, min_points=5, min_spread=0.0, n_bins=18, cap=0.2)
    facing = _fit_scan(xyz, np.array([0.0, 0.0, 5.0]), **kw)
    grazing = _fit_scan(xyz, np.array([5.0, 0.0, 0.5]), **kw)  # |cos a| = 0.1
    assert facing.ok.all() and (facing.meas_bin == 0).all()
    assert not grazing.ok.any()
    assert _fit_scan(xyz, np.array([5.0, 0.0, 0.5]), **{**kw, "cap": 0.05}).ok.all()


def test_occlusion_levels_hide_more_of_the_leaf_in_order():
    """Simulated neighbour counts: the whole leaf > one cut > the same cut on two sides.  300 echoes: the
    whole leaf and the shallowest cut differ by 0.8-1.3 echoes on seeds 3-5 (with the pruned pulse grids),
    the means' Monte Carlo error is about 0.1."""
    from tlsvox.leafangles._simulate import _CUTS, _MAX_COUNT, _simulate_kernel

    rng = np.random.default_rng(3)
    n = 300
    d = rng.normal(size=(n, 3)) * [0.2, 0.2, 0.0] + [1.0, 0.0, 0.6]
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    _, counts = _simulate_kernel(np.full(n, 8.0), d, np.zeros(n, int), np.zeros((n, 2)), step=(np.radians(0.06),) * 2,
                                 beam=VZ400_BEAM, leaf_size=0.05, radius=0.025, min_points=5, min_spread=0.0,
                                 n_bins=6, n_groups=1, range_noise=0.005, samples=4, cap=0.2, rng=rng,
                                 second_leaf=False)
    mean = (counts.mean(axis=1) * np.arange(_MAX_COUNT)).sum(axis=1) / counts.mean(axis=1).sum(axis=1)
    one_side = [lev for lev in range(len(_CUTS)) if _CUTS[lev, 2] > 1e8 and _CUTS[lev, 0] < 1e8]
    for lev in range(len(_CUTS)):
        if _CUTS[lev, 2] < 1e8:  # two cuts: fewer echoes than the same single cut
            single = next(k for k in one_side if np.allclose(_CUTS[k, :2], _CUTS[lev, :2]))
            assert mean[lev] < mean[single], (lev, mean)
    assert mean[0] == mean.max() and np.all(np.diff(mean[[0] + one_side]) < 0), mean


def test_second_leaf_levels_add_echoes_and_spread_the_normals():
    """A second leaf just behind the first (the nearest band, 0-2.5 cm): more neighbours than the same level
    alone, and fewer fits in their true inclination bin (pooled over the three levels).  On seeds 0-5 the
    pooled shares differed by 0.07-0.11 (with the pruned pulse grids), so the 0.03 margin is well below the
    smallest."""
    from tlsvox.leafangles._planes import _measured_bins
    from tlsvox.leafangles._simulate import _BANDS, _CUTS, _MAX_COUNT, _SECOND_CUTS, _simulate_kernel

    rng = np.random.default_rng(5)
    n = 600
    d = rng.normal(size=(n, 3)) * [0.2, 0.2, 0.0] + [1.0, 0.0, 0.6]
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    kernel, counts = _simulate_kernel(np.full(n, 8.0), d, np.zeros(n, int), np.zeros((n, 2)),
                                      step=(np.radians(0.06),) * 2, beam=VZ400_BEAM, leaf_size=0.05, radius=0.025,
                                      min_points=5, min_spread=0.0, n_bins=6, n_groups=1, range_noise=0.005,
                                      samples=8, cap=0.2, rng=rng, second_leaf=True)
    assert kernel.shape[0] == 1 and kernel.shape[1] == counts.shape[0] == len(_CUTS) + len(_SECOND_CUTS) * len(_BANDS)
    mean = (counts.mean(axis=1) * np.arange(_MAX_COUNT)).sum(axis=1) / counts.mean(axis=1).sum(axis=1)
    twos = list(range(len(_CUTS), len(_CUTS) + len(_SECOND_CUTS)))  # the nearest band
    singles = [next(k for k in range(len(_CUTS)) if np.allclose(_CUTS[k], cut)) for cut in _SECOND_CUTS]
    for two, single in zip(twos, singles):
        assert mean[two] > mean[single], (two, mean)
    by_bin = _measured_bins(kernel[0, :, 0], 6)  # (levels, true bin, measured bin)

    def in_true_bin(levels):  # share of the fits in their true bin
        return sum(np.trace(by_bin[k]) for k in levels) / sum(by_bin[k].sum() for k in levels)

    assert in_true_bin(twos) < in_true_bin(singles) - 0.03, (in_true_bin(twos), in_true_bin(singles))


def test_kernels_and_occlusion_are_fitted_per_scan_and_layer():
    slab, scan = _scan_of("planophile", noise=0.005)
    res = measure_leaf_angles([scan], layers=2, samples=1, max_simulated=300)
    mixes = res.params["occlusion_mix"]
    assert len(mixes) == 1 and len(mixes[0]) == 2  # one scan, two layers
    for mix in mixes[0]:
        assert mix is not None and abs(sum(mix) - 1) < 0.01 and min(mix) >= 0
    # a slab has no trunk: the outward model needs a centre, so only the uniform one is used, and said
    assert res.params["azimuth_models"] == ["uniform"] and res.params["crown_center_from"].startswith("no trunk")
    assert res.params["beam"][0]["subrays"] == 1  # the scan's own preset (pencil beams)
    with pytest.raises(InputError, match="crown_center"):
        measure_leaf_angles([scan], azimuth="outward")
    for bad in ((0.007, 0.35, 5), 7, ("a", 0.35, 7), (0.007, 0.35, float("nan")), (7.0, 0.35, 7), (0.007, 0.35)):
        with pytest.raises(InputError, match="beam"):
            measure_leaf_angles([scan], beam=bad)
    for bad in ((np.nan, 0.0), (1.0,), "centre"):
        with pytest.raises(InputError, match="crown_center"):
            measure_leaf_angles([scan], crown_center=bad)
    with pytest.raises(InputError, match="angular_step"):
        measure_leaf_angles([scan], angular_step=-0.06)
    with pytest.raises(InputError, match="zenith_groups"):
        measure_leaf_angles([scan], zenith_groups=0)


def test_azimuth_models_are_chosen_per_layer_and_stated():
    """With a crown centre both azimuth models are fitted, each layer keeps the one with the larger share, and
    the whole record goes into a scene file's JSON; the same seed gives the same result."""
    import json

    slab, scan = _scan_of("planophile", noise=0.005)
    kw = dict(layers=2, samples=1, max_simulated=300, crown_center=(-0.5, 0.0), iterations=50)
    res = measure_leaf_angles([scan], **kw)
    p = res.params
    assert p["azimuth_models"] == ["uniform", "outward"] and p["crown_center_from"] == "given"
    assert len(p["azimuth_model"]) == 2 and len(p["azimuth_share"]) == 2
    for share, model in zip(p["azimuth_share"], p["azimuth_model"]):
        assert abs(sum(share.values()) - 1) < 0.01 and model == max(share, key=share.get)
    doc = json.loads(json.dumps(res.to_dict()))
    assert doc["params"]["azimuth_model"] == p["azimuth_model"] and doc["params"]["scans_used"] == [scan.name]
    assert measure_leaf_angles([scan], **kw).to_dict() == res.to_dict()
    with pytest.raises(InputError, match="cap"):
        measure_leaf_angles([scan], cap=1.5)


def test_pulse_grid_keeps_every_pulse_that_can_give_a_neighbour():
    """The simulation scans each echo with only the pulses whose rays pass within the radius of it, the echo
    taken ``margin`` nearer than its range: checked against a wide grid by brute force (the exact distance from
    the echo to each ray) over ranges 3-30 m and beam zenith angles 30-150 deg, for one echo and for two echoes
    sharing a grid (each echo's pulses must be in it)."""
    from tlsvox.leafangles._simulate import _pulse_grid

    rng = np.random.default_rng(0)
    step = np.radians([0.06, 0.04])
    radius, margin = 0.025, 0.075
    wide = np.arange(-40, 41)
    i, k = (g.ravel().astype(float) for g in np.meshgrid(wide, wide, indexing="ij"))

    def needed(r, zen, azi):
        d = np.array([np.sin(zen) * np.cos(azi), np.sin(zen) * np.sin(azi), np.cos(zen)])
        e_a = np.array([-d[1], d[0], 0.0]) / np.hypot(d[0], d[1])
        e_z = np.cross(e_a, d)
        rays = d[None] + (i * step[0])[:, None] * e_z[None] + (k * step[1] * np.sin(zen))[:, None] * e_a[None]
        rays /= np.linalg.norm(rays, axis=1, keepdims=True)
        echo = d * (r - margin)  # the nearest the centre echo comes
        off_ray = np.linalg.norm(echo[None] - (rays @ echo)[:, None] * rays, axis=1)
        return {(a, b) for a, b, x in zip(i, k, off_ray) if x <= radius}

    dropped = 0
    for _ in range(150):
        r = rng.uniform(3.0, 30.0, 2)
        zen, azi = rng.uniform(np.radians(30), np.radians(150), 2), rng.uniform(0, 2 * np.pi, 2)
        one = _pulse_grid(r[:1], np.sin(zen[:1]), step=step, radius=radius, margin=margin, max_offsets=40)
        kept = set(zip(*one))
        assert needed(r[0], zen[0], azi[0]) <= kept, (r[0], np.degrees(zen[0]))
        dropped += len(kept) < (2 * max(abs(one[0])) + 1) * (2 * max(abs(one[1])) + 1)
        both = set(zip(*_pulse_grid(r, np.sin(zen), step=step, radius=radius, margin=margin, max_offsets=40)))
        for j in range(2):
            assert needed(r[j], zen[j], azi[j]) <= both, (r, np.degrees(zen), j)
    assert dropped > 75  # the grid is cut to the ellipse, not the bounding rectangle


def test_settings_group_the_options_and_repeat_a_measurement(tmp_path):
    """The keyword arguments are the fields of LeafAngleSettings (four groups); a measurement records them in
    full and is repeated bit for bit from that record, from a TOML file, or from the settings object."""
    from tlsvox.leafangles import LeafAngleSettings

    slab, scan = _scan_of("planophile", noise=0.005)
    kw = dict(layers=2, samples=1, max_simulated=300, iterations=30, beam=[0.007, 0.35, 7])
    first = measure_leaf_angles([scan], **kw)
    s = LeafAngleSettings.from_dict(first.params["settings"])
    assert s == LeafAngleSettings.from_kwargs(**kw) and s.instrument.beam == (0.007, 0.35, 7)
    assert s.histogram.layers == 2 and s.deconvolution.iterations == 30 and s.planes.radius == 0.025
    s.write(tmp_path / "angles.toml")
    assert LeafAngleSettings.read(tmp_path / "angles.toml") == s
    for again in (measure_leaf_angles([scan], s), measure_leaf_angles([scan], LeafAngleSettings.read(
            tmp_path / "angles.toml"))):
        assert again.to_dict() == first.to_dict()
    # a keyword replaces one field of the given settings
    assert measure_leaf_angles([scan], s, method="weighted").params["settings"]["histogram"]["method"] == "weighted"
    with pytest.raises(InputError, match=r"unknown leaf-angle setting\(s\) \['radious'\]"):
        measure_leaf_angles([scan], radious=0.03)
    with pytest.raises(InputError, match=r"unknown field\(s\) \['layer'\] in leaf-angle settings \[histogram\]"):
        LeafAngleSettings.from_dict({"histogram": {"layer": 3}})
