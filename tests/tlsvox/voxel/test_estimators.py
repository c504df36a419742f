"""LAD estimators on sampled Poisson (turbid medium) processes with known LAD.

Free paths in a turbid medium of LAD ``u`` are exponential with rate
``G(theta) u``.  Beams are sampled with that law, traced, and the estimate is
compared with ``u`` within 2 of its own standard errors.
"""

from __future__ import annotations

import numpy as np
import pytest

from tlsvox.errors import InputError
from tlsvox.voxel.estimators import Estimator, Flag, estimate_lad
from tlsvox.voxel.grid import VoxelGrid
from tlsvox.voxel.trace import Beams, EchoKind, trace
from voxlidar.leaf_orientation import LeafAngle


def _slab_beams(rng, grid, n, rate, *, axis=0, g=1.0, first=0.0):
    """n beams along +axis through a 1-voxel-thick grid, exponential leaf hits.

    ``rate`` is the attenuation (G u) per metre; ``first`` is where (as a
    fraction of h) the medium starts inside the voxel.
    """
    h = grid.voxel_size
    lo, hi = grid.lower, grid.upper
    o = lo + rng.random((n, 3)) * (hi - lo)
    o[:, axis] = lo[axis] - 1.0
    d = np.zeros((n, 3))
    d[:, axis] = 1.0
    x = rng.exponential(1.0 / rate, n) + first * h if rate > 0 else np.full(n, np.inf)
    length = 1.0 + h * grid.shape[axis]
    r = np.where(x < h * grid.shape[axis], 1.0 + x, np.inf)
    b = Beams.from_rays(o, d, hit_range=r, kind=EchoKind.LEAF, max_range=length + 1)
    b.g = np.full(n, g)
    return b


@pytest.mark.parametrize("estimator,lad,h,n", [
    ("bcmle", 2.0, 0.5, 4000),
    ("voxlad", 2.0, 0.5, 4000),
    ("beer_lambert", 2.0, 0.5, 4000),
    # contact frequency is only consistent for thin voxels (I ~ lambda delta): lambda delta = 0.01
    ("contact_frequency", 0.4, 0.05, 200000),
])
def test_known_lad_recovered_within_two_standard_errors(estimator, lad, h, n, rng):
    g = 0.5  # spherical leaves
    grid = VoxelGrid((0, 0, 0), h, (1, 1, 1))
    beams = _slab_beams(rng, grid, n, g * lad, g=g)
    res = estimate_lad(trace(grid, beams), estimator=estimator, leaf_size=None)
    got, se = float(res.lad[0, 0, 0]), float(res.lad_std[0, 0, 0])
    assert se > 0
    assert abs(got - lad) < 2 * se, (got, lad, se)
    assert res.flags[0, 0, 0] == 0


@pytest.mark.parametrize("estimator", ["bcmle", "voxlad"])
def test_pooled_directions_with_leaf_angle_g(estimator, rng):
    """Beams from all directions, planophile G(theta): the per-beam G pools exactly."""
    lad = 1.5
    model = LeafAngle("planophile")
    grid = VoxelGrid((0, 0, 0), 0.4, (1, 1, 1))
    n = 6000
    centre = np.full(3, 0.2)
    d = rng.normal(size=(n, 3))
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    target = centre + (rng.random((n, 3)) - 0.5) * 0.4
    o = target - 2.0 * d
    gb = model.G(np.arccos(d[:, 2]))
    x = rng.exponential(1.0 / (gb * lad))
    # entry distance of each beam into the cube, so hits are drawn inside it only
    t_in = np.max(np.minimum((grid.lower - o) / d, (grid.upper - o) / d), axis=1)
    r = t_in + x
    beams = Beams.from_rays(o, d, hit_range=r, kind=EchoKind.LEAF)
    beams.g = gb
    res = estimate_lad(trace(grid, beams), estimator=estimator, leaf_size=None)
    got, se = float(res.lad[0, 0, 0]), float(res.lad_std[0, 0, 0])
    assert abs(got - lad) < 2 * se, (got, lad, se)
    assert gb.min() < res.g_eff[0, 0, 0] < gb.max()


def test_bcmle_removes_the_small_sample_bias(rng):
    """Many voxels of 20 beams each: the MLE is biased high, bcmle is not."""
    lad, g, h, nv, per = 2.0, 0.5, 1.0, 2000, 20
    grid = VoxelGrid((0, 0, 0), h, (nv, 1, 1))
    n = nv * per
    o = np.column_stack([(np.repeat(np.arange(nv), per) + rng.random(n)) * h,
                         np.full(n, -1.0), rng.random(n) * h])
    d = np.tile([0.0, 1.0, 0.0], (n, 1))
    x = rng.exponential(1.0 / (g * lad), n)
    beams = Beams.from_rays(o, d, hit_range=np.where(x < h, 1.0 + x, np.inf), max_range=3.0)
    beams.g = np.full(n, g)
    stats = trace(grid, beams)
    bc = estimate_lad(stats, estimator="bcmle", leaf_size=None).lad.ravel()
    mle = estimate_lad(stats, estimator="voxlad", leaf_size=None).lad.ravel()
    se_bc = bc.std(ddof=1) / np.sqrt(nv)
    se_mle = mle.std(ddof=1) / np.sqrt(nv)
    assert abs(bc.mean() - lad) < 2 * se_bc, (bc.mean(), se_bc)
    assert mle.mean() - lad > 3 * se_mle, (mle.mean(), se_mle)


@pytest.mark.parametrize("estimator", [e.value for e in Estimator])
def test_all_transmitted_gives_zero(estimator, rng):
    grid = VoxelGrid((0, 0, 0), 0.3, (2, 2, 2))
    beams = _slab_beams(rng, grid, 500, 0.0)
    res = estimate_lad(trace(grid, beams), estimator=estimator, leaf_size=None)
    assert np.all(res.lad == 0.0) and np.all(res.lad_std == 0.0)
    assert np.all(res.flags == 0)


def _finite(res):
    for a in (res.lad, res.lad_std, res.lad_raw, res.g_eff):
        assert np.all(np.isfinite(a))
        assert np.all(a >= 0)


@pytest.mark.parametrize("estimator", [e.value for e in Estimator])
def test_too_few_beams_flagged_and_finite(estimator, rng):
    grid = VoxelGrid((0, 0, 0), 0.3, (1, 1, 1))
    beams = _slab_beams(rng, grid, 3, 2.0)
    res = estimate_lad(trace(grid, beams), estimator=estimator, n_min=5)
    _finite(res)
    assert res.flags[0, 0, 0] & Flag.FEW_BEAMS
    assert res.occluded[0, 0, 0] and res.lad[0, 0, 0] == 0.0


@pytest.mark.parametrize("estimator", [e.value for e in Estimator])
def test_no_beams_at_all_flagged_and_finite(estimator):
    grid = VoxelGrid((0, 0, 0), 0.3, (2, 1, 1))
    beams = Beams.from_rays([0, 0, 5], [[0, 0, 1]])  # misses the grid
    res = estimate_lad(trace(grid, beams), estimator=estimator)
    _finite(res)
    assert np.all(res.flags & Flag.FEW_BEAMS)


@pytest.mark.parametrize("estimator", [e.value for e in Estimator])
def test_saturated_voxel_flagged_and_finite(estimator, rng):
    """Every entering beam is stopped by a leaf inside the voxel."""
    grid = VoxelGrid((0, 0, 0), 0.3, (1, 1, 1))
    n = 50
    o = np.column_stack([np.full(n, -1.0), rng.random((n, 2)) * 0.3])
    beams = Beams.from_rays(o, np.tile([1.0, 0, 0], (n, 1)), hit_range=1.0 + rng.uniform(0.05, 0.25, n))
    res = estimate_lad(trace(grid, beams), estimator=estimator, leaf_size=None)
    _finite(res)
    assert res.flags[0, 0, 0] & Flag.SATURATED
    assert res.lad[0, 0, 0] > 0
    if estimator == "beer_lambert":  # ln(2N + 2) / (G delta), G = 1 here
        assert res.lad[0, 0, 0] == pytest.approx(np.log(2 * n + 2) / 0.3, rel=1e-9)


@pytest.mark.parametrize("estimator", [e.value for e in Estimator])
def test_hits_at_entry_face_low_explored_and_finite(estimator, rng):
    """All beams stop at the very front: no free path, nothing seen behind."""
    grid = VoxelGrid((0, 0, 0), 0.3, (1, 1, 1))
    n = 40
    o = np.column_stack([np.full(n, -1.0), rng.random((n, 2)) * 0.3])
    beams = Beams.from_rays(o, np.tile([1.0, 0, 0], (n, 1)), hit_range=np.full(n, 1.0))
    res = estimate_lad(trace(grid, beams), estimator=estimator, leaf_size=None)
    _finite(res)
    assert res.flags[0, 0, 0] & Flag.SATURATED
    assert res.flags[0, 0, 0] & Flag.LOW_EXPLORED
    assert res.occluded[0, 0, 0]


def test_large_leaves_flagged(rng):
    grid = VoxelGrid((0, 0, 0), 0.05, (1, 1, 1))
    beams = _slab_beams(rng, grid, 200, 1.0)
    stats = trace(grid, beams)
    assert estimate_lad(stats, leaf_size=0.05).flags[0, 0, 0] & Flag.LARGE_LEAVES
    assert not estimate_lad(stats, leaf_size=0.01).flags[0, 0, 0] & Flag.LARGE_LEAVES
    assert not estimate_lad(stats, leaf_size=None).flags[0, 0, 0] & Flag.LARGE_LEAVES


def test_layer_fill_and_small_voxel_factor(rng):
    """Occluded crown voxels take their layer's mean; the factor scales everything."""
    lad, g = 1.0, 0.5
    grid = VoxelGrid((0, 0, 0), 0.5, (3, 1, 1))
    n = 3000
    o = np.column_stack([np.full(n, -1.0), rng.random(n) * 0.5, rng.random(n) * 0.5])
    x = rng.exponential(1.0 / (g * lad), n)
    beams = Beams.from_rays(o, np.tile([1.0, 0, 0], (n, 1)), hit_range=np.where(x < 1.0, 1.0 + x, np.inf),
                            max_range=2.0)  # the third voxel is never reached
    beams.g = np.full(n, g)
    stats = trace(grid, beams)
    mask = np.ones(grid.shape, bool)
    plain = estimate_lad(stats, leaf_size=None)
    assert plain.occluded[2, 0, 0] and not plain.occluded[:2, 0, 0].any()
    filled = estimate_lad(stats, leaf_size=None, fill="layer", fill_mask=mask)
    assert filled.flags[2, 0, 0] & Flag.FILLED
    assert filled.lad[2, 0, 0] == pytest.approx(plain.lad[:2, 0, 0].mean(), rel=1e-12)
    scaled = estimate_lad(stats, leaf_size=None, small_voxel_factor=0.95)
    np.testing.assert_allclose(scaled.lad, 0.95 * plain.lad, rtol=1e-12)


def test_neighbourhood_fill_takes_the_nearest_seen_voxels(rng):
    """LAD rising along the beams (0.4, 0.8, ... 2.0 in x = 0..4) over five rows; the last column
    is never reached (occluded).  Its nearest cube holding at least FILL_MIN_SEEN seen voxels is
    the half-width 2 one (x = 3, 4), so the fill is the mean of their estimates, whose true value
    is 1.8 (a layer's mean would be 1.2): within 3 standard errors of that mean."""
    from tlsvox.voxel.fills import FILL_MIN_SEEN, fill_neighbourhood

    h, g = 0.5, 0.5
    grid = VoxelGrid((0, 0, 0), h, (6, 5, 1))
    true = 0.4 * (np.arange(5) + 1)
    n = 20000
    o = np.column_stack([np.full(n, -1.0), rng.random(n) * 2.5, rng.random(n) * 0.5])
    # free path through piecewise-constant LAD: the optical depth g u h per voxel crossed
    tau = np.concatenate([[0.0], np.cumsum(g * true * h)])
    e = rng.exponential(1.0, n)
    col = np.searchsorted(tau, e) - 1  # the voxel where the beam stops (5: passes all)
    inside = col < 5
    x = np.where(inside, col * h + (e - tau[np.minimum(col, 4)]) / (g * true[np.minimum(col, 4)]), np.inf)
    beams = Beams.from_rays(o, np.tile([1.0, 0, 0], (n, 1)), hit_range=np.where(inside, 1.0 + x, np.inf),
                            max_range=1.0 + 5 * h)  # the sixth column is never reached
    beams.g = np.full(n, g)
    stats = trace(grid, beams)
    plain = estimate_lad(stats, leaf_size=None)
    assert plain.occluded[5].all() and not plain.occluded[:5].any()
    mask = np.ones(grid.shape, bool)
    filled = estimate_lad(stats, leaf_size=None, fill="neighbourhood", fill_mask=mask)
    assert np.all(filled.flags[5] & Flag.FILLED) and filled.options["fill_min_seen"] == FILL_MIN_SEEN
    near = plain.lad[3:5]  # x = 3, 4: ten seen voxels around each occluded one (fewer at the edge rows)
    np.testing.assert_allclose(filled.lad[5, 2, 0], near.mean(), rtol=1e-12)
    se = np.sqrt(np.mean(plain.lad_std[3:5] ** 2) / near.size)
    assert abs(filled.lad[5, 2, 0] - 1.8) < 3 * se, (filled.lad[5, 2, 0], se)
    layer = estimate_lad(stats, leaf_size=None, fill="layer", fill_mask=mask)
    assert layer.lad[5, 2, 0] == pytest.approx(plain.lad[:5].mean(), rel=1e-12)
    assert abs(layer.lad[5, 2, 0] - 1.2) < 0.1
    # the function itself: voxels beyond every radius take their layer's mean
    lad = np.zeros((20, 1, 1))
    lad[0] = 3.0
    occ = np.zeros((20, 1, 1), bool)
    occ[15:] = True
    out, done = fill_neighbourhood(lad, occ, np.ones((20, 1, 1), bool), radii=(1,), min_seen=1)
    assert done[15:].all() and out[15, 0, 0] == 0.0 and out[19, 0, 0] == pytest.approx(3.0 / 15)
    # never below 0: the box sums run over values of very different sizes
    field = np.where(rng.random((30, 30, 30)) < 0.2, rng.lognormal(2.0, 2.0, (30, 30, 30)), 0.0)
    hidden = rng.random(field.shape) < 0.3
    out, done = fill_neighbourhood(np.where(hidden, 0.0, field), hidden, np.ones(field.shape, bool))
    assert done[hidden].all() and np.all(out >= 0) and np.all(np.isfinite(out))
    # a cube that needs no seen voxel would give 0 / 0
    for bad in (dict(min_seen=0), dict(radii=(0,)), dict(radii=()), dict(radii=(1.5,))):
        with pytest.raises(InputError, match="min_seen|radii"):
            fill_neighbourhood(lad, occ, np.ones((20, 1, 1), bool), **bad)


def _column_beams(rng, grid, true, g, n, *, reverse=False, columns=None):
    """n beams along +x (``reverse``: -x from the far side) through a grid whose LAD is
    ``true[x]`` per column, stopping after ``columns`` columns (the rest is never reached)."""
    h, nx = grid.voxel_size, grid.shape[0]
    order = np.arange(nx)[::-1] if reverse else np.arange(nx)
    order = order[:columns]
    tau = np.concatenate([[0.0], np.cumsum(g * true[order] * h)])
    e = rng.exponential(1.0, n)
    k = np.searchsorted(tau, e) - 1  # the k-th column crossed is where the beam stops
    inside = k < len(order)
    kk = np.minimum(k, len(order) - 1)
    x = np.where(inside, kk * h + (e - tau[kk]) / (g * true[order][kk]), np.inf)
    start = grid.upper[0] + 1.0 if reverse else grid.lower[0] - 1.0
    o = np.column_stack([np.full(n, start), rng.random(n) * grid.shape[1] * h, rng.random(n) * h])
    d = np.tile([-1.0 if reverse else 1.0, 0, 0], (n, 1))
    beams = Beams.from_rays(o, d, hit_range=np.where(inside, 1.0 + x, np.inf), max_range=1.0 + len(order) * h)
    beams.g = np.full(n, g)
    return beams


def test_calibrated_fill_measures_the_true_ratio(rng):
    """A dense core (LAD 4 in x = 3) between sparser columns, two scans from opposite sides,
    each reaching three columns: x = 3 is hidden from both, x = 4-6 from the first scan only and
    x = 0-2 from the second.  Here what one side hides is sparser than what that side sees next
    to it (the fill from the near side's LAD 2 column); the ratio the estimates give must be the
    ratio the true LAD gives through the same fill and the same occlusion (within 4 %: about 3
    standard errors of estimates pooled over 30 voxels of ~1,000 hits each), and the core's fill
    is the pooled neighbourhood fill times that ratio."""
    from tlsvox.voxel.fills import cross_scan_ratio, fill_neighbourhood

    h, g, n = 0.5, 0.5, 20000
    grid = VoxelGrid((0, 0, 0), h, (7, 5, 1))
    true = np.array([0.5, 1.0, 2.0, 4.0, 2.0, 1.0, 0.5])
    scans = [trace(grid, _column_beams(rng, grid, true, g, n, columns=3)),
             trace(grid, _column_beams(rng, grid, true, g, n, reverse=True, columns=3))]
    pooled = scans[0] + scans[1]
    mask = np.ones(grid.shape, bool)
    own = [estimate_lad(s, leaf_size=None) for s in scans]
    assert own[0].occluded[3:].all() and not own[0].occluded[:3].any()
    assert own[1].occluded[:4].all() and not own[1].occluded[4:].any()
    # the expected ratio: the same fill and occlusion on the true LAD
    field = np.broadcast_to(true[:, None, None], grid.shape)
    num = den = 0.0
    for b, a in ((0, 1), (1, 0)):
        filled, reached = fill_neighbourhood(np.where(own[b].occluded, 0.0, field), own[b].occluded, mask)
        hidden = own[b].occluded & reached & ~own[a].occluded
        num, den = num + field[hidden].sum(), den + filled[hidden].sum()
    expected = num / den
    assert abs(expected - 1) > 0.2  # a ratio the test can tell from 1
    got = cross_scan_ratio(scans, mask)
    assert got["voxels"] == 30 and got["ratio"] == pytest.approx(expected, rel=0.04), (got, expected)
    cal = estimate_lad(pooled, leaf_size=None, fill="calibrated", fill_mask=mask, scan_stats=scans)
    plain = estimate_lad(pooled, leaf_size=None, fill="neighbourhood", fill_mask=mask)
    assert cal.occluded[3].all() and np.all(cal.flags[3] & Flag.FILLED)
    assert cal.options["fill_ratio"] == got["ratio"]
    np.testing.assert_allclose(cal.lad[3], plain.lad[3] * got["ratio"], rtol=1e-12)
    np.testing.assert_array_equal(cal.lad[~cal.occluded], plain.lad[~plain.occluded])
    # bad calls: one line each, never a traceback from numpy
    with pytest.raises(InputError, match="two or more scans, got 1"):
        estimate_lad(pooled, leaf_size=None, fill="calibrated", fill_mask=mask, scan_stats=scans[:1])
    with pytest.raises(InputError, match="two or more scans"):
        cross_scan_ratio(scans[:1], mask)
    with pytest.raises(InputError, match="scan_stats="):
        estimate_lad(pooled, leaf_size=None, fill="calibrated", fill_mask=mask)
    with pytest.raises(InputError, match="must hold VoxelStats"):
        estimate_lad(pooled, leaf_size=None, fill="calibrated", fill_mask=mask, scan_stats=[scans[0], "b"])
    other = trace(VoxelGrid((0, 0, 0), h, (7, 5, 2)), _column_beams(rng, grid, true, g, 10, columns=3))
    with pytest.raises(InputError, match="different grid"):
        estimate_lad(pooled, leaf_size=None, fill="calibrated", fill_mask=mask, scan_stats=[scans[0], other])
    with pytest.raises(InputError, match="mask has shape"):
        cross_scan_ratio(scans, mask[:, :, :0])
    gen = (s for s in scans)  # any iterable of sums
    assert estimate_lad(pooled, leaf_size=None, fill="calibrated", fill_mask=mask, scan_stats=gen).options[
        "fill_ratio"] == got["ratio"]


def _stats_seeing(grid, lad, seen):
    """Sums whose ``bcmle`` estimate is exactly ``lad`` in the voxels ``seen`` (100 beams, no
    echo depth term) and which leave every other voxel without a beam (occluded)."""
    from tlsvox.voxel.stats import FIELDS, NF, VoxelStats

    acc = np.zeros((grid.n_voxels, NF))
    flat = np.flatnonzero(np.asarray(seen).ravel())
    col = {name: FIELDS.index(name) for name in FIELDS}
    acc[flat, col["count"]] = acc[flat, col["n_w"]] = 100.0
    acc[flat, col["path_wg"]] = 10.0
    acc[flat, col["path_w"]] = acc[flat, col["chord_w"]] = 20.0
    acc[flat, col["leaf_w"]] = 10.0 * np.asarray(lad).ravel()[flat]
    return VoxelStats(grid, acc)


def test_calibrated_ratio_counts_only_voxels_the_fill_reaches():
    """A column of 20 voxels, LAD 1 + (z/10)^2: scan a sees z = 0-5, scan b z = 8-19.  a's
    neighbourhood fill (at least 5 seen voxels in a cube of half-width 1, 2, 4 or 8) reaches
    z = 6-9 only, b's z = 4-7; the voxels one scan sees that the other's fill reaches are z = 8, 9
    (b sees) and z = 4, 5 (a sees).  By hand: ratio = (u8 + u9 + u4 + u5) / (mean u0..5 + mean
    u1..5 + mean u8..12 + mean u8..13); the voxels b sees above z = 9, which a's fill never
    reaches, must not count."""
    from tlsvox.voxel.fills import cross_scan_ratio

    grid = VoxelGrid((0, 0, 0), 1.0, (1, 1, 20))
    z = np.arange(20)
    u = 1.0 + (z / 10.0) ** 2
    lad = u.reshape(grid.shape)
    a = _stats_seeing(grid, lad, (z <= 5).reshape(grid.shape))
    b = _stats_seeing(grid, lad, (z >= 8).reshape(grid.shape))
    np.testing.assert_allclose(estimate_lad(a, leaf_size=None).lad.ravel()[:6], u[:6], rtol=1e-12)
    got = cross_scan_ratio([a, b], np.ones(grid.shape, bool))
    seen = u[8] + u[9] + u[4] + u[5]
    filled = u[0:6].mean() + u[1:6].mean() + u[8:13].mean() + u[8:14].mean()
    assert got["voxels"] == 4 and got["measured"] == pytest.approx(seen / filled, rel=1e-12)
    # four voxels: under CALIBRATION_MIN_VOXELS, so the fill is not scaled
    assert not got["calibrated"] and got["ratio"] == 1.0
    assert [p["voxels"] for p in got["per_scan"]] == [2, 2]


def test_leaf_angles_per_layer_recover_both_layers(tracer, rng):
    """Two 0.5 m layers of LAD 1.5, planophile leaves below and erectophile above, crossed by
    horizontal beams (G 0.270 and 0.540 at 90 degrees).  With one G table per layer
    (``g_layer``) both layers' estimates are within 3 standard errors of 1.5; with the beams' one
    G (the uniform model's 0.405) the lower layer reads 1.5 x 0.270 / 0.405 = 1.0 and the upper
    2.0, each more than 5 standard errors off.  On every tracer device."""
    from tlsvox.voxel.pulses import layer_g_tables

    h, lad, n = 0.5, 1.5, 6000
    grid = VoxelGrid((0, 0, 0), h, (1, 1, 2))
    models = [LeafAngle("planophile"), LeafAngle("erectophile")]
    z = rng.random(n) * 2 * h
    layer = (z >= h).astype(int)
    g_true = np.array([float(m.G(np.pi / 2)) for m in models])[layer]
    o = np.column_stack([np.full(n, -1.0), rng.random(n) * h, z])
    x = rng.exponential(1.0 / (g_true * lad))
    beams = Beams.from_rays(o, np.tile([1.0, 0, 0], (n, 1)), hit_range=np.where(x < h, 1.0 + x, np.inf),
                            kind=EchoKind.LEAF, max_range=1.0 + h + 1.0)
    beams.g = np.full(n, float(LeafAngle("uniform").G(np.pi / 2)))
    tables = layer_g_tables(models, outward=False)
    per_layer = estimate_lad(tracer.trace(grid, beams, outward=(tables, (0.0, 0.0)), g_layer=[0, 1]), leaf_size=None)
    one = estimate_lad(tracer.trace(grid, beams), leaf_size=None)
    for k in range(2):
        got, se = float(per_layer.lad[0, 0, k]), float(per_layer.lad_std[0, 0, k])
        assert abs(got - lad) < 3 * se, (k, got, se)
        assert abs(float(one.lad[0, 0, k]) - lad) > 5 * se, (k, float(one.lad[0, 0, k]), se)
    for bad in ([0, 2], [0.9, 1.0], [[0, 1]], ["a", "b"]):
        with pytest.raises(InputError, match="g_layer must give an integer layer"):
            tracer.trace(grid, beams, outward=(tables, (0.0, 0.0)), g_layer=bad)
    with pytest.raises(InputError, match="needs outward"):
        tracer.trace(grid, beams, g_layer=[0, 1])


def test_bad_options_rejected(rng):
    grid = VoxelGrid((0, 0, 0), 0.3, (1, 1, 1))
    stats = trace(grid, _slab_beams(rng, grid, 10, 1.0))
    with pytest.raises(InputError, match="bcmle, voxlad, beer_lambert, contact_frequency"):
        estimate_lad(stats, estimator="beer-lambert")
    with pytest.raises(InputError, match="fill"):
        estimate_lad(stats, fill="height")
    with pytest.raises(InputError, match="n_min"):
        estimate_lad(stats, n_min=0)
    with pytest.raises(InputError, match="small_voxel_factor"):
        estimate_lad(stats, small_voxel_factor=-1)
