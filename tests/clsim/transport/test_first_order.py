"""The deterministic first order (clsim.transport.first_order) against closed forms, its float64
oracle and the Monte Carlo kernel.

Known answers (DESIGN.md section 6; clsim.validation.meshref for the hot spot): a turbid layer of
spherical leaves (LAD u, thickness H) over a Lambertian ground, nadir, single scattering, has
ground energy (A / R^2)(rho_g / pi) exp(-m G u H) and canopy energy
A (rho_l / (3 pi)) u int exp(-m G u (z_top - z)) / s(z)^2 dz, m = 2 (turbid) or 1 (hot spot).
Tolerances: the closed forms 1e-5 relative (float32 on the device, the beam's 0.25 mrad spread
changes them by 1e-7); the oracle 1e-5 on totals (the same integral in float64); the Monte Carlo
kernel 4 of its standard errors plus what the finite set of beam samples leaves (tested apart).
"""

from __future__ import annotations

import numpy as np
import pytest
from scipy.integrate import quad

from clsim.digitize import digitize
from clsim.errors import InputError
from clsim.sensor import Sensor
from clsim.survey import ScanPattern, Trajectory, survey_pulses
from clsim.transport.first_order import (
    FirstOrderRunner,
    beam_samples,
    first_order_reference,
    leaf_cos2,
    outward_tables,
    pulse_grid,
)
from clsim.transport.setup import prepare_scene
from clsim.validation import testscenes

SENSOR = Sensor.preset("ahab-chiroptera-i")


class _Pulses:
    """The fields of clsim.survey.Pulses that the first order reads."""

    def __init__(self, position, direction, target):
        self.position, self.direction, self.target = (np.atleast_2d(np.asarray(a, dtype=float))
                                                      for a in (position, direction, target))

    def __len__(self):
        return len(self.position)


def nadir_pulse(scene, sensor=SENSOR, offset=(0.0, 0.0)):
    lo = scene.origin
    hi = lo + scene.voxel_size * np.asarray(scene.shape)
    target = np.array([(lo[0] + hi[0]) / 2 + offset[0], (lo[1] + hi[1]) / 2 + offset[1], scene.ground_z])
    return _Pulses(sensor.position(target), sensor.beam_axis(), target)


def run(sim, scene, pulses, *, n=19, hotspot=False, sensor=SENSOR, bin_ns=0.05):
    ss = prepare_scene(scene, wavelength_nm=sensor.wavelength_nm)
    grid = pulse_grid(scene, pulses, sensor, bin_ns=bin_ns)
    wave, energy, outside, _, fine = FirstOrderRunner(sim).run(ss, grid, sensor, beam_samples(n), hotspot=hotspot,
                                                               fine=True)
    return ss, grid, wave, energy, outside, fine


def test_beam_samples_are_the_gaussian_beam():
    s = beam_samples(271)
    assert s.shape == (271, 3) and np.allclose(s[:, 2], 1 / 271)
    r2 = s[:, 0] ** 2 + s[:, 1] ** 2
    assert abs(np.mean(r2) / 2.0 - 1) < 0.01                       # E[a^2 + b^2] = 2 for unit sigma per axis
    assert abs(np.mean(s[:, 0])) < 0.01 and abs(np.mean(s[:, 1])) < 0.01
    assert np.array_equal(beam_samples(19), beam_samples(19))
    for bad in (0, -1, 1.5, True, "19"):
        with pytest.raises(InputError, match="beam samples"):
            beam_samples(bad)


@pytest.mark.parametrize("hotspot", [False, True])
def test_turbid_layer_closed_forms(sim, hotspot):
    u, H, base = 1.0, 2.0, 2.0
    sc = testscenes.homogeneous_layer(lad=u, thickness=H, base_height=base)
    ss, grid, wave, energy, outside, fine = run(sim, sc, nadir_pulse(sc), hotspot=hotspot)
    m = 1.0 if hotspot else 2.0
    A, R = SENSOR.aperture_area_m2, SENSOR.range_m
    rho_l, rho_g = ss.optics["leaf"][0], ss.optics["ground"][0]
    ground = A / R**2 * rho_g / np.pi * np.exp(-m * 0.5 * u * H)
    canopy = quad(lambda z: A * rho_l / (3 * np.pi) * u * np.exp(-m * 0.5 * u * (base + H - z)) / (R - z) ** 2,
                  base, base + H, epsabs=0, epsrel=1e-12)[0]
    assert fine[0, 1].sum() == pytest.approx(ground, rel=1e-5)
    assert fine[0, 0].sum() == pytest.approx(canopy, rel=1e-5)
    assert outside[0] == 0.0
    # the digitised waveform keeps the energy: sum / sampling rate
    assert wave[0].sum() / SENSOR.sampling_ghz == pytest.approx(ground + canopy, rel=1e-4)
    assert energy[0] == pytest.approx(ground + canopy, rel=1e-5)
    # the canopy's return decays with depth as exp(-m G u z): 1 ns of fine bins, 1 m apart
    # (one bin alone moves by float32 steps of distance at 360 m)
    c = 0.299792458
    t_top = 2 * (R - base - H) / c
    i0 = int(np.floor((t_top - grid.fine_start_ns[0]) / grid.dt_ns)) + 2
    di, w = int(round(2 * 1.0 / c / grid.dt_ns)), int(round(1.0 / grid.dt_ns))
    ratio = fine[0, 0, i0 + di:i0 + di + w].sum() / fine[0, 0, i0:i0 + w].sum()
    assert ratio == pytest.approx(np.exp(-m * 0.5 * u * 1.0) * ((R - base - H) / (R - base - H + 1)) ** 2, rel=2e-3)


def test_digitised_on_the_device_as_digitize_does(sim):
    sc = testscenes.homogeneous_layer(lad=1.0, thickness=2.0, base_height=2.0)
    _, grid, wave, _, _, fine = run(sim, sc, nadir_pulse(sc), bin_ns=0.1)
    edges = grid.fine_start_ns[0] + grid.dt_ns * np.arange(grid.nbins + 1)
    t, w = digitize(edges, fine[0].sum(axis=0), sampling_ghz=SENSOR.sampling_ghz, pulse_fwhm_ns=SENSOR.pulse_fwhm_ns,
                    t0_ns=grid.t0_ns[0])
    n = int(grid.n_samples[0])
    assert t[0] == pytest.approx(grid.t0_ns[0])
    assert np.allclose(wave[0, :n], w[:n], rtol=1e-4, atol=1e-6 * w.max())


def rich_scene():
    """Leaves of a planophile distribution facing out of the crown, bark with directions (half of it
    cylinders, a few voxels solid), a ground: every branch of the kernel."""
    sc = testscenes.homogeneous_layer(lad=0.8, thickness=1.5, base_height=2.0, width=4.0, voxel_size=0.5,
                                      leaf_angle="planophile", leaf_azimuth="outward", wood=0.2)
    rng = np.random.default_rng(3)
    ax = rng.normal(size=(sc.n_voxels, 3))
    sc.wood_axis = ax / np.linalg.norm(ax, axis=1, keepdims=True)
    sc.wood_beta = rng.uniform(0, 1, sc.n_voxels)
    sc.wood_solid = rng.uniform(size=sc.n_voxels) < 0.1
    sc.wood_cap = np.full(sc.n_voxels, 0.3)
    sc.__post_init__()
    return testscenes.set_optics(sc, SENSOR.wavelength_nm, leaf=(0.45, 0.4), bark=(0.5, 0.0), ground=(0.3, 0.0))


@pytest.mark.parametrize("hotspot", [False, True])
def test_kernel_matches_its_float64_oracle(sim, hotspot):
    sc = rich_scene()
    assert sc.wood_directional and sc.leaf_azimuth == "outward"
    sensor = SENSOR.replace(off_nadir_deg=20.0, azimuth_deg=30.0, divergence_mrad=8.0, fov_mrad=10.0)
    p = nadir_pulse(sc, sensor, offset=(0.6, -0.4))
    ss, grid, _, _, _, fine = run(sim, sc, p, n=7, hotspot=hotspot, sensor=sensor)
    ref = first_order_reference(ss, grid, sensor, beam_samples(7), hotspot=hotspot)
    for kind in (0, 1):
        assert fine[0, kind].sum() == pytest.approx(ref[0, kind].sum(), rel=2e-4)
    # bin by bin, after a 1 ns box (float32 distances at 360 m move energy between neighbouring bins)
    k = int(round(1.0 / grid.dt_ns))
    a = np.convolve(fine[0].sum(0), np.ones(k), "same")
    b = np.convolve(ref[0].sum(0), np.ones(k), "same")
    assert np.abs(a - b).max() < 2e-3 * b.max()


def test_outward_tables():
    """At beta = pi/2 (a vertical beam) n . d = cos(theta); at beta = 0 (horizontal, along the
    leaves' azimuth) sin(theta): the tables hold their means and the means of their squares."""
    from voxlidar.leaf_orientation import LeafAngle

    ppf = LeafAngle("planophile").ppf(np.linspace(0, 1, 4097))
    tab = outward_tables(ppf)
    g, q = tab[:1025], tab[1025:]
    w = np.full(4097, 1 / 4096)
    w[[0, -1]] /= 2
    assert g[768] == pytest.approx(w @ np.cos(ppf), rel=1e-9) and q[768] == pytest.approx(leaf_cos2(ppf), rel=1e-9)
    assert g[512] == pytest.approx(w @ np.sin(ppf), rel=1e-9) and q[512] == pytest.approx(1 - leaf_cos2(ppf), rel=1e-9)
    assert leaf_cos2(ppf) > 0.5                                     # planophile: mostly flat leaves


def test_agrees_with_the_monte_carlo_kernel(sim):
    """The Monte Carlo kernel's order-1 tallies estimate the same expectation over the Gaussian beam.
    Tolerance: 4 of its standard errors plus twice what the beam samples leave, estimated as the
    change from 271 to 1,089 samples (the wood's voxel-to-voxel jumps across the footprint make
    the quadrature converge slowly)."""
    sc = rich_scene()
    sensor = SENSOR.replace(divergence_mrad=2.0, fov_mrad=3.0)    # the footprint inside the scene
    p = nadir_pulse(sc, sensor, offset=(0.3, 0.2))
    for hot in (False, True):
        coarse = run(sim, sc, p, n=271, hotspot=hot, sensor=sensor)[-1]
        fine = run(sim, sc, p, n=1089, hotspot=hot, sensor=sensor)[-1]
        mc = sim.run(sc, sensor, photons=400_000, seed=5, max_order=1, hotspot=hot, target=p.target[0])
        for kind, k in (("vegetation", 0), ("ground", 1)):
            e, se = mc.energy(kind=kind)
            quad_err = abs(fine[0, k].sum() - coarse[0, k].sum())
            assert abs(fine[0, k].sum() - e) < 4 * se + 2 * quad_err, (hot, kind)


def line_pulses(n=40):
    tr = Trajectory.line((-1.0, 0.0), (1.0, 0.0), altitude_m=300.0, speed_mps=40.0)
    pat = ScanPattern(kind="polygon", pulse_rate_hz=2000.0, scan_rate_hz=50.0, fov_deg=0.3)  # inside the scene
    return survey_pulses(tr, pat, SENSOR, count=n, seed=3)


def test_run_pulses_deterministic(sim):
    sc = rich_scene()
    p = line_pulses()
    a = sim.run_pulses(sc, p, SENSOR, photons=1, max_order=1, first_order="deterministic", beam_samples=19)
    b = sim.run_pulses(sc, p, SENSOR, photons=1, max_order=1, first_order="deterministic", beam_samples=19)
    assert np.array_equal(a.waveform, b.waveform) and np.array_equal(a.t0_ns, b.t0_ns)   # no seed, same bits
    assert len(a) == len(p) and np.all(a.energy > 0)
    # each pulse as a batch of its own: the same waveform
    one = sim.run_pulses(sc, p[[7]], SENSOR, photons=1, max_order=1, first_order="deterministic")
    n = int(one.n_samples[0])
    assert one.t0_ns[0] == a.t0_ns[7] and np.allclose(one.waveform[0, :n], a.waveform[7, :n], rtol=1e-6)
    # the Monte Carlo path estimates the same waveforms
    mc = sim.run_pulses(sc, p[:4], SENSOR, photons=100_000, max_order=1)
    assert np.allclose(mc.energy, a.energy[:4], rtol=0.02)
    with pytest.raises(InputError, match="first_order"):
        sim.run_pulses(sc, p, SENSOR, photons=1, first_order="exact")
    with pytest.raises(InputError, match="paper"):
        sim.run_pulses(sc, p, SENSOR, photons=1, first_order="deterministic", mode="paper")


def test_higher_orders_added_by_the_photons(sim):
    """max_order 3: the deterministic order 1 plus the photons' orders 2-3 (their order-1 tallies
    skipped) estimate what the photons alone do: energies within 3 %, a Monte Carlo margin at
    20,000 photons (orders 2-3 are about a third of the return here)."""
    sc = rich_scene()
    p = line_pulses(4)
    hyb = sim.run_pulses(sc, p, SENSOR, photons=20_000, max_order=3, first_order="deterministic")
    order1 = sim.run_pulses(sc, p, SENSOR, photons=1, max_order=1, first_order="deterministic")
    mc = sim.run_pulses(sc, p, SENSOR, photons=200_000, max_order=3)
    assert np.all(hyb.energy > 1.05 * order1.energy)
    assert np.allclose(hyb.energy, mc.energy, rtol=0.03)
