"""Airborne beams with energy weights, traced and estimated: a known turbid layer comes back."""

from __future__ import annotations

import numpy as np
import pytest

from tlsvox.errors import InputError
from tlsvox.voxel.airborne import airborne_beams, full_hit_energy, pool_layers, voxelize_beams


def test_energy_weights_cap_and_tail():
    beams = airborne_beams(np.zeros((2, 3)) + [0, 0, 100], [[0, 0, -1], [0, 0, -1]],
                           echo_pulse=[0, 0, 1], echo_range=[95.0, 90.0, 92.0], echo_energy=[3.0, 1.0, 6.0],
                           full_energy=4.0, record_end=[96.0, 93.0])
    # pulse 0: 1/4 then 3/4 of its beam (sorted by range); pulse 1: 6/4 is more than a beam, scaled to 1
    assert beams.echo_range.tolist() == [90.0, 95.0, 92.0]
    assert np.allclose(beams.echo_weight, [0.25, 0.75, 1.0])
    assert np.allclose(beams.tail, [0.0, 0.0]) and beams.meta["capped"] == 1
    assert beams.max_range.tolist() == [96.0, 93.0]
    assert full_hit_energy([1.0, 2.0, 3.0, 4.0, 100.0], percentile=50) == 3.0
    with pytest.raises(InputError, match="full_energy"):
        airborne_beams([[0, 0, 1]], [[0, 0, -1]], echo_pulse=[0], echo_range=[1.0], echo_energy=[1.0],
                       full_energy=0.0, record_end=[2.0])


def _layer_beams(lad=1.0, top=12.0, bottom=10.0, spacing=0.1, width=2.0, slice_m=0.05):
    """Vertical pulses over a turbid layer (spherical leaves, G = 1/2): each slice stops exactly its
    share exp(-G u z0) - exp(-G u z1) of the beam, as a waveform's echoes would tell it."""
    g = 0.5
    x = np.arange(spacing / 2, width, spacing)
    xy = np.array([(a, b) for a in x for b in x])
    n = len(xy)
    depth = np.arange(0.0, top - bottom, slice_m)
    share = np.exp(-g * lad * depth) - np.exp(-g * lad * (depth + slice_m))
    rng_ = 100.0 - top + depth + slice_m / 2  # from a sensor at z = 100
    origin = np.c_[xy, np.full(n, 100.0)]
    pulse = np.repeat(np.arange(n), depth.size)
    return airborne_beams(origin, np.tile([0.0, 0.0, -1.0], (n, 1)), echo_pulse=pulse,
                          echo_range=np.tile(rng_, n), echo_energy=np.tile(share, n), full_energy=1.0,
                          record_end=np.full(n, 100.0 - bottom + 1.0))


@pytest.mark.parametrize("pool", [0.0, 0.3])
@pytest.mark.parametrize("estimator, tol", [("beer_lambert", 0.002), ("bcmle", 0.03)])
def test_a_known_layer_comes_back(pool, estimator, tol):
    beams = _layer_beams()
    scene = voxelize_beams(beams, voxel_size=0.5, bounds=[[0, 0, 10], [2, 2, 12]], pool_m=pool, estimator=estimator)
    inner = np.all((scene.ijk[:, :2] >= 1) & (scene.ijk[:, :2] <= 2), axis=1)
    lad = scene.lad[inner & ~scene.occluded]
    assert lad.size == 16
    # Beer-Lambert on each voxel's intercepted share is exact here; the bcMLE's small-sample correction,
    # made for 0/1 hits, takes about 1/(2N) off with N = 25 beams per voxel (2 %; measured 2.2 %)
    assert np.allclose(lad, 1.0, rtol=tol), lad
    assert scene.meta["airborne"]["pool_m"] == pool


def test_pooling_sums_a_footprint_of_beams():
    from tlsvox.voxel.grid import VoxelGrid
    from tlsvox.voxel.stats import NF, VoxelStats

    grid = VoxelGrid((0, 0, 0), 0.25, (21, 21, 2))
    acc = np.ones((grid.n_voxels, NF))
    pooled = pool_layers(VoxelStats(grid, acc), 0.5)
    centre = pooled.field("count")[10, 10, 0]
    assert centre == pytest.approx(2 * np.pi * (0.5 / 0.25) ** 2, rel=0.02)  # the Gaussian's sum over the layer
    # no mixing between heights: a field on the lower layer only stays there
    acc = np.zeros((grid.n_voxels, NF))
    acc.reshape(*grid.shape, NF)[:, :, 0] = 1.0
    pooled = pool_layers(VoxelStats(grid, acc), 0.5)
    assert pooled.field("count")[:, :, 1].max() == 0.0 and pooled.field("count")[:, :, 0].max() > 0


def _layer_over_ground(ground_z=5.0):
    """The layer's beams, each ending on the ground: what the layer left of it stopped there."""
    b = _layer_beams(bottom=10.0)
    n = len(b)
    pulse = np.repeat(np.arange(n), np.diff(b.echo_start))
    rng = np.r_[b.echo_range, np.full(n, 100.0 - ground_z)]
    energy = np.r_[b.echo_weight, b.tail]
    return airborne_beams(b.origin, b.direction, echo_pulse=np.r_[pulse, np.arange(n)], echo_range=rng,
                          echo_energy=energy, full_energy=1.0, record_end=np.full(n, 100.0 - ground_z + 1.0))


@pytest.mark.parametrize("ground", ["ransac", 5.0])
def test_ground_echoes_stop_beams_as_ground_not_leaves(ground):
    beams = _layer_over_ground()
    scene = voxelize_beams(beams, voxel_size=0.5, ground=ground, estimator="beer_lambert")
    assert scene.ground_z == pytest.approx(5.0, abs=1e-6)
    assert scene.meta["airborne"]["ground_echoes"] == len(beams)
    centre_z = scene.origin[2] + (scene.ijk[:, 2] + 0.5) * scene.voxel_size
    assert centre_z.min() > 5.0  # nothing stored at or below the ground
    inner = np.all((scene.ijk[:, :2] >= 1) & (scene.ijk[:, :2] <= 2), axis=1) & (centre_z > 10) & (centre_z < 12)
    assert np.allclose(scene.lad[inner & ~scene.occluded], 1.0, rtol=0.002)
    # without a ground the whole rest of each beam is a dense layer at z = 5
    plain = voxelize_beams(_layer_over_ground(), voxel_size=0.5)
    low = plain.origin[2] + (plain.ijk[:, 2] + 0.5) * plain.voxel_size < 5.5
    assert plain.ground_z is None and plain.lad[low].min() > 3.0 and plain.meta["flags"]["saturated"] > 0
    with pytest.raises(InputError, match="ground"):
        voxelize_beams(_layer_over_ground(), voxel_size=0.5, ground="lowest")
