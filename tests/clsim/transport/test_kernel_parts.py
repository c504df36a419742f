"""Unit checks of the simulator's parts: RNG, sensor, bricks, waveform, struct layout, CLI."""

from __future__ import annotations

import argparse
import json
from importlib import resources

import numpy as np
import pytest

from clsim.cli.simulate import register
from clsim.digitize import digitize, fine_edges, pulse_kernel
from clsim.errors import DeviceError, InputError
from clsim.sensor import Sensor, list_presets
from clsim.transport.bricks import build_bricks, extinction
from clsim.transport.rng import philox4x32_10, uniforms
from clsim.transport.setup import PARAMS_DTYPE
from clsim.transport.simulator import Simulator, build_options
from clsim.validation import testscenes


def test_philox_known_answers():
    # Random123 known-answer vectors for philox4x32-10
    assert [hex(v) for v in philox4x32_10((0xFFFFFFFF,) * 4, (0xFFFFFFFF, 0xFFFFFFFF))] == \
        ["0x408f276d", "0x41c83b0e", "0xa20bc7c6", "0x6d5451fd"]
    got = philox4x32_10((0x243F6A88, 0x85A308D3, 0x13198A2E, 0x03707344), (0xA4093822, 0x299F31D0))
    assert [hex(v) for v in got] == ["0xd16cfe09", "0x94fdcceb", "0x5001e420", "0x24126ea1"]


KERNEL_MATH = """
#include "common.cl"
#include "philox.cl"
#include "geometry.cl"
__kernel void math(__global const float *u, __global float *out, __global uint *ph)
{
    const int i = get_global_id(0);
    float c;
    const float s = sincos_turns(u[i], &c);
    out[6 * i] = s;
    out[6 * i + 1] = c;
    out[6 * i + 2] = sincos_quarter(u[i] * 1.5707963f, &c);
    out[6 * i + 3] = c;
    out[6 * i + 4] = neg_log_unit(u[i]);
    out[6 * i + 5] = fast_acos(2.0f * u[i] - 1.0f);
    if (i == 0) {
        const uint4 a = philox4x32_10((uint4)(0xFFFFFFFFu), (uint2)(0xFFFFFFFFu));
        const uint4 b = philox4x32_10((uint4)(0x243F6A88u, 0x85A308D3u, 0x13198A2Eu, 0x03707344u),
                                      (uint2)(0xA4093822u, 0x299F31D0u));
        vstore4(a, 0, ph);
        vstore4(b, 1, ph);
    }
}
"""


def test_kernel_math_helpers(sim):
    """The kernels' own sin/cos of 2 pi u, sin/cos on [0, pi/2], -log u, acos and Philox rounds
    against float64 NumPy and the Random123 known answers (kernels/common.cl, philox.cl),
    on each device of the matrix."""
    import pyopencl as cl

    kdir = resources.files("clsim") / "kernels"
    # the transport's own options on this device (fast math; clang's sqrt builtin on PoCL)
    opts = [o for o in build_options(sim.info, "exact", "nee") if not o.startswith("-DNTAB")]
    prg = cl.Program(sim.context, KERNEL_MATH).build(options=[f"-I{kdir}", "-DNTAB=2", *opts])
    # the uniforms the RNG gives, ((k + 1/2) 2^-23), thinned, with both ends
    k = np.concatenate([np.arange(0, 2**23, 97), [2**23 - 1]]).astype(np.float64)
    u64 = (k + 0.5) * 2.0**-23
    u = u64.astype(np.float32)
    assert np.array_equal(u.astype(np.float64), u64)  # exact in float32
    mf = cl.mem_flags
    ub = cl.Buffer(sim.context, mf.READ_ONLY | mf.COPY_HOST_PTR, hostbuf=u)
    out = np.empty((u.size, 6), np.float32)
    ph = np.empty(8, np.uint32)
    ob = cl.Buffer(sim.context, mf.WRITE_ONLY, out.nbytes)
    pb = cl.Buffer(sim.context, mf.WRITE_ONLY, ph.nbytes)
    prg.math(sim.queue, (u.size,), None, ub, ob, pb)
    cl.enqueue_copy(sim.queue, out, ob)
    cl.enqueue_copy(sim.queue, ph, pb)
    x = 2 * np.pi * u.astype(np.float64)
    assert np.abs(out[:, 0] - np.sin(x)).max() < 3e-7
    assert np.abs(out[:, 1] - np.cos(x)).max() < 3e-7
    t = np.float32(1.5707963) * u.astype(np.float64)
    assert np.abs(out[:, 2] - np.sin(t)).max() < 3e-7
    assert np.abs(out[:, 3] - np.cos(t)).max() < 3e-7
    nl = -np.log(u.astype(np.float64))
    assert np.max(np.abs(out[:, 4] - nl) / nl) < 1e-6
    # acos: the polynomial's 2e-8 plus float32 evaluation, within 3 float32 ulps of the value
    ac = np.arccos(2 * u.astype(np.float64) - 1)
    assert np.all(np.abs(out[:, 5] - ac) < 2e-8 + 3 * np.spacing(ac.astype(np.float32)))
    assert [hex(v) for v in ph] == ["0x408f276d", "0x41c83b0e", "0xa20bc7c6", "0x6d5451fd",
                                    "0xd16cfe09", "0x94fdcceb", "0x5001e420", "0x24126ea1"]


def test_uniforms_are_uniform():
    u = uniforms(np.repeat(np.arange(2000), 50), np.tile(np.arange(50), 2000), seed=5).ravel()
    assert u.min() > 0 and u.max() < 1
    assert abs(u.mean() - 0.5) < 4 * np.sqrt(1 / 12 / u.size)
    hist = np.histogram(u, bins=20, range=(0, 1))[0]
    chi2 = ((hist - u.size / 20) ** 2 / (u.size / 20)).sum()
    assert chi2 < 45  # 19 dof, p ~ 1e-3


def test_sensor_preset_and_overrides(tmp_path):
    assert "ahab-chiroptera-i" in list_presets()
    s = Sensor.preset("ahab-chiroptera-i")
    assert (s.wavelength_nm, s.altitude_m, s.divergence_mrad, s.sampling_ghz, s.pulse_fwhm_ns,
            s.aperture_m) == (1064.0, 360.0, 0.5, 1.8, 4.0, 0.05)
    assert s.pulse_sigma_ns == pytest.approx(4.0 / 2.354820045)
    p = tmp_path / "mine.toml"
    p.write_text('name = "mine"\naltitude_m = 500.0\n')
    assert Sensor.preset(str(p)).altitude_m == 500.0
    p.write_text('altitude = 500.0\n')
    with pytest.raises(InputError, match="unknown sensor keys"):
        Sensor.from_toml(p)
    with pytest.raises(InputError, match="off_nadir_deg"):
        s.replace(off_nadir_deg=80.0)
    axis = s.replace(off_nadir_deg=30.0, azimuth_deg=90.0).beam_axis()
    assert axis == pytest.approx([0.0, -0.5, -np.sqrt(3) / 2], abs=1e-12)


def test_bricks_hold_every_voxel():
    scene = testscenes.homogeneous_layer(width=9.0, voxel_size=0.5, wood=0.3)  # 18 voxels: partial bricks
    g = build_bricks(scene)
    lad, sw, _ = extinction(scene)
    B = g.brick
    for (i, j, k), lv, w in zip(scene.ijk, lad, sw):
        b = np.array([i, j, k]) // B
        slot = g.index[b[0] + g.brick_shape[0] * (b[1] + g.brick_shape[1] * b[2])]
        row = slot * B**3 + i % B + B * (j % B + B * (k % B))
        assert g.pool[row, 0] == np.float32(lv) and g.pool[row, 1] == np.float32(w)
    assert sw[0] == pytest.approx(-np.log(0.7) / 0.5)
    assert (g.index >= 0).sum() == g.n_bricks
    assert g.pool[:, 0].sum() == pytest.approx(lad.sum(), rel=1e-6)
    assert np.all(build_bricks(scene, leaf_off=True).pool[:, 0] == 0)


def test_pulse_keeps_energy_and_width():
    k, lag0 = pulse_kernel(0.05, 4.0)
    assert k.sum() == pytest.approx(1.0)
    t = (np.arange(k.size) - lag0) * 0.05
    assert np.sqrt(np.sum(k * t**2)) == pytest.approx(4.0 / 2.354820045, rel=2e-3)
    k2, _ = pulse_kernel(0.05, 4.0, impulse=[0.0, 1.0, 0.5, 0.0], impulse_dt_ns=1.0)
    assert k2.sum() == pytest.approx(1.0) and k2.size > k.size
    with pytest.raises(InputError, match="impulse"):
        pulse_kernel(0.05, 4.0, impulse=[1.0])


def test_digitize_two_returns():
    edges = fine_edges(0.0, 100.0, 0.05)
    e = np.zeros((2, len(edges) - 1))
    e[0, 400], e[1, 1200] = 2e-6, 1e-6  # 20 ns and 60 ns
    t, wf = digitize(edges, e, sampling_ghz=1.8, pulse_fwhm_ns=4.0)
    assert wf.shape == (2, t.size) and np.diff(t) == pytest.approx(1 / 1.8)
    assert wf.sum(axis=1) / 1.8 == pytest.approx([2e-6, 1e-6], rel=1e-3)
    assert t[np.argmax(wf[1])] == pytest.approx(60.0, abs=0.3)


def test_params_struct_matches_c(sim):
    """PARAMS_DTYPE has the field offsets and size of params_t in kernels/params.cl,
    on each device of the matrix."""
    import pyopencl as cl

    names = list(PARAMS_DTYPE.names)
    body = "\n".join(f"o[{i}] = (int)__builtin_offsetof(params_t, {n});" for i, n in enumerate(names))
    src = f'#include "params.cl"\n__kernel void offs(__global int *o) {{ {body} o[{len(names)}] = (int)sizeof(params_t); }}'
    kdir = resources.files("clsim") / "kernels"
    prg = cl.Program(sim.context, src).build(options=[f"-I{kdir}"])
    out = np.zeros(len(names) + 1, np.int32)
    buf = cl.Buffer(sim.context, cl.mem_flags.WRITE_ONLY, out.nbytes)
    cl.Kernel(prg, "offs")(sim.queue, (1,), None, buf)
    cl.enqueue_copy(sim.queue, out, buf)
    assert out[-1] == PARAMS_DTYPE.itemsize
    assert out[:-1].tolist() == [PARAMS_DTYPE.fields[n][1] for n in names]


@pytest.fixture
def parser():
    p = argparse.ArgumentParser(prog="clsim")
    register(p.add_subparsers(dest="command", required=True))
    return p


def test_cli_simulate_devices_bench(parser, tmp_path, capsys):
    scene_path = testscenes.homogeneous_layer(width=6.0).save(tmp_path / "layer.npz")
    out, png = tmp_path / "wf.npz", tmp_path / "wf.png"
    a = parser.parse_args(["simulate", str(scene_path), "--photons", "5000", "--seed", "2", "-o", str(out),
                           "--max-order", "2", "--plot", str(png), "--trace", "4",
                           "--trace-plot", str(tmp_path / "tr.png")])
    try:
        Simulator()
    except DeviceError:
        a.reference = True
    assert a.func(a) == 0
    z = np.load(out)
    assert z["by_order"].shape == (2, z["time_ns"].size) and z["waveform"].shape == z["time_ns"].shape
    settings = json.loads(str(z["settings"]))
    assert settings["photons"] == 5000 and settings["mode"] == "exact" and settings["seed"] == 2
    assert z["traces"].shape == (4, 16, 4)
    assert png.stat().st_size > 1000 and (tmp_path / "tr.png").stat().st_size > 1000
    assert "received energy" in capsys.readouterr().out

    from clsim.cli.app import main

    assert main(["simulate", str(tmp_path / "missing.npz"), "-o", str(out)]) == 2
    assert "does not exist" in capsys.readouterr().err
    with pytest.raises(SystemExit):
        parser.parse_args(["simulate", str(scene_path), "-o", str(out), "--mode", "exakt"])
    assert "invalid choice" in capsys.readouterr().err

    a = parser.parse_args(["devices"])
    a.func(a)
    a = parser.parse_args(["bench", "--photons", "2000", "--repeats", "1"])
    if a.func(a) == 0:
        assert "voxel steps/s" in capsys.readouterr().out


def test_cli_reference_fallback(parser, tmp_path):
    scene_path = testscenes.ground_only().save(tmp_path / "g.npz")
    a = parser.parse_args(["simulate", str(scene_path), "--photons", "200", "-o", str(tmp_path / "w.npz"),
                           "--reference", "--max-order", "1"])
    assert a.func(a) == 0
    assert "NumPy" in json.loads(str(np.load(tmp_path / "w.npz")["settings"]))["device"]
