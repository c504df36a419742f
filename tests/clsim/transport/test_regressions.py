"""Regressions found on the synthetic oak."""

import os
import subprocess
import sys
import textwrap

import pytest


@pytest.fixture(scope="module")
def oak_scene_file(tmp_path_factory):
    """The synthetic oak's 20 cm exact-LAD scene, built once (9 s) for every device's run."""
    from tlsvox.truth.synthetic import make_tree

    return make_tree(seed=1).truth_scene(0.2).save(tmp_path_factory.mktemp("oak") / "oak20.npz")


def test_brick_jump_never_walks_backwards(cl_device, oak_scene_file):
    # Photon 293409 of this run used to bounce between two empty bricks forever
    # (float32 rounding of the brick-exit point put it back in the brick it had
    # left), hanging the kernel.  Run it in a subprocess with a deadline, on each
    # device of the matrix.
    code = textwrap.dedent(f"""
        from voxlidar.scene import Scene
        from clsim import Simulator, Sensor
        scene = Scene.load({str(oak_scene_file)!r})
        s = Sensor.preset("ahab-chiroptera-i", off_nadir_deg=15.0, azimuth_deg=200.0)
        r = Simulator().run(scene, s, photons=293_410, seed=1, max_order=3, target=(4.5, 0.0))
        print("ok", r.energy()[0] > 0)
    """)
    env = dict(os.environ, VOXLIDAR_DEVICE=cl_device.key)
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=240, env=env)
    assert out.returncode == 0, out.stderr[-2000:]
    assert "ok True" in out.stdout
