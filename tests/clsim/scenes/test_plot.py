"""Plots of many trees against known answers: leaf area is the sum of the trees',
instances share bricks (one copy per tree on the brick lattice), the shared and
the copied plot hold bit-identical voxels and give the identical waveform,
overlapping crowns add, and bad input is one line."""

from __future__ import annotations

import math
import re

import numpy as np
import pytest

from clsim.scenes import PlotScene, make_plot, merge_voxels, plot_canopy, random_tree_params, synthetic_tree_scene
from clsim.sensor import Sensor
from clsim.transport.bricks import BRICK, build_bricks
from clsim.transport.setup import prepare_run
from voxlidar.errors import InputError
from voxlidar.scene import Scene

H = 0.5                      # voxel size of the test plots, m


def dense(grid):
    """(cells, BRICK**3, 2) values per brick cell, zeros where empty: what the kernel reads."""
    out = np.zeros((int(np.prod(grid.brick_shape)), BRICK**3, 2), np.float32)
    occ = grid.index >= 0
    out[occ] = grid.pool.reshape(-1, BRICK**3, 2)[grid.index[occ]]
    return out


@pytest.fixture(scope="module")
def small_tree():
    """One synthetic tree at 0.5 m voxels (a few thousand triangles)."""
    params = random_tree_params("small", np.random.default_rng(4))
    return synthetic_tree_scene(params, seed=11, voxel_size=H, name="small")


@pytest.fixture(scope="module")
def plot():
    """Crowded on purpose: 10 trees of 3 models on a 28 m plot, crowns meeting."""
    return make_plot(28.0, 10, seed=7, n_models=3, voxel_size=H, kinds=("small", "narrow"),
                     min_spacing_m=3.0)


# -- leaf area, counts, placement ---------------------------------------------------------
def test_leaf_area_is_the_sum_of_the_trees(plot):
    tab = plot.table()
    models = {int(m): a for m, a in zip(tab["model"], tab["leaf_area_m2"])}
    assert len(tab) == plot.n_trees == 10 and len(models) == plot.n_models == 3
    # exact: the correctly rounded sum of each instance's Scene.total_leaf_area()
    assert plot.total_leaf_area() == math.fsum(models[int(m)] for m in tab["model"])
    # the copied scene sums LAD where crowns meet: same leaf area to rounding
    copied = plot.to_scene()
    assert copied.meta["merged_voxels"] > 0
    assert copied.total_leaf_area() == pytest.approx(plot.total_leaf_area(), rel=1e-12)
    # and each model's leaf area is its mesh's (exact LAD per voxel)
    for m, scene in enumerate(plot._models):
        assert models[m] == pytest.approx(np.sum(scene.lad) * H**3, rel=1e-12)


def test_mesh_leaf_area_kept_by_the_voxel_tree():
    from tlsvox.truth.synthetic import make_tree

    params = random_tree_params("small", np.random.default_rng(2))
    tree = make_tree(params, seed=3)
    p = PlotScene(20.0, voxel_size=H)
    for xy in ((6, 6), (14, 14)):
        p.add_tree(tree, *xy)                                  # a SyntheticTree, voxelised once
    assert p.n_models == 1 and p.table()["source"].tolist() == ["synthetic"] * 2
    assert p.total_leaf_area() == pytest.approx(2 * tree.leaf_area(), rel=1e-12)
    assert p.total_leaf_area() == pytest.approx(params.total_leaf_area * 2, rel=1e-9)


def test_same_seed_same_plot_and_spacing_kept():
    a = make_plot(30.0, 8, seed=3, n_models=2, kinds=("small",), min_spacing_m=6.0)
    b = make_plot(30.0, 8, seed=3, n_models=2, kinds=("small",), min_spacing_m=6.0)
    c = make_plot(30.0, 8, seed=4, n_models=2, kinds=("small",), min_spacing_m=6.0)
    ta, tb, tc = a.table(), b.table(), c.table()
    assert np.array_equal(ta, tb) and not np.array_equal(ta, tc)
    xy = np.column_stack([ta["x_m"], ta["y_m"]])
    d = np.hypot(*(xy[:, None] - xy[None]).transpose(2, 0, 1))
    assert d[np.triu_indices(len(xy), 1)].min() >= 6.0
    assert np.all(ta["on_lattice"])                               # snap="brick": every 8 voxels
    np.testing.assert_allclose(np.mod(xy, BRICK * H), 0.0, atol=1e-9)
    # the whole crown inside the plot (add_tree refuses otherwise)
    assert np.all((xy - ta["crown_radius_m"][:, None] >= 0) & (xy + ta["crown_radius_m"][:, None] <= 30.0))


def test_default_plot_has_30_trees_on_50_m():
    p = make_plot(seed=0)
    assert (p.n_trees, p.n_models, p.width_m, p.length_m) == (30, 6, 50.0, 50.0)
    assert set(p.table()["name"]) == {f"{k}-{i}" for i, k in enumerate(["broadleaf", "narrow", "small"] * 2)}
    mem = p.memory()
    assert mem["pool_bytes"] < mem["copied_pool_bytes"]


# -- shared bricks against copies -----------------------------------------------------------
@pytest.mark.parametrize("leaf_off", [False, True])
def test_shared_bricks_hold_exactly_the_copied_values(plot, leaf_off):
    shared = plot.brick_grid(leaf_off=leaf_off)
    copied = build_bricks(plot.to_scene(), leaf_off=leaf_off)
    assert shared.flags["merged_bricks"] > 0                     # the overlap path ran
    assert np.array_equal(shared.brick_shape, copied.brick_shape)
    assert np.array_equal(shared.index >= 0, copied.index >= 0)
    assert np.array_equal(dense(shared), dense(copied))          # bit for bit
    mem = plot.memory(leaf_off=leaf_off)
    assert mem["copied_pool_bytes"] == copied.pool.nbytes
    assert mem["pool_bytes"] == shared.pool.nbytes < copied.pool.nbytes


def test_off_lattice_trees_get_their_own_copy_and_same_values(small_tree):
    p = PlotScene(40.0, voxel_size=H)
    p.add_tree(small_tree, 8.0, 8.0, snap="brick")
    p.add_tree(small_tree, 24.0, 8.0, snap="brick")               # shares with the first
    p.add_tree(small_tree, 8.5, 25.5)                             # 1 voxel off the lattice: a copy
    p.add_tree(small_tree, 30.0, 30.0, trunk_xy=(0.5, 0.0))       # another anchor: another model
    tab = p.table()
    assert tab["on_lattice"].tolist() == [True, True, False, False]
    assert tab["x_m"].tolist() == [8.0, 24.0, 8.5, 30.0] and p.n_models == 2
    mem = p.memory()
    assert mem["merged_bricks"] == 0
    assert np.array_equal(dense(p.brick_grid()), dense(build_bricks(p.to_scene())))
    # known answer: the pool is the copies less the second lattice tree's bricks
    alone = PlotScene(40.0, voxel_size=H)
    alone.add_tree(small_tree, 24.0, 8.0, snap="brick")
    assert mem["pool_bytes"] == mem["copied_pool_bytes"] - alone.memory()["copied_pool_bytes"]


def test_voxel_snapped_plot_matches_its_copies():
    p = make_plot(30.0, 6, seed=5, n_models=2, kinds=("small",), snap="voxel", min_spacing_m=5.0)
    xy = np.column_stack([p.table()["x_m"], p.table()["y_m"]])
    assert not p.table()["on_lattice"].all()
    np.testing.assert_allclose(np.mod(xy + 1e-9, H), 1e-9, atol=1e-8)           # on voxel corners
    assert np.array_equal(dense(p.brick_grid()), dense(build_bricks(p.to_scene())))


def test_lattice_instances_share_one_copy(small_tree):
    """N instances of one tree on the brick lattice, apart: the pool is one tree's bricks."""
    p = PlotScene(64.0, voxel_size=H)
    for x in (8.0, 24.0, 40.0, 56.0):
        for y in (8.0, 24.0):
            p.add_tree(small_tree, x, y, snap="brick")
    g = p.brick_grid()
    model_pool = p._model_bricks(0, (0, 0, 0), False)[0].pool
    assert g.pool.nbytes == model_pool.nbytes
    assert p.memory()["copied_pool_bytes"] == 8 * model_pool.nbytes
    assert np.array_equal(dense(g), dense(build_bricks(p.to_scene())))


def test_crowns_at_one_place_add():
    tree = Scene(origin=(0, 0, 0), voxel_size=H, shape=(2, 2, 4), ijk=[[0, 0, 2], [1, 1, 3]], lad=[1.0, 0.5],
                 wood=[0.2, 0.0], ground_z=0.0, crown_center=(0.0, 0.0))
    p = PlotScene(8.0, voxel_size=H)
    p.add_tree(tree, 4.0, 4.0)
    p.add_tree(tree, 4.0, 4.0)
    s = p.to_scene()
    np.testing.assert_array_equal(s.lad, [2.0, 1.0])
    np.testing.assert_allclose(s.wood, [1 - 0.8**2, 0.0], rtol=1e-15)
    assert s.meta["merged_voxels"] == 2 and p.total_leaf_area() == 2 * tree.total_leaf_area()
    assert np.array_equal(dense(p.brick_grid()), dense(build_bricks(s)))


def test_merge_keeps_single_voxels_bit_for_bit():
    rng = np.random.default_rng(0)
    ijk = np.array([[0, 0, 0], [1, 0, 0], [0, 0, 0]])
    p = rng.uniform(0.1, 0.9, 3)
    out = merge_voxels(ijk, np.array([1.0, 2.0, 3.0]), p, np.zeros(3, bool), None, (2, 1, 1), "probability")
    assert out[0].tolist() == [[0, 0, 0], [1, 0, 0]] and out[1].tolist() == [4.0, 2.0]
    assert out[2][1] == p[1] and out[2][0] == pytest.approx(1 - (1 - p[0]) * (1 - p[2]), rel=1e-15)


def test_scanned_tree_from_a_file_with_other_wood_kind(tmp_path, small_tree):
    scanned = Scene(origin=(100.0, 200.0, 50.0), voxel_size=H, shape=(6, 6, 10),
                    ijk=[[2, 3, 4], [3, 3, 6], [3, 3, 2], [4, 4, 1]], lad=[0.8, 1.2, 0.0, 0.3],
                    wood=[0.0, 0.0, 0.6, 0.0],
                    wood_kind="area_density", ground_z=51.0, crown_center=(101.5, 201.5),
                    leaf_angle=small_tree.leaf_angle, leaf_azimuth="outward", materials=small_tree.materials)
    path = scanned.save(tmp_path / "scanned.npz")
    p = PlotScene(20.0, voxel_size=H, ground_z=3.0)
    p.add_tree(small_tree, 6.0, 6.0)
    p.add_tree(path, 14.0, 14.0)
    p.add_tree(str(path), 14.0, 6.0)                             # the same file: the same model
    tab = p.table()
    assert p.n_models == 2 and tab["source"].tolist() == ["synthetic", "scene", "scene"]
    assert tab["name"][1] == "scanned" and tab["height_m"][1] == pytest.approx(5 * H)   # top of voxel k=6, ground k=2
    assert any("outward" in n for n in p.notes) and any("converted" in n for n in p.notes)
    s = p.to_scene()
    assert s.ground_z == 3.0 and s.wood_kind == "probability"
    # a voxel one layer below the scanned tree's ground: the grid reaches one brick below the plot's ground
    assert s.origin[2] == 3.0 - BRICK * H and s.n_voxels == p.n_voxels
    assert s.total_leaf_area() == pytest.approx(p.total_leaf_area(), rel=1e-12)
    # the wood voxel sits one voxel above the plot ground, its extinction kept: p = 1 - exp(-WAD h / 2)
    k_ground = int(round((3.0 - s.origin[2]) / H))
    for x, y in ((14.0, 14.0), (14.0, 6.0)):
        at = np.all(s.ijk == [round(x / H), round(y / H), k_ground], axis=1)
        assert s.wood[at].tolist() == pytest.approx([1 - math.exp(-0.6 * H / 2)], rel=1e-12)
        assert s.lad[at].tolist() == [0.0]
    assert np.array_equal(dense(p.brick_grid()), dense(build_bricks(s)))


def test_prepare_run_takes_the_plot(plot):
    sensor = Sensor.preset("ahab-chiroptera-i")
    setup = prepare_run(plot, sensor, photons=1000, seed=1)
    assert setup.bricks is plot.brick_grid()
    assert setup.settings["scene"]["n_voxels"] == plot.n_voxels
    np.testing.assert_allclose(setup.settings["target"], [*plot.crown_center, 0.0])


# -- the simulator ---------------------------------------------------------------------------
def test_pulse_over_shared_plot_equals_pulse_over_copies(sim, plot):
    """Same seed, same device: the identical waveform from shared bricks and from copies."""
    sensor = Sensor.preset("ahab-chiroptera-i")
    tab = plot.table()
    target = (tab["x_m"][0] + 0.7, tab["y_m"][0] - 0.4)
    a = sim.run(plot, sensor, photons=20_000, seed=9, target=target, max_order=3)
    b = sim.run(plot.to_scene(), sensor, photons=20_000, seed=9, target=target, max_order=3)
    assert np.array_equal(a.fine_batches, b.fine_batches)
    assert a.stats.keys() == b.stats.keys() and all(np.array_equal(a.stats[k], b.stats[k]) for k in a.stats)
    e, se = a.energy(kind="vegetation")
    assert e > 10 * se > 0                                        # the beam met the canopy


@pytest.fixture(scope="module")
def oracle_over_plot(plot):
    from clsim.transport.reference import ReferenceSimulator

    tab = plot.table()
    target = (tab["x_m"][0] + 0.7, tab["y_m"][0] - 0.4)
    return target, ReferenceSimulator().run(plot, Sensor.preset("ahab-chiroptera-i"), photons=3000, seed=1,
                                            target=target)


def test_kernel_over_shared_plot_matches_the_float64_oracle(sim, plot, oracle_over_plot):
    """The NumPy oracle reads the copied scene in float64; the kernel the shared bricks.
    Independent seeds: |a - b| < 4 sqrt(se_a^2 + se_b^2) for canopy and ground energy."""
    target, ref = oracle_over_plot
    res = sim.run(plot, Sensor.preset("ahab-chiroptera-i"), photons=100_000, seed=2, target=target)
    for kind in ("vegetation", "ground"):
        (a, sa), (b, sb) = res.energy(kind=kind), ref.energy(kind=kind)
        assert b > 0 and abs(a - b) < 4 * math.hypot(sa, sb), (kind, a, sa, b, sb)


# -- bad input and the picture -------------------------------------------------------------------
def _one_line(excinfo):
    msg = str(excinfo.value)
    assert "\n" not in msg and len(msg) < 400
    return msg


def test_bad_input_is_one_line(small_tree, tmp_path):
    p = PlotScene(20.0, voxel_size=H)
    other = Scene(origin=(0, 0, 0), voxel_size=0.25, shape=(2, 2, 2), ijk=[[0, 0, 0]], lad=[1.0])
    cases = [
        (lambda: PlotScene(20.0, voxel_size=0.0), "voxel_size"),
        (lambda: PlotScene(float("nan"), voxel_size=H), "width_m"),
        (lambda: p.add_tree(other, 5, 5), "voxel_size 0.25"),
        (lambda: p.add_tree(small_tree, 1.0, 10.0), "outside the plot"),
        (lambda: p.add_tree(small_tree, 10.0, 10.0, snap="grid"), "snap"),
        (lambda: p.add_tree(7, 10.0, 10.0), "model 7 does not exist"),
        (lambda: p.add_tree([1, 2], 10.0, 10.0), "a tree must be"),
        (lambda: p.add_tree(small_tree, "x", 10.0), "tree x"),
        (lambda: p.add_tree(tmp_path / "none.npz", 10.0, 10.0), "does not exist"),
        (lambda: make_plot(20.0, 40, seed=1, kinds=("small",), n_models=1), "could not place tree"),
        (lambda: make_plot(20.0, 3, seed=1, kinds=("oak",)), "tree kind 'oak'"),
        (lambda: make_plot(20.0, 0, seed=1), "n_trees"),
        (lambda: make_plot(3.0, 1, seed=1, kinds=("broadleaf",)), "does not fit"),
    ]
    for call, words in cases:
        with pytest.raises(InputError) as excinfo:
            call()
        assert words in _one_line(excinfo), (words, str(excinfo.value))
    q = PlotScene(20.0, voxel_size=H)
    q.add_tree(small_tree, 10.0, 10.0)
    planophile = Scene(origin=(0, 0, 0), voxel_size=H, shape=(2, 2, 2), ijk=[[0, 0, 0]], lad=[1.0],
                       leaf_angle="planophile")
    with pytest.raises(InputError) as excinfo:
        q.add_tree(planophile, 5.0, 5.0)
    assert "PlotScene(leaf_angle=...)" in _one_line(excinfo)
    assert q.n_trees == 1                                        # nothing added by a refused call
    with pytest.raises(InputError) as excinfo:
        prepare_run(object(), Sensor.preset("ahab-chiroptera-i"), photons=10, seed=1)
    assert "PlotScene" in _one_line(excinfo)


def test_canopy_picture_has_title_units_legend_and_colorbar(plot, tmp_path):
    out = plot_canopy(plot, tmp_path / "plot.svg")
    svg = out.read_text()
    for text in ("10 trees of 3 models", "x (m)", "y (m)", "canopy height above ground (m)",
                 "trunk, synthetic tree", "crown (disc of its projected area)"):
        assert text in svg, text
    assert plot_canopy(plot, tmp_path / "plot.png").read_bytes()[:4] == b"\x89PNG"
    with pytest.raises(InputError):
        plot_canopy(PlotScene(10.0, voxel_size=H), tmp_path / "empty.png")
    chm = plot.canopy_height()
    assert np.nanmax(chm) == pytest.approx(plot.table()["height_m"].max())


def test_save_load_and_pickle_keep_the_plot(plot, tmp_path):
    import pickle

    path = plot.save(tmp_path / "plot.npz")
    for back in (type(plot).load(path), pickle.loads(pickle.dumps(plot))):
        assert np.array_equal(back.table(), plot.table())
        assert back.total_leaf_area() == plot.total_leaf_area()
        assert back.shape == plot.shape and np.array_equal(back.origin, plot.origin)
        assert np.array_equal(back.brick_grid().pool, plot.brick_grid().pool)
        assert np.array_equal(back.brick_grid().index, plot.brick_grid().index)
    with pytest.raises(InputError) as excinfo:
        PlotScene.load(Scene(origin=(0, 0, 0), voxel_size=H, shape=(1, 1, 1), ijk=[[0, 0, 0]],
                             lad=[1.0]).save(tmp_path / "tree.npz"))
    assert "Scene.load" in _one_line(excinfo)
    with pytest.raises(InputError) as excinfo:
        PlotScene.load(tmp_path / "missing.npz")
    assert "does not exist" in _one_line(excinfo)


def test_example_prints_the_known_leaf_area_and_identical_waveforms(tmp_path, capsys):
    import runpy
    from pathlib import Path

    scanned = Scene(origin=(-2.0, -2.0, 0.0), voxel_size=H, shape=(8, 8, 12),
                    ijk=[[a, b, c] for a in range(2, 6) for b in range(2, 6) for c in range(4, 10)],
                    lad=np.full(96, 0.7), ground_z=0.0, crown_center=(0.0, 0.0)).save(tmp_path / "scanned.npz")
    example = runpy.run_path(str(Path(__file__).parents[3] / "examples" / "plot_scene.py"))
    example["main"](tmp_path, scanned)
    out = capsys.readouterr().out
    line = next(x for x in out.splitlines() if x.startswith("leaf area"))
    plot_area, trees_area, copied_area = (float(v) for v in re.findall(r"([\d.]+) m2", line))
    assert plot_area == trees_area == pytest.approx(copied_area, abs=1e-6)
    assert "31 trees of 7 models" in out and "waveforms identical: True" in out
    assert (tmp_path / "plot_canopy.png").stat().st_size > 0


def test_clsim_simulate_reads_a_plot_file(plot, tmp_path, capsys, cl_device):
    """`clsim simulate plot.npz` runs the shared plot: the waveform file equals an in-process run."""
    from clsim.cli.app import main
    from clsim.transport.simulator import Simulator

    path = plot.save(tmp_path / "plot.npz")
    tab = plot.table()
    target = f"{tab['x_m'][1]:g},{tab['y_m'][1]:g}"
    rc = main(["simulate", str(path), "--photons", "5000", "--seed", "4", "--target", target, "--device",
               cl_device.key, "--quiet", "-o", str(tmp_path / "wf.npz")])
    assert rc == 0 and "received energy" in capsys.readouterr().out
    ref = Simulator(device=cl_device).run(plot, Sensor.preset("ahab-chiroptera-i"), photons=5000, seed=4,
                                           target=(tab["x_m"][1], tab["y_m"][1]))
    with np.load(tmp_path / "wf.npz") as z:
        assert np.array_equal(z["waveform"], ref.waveform)


def test_solid_and_directional_wood_are_named_in_the_notes(small_tree):
    """A plot keeps one turbid wood value per voxel: a tree's solid wood and bark directions
    are simulated as turbid wood, and the plot's notes say so."""
    solid = Scene(origin=(0.0, 0.0, 0.0), voxel_size=H, shape=(4, 4, 6), ijk=[[1, 1, 1], [1, 1, 2], [2, 2, 4]],
                  lad=[0.0, 0.0, 1.0], wood=[0.9, 0.9, 0.0], wood_solid=[True, False, False],
                  wood_beta=[0.0, 0.8, 0.0], wood_axis=[[0, 0, 1]] * 3, leaf_angle=small_tree.leaf_angle,
                  materials=small_tree.materials, ground_z=0.0)
    p = PlotScene(20.0, voxel_size=H, ground_z=0.0)
    p.add_tree(solid, 10.0, 10.0)
    note = [n for n in p.notes if "turbid" in n]
    assert len(note) == 1 and "1 solid wood voxels" in note[0] and "wood_axis" in note[0]
    plain = Scene(origin=(0.0, 0.0, 0.0), voxel_size=H, shape=(4, 4, 6), ijk=[[2, 2, 4]], lad=[1.0],
                  leaf_angle=small_tree.leaf_angle, materials=small_tree.materials, ground_z=0.0)
    q = PlotScene(20.0, voxel_size=H, ground_z=0.0)
    q.add_tree(plain, 10.0, 10.0)
    assert not any("turbid" in n for n in q.notes)
