"""The explicit-geometry (mesh) reference against closed-form answers.

A Boolean canopy (Poisson-placed random flat leaves, spherical angles, LAD u,
thickness H) over a Lambertian ground, seen at nadir by a monostatic sensor.
Single scattering retraces its incoming path, which was free, so the mesh
shows the full hot spot:

    ground = (A/R^2) (rho_g/pi) exp(-G u H)
    canopy = (A/R^2) (rho_l/(3 pi)) (1 - exp(-G u H)) / G

and the fraction of photons reaching the ground unscattered is exp(-G u H).
"""

import numpy as np
import pytest

from clsim.sensor import Sensor
from clsim.validation.meshref import MeshReferenceSimulator
from tlsvox.truth.synthetic import make_leaf_slab

U, H, G = 1.0, 1.0, 0.5


@pytest.fixture(scope="module")
def runs():
    # wide beam (2 mrad) so the footprint averages many leaves; FOV 4x the beam
    sensor = Sensor.preset("ahab-chiroptera-i", divergence_mrad=2.0, fov_mrad=8.0)
    out = []
    for seed in range(3):
        slab = make_leaf_slab(lad=U, size=(5.0, 5.0, H), origin=(-2.5, -2.5, 2.0), seed=seed, ground=True,
                              leaf_length=0.03, leaf_width=0.015)
        res = MeshReferenceSimulator().run(slab, sensor, photons=20000, seed=seed, max_order=1)
        out.append((slab, res))
    return sensor, out


def _check(sensor, out, kind, expected_fn):
    ratios, ses = [], []
    for slab, res in out:
        scene = slab.truth_scene(0.5)
        expected = expected_fn(scene, sensor)
        e, se = res.energy(kind=kind)
        ratios.append(e / expected)
        ses.append(se / expected)
    ratios = np.array(ratios)
    # each realisation differs by Monte Carlo noise and by its own Poisson leaf count in the
    # footprint: the spread across realisations measures both
    se_mean = max(ratios.std(ddof=1), np.sqrt(np.mean(np.square(ses)))) / np.sqrt(len(ratios))
    assert abs(ratios.mean() - 1.0) < 4 * se_mean, (ratios, se_mean)
    assert abs(ratios.mean() - 1.0) < 0.03


def test_ground_return_is_one_way_beer_lambert(runs):
    sensor, out = runs

    def expected(scene, s):
        rg, _ = scene.optics("ground", s.wavelength_nm)
        return s.aperture_area_m2 / s.range_m**2 * rg / np.pi * np.exp(-G * U * H)

    _check(sensor, out, "ground", expected)


def test_canopy_return_has_the_hot_spot(runs):
    sensor, out = runs

    def expected(scene, s):
        rl, _ = scene.optics("leaf", s.wavelength_nm)
        return s.aperture_area_m2 / s.range_m**2 * rl / (3 * np.pi) * (1 - np.exp(-G * U * H)) / G

    _check(sensor, out, "vegetation", expected)


def test_unscattered_ground_fraction(runs):
    _, out = runs
    for _, res in out:
        p, se = res.stat("ground_direct")
        assert abs(p - np.exp(-G * U * H)) < 4 * se + 0.02  # + footprint-scale leaf count noise


def test_same_seed_same_waveform(runs):
    sensor, out = runs
    slab, res = out[0]
    again = MeshReferenceSimulator().run(slab, sensor, photons=20000, seed=0, max_order=1)
    np.testing.assert_array_equal(again.waveform, res.waveform)
