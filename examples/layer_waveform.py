"""Simulate a waveform over a homogeneous leaf layer and compare with the closed form.

A 2 m layer of spherical leaves (LAD 1 m2/m3) 2 m above a Lambertian ground,
seen at nadir by the AHAB Chiroptera I preset: the single-scattering canopy
and ground energies are known in closed form (docs/method.md §8), for the turbid
return and, with ``hotspot=True``, for the correlated (one-way) return.

    .venv/bin/python examples/layer_waveform.py
"""

import numpy as np

from clsim import ReferenceSimulator, Sensor
from clsim.errors import DeviceError
from clsim.validation import testscenes


def main():
    u, H, base = 1.0, 2.0, 2.0
    scene = testscenes.homogeneous_layer(lad=u, thickness=H, base_height=base, width=10.0, voxel_size=0.5,
                                         leaf_angle="spherical")
    sensor = Sensor.preset("ahab-chiroptera-i", fov_mrad=3.0)
    try:
        from clsim import Simulator

        sim, photons = Simulator(), 400_000
    except DeviceError:
        sim, photons = ReferenceSimulator(), 50_000
    rl, _ = scene.optics("leaf", sensor.wavelength_nm)
    rg, _ = scene.optics("ground", sensor.wavelength_nm)
    A, R, G = sensor.aperture_area_m2, sensor.range_m, 0.5
    top = R - base - H
    for hot in (False, True):
        k = (1.0 if hot else 2.0) * G * u
        canopy = A / top**2 * rl / (3 * np.pi) * (1 - np.exp(-k * H)) / (k / u)
        ground = A / R**2 * rg / np.pi * np.exp(-k * H)
        res = sim.run(scene, sensor, photons=photons, seed=1, max_order=1, hotspot=hot)
        (ec, sc), (eg, sg) = res.energy(kind="vegetation"), res.energy(kind="ground")
        label = "hot spot (one-way)" if hot else "turbid (two-way)"
        print(f"{label:>20}: canopy {ec:.4e} +- {sc:.1e} (closed form {canopy:.4e}, {100 * (ec / canopy - 1):+.2f} %); "
              f"ground {eg:.4e} +- {sg:.1e} (closed form {ground:.4e}, {100 * (eg / ground - 1):+.2f} %)")


if __name__ == "__main__":
    main()
