"""Solid wood (docs/method.md, "Solid wood") against closed forms.

A layer of solid voxels (``Scene.wood_solid``, axis z, cap share c) stops every
photon in its top voxel from any direction, and what a photon hits there is an
end cap (normal +-z) or the side of a vertical cylinder, in proportion to their
projected areas: cap ``c |cos psi|``, side ``(1 - c) sin(psi) / pi`` (psi: the
beam's angle to the axis).  A Lambertian cap returns ``|cos psi|`` towards a
monostatic sensor, the side ``sin(psi) E|cos phi| = sin(psi) pi / 4``, so with
the hot spot (the return retraces the free incoming path) the order-1 wood
energy is

    A R_w / (pi r0^2) [c cos^2 psi + (1 - c) sin^2 psi / 4] / [c |cos psi| + (1 - c) sin psi / pi]

with r0 the range to the layer's top along the beam.  Random facets (the model
before solid voxels carried a surface) return ``2 / 3`` whatever the direction.
The hit lies an exponential depth (extinction ``-ln(1e-6) / h``) inside the top
voxel: ``1 / r0^2`` becomes ``(1 - 2 / (sigma r0)) / r0^2`` to first order.
Tolerance: 3 Monte Carlo standard errors (16 batch means) plus 1e-4 of the
answer (float32 ranges near 360 m).
"""

from __future__ import annotations

import numpy as np
import pytest

from clsim.sensor import Sensor
from clsim.transport.reference import ReferenceSimulator
from clsim.validation import testscenes

H, BASE, VOXEL = 1.0, 2.0, 0.5
RHO_W = 0.45
PHOTONS = {"kernel": 200_000, "oracle": 20_000}


def solid_layer(cap):
    s = testscenes.homogeneous_layer(lad=0.0, wood=1.0 - 1e-6, thickness=H, base_height=BASE, width=10.0,
                                     voxel_size=VOXEL)
    s.wood_solid = np.ones(s.n_voxels, bool)
    s.wood_cap = np.full(s.n_voxels, float(cap))
    s.wood_axis = np.tile([0.0, 0.0, 1.0], (s.n_voxels, 1))
    s.__post_init__()
    return testscenes.set_optics(s, 1064, bark=(RHO_W, 0.0), ground=(0.3, 0.0))


def surface_factor(cap, psi):
    """E|n . d| over the hit normals of a solid voxel (cap share ``cap``, beam at ``psi`` to the axis)."""
    c, s = abs(np.cos(psi)), np.sin(psi)
    end, side = cap * c, (1.0 - cap) * s / np.pi
    return (end * c + side * s * np.pi / 4.0) / (end + side)


def run(backend, sim, scene, sensor):
    s = sim if backend == "kernel" else ReferenceSimulator()
    return s.run(scene, sensor, photons=PHOTONS[backend], seed=20261123, max_order=1, batches=16, hotspot=True)


@pytest.mark.parametrize("backend", ["kernel", "oracle"])
@pytest.mark.parametrize("deg,cap", [(0.0, 0.5), (30.0, 0.0), (30.0, 0.4), (50.0, 1.0)])
def test_solid_layer_stops_everything_and_returns_its_surface(backend, deg, cap, sim):
    th = np.radians(deg)
    sensor = Sensor.preset("ahab-chiroptera-i", off_nadir_deg=deg, fov_mrad=3.0)
    res = run(backend, sim, solid_layer(cap), sensor)
    t, _ = res.stat("ground_direct")
    assert t < 1e-4, t  # opaque from every direction, also along a side-only cylinder's axis
    r0 = sensor.range_m - (BASE + H) / np.cos(th)
    # the hit lies an exponential depth (extinction -ln(1e-6) / h) below the top: mean 1/(r0 + s)^2
    sig = -np.log(1e-6) / VOXEL
    known = sensor.aperture_area_m2 * RHO_W / np.pi * surface_factor(cap, th) / r0**2 * (1 - 2 / (sig * r0))
    e, se = res.energy(order=1, kind="vegetation")
    assert abs(e - known) < 3 * se + 1e-4 * known, (deg, cap, e, se, known, e / known - 1)
    assert se / e < 0.03
    # random facets would return 2/3: far outside the tolerance in every case here
    facets = sensor.aperture_area_m2 * RHO_W / np.pi * (2.0 / 3.0) / r0**2
    assert abs(e - facets) > 10 * se


def test_solid_voxels_are_carried_to_the_device():
    """The wdir rows of solid voxels hold (axis, -1 - cap); their wood is opaque whatever ``wood`` says."""
    from clsim.transport.bricks import WOOD_P_MAX
    from clsim.transport.setup import prepare_run

    s = solid_layer(0.25)
    s.wood = np.full(s.n_voxels, 0.1)  # the value of a solid voxel's wood does not matter
    s.__post_init__()
    g = prepare_run(s, Sensor(), photons=10, seed=1).bricks
    rows = np.flatnonzero(g.pool[:, 1] > 0)
    assert np.allclose(g.wdir[rows, 3], -1.25) and np.all(g.wdir[rows, 2] == 1.0)
    assert np.allclose(g.pool[rows, 1], -np.log1p(-WOOD_P_MAX) / VOXEL, rtol=1e-6)


def test_scene_checks_and_keeps_solid_wood(tmp_path):
    from voxlidar.errors import InputError
    from voxlidar.scene import Scene

    s = solid_layer(0.3)
    back = Scene.load(s.save(tmp_path / "solid.npz"))
    assert back.wood_solid.all() and np.allclose(back.wood_cap, 0.3) and back.wood_directional
    with pytest.raises(InputError, match="wood_cap"):
        Scene(origin=(0, 0, 0), voxel_size=1.0, shape=(1, 1, 1), ijk=[[0, 0, 0]], lad=[0.0],
              wood_solid=[True], wood_cap=[1.5])
