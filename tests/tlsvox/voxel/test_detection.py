"""The detection-threshold model (tlsvox.voxel.detection) against analytic limits and synthetic truth."""

import dataclasses

import numpy as np
import pytest

from tlsvox.errors import InputError
from tlsvox.voxel.detection import DetectionModel, Undetected, missed_share, projection_tables

VZ400 = dict(threshold_db=-20.0, n_subrays=7, exit_radius=0.0035, half_divergence=1.75e-4, noise_db=0.0,
             leaf_reflectance=0.267)


def test_large_leaves_are_missed_exactly_below_the_full_hit_cosine():
    """Leaves far wider than the beam are hit by all its parts: the echo reads rho mu, lost
    exactly where rho mu < 10^(threshold / 10)."""
    m = DetectionModel(**VZ400, leaf_length=20.0, leaf_width=20.0)
    mu_c = 10 ** (-20.0 / 10) / 0.267
    mu = np.array([0.5 * mu_c, 0.9 * mu_c, 1.1 * mu_c, 2 * mu_c, 0.5])
    q, spread = missed_share(m, mu, [0.0005], placements=4000)
    # partial hits (which read lower) need the beam on the leaf's edge: a share of about
    # 2 x 0.7 mm / (20 m x mu) of the hits, under 0.2 % here
    assert q[:, 0] == pytest.approx([1, 1, 0, 0, 0], abs=0.004)
    assert np.all(np.abs(spread - 1) < 0.004)


def test_missed_share_falls_with_incidence_and_partial_hits_widen_the_leaf():
    m = DetectionModel(**VZ400)
    mu = np.linspace(0.02, 1.0, 50)
    q, spread = missed_share(m, mu, [0.005])
    assert q[0, 0] > 0.9 and q[-1, 0] == 0.0
    # one part of seven on a leaf reads rho mu / 7: lost below mu = 0.262 whatever the leaf
    assert np.all(q[mu > 0.27, 0] == 0.0)
    assert np.all(np.diff(q[:, 0]) <= 1e-12)  # common random numbers: monotone
    assert np.all(spread >= 1.0)
    # reproducible
    assert np.array_equal(missed_share(m, mu, [0.005])[0], q)


def test_unrecorded_projection_is_at_most_g():
    from voxlidar.leaf_orientation import LeafAngle

    m = DetectionModel(**VZ400)
    for la in (LeafAngle("uniform"), LeafAngle("erectophile")):
        h, g_any, w = projection_tables(m, la, ranges=(5.0, 20.0), n_theta=19)
        g = la.G(np.linspace(0, np.pi, 19))
        assert np.all(h[:, 0, :] <= g[:, None] + 1e-3)
        assert np.all(g_any[:, 0, :] >= g[:, None] - 1e-3)
        assert h.max() > 0


def test_bad_detection_inputs_say_what_to_do():
    with pytest.raises(InputError, match="threshold_db"):
        DetectionModel(**{**VZ400, "threshold_db": float("nan")})
    with pytest.raises(InputError, match="leaf_length"):
        DetectionModel(**VZ400, leaf_length=0.0)
    with pytest.raises(InputError, match="undetected"):
        Undetected.parse("maybe", "undetected")

    with pytest.raises(InputError, match="detection_threshold_db"):
        DetectionModel.for_scan(_Bare({}))


class _Bare:
    """What DetectionModel.for_scan reads of a scan."""

    name = "bare"

    def __init__(self, meta):
        self.meta = meta


def test_for_scan_takes_what_the_scan_does_not_state_from_the_vz400_preset():
    """No preset: every instrument number is the VZ-400 preset's (the threshold must be given); a
    partial preset: its own numbers, the rest the VZ-400's, and the source says which."""
    from tlsvox.truth.scanner import ScannerPreset

    vz = ScannerPreset.riegl_vz400()
    bare = DetectionModel.for_scan(_Bare({}), threshold_db=-20.0)
    assert (bare.n_subrays, bare.exit_radius, bare.half_divergence, bare.noise_db, bare.range_resolution) == (
        vz.n_subrays, vz.beam_radius_exit, vz.half_divergence, vz.reflectance_noise_db, vz.range_resolution_m)
    assert "VZ-400 preset (the scan states none)" in bare.source
    part = DetectionModel.for_scan(_Bare({"preset": {"min_reflectance_db": -25.0, "divergence_mrad": 0.5,
                                                     "n_subrays": 19}}))
    assert part.threshold_db == -25.0 and part.n_subrays == 19
    assert part.half_divergence == pytest.approx(2.5e-4) and part.exit_radius == vz.beam_radius_exit
    assert "with beam_exit_diameter_m, reflectance_noise_db, range_resolution_m of the RIEGL VZ-400" in part.source
    full = DetectionModel.for_scan(_Bare({"preset": dataclasses.asdict(vz)}))
    assert full.source.startswith("the scan's preset;") and full.threshold_db == vz.min_reflectance_db


# ---- against synthetic truth: leaves scanned with the floor at -60 dB, so every weak echo is there

@pytest.fixture(scope="module")
def slab_scan():
    pytest.importorskip("open3d")
    from tlsvox.truth.scanner import ScannerPreset, ScanPose, simulate_scan
    from tlsvox.truth.synthetic import make_leaf_slab

    def scan(lad, angle, size):
        box = make_leaf_slab(lad=lad, size=(size,) * 3, origin=(8.0, -size / 2, 1.0), leaf_angle=angle, seed=3)
        return simulate_scan(box, pose=ScanPose(position=(0.0, 0.0, 2.0)), seed=1, progress=False,
                             preset=ScannerPreset.riegl_vz400(min_reflectance_db=-60.0))
    return scan


@pytest.mark.parametrize("lad, angle, size", [(0.05, "uniform", 4.0), (0.3, "erectophile", 2.0)])
def test_missed_share_matches_the_scanner(slab_scan, lad, angle, size):
    """The share of the leaf interception under -20 dB, measured on a sparse leaf slab, against
    the model (with the merging of echoes within the range resolution, at the slab's LAD).
    Tolerance: 3 standard errors of the measured share (echoes independent) plus 3 of the
    model's own Monte Carlo, taken from three other seeds of its placements."""
    from tlsvox.voxel import detection
    from voxlidar.leaf_orientation import LeafAngle

    s = slab_scan(lad, angle, size)
    leaf = s.truth_material == 1
    f = s.beam_fraction[leaf].astype(float)
    miss = s.reflectance_db[leaf] < -20.0
    measured = f[miss].sum() / f.sum()
    se = np.sqrt(np.sum((f * (miss - measured)) ** 2)) / f.sum()
    model = DetectionModel.for_scan(s, threshold_db=-20.0)
    la = LeafAngle(angle)
    r = np.linalg.norm(s.xyz[leaf], axis=1)
    theta = np.arccos(np.clip(s.xyz[leaf, 2] / r, -1, 1))
    preds = []
    for seed in (0, 1, 2, 3):
        h, g_any, w = projection_tables(model, la, ranges=(r.min(), r.max()), n_w=3, seed=seed)
        hv = detection._interp_h(h, w, theta, np.zeros_like(theta), model.beam_radius(r))
        gv = detection._interp_h(g_any, w, theta, np.zeros_like(theta), model.beam_radius(r))
        preds.append(np.sum(f * hv / la.G(theta) * np.exp(-gv * lad * model.range_resolution)) / f.sum())
    model_se = float(np.std(preds[1:], ddof=1))
    assert abs(preds[0] - measured) < 3 * se + 3 * model_se, (measured, se, preds)
    assert 0.005 < measured < 0.1


# ---- the correction in the estimators: the leaf box of test_weights at the VZ-400's -20 dB

# the fixture ``bench`` (benchmarks/bench_echo_weights.py) is in conftest.py


@pytest.fixture(scope="module")
def box_scans_02(bench):
    """The leaf box and its scans at a 0.2 degree step, simulated once for the tests that share them."""
    box = bench.leaf_box()
    return box, bench.scan_box(box, 7, 0.2)


def test_model_removes_the_detection_floor_bias_on_the_leaf_box(bench):
    """With echoes under -20 dB lost the share rule reads the box 2.7 % low (test_weights);
    the model gives the unrecorded interception back (measured -1.2 %; the scan that records
    every echo: -1.0 %): within the tolerance that scan is held to (3 SE + 0.5 %)."""
    box = bench.leaf_box()
    scans = bench.scan_box(box, 7, 0.1)
    ignore = bench.score(box, scans, "fraction")
    model = bench.score(box, scans, "fraction", undetected="model")
    assert model["mean"] > ignore["mean"]
    assert abs(model["mean"] - model["true"]) < 3 * model["se"] + 0.005 * model["true"], (ignore, model)


def test_the_rule_is_stated_and_the_sparse_layout_gives_back_alike(bench, box_scans_02):
    """meta["undetected"] says what was done; the sparse layout (brick-layer fill of occluded
    voxels) gives back within 10 % of the dense one (voxel-layer fill there) on the leaf box."""
    from tlsvox import voxelize

    _, scans = box_scans_02
    plain = voxelize(scans, voxel_size=0.5, leaf_angle="spherical", ground=None, bounds=bench.BOUNDS,
                     progress=False)
    assert plain.scene.meta["undetected"] == {"rule": "ignore", "detection_threshold_db": [-20.0, -20.0]}
    given = {}
    for layout in ("dense", "sparse"):
        res = voxelize(scans, voxel_size=0.5, leaf_angle="spherical", ground=None, bounds=bench.BOUNDS,
                       progress=False, layout=layout, undetected="model", undetected_iterations=2)
        meta = res.scene.meta["undetected"]
        assert meta["rule"] == "model" and meta["iterations"] == 2 and len(meta["given_back_share"]) == 2
        assert meta["models"][0]["threshold_db"] == -20.0
        given[layout] = meta["given_back_share"][-1]
    assert 0.002 < given["dense"] < 0.1
    assert given["sparse"] == pytest.approx(given["dense"], rel=0.1)


def test_calibrated_fill_traces_the_corrected_beams_scan_by_scan(bench, box_scans_02):
    """fill='calibrated' traces each scan on its own, in the detection model's rounds too: the
    pooled sums hold the given-back interception (leaf echo weight up by the share the model
    reports, against the same run without the model), not the scans' recorded echoes again; and a
    run whose scans share too few hidden voxels to calibrate says so."""
    from tlsvox import voxelize

    _, scans = box_scans_02
    kw = dict(voxel_size=0.2, leaf_angle="spherical", ground=None, bounds=bench.BOUNDS, progress=False,
              layout="dense", fill="calibrated", n_min=60)
    plain = voxelize(scans, **kw)
    model = voxelize(scans, undetected="model", undetected_iterations=2, **kw)
    share = model.scene.meta["undetected"]["given_back_share"][-1]
    assert share > 0.002
    ratio = model.stats.field("leaf_w").sum() / plain.stats.field("leaf_w").sum()
    assert ratio == pytest.approx(1 + share, rel=2e-3), (ratio, share)
    for res in (plain, model):
        cal = res.scene.meta["options"]["fill_calibration"]
        said = [w for w in res.scene.meta["warnings"] if "fill='calibrated' found" in w]
        assert bool(said) == (not cal["calibrated"]), (cal, said)


def test_sparse_layout_weighs_its_bricks_and_matches_the_dense_model(bench, box_scans_02):
    """undetected='model' in both layouts, with occlusion (n_min 60 at 20 cm) and air around the box.

    The voxels holding echoes (rows) are flagged as in the dense layout but where the weight
    entering lies within 1 % of n_min, and the seen voxels' leaf area agrees within 1 %: the
    layouts fill occluded voxels differently for the optical depth (voxel layers in the crown
    hull against brick layers), so the echoes given back differ a little (measured: 4 rows of
    1,920 flagged differently, n_w 59.9 against 60.0; leaf area 0.24 %; given back 0.0084
    against 0.0080).  The echo-free voxels are judged per brick by the weighted rule: the
    dense rule (count and n_w under n_min, or little explored) on the brick's summed voxel sums."""
    from tlsvox import voxelize
    from tlsvox.voxel.estimators import safe_divide

    _, scans = box_scans_02
    bounds = bench.BOUNDS + np.array([[-1.2, -1.2, -0.6], [1.2, 1.2, 0.6]])
    n_min = 60
    out = {}
    for layout in ("dense", "sparse"):
        out[layout] = voxelize(scans, voxel_size=0.2, leaf_angle="spherical", ground=None, bounds=bounds, n_min=n_min,
                               progress=False, layout=layout, undetected="model", undetected_iterations=2)
    dense, sparse = out["dense"], out["sparse"]
    rows = tuple(sparse.lad.rows.ijk.T)
    d_occ = dense.lad.occluded[rows]
    assert 0.1 < d_occ.mean() < 0.9
    differ = d_occ != sparse.lad.occluded
    assert differ.mean() < 0.01
    assert np.all(np.abs(sparse.stats.field("n_w")[differ] / n_min - 1) < 0.01)
    area = [r.lad.lad[~r.lad.occluded].sum() for r in (dense, sparse)]
    assert area[1] == pytest.approx(area[0], rel=0.01)
    given = [r.scene.meta["undetected"]["given_back_share"][-1] for r in (dense, sparse)]
    assert given[1] == pytest.approx(given[0], rel=0.1)
    # the brick rule, weighted: the dense rule on each brick's summed voxel sums (visits: the
    # dense count summed, visits_w: the dense n_w summed; test_bricks checks those sums)
    f = sparse.stats.brick_field
    voxels = sparse.lad.rows.voxels_in_grid()
    few = f("visits") / voxels < n_min
    few_w = f("visits_w") / voxels < n_min
    rule = few | few_w | (safe_divide(f("path_w"), f("chord_w")) < 0.05)
    assert np.array_equal(sparse.lad.brick_occluded, rule)
    assert (few_w & ~few).any(), "the weighted rule decides some brick here"


def test_weighted_count_flags_voxels_reached_only_by_tail_leftovers():
    """Ten beams of a tenth of a pulse each: ten beams, one pulse's worth of weight."""
    from tlsvox.voxel.estimators import Flag, estimate_lad
    from tlsvox.voxel.grid import VoxelGrid
    from tlsvox.voxel.trace import Beams, trace

    grid = VoxelGrid((0, 0, 0), 1.0, (1, 1, 1))
    y = np.linspace(0.05, 0.95, 10)
    rays = Beams.from_rays(np.column_stack([np.full(10, -1.0), y, np.full(10, 0.5)]), [[1, 0, 0]] * 10)
    beams = Beams(rays.origin, rays.direction, rays.echo_start, rays.echo_range, rays.echo_weight, rays.echo_kind,
                  np.full(10, 0.1), rays.max_range)
    stats = trace(grid, beams)
    assert stats.field("count")[0, 0, 0] == 10 and stats.field("n_w")[0, 0, 0] == pytest.approx(1.0)
    plain = estimate_lad(stats, n_min=5)
    weighted = estimate_lad(stats, n_min=5, weighted_count=True)
    assert not plain.flags[0, 0, 0] & Flag.FEW_BEAMS
    assert weighted.flags[0, 0, 0] & Flag.FEW_BEAMS and weighted.options["weighted_count"]


def test_a_beam_without_divergence_has_one_radius_node():
    """A zero divergence (every radius the same) gives one radius node and finite H
    at any radius, where six equal nodes made a 0/0 and an IndexError."""
    import dataclasses

    from tlsvox.voxel import detection
    from voxlidar.leaf_orientation import LeafAngle

    m = dataclasses.replace(DetectionModel(**VZ400), half_divergence=0.0)
    h, g_any, w = projection_tables(m, LeafAngle("uniform"), ranges=(5.0, 20.0), n_theta=19, nodes=64)
    assert w.size == 1 and h.shape[-1] == 1
    theta = np.linspace(0.1, 3.0, 7)
    hv = detection._interp_h(h, w, theta, np.zeros_like(theta), np.full(theta.size, 0.0035))
    assert np.all(np.isfinite(hv)) and np.all(hv >= 0)


def test_added_echoes_are_returned_with_their_voxels():
    """info["added"] lists the given-back echoes (pulse, range): with the recorded echoes' voxels
    they make the corrected beams' echo voxels, which the sparse rounds of voxelize rely on."""
    from tlsvox.voxel.beams import Beams, EchoKind, echo_voxels, voxels_along
    from tlsvox.voxel.detection import unrecorded_echoes
    from tlsvox.voxel.grid import VoxelGrid
    from voxlidar.leaf_orientation import LeafAngle

    rng = np.random.default_rng(5)
    grid = VoxelGrid((0.0, 0.0, 0.0), 0.5, (12, 12, 12))
    n = 400
    origin = np.column_stack([np.full(n, -5.0), rng.uniform(0.5, 5.5, n), rng.uniform(0.5, 5.5, n)])
    d = np.column_stack([np.ones(n), rng.normal(0, 0.05, (n, 2))])
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    hits = rng.random(n) < 0.5
    rays = Beams.from_rays(origin, d, hit_range=np.where(hits, rng.uniform(6.0, 10.0, n), np.inf))
    beams = Beams(rays.origin, rays.direction, rays.echo_start, rays.echo_range, 0.6 * rays.echo_weight,
                  rays.echo_kind, np.where(hits, 0.4, 1.0), np.full(n, 20.0))
    model = DetectionModel(**VZ400)
    new, info = unrecorded_echoes(beams, grid, lambda flat: np.full(np.shape(flat), 1.0), model,
                                  LeafAngle("uniform"))
    pulse, ranges = info["added"]
    assert len(ranges) == new.n_echoes - beams.n_echoes > 0 and info["pulses"] == len(np.unique(pulse))
    assert np.all(new.echo_kind[np.isin(new.echo_range, ranges)] == EchoKind.LEAF)
    both = np.union1d(grid.flat(echo_voxels(grid, beams)),
                      grid.flat(voxels_along(grid, beams.origin[pulse], beams.direction[pulse], ranges)))
    assert np.array_equal(both, grid.flat(echo_voxels(grid, new)))
