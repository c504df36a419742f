"""The NumPy oracle's walk through a turbid layer against Beer-Lambert."""

from __future__ import annotations

import numpy as np

from clsim.sensor import Sensor
from clsim.transport.reference_walk import GROUND, LEAF, SceneWalker
from clsim.transport.setup import prepare_run
from clsim.validation.testscenes import homogeneous_layer

LAD, THICKNESS, G = 1.0, 2.0, 0.5  # spherical leaves: G = 1/2 in every direction


def _walker(mode="exact"):
    scene = homogeneous_layer(lad=LAD, thickness=THICKNESS, width=4.0, voxel_size=0.5)
    return SceneWalker(prepare_run(scene, Sensor(), photons=1, seed=5, mode=mode))


def _down(walker, n):
    """n rays straight down from above the grid, off the voxel faces."""
    top = np.array([0.5 * walker.L[0] + 0.1, 0.5 * walker.L[1] + 0.1, walker.L[2] + 1.0])
    return np.tile(top, (n, 1)), np.tile([0.0, 0.0, -1.0], (n, 1))


def test_transmittance_down_through_the_layer_is_beer_lambert():
    w = _walker()
    o, d = _down(w, 3)
    t = w.optical_depth_transmittance(o, d, np.full(3, 1e3))
    np.testing.assert_allclose(t, np.exp(-G * LAD * THICKNESS), rtol=1e-12)


def test_free_flights_reach_the_ground_with_the_layers_transmittance():
    """Delta tracking: the share of flights with no leaf collision is exp(-G LAD H), within 4 standard errors."""
    w = _walker()
    n = 20_000
    w.pid, w.ctr = np.arange(n, dtype=np.uint64), np.zeros(n, np.uint64)
    o, d = _down(w, n)
    ev, t, _ = w.walk(o, d, w.ground_t(o, d), np.arange(n), shadow=False)
    assert set(np.unique(ev)) <= {LEAF, GROUND}
    p = np.exp(-G * LAD * THICKNESS)
    assert abs(np.mean(ev == GROUND) - p) < 4 * np.sqrt(p * (1 - p) / n)
    np.testing.assert_allclose(t[ev == GROUND], o[0, 2] - w.ground, rtol=1e-12)
    assert w.steps > 0
