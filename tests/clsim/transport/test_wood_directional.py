"""Directional wood (docs/method.md, "Directional wood") against closed forms.

A layer of vertical wood cylinders (every voxel: bark area density alpha,
axis z, beta = 1) has extinction alpha sin(theta) / pi along a beam at zenith
theta, where randomly oriented bark (beta = 0) has alpha / 4:

    direct transmission  exp(-alpha sin(theta) / pi * H / cos(theta))   vs  exp(-alpha / 4 * H / cos(theta))

and single scattering back to a monostatic sensor with the area scattering
coefficient Gamma = sigma E_w[R |n.d| / pi] (hit normals weighted by |n.d|):
alpha R sin(theta)^2 / (4 pi) for the cylinders (normals across the axis),
alpha R / (6 pi) for random facets, so the first-order wood energy is

    A Gamma int_0^{H / cos} exp(-2 sigma s) / (r0 + s)^2 ds.

Tolerance: 3 Monte Carlo standard errors (16 batch means); the isotropic and
directional answers differ by many standard errors, so a kernel that ignored
the direction fails.
"""

from __future__ import annotations

import numpy as np
import pytest
from scipy.integrate import quad

from clsim.sensor import Sensor
from clsim.transport.reference import ReferenceSimulator
from clsim.validation import testscenes

H, BASE, VOXEL = 2.0, 2.0, 0.5
ALPHA = 1.2  # bark area density, m2/m3
RHO_W = 0.45
PHOTONS = {"kernel": 300_000, "oracle": 40_000}


def wood_layer(beta):
    """Wood only: direction-averaged sigma alpha / 4 stored as the crossing probability."""
    p = 1.0 - np.exp(-ALPHA / 4.0 * VOXEL)
    s = testscenes.homogeneous_layer(lad=0.0, wood=p, thickness=H, base_height=BASE, width=10.0,
                                     voxel_size=VOXEL)
    s.wood_beta = np.full(s.n_voxels, float(beta))
    s.wood_axis = np.tile([0.0, 0.0, 1.0], (s.n_voxels, 1))
    s.__post_init__()
    return testscenes.set_optics(s, 1064, bark=(RHO_W, 0.0), ground=(0.3, 0.0))


def sigma(beta, theta):
    return ALPHA * (beta * np.sin(theta) / np.pi + (1.0 - beta) / 4.0)


def gamma(beta, theta):
    """Area scattering coefficient towards the source (backscatter), 1/m/sr."""
    return ALPHA * RHO_W * (beta * np.sin(theta) ** 2 / (4.0 * np.pi) + (1.0 - beta) / (6.0 * np.pi))


def run(backend, sim, scene, sensor, **kw):
    s = sim if backend == "kernel" else ReferenceSimulator()
    return s.run(scene, sensor, photons=PHOTONS[backend], seed=20261123, max_order=1, batches=16, **kw)


@pytest.mark.parametrize("backend", ["kernel", "oracle"])
@pytest.mark.parametrize("deg", [0.0, 30.0, 45.0])
def test_vertical_cylinders_transmission_and_return(backend, deg, sim):
    th = np.radians(deg)
    sensor = Sensor.preset("ahab-chiroptera-i", off_nadir_deg=deg, fov_mrad=3.0)
    L = H / np.cos(th)
    A, R = sensor.aperture_area_m2, sensor.range_m
    r0 = R - (BASE + H) / np.cos(th)
    for beta in (1.0, 0.0):
        res = run(backend, sim, wood_layer(beta), sensor)
        t, tse = res.stat("ground_direct")
        expect = np.exp(-sigma(beta, th) * L)
        if beta == 1.0 and deg == 0.0:
            # the beam's divergence (~0.3 mrad) is all that crosses the cylinders
            assert t > 0.999, t
            continue
        assert abs(t - expect) < 3 * tse + 1e-9, (beta, deg, t, tse, expect)
        e, se = res.energy(order=1, kind="vegetation")
        s = sigma(beta, th)
        known = A * gamma(beta, th) * quad(lambda x: np.exp(-2 * s * x) / (r0 + x) ** 2, 0, L)[0]
        assert abs(e - known) < 3 * se, (beta, deg, e, se, known)
        assert se / e < 0.02


def test_cylinders_and_facets_are_told_apart(sim):
    """At 30 deg the vertical cylinders stop 0.637 x what random facets stop (sin 30 / pi
    against 1/4) and return 0.375 x per unit path (sin^2 30 / 4 against 1/6); resolved."""
    sensor = Sensor.preset("ahab-chiroptera-i", off_nadir_deg=30.0, fov_mrad=3.0)
    cyl = run("kernel", sim, wood_layer(1.0), sensor)
    iso = run("kernel", sim, wood_layer(0.0), sensor)
    (tc, sc), (ti, si) = cyl.stat("ground_direct"), iso.stat("ground_direct")
    assert tc - ti > 20 * np.hypot(sc, si)
    (ec, sec), (ei, sei) = cyl.energy(order=1, kind="vegetation"), iso.energy(order=1, kind="vegetation")
    assert ei - ec > 20 * np.hypot(sec, sei)


@pytest.mark.parametrize("mode", ["exact", "paper"])
def test_directional_build_reduces_to_the_isotropic_one(mode, sim):
    """beta = 0 everywhere through the directional kernel build: the same physics as the
    direction-free build, with the same random numbers, so the same waveform (to float
    rounding of the extra arithmetic)."""
    scene = testscenes.set_optics(testscenes.homogeneous_layer(lad=1.0, wood=0.2, thickness=2.0, voxel_size=0.5),
                                  1064, bark=(RHO_W, 0.0))
    sensor = Sensor.preset("ahab-chiroptera-i", off_nadir_deg=20.0, fov_mrad=3.0)
    from clsim.transport.setup import prepare_run

    setup = prepare_run(scene, sensor, photons=50_000, seed=3, max_order=3, mode=mode)
    assert setup.bricks.wdir is None
    a = sim.run_setup(setup)
    setup.bricks.wdir = np.zeros((len(setup.bricks.pool), 4), np.float32)
    setup.bricks.wdir[:, 2] = 1.0
    b = sim.run_setup(setup)
    ea, eb = a.energy()[0], b.energy()[0]
    assert ea > 0 and abs(ea / eb - 1) < 1e-4, (ea, eb)


def test_old_scenes_build_the_direction_free_kernel():
    """Scenes without bark directions compile with WOOD_DIR=0, the kernel of before."""
    from clsim.transport.setup import prepare_run

    scene = testscenes.homogeneous_layer(lad=1.0, wood=0.2, thickness=2.0, voxel_size=0.5)
    assert prepare_run(scene, Sensor(), photons=10, seed=1).bricks.wdir is None
    d = wood_layer(1.0)
    g = prepare_run(d, Sensor(), photons=10, seed=1).bricks
    assert g.wdir is not None and g.wdir.shape == (len(g.pool), 4)
    rows = np.flatnonzero(g.pool[:, 1] > 0)
    assert np.all(g.wdir[rows, 3] == 1.0) and np.all(g.wdir[rows, 2] == 1.0)
