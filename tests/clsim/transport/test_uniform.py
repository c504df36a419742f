"""Uniform bricks crossed in one segment (kernels/scene.cl, docs/method.md "Uniform bricks").

The host's record of uniform boxes is checked on hand-made bricks; the kernel's
crossing against the voxel-by-voxel walk (same seed: the same random numbers, so
the two runs agree far inside their Monte Carlo error) and against the float64
oracle, which walks voxel by voxel (independent seeds, |a - b| < 4 sigma as in
test_simulator.py), on a scene that mixes uniform bricks, partly filled uniform
bricks, bricks with two LAD values and uniform bricks with directional wood.
"""

from __future__ import annotations

import numpy as np
import pytest

from clsim.sensor import Sensor
from clsim.transport.bricks import BRICK, build_bricks, uniform_boxes
from clsim.transport.reference import ReferenceSimulator
from clsim.transport.simulator import Simulator
from clsim.validation import testscenes
from voxlidar.scene import Scene

SENSOR = Sensor.preset("ahab-chiroptera-i", fov_mrad=3.0)


def close(a, b, k=4.0):
    return abs(a[0] - b[0]) <= k * np.hypot(a[1], b[1])


def unpack(box):
    return [int(box >> (3 * k)) & (BRICK - 1) for k in range(6)]


def one_brick(ijk, lad, wood=None, **kw):
    ijk = np.asarray(ijk, dtype=np.int32).reshape(-1, 3)
    return Scene(origin=(0.0, 0.0, 0.0), voxel_size=0.5, shape=(BRICK, BRICK, BRICK), ijk=ijk,
                 lad=np.broadcast_to(np.asarray(lad, float), len(ijk)).copy(),
                 wood=None if wood is None else np.broadcast_to(np.asarray(wood, float), len(ijk)).copy(), **kw)


def box_ijk(lo, hi):
    g = np.meshgrid(*[np.arange(a, b + 1) for a, b in zip(lo, hi)], indexing="ij")
    return np.column_stack([c.ravel() for c in g])


def boxes_of(scene):
    g = build_bricks(scene)
    return uniform_boxes(g.pool, g.wdir)


def test_uniform_boxes_known_bricks():
    full = box_ijk((0, 0, 0), (7, 7, 7))
    assert [unpack(b) for b in boxes_of(one_brick(full, 1.5))] == [[0, 0, 0, 7, 7, 7]]
    part = box_ijk((1, 2, 3), (6, 4, 3))
    assert [unpack(b) for b in boxes_of(one_brick(part, 0.7, wood=0.1))] == [[1, 2, 3, 6, 4, 3]]
    # not a box (an L), two values, two wood values: not uniform
    ell = np.vstack([box_ijk((0, 0, 0), (3, 0, 0)), [[0, 1, 0]]])
    assert boxes_of(one_brick(ell, 1.0)).tolist() == [-1]
    lad = np.ones(len(full))
    lad[17] = 1.25
    assert boxes_of(one_brick(full, lad)).tolist() == [-1]
    wood = np.zeros(len(full))
    wood[5] = 0.2
    assert boxes_of(one_brick(full, 1.0, wood=wood)).tolist() == [-1]
    # directional bark: uniform only when every voxel has the same axis and anisotropy
    n = len(part)
    same = one_brick(part, 1.0, wood=0.1, wood_axis=np.tile([0.0, 0.6, 0.8], (n, 1)), wood_beta=np.full(n, 0.7))
    assert [unpack(b) for b in boxes_of(same)] == [[1, 2, 3, 6, 4, 3]]
    beta = np.full(n, 0.7)
    beta[0] = 0.2
    other = one_brick(part, 1.0, wood=0.1, wood_axis=np.tile([0.0, 0.6, 0.8], (n, 1)), wood_beta=beta)
    assert boxes_of(other).tolist() == [-1]


def test_uniform_boxes_of_a_layer_per_brick():
    """0.1 m voxels, layer 2 m thick from 2 m: z voxels 20..39, bricks z 2 (partly: 20..23), 3, 4."""
    g = build_bricks(testscenes.homogeneous_layer(width=1.6, voxel_size=0.1))
    b = g.boxes
    assert len(b) == g.n_bricks == 2 * 2 * 3 and np.all(b >= 0)
    assert sorted({tuple(unpack(x)) for x in b}) == [(0, 0, 0, 7, 7, 7), (0, 0, 4, 7, 7, 7)]


def mixed_scene():
    """0.25 m voxels, 6 m x 6 m x 2 m from 1 m: 3 x 3 x 2 bricks, each filled in z 4..7 or 0..3.
    Brick column (0, 0) holds two LAD values; column (2, 2) uniform wood, column (2, 0)
    uniform directional wood; the rest plain uniform leaves."""
    s = testscenes.homogeneous_layer(width=6.0, thickness=2.0, base_height=1.0, voxel_size=0.25)
    i, j = s.ijk[:, 0], s.ijk[:, 1]
    s.lad = s.lad.copy()
    s.lad[(i < 5) & (j < 5)] = 2.5
    wood = np.zeros(s.n_voxels)
    wood[(i >= 16) & (j >= 16)] = 0.15
    wood[(i >= 16) & (j < 8)] = 0.3
    s.wood = wood
    s.wood_axis = np.tile([0.6, 0.0, 0.8], (s.n_voxels, 1))
    s.wood_beta = np.where((i >= 16) & (j < 8), 0.8, 0.0)
    s.__post_init__()
    return testscenes.set_optics(s, 1064, leaf=(0.45, 0.40), ground=(0.3, 0.0), bark=(0.45, 0.0))


def test_mixed_scene_has_every_kind_of_brick():
    g = build_bricks(mixed_scene())
    assert g.wdir is not None and g.n_bricks == 18
    b = g.boxes
    assert np.count_nonzero(b < 0) == 2  # the two bricks of column (0, 0)
    assert {tuple(unpack(x)) for x in b[b >= 0]} == {(0, 0, 4, 7, 7, 7), (0, 0, 0, 7, 7, 3)}


_WALKS = {}


def _voxel_walk(sim):
    """The voxel-by-voxel walk on ``sim``'s device, its program built once per device."""
    if sim.info.key not in _WALKS:
        _WALKS[sim.info.key] = Simulator(device=sim.info, features={"uniform": False})
    return _WALKS[sim.info.key]


@pytest.mark.parametrize("off_nadir", [0.0, 35.0])
def test_segments_match_the_voxel_walk_and_the_oracle(off_nadir, sim):
    scene = mixed_scene()
    sensor = SENSOR.replace(off_nadir_deg=off_nadir)
    kw = dict(max_order=3, target=(-1.9, -1.9))  # the beam enters the LAD-2.5 corner beside plain bricks
    n = 100_000
    a = sim.run(scene, sensor, photons=n, seed=71, **kw)
    walk = _voxel_walk(sim)
    b = walk.run(scene, sensor, photons=n, seed=71, **kw)
    # the segment replaces steps: fewer walk steps, the same voxels; without it one step per voxel
    assert a.stat("walk_steps")[0] < 0.9 * b.stat("walk_steps")[0]
    assert b.stat("walk_steps")[0] == b.stat("voxel_steps")[0]
    o = ReferenceSimulator().run(scene, sensor, photons=15_000, seed=72, **kw)
    compared = 0
    for order in (1, 2, 3):
        for kind in ("vegetation", "ground"):
            ea, eb, eo = (r.energy(order=order, kind=kind) for r in (a, b, o))
            if ea[0] == 0 and eo[0] == 0:
                continue
            # same random numbers: only float rounding tells the two kernel runs apart
            assert close(ea, eb, k=0.5), (order, kind, ea, eb)
            eo = (eo[0], max(eo[1], ea[1] * np.sqrt(n / 15_000)))
            assert close(ea, eo), (order, kind, ea, eo)
            compared += 1
    assert compared >= 5
    for st in ("ground_direct", "escaped_up", "absorbed"):
        assert close(a.stat(st), o.stat(st)), (st, a.stat(st), o.stat(st))


def test_uniform_segments_are_deterministic(sim):
    scene = testscenes.homogeneous_layer(width=4.0, voxel_size=0.1)
    r1 = sim.run(scene, SENSOR.replace(off_nadir_deg=20.0), photons=20_000, seed=3)
    r2 = Simulator(device=sim.info).run(scene, SENSOR.replace(off_nadir_deg=20.0), photons=20_000, seed=3)
    assert np.array_equal(r1.fine, r2.fine)
    assert r1.stat("walk_steps")[0] < r1.stat("voxel_steps")[0] / 2


def test_simulator_rebuilds_the_bricks_of_a_scene_changed_in_place(sim):
    """Simulator.run keeps the last scene's bricks; changing the scene's LAD in place is noticed
    (bricks_key fingerprints the arrays), so the result equals a fresh simulator's."""
    scene = testscenes.homogeneous_layer(width=4.0, voxel_size=0.25)
    kw = dict(photons=5_000, seed=4, max_order=2)
    a = sim.run(scene, SENSOR, **kw)
    assert np.array_equal(a.fine, sim.run(scene, SENSOR, **kw).fine)  # from the kept bricks
    scene.lad *= 3.0
    b = sim.run(scene, SENSOR, **kw)
    assert b.energy(order=1, kind="ground")[0] < 0.5 * a.energy(order=1, kind="ground")[0]
    assert np.array_equal(b.fine, Simulator(device=sim.info).run(scene, SENSOR, **kw).fine)


@pytest.mark.parametrize("scene_kind", ["mixed", "outward"])
def test_uniform_segments_count_the_voxels_the_walk_reaches(scene_kind, sim):
    """voxel_steps with uniform bricks is the number of voxels the voxel-by-voxel walk visits
    (free flights and the shadow rays of next-event estimation alike): a segment counts the
    voxels it crosses in its brick and gives back those beyond a collision or a cut-off.
    Same seed, same random numbers, the same paths: per photon the counts are equal, and in
    total they can differ only where float32 rounding moves a segment's end across a voxel
    plane (about one voxel in 10^6 here), so the totals agree to 1e-4."""
    if scene_kind == "mixed":
        scene = mixed_scene()
        kw = dict(max_order=3, target=(-1.9, -1.9))
    else:  # ratio tracking in the shadow rays, null collisions in the flights
        scene = testscenes.set_optics(testscenes.homogeneous_layer(width=4.0, voxel_size=0.1,
                                                                   leaf_azimuth="outward"), 1064)
        kw = dict(max_order=3)
    walk = _voxel_walk(sim)
    sensor = SENSOR.replace(off_nadir_deg=25.0)
    for detect in ("nee", "analog"):
        a = sim.run(scene, sensor, photons=20_000, seed=12, detect=detect, **kw)
        b = walk.run(scene, sensor, photons=20_000, seed=12, detect=detect, **kw)
        va, vb = a.stat("voxel_steps")[0], b.stat("voxel_steps")[0]
        assert vb == b.stat("walk_steps")[0] and a.stat("walk_steps")[0] < 0.9 * va
        assert abs(va - vb) <= 1e-4 * vb, (detect, va, vb)
    per_photon = [(sim.run(scene, sensor, photons=1, seed=s, **kw).stat("voxel_steps")[0],
                   walk.run(scene, sensor, photons=1, seed=s, **kw).stat("voxel_steps")[0]) for s in range(20)]
    assert all(x == y for x, y in per_photon), per_photon
    assert sum(x for x, _ in per_photon) > 20 * 10
