"""The sparse layout (tlsvox.voxel.bricks): the listed voxels' sums equal the dense
trace's (bit for bit with private copies; within the fixed-point resolution with the
atomic GPU tracer, whose sparse sums use the coarser brick scale), the brick sums equal the dense sums gathered per brick, and
voxelize gives the same LAD either way while its memory follows the echoes."""

from __future__ import annotations

import numpy as np
import pytest

from tests.tlsvox.voxel.test_voxlad import box_scans  # noqa: F401  (fixture)
from tlsvox.errors import InputError
from tlsvox.voxel.bricks import BRICK, Bricks
from tlsvox.voxel.grid import VoxelGrid
from tlsvox.voxel.stages import Layout, memory_plan, voxelize
from tlsvox.voxel.trace import FIELDS, Beams, EchoKind, Tracer, echo_rows, fixed_point_scale


def _beams(rng, n=6000):
    """Rays from one side of the grid with 0-3 echoes of every kind, a tail on some."""
    o = rng.uniform(-1, 0, (n, 3))
    d = rng.normal(size=(n, 3))
    d[:, 0] = np.abs(d[:, 0]) + 0.3
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    k = rng.integers(0, 4, n)
    start = np.concatenate([[0], np.cumsum(k)])
    ranges = np.concatenate([np.sort(rng.uniform(0.5, 4.0, m)) for m in k])
    weight = np.concatenate([np.full(m, 0.8 / max(m, 1)) for m in k])
    kind = rng.choice([EchoKind.LEAF, EchoKind.WOOD, EchoKind.OTHER], len(ranges)).astype(np.uint8)
    tail = np.where(k == 0, 1.0, 0.2)
    return Beams(o, d, start, ranges, weight, kind, tail, np.full(n, 6.0))


def assert_same_sums(tracer, grid, beams, sparse_acc, dense_acc, dense_count):
    """Equal bit for bit with private copies; with atomics each add rounds to 1/scale
    in each trace, so a voxel's sums agree within adds x (1/dense + 1/sparse scale)."""
    if not tracer.atomics:
        np.testing.assert_array_equal(sparse_acc, dense_acc)
        return
    unit = 1 / fixed_point_scale(beams, grid.voxel_size) + 1 / fixed_point_scale(beams, grid.voxel_size,
                                                                                   sparse=True)
    adds = np.asarray(dense_count, float)[:, None] + 1.0
    assert np.all(np.abs(sparse_acc - dense_acc) <= adds * unit), np.abs(sparse_acc - dense_acc).max()


@pytest.fixture(scope="module")
def traced(tracer):
    grid = VoxelGrid((-0.3, -0.4, -0.5), 0.1, (37, 21, 19))  # bricks stick out of the grid on every axis
    beams = _beams(np.random.default_rng(7))
    rows = echo_rows(grid, beams)
    return grid, beams, rows, tracer.trace(grid, beams), tracer.trace(grid, beams, rows=rows)


def test_rows_equal_the_dense_trace(traced, tracer):
    grid, beams, rows, dense, sparse = traced
    assert sparse.sparse and not dense.sparse
    flat = grid.flat(rows.ijk)
    assert_same_sums(tracer, grid, beams, sparse.acc, dense.acc[flat],
                     dense.field("count").reshape(-1)[flat])
    assert sparse.n_steps == dense.n_steps
    others = np.ones(grid.n_voxels, bool)
    others[flat] = False
    for name in ("leaf_w", "wood_w"):  # every leaf and wood echo landed in a listed voxel
        assert dense.acc[others, FIELDS.index(name)].sum() == 0.0
    assert sparse.field("leaf_w").shape == (rows.n_rows,)


def test_atomic_sums_agree_within_their_resolution(tracer):
    """The GPU's accumulation (64-bit fixed-point atomics), run on this device: sparse and
    dense sums agree within the fixed-point bound, and with private copies' float64 sums."""
    if not tracer.info.int64_atomics:
        pytest.skip(f"{tracer.info.label} has no 64-bit atomics")
    atomic = Tracer(device=tracer.info, atomics=True)
    grid = VoxelGrid((-0.3, -0.4, -0.5), 0.1, (37, 21, 19))
    beams = _beams(np.random.default_rng(7))
    rows = echo_rows(grid, beams)
    dense, sparse = atomic.trace(grid, beams), atomic.trace(grid, beams, rows=rows)
    flat = grid.flat(rows.ijk)
    count = dense.field("count").reshape(-1)[flat]
    assert_same_sums(atomic, grid, beams, sparse.acc, dense.acc[flat], count)
    exact = Tracer(device=tracer.info, atomics=False).trace(grid, beams)
    bound = (dense.field("count").reshape(-1)[:, None] + 1.0) / fixed_point_scale(beams, grid.voxel_size)
    assert np.all(np.abs(dense.acc.reshape(exact.acc.shape) - exact.acc) <= bound.reshape(-1, 1))


def test_brick_sums_gather_the_dense_sums(traced):
    grid, _, rows, dense, sparse = traced
    brick = tuple((grid.unflat(np.arange(grid.n_voxels)) // BRICK).T)
    for name, dense_name in (("path_w", "path_w"), ("chord_w", "chord_w"), ("path_wg", "path_wg"),
                             ("visits_w", "n_w"), ("visits", "count")):
        gathered = np.zeros(rows.shape)
        np.add.at(gathered, brick, dense.field(dense_name).ravel())
        np.testing.assert_allclose(sparse.brick_field(name), gathered, rtol=1e-12, atol=1e-12)
    # beams crossing a brick: at least as many as enter its busiest voxel, at most the visits
    busiest = np.zeros(rows.shape)
    np.maximum.at(busiest, brick, dense.field("count").ravel())
    visits = np.zeros(rows.shape)
    np.add.at(visits, brick, dense.field("count").ravel())
    count = sparse.brick_field("count")
    assert np.all(count >= busiest) and np.all(count <= visits) and count.sum() > 0


def test_atomic_sparse_trace_matches(traced, tracer):
    if not tracer.info.int64_atomics:
        pytest.skip("this OpenCL device has no 64-bit atomics")
    grid, beams, rows, _, sparse = traced
    got = Tracer(tracer.info, atomics=True).trace(grid, beams, rows=rows)
    np.testing.assert_allclose(got.acc, sparse.acc, rtol=1e-9, atol=1e-9)
    np.testing.assert_allclose(got.bricks, sparse.bricks, rtol=1e-9, atol=1e-9)


def test_bricks_index_rows_by_brick():
    g = VoxelGrid((0, 0, 0), 1.0, (20, 9, 3))
    ijk = np.array([[19, 8, 2], [0, 0, 0], [8, 0, 0], [7, 7, 2], [0, 0, 0]])
    rows = Bricks.from_ijk(g, ijk)
    assert rows.shape == (3, 2, 1) and rows.n_rows == 4
    assert rows.ijk.tolist() == [[0, 0, 0], [7, 7, 2], [8, 0, 0], [19, 8, 2]]
    assert rows.start.tolist() == [0, 2, 2, 3, 3, 3, 4]
    assert rows.voxels_in_grid().sum() == g.n_voxels
    assert len(rows.brick_voxels([5])) == 4 * 1 * 3
    with pytest.raises(InputError, match="inside the grid"):
        Bricks.from_ijk(g, [[20, 0, 0]])


def test_voxelize_sparse_gives_the_dense_lad(box_scans):  # noqa: F811
    kw = dict(voxel_size=0.25, leaf_angle="spherical", ground=None, progress=False)
    dense = voxelize(box_scans, layout="dense", **kw)
    sparse = voxelize(box_scans, layout="sparse", **kw)
    assert dense.scene.meta["layout"] == "dense" and sparse.scene.meta["layout"] == "sparse"
    flat = dense.grid.flat(sparse.lad.rows.ijk)
    if Tracer().atomics:  # the GPU's fixed-point sums: equal within their resolution (2^-40 of a sum)
        np.testing.assert_allclose(sparse.lad.lad, dense.lad.lad.reshape(-1)[flat], rtol=1e-9)
    else:
        np.testing.assert_array_equal(sparse.lad.lad, dense.lad.lad.reshape(-1)[flat])
    np.testing.assert_array_equal(sparse.lad.flags, dense.lad.flags.reshape(-1)[flat])
    # every voxel with leaves is a row, so the scenes hold the same leaf area
    assert sparse.scene.lad.sum() == pytest.approx(dense.scene.lad.sum(), rel=1e-12)
    assert "occluded_bricks" in sparse.scene.meta


def test_sparse_layer_fill_recovers_the_box(box_scans):  # noqa: F811
    # 0.1 m voxels and n_min = 12 leave about half the box's voxels occluded; both fills must
    # bring the leaf area back to the truth (LAD 0.8 x 8 m3) within 10 % (the unfilled
    # estimate's Monte Carlo error is ~2 %, the layer fill's model error the rest)
    kw = dict(voxel_size=0.1, leaf_angle="spherical", ground=None, progress=False, fill="layer", n_min=12)
    truth = 0.8 * 8.0
    for layout in ("dense", "sparse"):
        res = voxelize(box_scans, layout=layout, **kw)
        assert res.scene.occluded.mean() > 0.3
        assert res.scene.lad.sum() * 0.1**3 == pytest.approx(truth, rel=0.1), layout
    # the neighbourhood fill (dense only) on the same homogeneous box: as close
    res = voxelize(box_scans, layout="dense", **{**kw, "fill": "neighbourhood"})
    assert res.scene.meta["options"]["fill"] == "neighbourhood" and res.scene.meta["options"]["fill_radii"]
    assert res.scene.lad.sum() * 0.1**3 == pytest.approx(truth, rel=0.1)
    with pytest.raises(InputError, match="fill='neighbourhood' needs the dense layout"):
        voxelize(box_scans, layout="sparse", **{**kw, "fill": "neighbourhood"})
    # the calibrated fill: in a homogeneous box what one scan hides holds what its neighbours do, so
    # the scans' own ratio stays near 1 (within 20 %: its two per-scan parts, ~500 voxels each at the
    # box's edges where few beams enter, scatter by more, 0.88 and 1.54 measured) and the total as close
    res = voxelize(box_scans, layout="dense", **{**kw, "fill": "calibrated"})
    cal = res.scene.meta["options"]["fill_calibration"]
    assert cal["calibrated"] and cal["voxels"] > 500 and len(cal["per_scan"]) == 2
    assert 0.8 < res.scene.meta["options"]["fill_ratio"] < 1.25
    assert res.scene.lad.sum() * 0.1**3 == pytest.approx(truth, rel=0.1)
    with pytest.raises(InputError, match="fill='calibrated' needs the dense layout"):
        voxelize(box_scans, layout="sparse", **{**kw, "fill": "calibrated"})
    one_scan = "needs two or more scans, got 1; with one scan use fill='neighbourhood' \\(CLI --fill neighbourhood\\)"
    with pytest.raises(InputError, match=one_scan):
        voxelize(box_scans[:1], layout="dense", **{**kw, "fill": "calibrated"})


def test_memory_plan_chooses_and_explains(box_scans, tracer):  # noqa: F811
    from tlsvox.voxel.plan import with_allocator
    from tlsvox.voxel.pulses import beams_from_scan

    grid = VoxelGrid.from_bounds([-4, -4, 0], [4, 4, 4], voxel_size=0.1)  # the box and much air around it

    beams = Beams.concat([beams_from_scan(s)[0] for s in box_scans])
    plan = memory_plan(grid, beams, tracer)
    assert plan.layout is Layout.DENSE and plan.sparse < plan.dense
    assert "hold echoes" in plan.describe()
    roomy = with_allocator(plan.beams + plan.echoes + plan.sparse) + 1024  # the sparse run fits, the dense not
    assert memory_plan(grid, beams, tracer, max_bytes=roomy).layout is Layout.SPARSE
    with pytest.raises(InputError, match=r"tracing and estimating with the dense layout need .* but only .* is "
                                         r"available; use layout='sparse'"):
        memory_plan(grid, beams, tracer, layout="dense", max_bytes=roomy)
    with pytest.raises(InputError, match="voxel_size of at least"):
        memory_plan(grid, beams, tracer, max_bytes=1024)


def test_memory_plan_counts_the_detection_model(box_scans, tracer):  # noqa: F811
    """undetected='model' keeps the scans' beams, a corrected copy and the joined copy (with up to
    ECHOES_PER_TAIL added echoes per pulse with a tail), its walk along the beams and a LAD lookup:
    the plan adds them, and a budget that fits the plain run but not the model refuses the model."""
    from tlsvox.voxel.detection import ECHOES_PER_TAIL
    from tlsvox.voxel.pulses import beams_from_scan
    from tlsvox.voxel.stages import undetected_bytes

    grid = VoxelGrid.from_bounds([-4, -4, 0], [4, 4, 4], voxel_size=0.1)
    beams = Beams.concat([beams_from_scan(s)[0] for s in box_scans])
    plain = memory_plan(grid, beams, tracer, layout="dense")
    model = memory_plan(grid, beams, tracer, layout="dense", undetected="model")
    assert plain.undetected == 0 and model.undetected == undetected_bytes(grid, beams, plain.beams, "dense", plain.rows)
    # at least the two extra copies of the beams and the added echoes' ranges and weights
    with_tail = int(np.count_nonzero(beams.tail > 1e-9))
    assert model.undetected >= 2 * plain.beams + with_tail * ECHOES_PER_TAIL * 16 + grid.n_voxels * 8
    assert model.run == plain.run + model.undetected
    assert "undetected='model'" in model.describe() and "undetected" not in plain.describe()
    with pytest.raises(InputError, match="with the dense layout need "):
        memory_plan(grid, beams, tracer, layout="dense", undetected="model", max_bytes=plain.need + 1024)


def test_memory_plan_counts_the_neighbourhood_fill(box_scans, tracer, rng):  # noqa: F811
    """fill='neighbourhood' (dense) adds NEIGHBOURHOOD_BYTES per voxel to the plan, and that bound
    holds for the fill's measured peak (tracemalloc, after a first call has loaded scipy)."""
    import tracemalloc

    from tlsvox.voxel.fills import fill_neighbourhood
    from tlsvox.voxel.plan import NEIGHBOURHOOD_BYTES, format_bytes
    from tlsvox.voxel.pulses import beams_from_scan

    grid = VoxelGrid.from_bounds([-4, -4, 0], [4, 4, 4], voxel_size=0.1)
    beams = Beams.concat([beams_from_scan(s)[0] for s in box_scans])
    plain = memory_plan(grid, beams, tracer, layout="dense")
    filled = memory_plan(grid, beams, tracer, layout="dense", fill="neighbourhood")
    assert filled.fill == grid.n_voxels * NEIGHBOURHOOD_BYTES and filled.run == plain.run + filled.fill
    assert f"the fill {format_bytes(filled.fill)}" in filled.describe()
    assert memory_plan(grid, beams, tracer, layout="sparse", fill="neighbourhood").fill == 0  # refused later
    calibrated = memory_plan(grid, beams, tracer, layout="dense", fill="calibrated", scans=2)
    with pytest.raises(InputError, match="two or more scans"):
        memory_plan(grid, beams, tracer, layout="dense", fill="calibrated")
    shape = (60, 60, 60)
    lad, occ, crown = rng.random(shape), rng.random(shape) < 0.3, rng.random(shape) < 0.8
    fill_neighbourhood(lad[:4, :4, :4], occ[:4, :4, :4], crown[:4, :4, :4])
    tracemalloc.start()
    fill_neighbourhood(np.where(occ, 0.0, lad), occ, crown)
    peak = tracemalloc.get_traced_memory()[1]
    tracemalloc.stop()
    assert peak <= NEIGHBOURHOOD_BYTES * lad.size
    # the calibrated fill: each scan's sums held beside the pooled ones, and the ratio's work on top of
    # the neighbourhood fill's, measured on the estimate of two scans' sums
    from tlsvox.voxel.estimators import estimate_lad
    from tlsvox.voxel.stats import FIELDS, NF, VoxelStats

    g = VoxelGrid((0, 0, 0), 0.2, shape)

    def sums():
        acc = rng.random((g.n_voxels, NF)) * 10
        acc[:, FIELDS.index("count")] = rng.integers(0, 20, g.n_voxels)
        return VoxelStats(g, acc)

    own = [sums(), sums()]
    pooled = own[0] + own[1]
    estimate_lad(pooled, fill="neighbourhood", fill_mask=crown)  # scipy loaded
    peaks = {}
    for fill, kw in (("neighbourhood", {}), ("calibrated", {"scan_stats": own})):
        tracemalloc.start()
        estimate_lad(pooled, fill=fill, fill_mask=crown, **kw)
        peaks[fill] = tracemalloc.get_traced_memory()[1]
        tracemalloc.stop()
    held = sum(s.acc.nbytes for s in own)
    per_voxel = (calibrated.fill - filled.fill) / grid.n_voxels
    assert peaks["calibrated"] - peaks["neighbourhood"] + held <= per_voxel * g.n_voxels, (peaks, held, per_voxel)


def test_outward_leaves_take_g_per_voxel(tracer):
    """With outward leaves each voxel's G comes from the table at the beam's zenith and the cosine c between
    the beam's horizontal direction and the voxel's outward direction: a table linear in both is
    interpolated exactly, so path_wg / path_w is known in every voxel crossed, dense and sparse alike."""
    grid = VoxelGrid((-2.0, -2.0, 0.0), 0.25, (16, 16, 8))
    rng = np.random.default_rng(3)
    n = 400
    o = np.column_stack([rng.uniform(-6, -3, n), rng.uniform(-1.5, 1.5, n), rng.uniform(0.2, 1.8, n)])
    d = np.column_stack([np.ones(n), rng.uniform(-0.5, 0.5, n), rng.uniform(-0.3, 0.3, n)])
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    beams = Beams(o, d, np.zeros(n + 1, np.int64), np.zeros(0), np.zeros(0), np.zeros(0, np.uint8), np.ones(n),
                  np.full(n, 20.0))
    theta, c = np.linspace(0, np.pi, 181), np.linspace(-1, 1, 129)
    table = 0.3 + 0.1 * theta[:, None] + 0.2 * c[None, :]
    centre = np.array([0.1, -0.2])
    stats = tracer.trace(grid, beams, outward=(table, centre))
    path = stats.field("path_w")
    assert (path > 0).sum() > 200
    # expected G of every voxel for every beam: average over the beams crossing it, weighted by their path
    expect = np.zeros(grid.shape)
    for b in range(n):
        one = tracer.trace(grid, Beams(o[b:b + 1], d[b:b + 1], np.zeros(2, np.int64), np.zeros(0), np.zeros(0),
                                       np.zeros(0, np.uint8), np.ones(1), np.full(1, 20.0)))
        p = one.field("path_w")
        ijk = np.argwhere(p > 0)
        r = grid.centers(ijk)[:, :2] - centre
        h = d[b, :2] / np.linalg.norm(d[b, :2])
        cv = (r @ h) / np.linalg.norm(r, axis=1)
        expect[tuple(ijk.T)] += p[tuple(ijk.T)] * (0.3 + 0.1 * np.arccos(d[b, 2]) + 0.2 * cv)
    seen = path > 0
    np.testing.assert_allclose(stats.field("path_wg")[seen] / path[seen], expect[seen] / path[seen], rtol=1e-9)
    rows = Bricks.from_ijk(grid, np.argwhere(seen))
    sparse = tracer.trace(grid, beams, rows=rows, outward=(table, centre))
    flat = grid.flat(rows.ijk)
    assert_same_sums(tracer, grid, beams, sparse.acc, stats.acc[flat], stats.field("count").reshape(-1)[flat])
    np.testing.assert_allclose(sparse.bricks[:, 5].sum(), stats.field("path_wg").sum(), rtol=1e-12)


def test_outward_g_table_averages_to_g():
    """Averaged over the beam's azimuth against the outward direction, outward leaves project as G(theta)."""
    from tlsvox.voxel.pulses import outward_g_table
    from voxlidar.leaf_orientation import LeafAngle

    for name in ("uniform", "planophile", "erectophile"):
        la = LeafAngle(name)
        phi = np.linspace(0, np.pi, 2001)
        table = outward_g_table(la, n_theta=7, n_c=4001)
        c = np.linspace(-1, 1, 4001)
        mean = np.array([np.trapezoid(np.interp(np.cos(phi), c, row), phi) / np.pi for row in table])
        np.testing.assert_allclose(mean, la.G(np.linspace(0, np.pi, 7)), atol=2e-3)


def test_cli_calibrated_fill(box_scans, tmp_path, capsys):  # noqa: F811
    """--fill calibrated: the ratio is in the scene; one scan gets one line naming the fix, and no file."""
    from tlsvox.cli.app import main as tlsvox_main
    from voxlidar.scene import Scene

    paths = []
    for s in box_scans:
        paths.append(str(tmp_path / f"{s.name}.laz"))
        s.write(paths[-1])
    common = ["--voxel-size", "0.1", "--ground", "none", "--leaf-angle", "spherical", "--n-min", "12",
              "--layout", "dense", "--fill", "calibrated"]
    assert tlsvox_main(["voxelize", *paths, "-o", str(tmp_path / "two.npz"), *common]) == 0
    scene = Scene.load(tmp_path / "two.npz")
    from tlsvox.voxel.fills import CALIBRATION_MIN_VOXELS

    cal = scene.meta["options"]["fill_calibration"]
    assert scene.meta["options"]["fill"] == "calibrated" and cal["calibrated"]
    assert cal["voxels"] >= CALIBRATION_MIN_VOXELS and scene.meta["options"]["fill_ratio"] == cal["ratio"]
    capsys.readouterr()
    assert tlsvox_main(["voxelize", paths[0], "-o", str(tmp_path / "one.npz"), *common]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "two or more scans" in err[0] and "fill='neighbourhood'" in err[0]
    assert not (tmp_path / "one.npz").exists()
