"""``clsim pick``: the Open3D window session over a scene, run under a virtual display (xvfb-run)."""

from __future__ import annotations

import os
import shutil
import subprocess
import sys

import numpy as np
import pytest

from clsim.cli.app import main


@pytest.fixture(scope="module")
def layer(tmp_path_factory):
    from clsim.validation.testscenes import homogeneous_layer

    d = tmp_path_factory.mktemp("pick")
    homogeneous_layer(width=4.0, voxel_size=0.5).save(d / "layer.npz")
    return d


@pytest.mark.skipif(shutil.which("xvfb-run") is None,
                    reason="no xvfb-run (apt-get install xvfb xauth; `make setup` does it as root)")
def test_pick_session_under_a_virtual_display(layer, tmp_path):
    """The window opens and shows the voxels; each picked voxel's pulse equals `clsim simulate --target` there."""
    argv = [sys.executable, "-m", "clsim.cli", "pick", str(layer / "layer.npz"), "--pick-voxel", "3", "40",
            "--seconds", "1", "--screenshot", str(tmp_path / "shot.png"), "--plot", str(tmp_path / "pick.png"),
            "-o", str(tmp_path / "pick.npz"), "--photons", "20000", "--seed", "5", "-q"]
    env = {k: v for k, v in os.environ.items() if k not in ("DISPLAY", "WAYLAND_DISPLAY")}
    r = subprocess.run(["xvfb-run", "-a", "-s", "-screen 0 1280x1024x24", *argv], capture_output=True, text=True,
                       timeout=300, env=env)
    assert r.returncode == 0, r.stderr[-2000:]
    import matplotlib.image as mpimg

    shot = mpimg.imread(tmp_path / "shot.png")[..., :3]
    assert shot.shape[0] > 100 and shot.std() > 0.01  # the voxels are drawn, not a blank window
    assert (tmp_path / "pick.png").stat().st_size > 1000
    picks = np.load(tmp_path / "pick.npz")
    assert picks["waveform"].shape[0] == 2
    for k in range(2):
        x, y = picks["targets"][k, :2]
        one = tmp_path / f"one{k}.npz"
        assert main(["simulate", str(layer / "layer.npz"), f"--target={x},{y}", "--photons", "20000", "--seed", "5",
                     "--max-order", "3", "-o", str(one), "-q"]) == 0
        w = np.load(one)["waveform"]
        assert np.array_equal(picks["waveform"][k, :w.size], w)


def test_pick_without_a_display_says_how(layer, tmp_path, monkeypatch, capsys):
    monkeypatch.delenv("DISPLAY", raising=False)
    monkeypatch.delenv("WAYLAND_DISPLAY", raising=False)
    assert main(["pick", str(layer / "layer.npz"), "--plot", str(tmp_path / "p.png")]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "xvfb-run" in err[0] and not (tmp_path / "p.png").exists()


def test_pick_refuses_a_voxel_the_scene_has_not(layer, tmp_path, monkeypatch, capsys):
    monkeypatch.setenv("DISPLAY", ":99")  # checked before any window opens
    assert main(["pick", str(layer / "layer.npz"), "--plot", str(tmp_path / "p.png"), "--pick-voxel", "99999"]) == 2
    assert "leaf voxels" in capsys.readouterr().err
