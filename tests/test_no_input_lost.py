"""No command overwrites its own input: the data-loss cases found by a new user's trial.

Each case runs the real command in-process on small generated files, then
checks: exit code 2, one clean error line, every input byte-identical (sha256),
and no output written.
"""

from __future__ import annotations

import hashlib
import os
from pathlib import Path

import numpy as np
import pytest

from clsim.cli.app import main as clsim_main
from tlsvox.cli.app import main as tlsvox_main


def sha(path: Path) -> str:
    return hashlib.sha256(path.read_bytes()).hexdigest()


@pytest.fixture(scope="module")
def files(tmp_path_factory):
    """A scene, and a small scanned leaf box with its sidecars."""
    from clsim.validation.testscenes import homogeneous_layer

    d = tmp_path_factory.mktemp("inputs")
    homogeneous_layer(width=4.0, voxel_size=0.5).save(d / "scene.npz")
    pytest.importorskip("open3d")
    from tlsvox.truth.scanner import ScannerPreset, ScanPose, simulate_scan
    from tlsvox.truth.synthetic import make_leaf_slab

    box = make_leaf_slab(lad=1.0, size=(1.0, 1.0, 1.0), origin=(-0.5, -0.5, 1.0), seed=3)
    preset = ScannerPreset.riegl_vz400(zenith_step_deg=1.0, azimuth_step_deg=1.0, n_subrays=1)
    for i, x in enumerate((-5.0, 5.0)):
        scan = simulate_scan(box, pose=ScanPose(position=(x, 0.0, 1.7)), preset=preset, seed=i, progress=False)
        scan.pose = scan.pose_true
        scan.write(d / f"s{i + 1}.laz")
    return d


def _check(main, argv, inputs, capsys, expect_missing=()):
    before = {p: sha(p) for p in inputs}
    code = main([str(a) for a in argv])
    err = capsys.readouterr().err.strip().splitlines()
    assert code == 2, err
    assert len(err) == 1 and "nothing was written" in err[0], err
    assert {p: sha(p) for p in inputs} == before
    for p in expect_missing:
        assert not Path(p).exists(), p
    return err[0]


def test_clsim_decompose_never_replaces_its_input(tmp_path, capsys):
    rows = tmp_path / "return.csv"
    rows.write_text("10,12,40,90,40,12,10\n11,10,30,70,30,10,11\n")
    _check(clsim_main, ["decompose", rows, "-o", rows], [rows], capsys)
    _check(clsim_main, ["decompose", rows, "-o", tmp_path / "e.csv", "--plot", rows], [rows], capsys,
           expect_missing=[tmp_path / "e.csv"])


CLSIM_CASES = {
    "-o equals the scene": lambda d: ["-o", d / "scene.npz"],
    "--plot equals the scene": lambda d: ["-o", d / "wf_out.npz", "--plot", d / "scene.npz"],
    "--plot equals -o": lambda d: ["-o", d / "wf_out.npz", "--plot", d / "wf_out.npz"],
    "-o through ..": lambda d: ["-o", d / "nowhere" / ".." / "scene.npz"],
}


@pytest.mark.parametrize("case", sorted(CLSIM_CASES))
def test_clsim_simulate_never_replaces_its_input(case, files, capsys):
    argv = ["simulate", files / "scene.npz", "--photons", "100", *CLSIM_CASES[case](files)]
    _check(clsim_main, argv, [files / "scene.npz"], capsys, expect_missing=[files / "wf_out.npz"])


def test_clsim_simulate_through_a_symlink(files, tmp_path, capsys):
    link = tmp_path / "link.npz"
    os.symlink(files / "scene.npz", link)
    msg = _check(clsim_main, ["simulate", files / "scene.npz", "--photons", "100", "-o", link],
                 [files / "scene.npz"], capsys)
    assert "same file as the input scene" in msg


def test_unwritable_folder_is_one_line(files, tmp_path, capsys):
    if os.geteuid() == 0:
        pytest.skip("root can write into any folder")
    locked = tmp_path / "locked"
    locked.mkdir(mode=0o500)
    msg = _check(clsim_main, ["simulate", files / "scene.npz", "--photons", "100", "-o", locked / "wf.npz"],
                 [files / "scene.npz"], capsys)
    assert "cannot be written" in msg


def _scan_files(d):
    return [d / n for n in ("s1.laz", "s1.pulses.npz", "s1.pose.json", "s2.laz", "s2.pulses.npz", "s2.pose.json")]


TLSVOX_CASES = {
    "voxelize -o equals a scan": lambda d: ["voxelize", d / "s1.laz", "-o", d / "s1.laz"],
    "voxelize -o equals the pulse table": lambda d: ["voxelize", d / "s1.laz", "-o", d / "s1.pulses.npz"],
    "voxelize --vox equals a scan": lambda d: ["voxelize", d / "s1.laz", "-o", d / "new.npz", "--vox", d / "s1.laz"],
    "voxelize --vox equals -o": lambda d: ["voxelize", d / "s1.laz", "-o", d / "new.npz", "--vox", d / "new.npz"],
    "register -o equals a scan": lambda d: ["register", d / "s1.laz", d / "s2.laz", "-o", d / "s1.laz"],
    "register transforms equal a pose sidecar": lambda d: ["register", d / "s1.laz", d / "s2.laz", "-o",
                                                          d / "m.laz", "--transforms", d / "s2.pose.json"],
    "classify -o is a scan file": lambda d: ["classify", d / "s1.laz", "-o", d / "s2.laz", "--no-ground"],
    "view --screenshot equals the scan": lambda d: ["view", d / "s1.laz", "--screenshot", d / "s1.laz"],
    "view --screenshot equals its pose sidecar": lambda d: ["view", d / "s1.laz", "--screenshot", d / "s1.pose.json"],
}


@pytest.mark.parametrize("case", sorted(TLSVOX_CASES))
def test_tlsvox_commands_never_replace_their_inputs(case, files, capsys):
    argv = TLSVOX_CASES[case](files)
    _check(tlsvox_main, argv, _scan_files(files), capsys,
           expect_missing=[files / "new.npz", files / "m.laz"])


def test_ctrl_c_is_one_line_and_exit_130(files, monkeypatch, capsys):
    import clsim.cli.simulate as cs

    def interrupted(args):
        raise KeyboardInterrupt

    monkeypatch.setattr(cs, "cmd_simulate", interrupted)
    from clsim.cli.app import build_parser

    args = build_parser().parse_args(["simulate", str(files / "scene.npz"), "-o", str(files / "x.npz")])
    assert args.func is interrupted
    assert clsim_main(["simulate", str(files / "scene.npz"), "-o", str(files / "x.npz")]) == 130
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "interrupted" in err[0]


def test_json_outputs_are_standard_json(tmp_path):
    """NaN and infinities become null: strict JSON readers accept what we write."""
    import json

    from clsim.validation.testscenes import homogeneous_layer
    from voxlidar.safeio import json_text

    def strict(text):
        return json.loads(text, parse_constant=lambda c: pytest.fail(f"non-standard JSON constant {c}"))

    assert strict(json_text({"a": float("nan"), "b": [1.0, float("-inf")], "c": np.float32(2.5)})) == \
        {"a": None, "b": [1.0, None], "c": 2.5}
    scene = homogeneous_layer(width=4.0, voxel_size=0.5)
    scene.meta["fitness"] = float("nan")
    path = scene.save(tmp_path / "s.npz")
    assert strict(str(np.load(path)["meta"]))["fitness"] is None


def test_view_without_a_display_says_so_at_once(files, monkeypatch, capsys):
    """It used to open an Open3D window that never appeared and hang."""
    monkeypatch.delenv("DISPLAY", raising=False)
    monkeypatch.delenv("WAYLAND_DISPLAY", raising=False)
    assert tlsvox_main(["view", str(files / "s1.laz")]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "no display" in err[0] and "--screenshot" in err[0]


def test_simulate_takes_a_target_and_a_vox_scene(files, tmp_path, capsys):
    """The guide's --target, and an AMAPVox .vox as the scene."""
    import json

    from tlsvox.voxel.amapvox import write_vox
    from voxlidar.scene import Scene

    out = tmp_path / "wf.npz"
    argv = ["simulate", str(files / "scene.npz"), "--photons", "2000", "-o", str(out), "-q", "--target", "0.5,-0.25"]
    assert clsim_main(argv) == 0
    settings = json.loads(str(np.load(out)["settings"]))
    assert settings["target"][:2] == [0.5, -0.25]
    vox = write_vox(Scene.load(files / "scene.npz"), tmp_path / "scene.vox")
    assert clsim_main(["simulate", str(vox), "--photons", "2000", "-o", str(tmp_path / "v.npz"), "-q"]) == 0
    assert np.load(tmp_path / "v.npz")["waveform"].sum() > 0
    with pytest.raises(SystemExit) as stop:  # a usage error: argparse's exit 2, one line
        clsim_main(["simulate", str(files / "scene.npz"), "-o", str(tmp_path / "x.npz"), "--target", "1"])
    assert stop.value.code == 2
    assert "argument --target: must be X,Y or X,Y,Z in metres" in capsys.readouterr().err


def test_voxelize_strict_fails_on_a_quality_warning(files, tmp_path, monkeypatch, capsys):
    """Warnings go to stderr; with --strict the command fails and writes nothing."""
    import importlib

    vx = importlib.import_module("tlsvox.voxel.stages")  # the module (tlsvox.voxel.stages is also a function)

    out = tmp_path / "scene.npz"
    argv = ["voxelize", str(files / "s1.laz"), str(files / "s2.laz"), "-o", str(out), "--voxel-size", "0.5", "-q"]
    assert tlsvox_main(argv) == 0 and out.exists()
    monkeypatch.setattr(vx, "quality_warnings", lambda *a: ["12 voxels have LAD above 20 m2/m3 (max 382)"])
    out2 = tmp_path / "strict.npz"
    assert tlsvox_main(argv[:4] + [str(out2)] + argv[5:] + ["--strict"]) == 2
    err = capsys.readouterr().err
    assert "warning: 12 voxels have LAD above 20" in err and "nothing was written" in err
    assert not out2.exists()


def test_implausible_inputs_are_refused(files, tmp_path, capsys):
    """Values that used to change results silently: a negative --max-range, a LAD of 1e6,
    a negative PAD in a .vox file."""
    from tlsvox.errors import InputError
    from voxlidar.scene import Scene

    out = tmp_path / "s.npz"
    assert tlsvox_main(["voxelize", str(files / "s1.laz"), "-o", str(out), "--max-range", "-5", "-q"]) == 2
    assert "max_range=-5.0 must be a positive distance" in capsys.readouterr().err and not out.exists()
    with pytest.raises(InputError, match="no canopy is that dense"):  # 1e6 m2/m3
        Scene(origin=(0, 0, 0), voxel_size=1, shape=(1, 1, 1), ijk=[[0, 0, 0]], lad=[1e6])
    vox = tmp_path / "neg.vox"
    vox.write_text("VOXEL SPACE\n#min_corner: 0 0 0\n#max_corner: 2 1 1\n#split: 2 1 1\n#res: 1\n"
                   "i j k PadBVTotal\n0 0 0 0.5\n1 0 0 -2.0\n")
    from tlsvox.voxel.amapvox import read_vox

    with pytest.raises(InputError, match="negative PadBVTotal"):
        read_vox(vox)


def test_pictures_follow_their_suffix(files, tmp_path, capsys):
    """--plot x.jpg writes a JPEG (it used to write a PNG under that name); an unknown
    suffix is one line and nothing is written."""
    jpg, bad = tmp_path / "wf.jpg", tmp_path / "wf.tiff"
    argv = ["simulate", str(files / "scene.npz"), "--photons", "2000", "-q", "-o"]
    assert clsim_main(argv + [str(tmp_path / "a.npz"), "--plot", str(jpg)]) == 0
    assert jpg.read_bytes()[:3] == b"\xff\xd8\xff"  # JPEG magic
    assert clsim_main(argv + [str(tmp_path / "b.npz"), "--plot", str(bad)]) == 2
    assert "unknown picture format '.tiff'" in capsys.readouterr().err and not bad.exists()
    assert not (tmp_path / "b.npz").exists()  # refused before any work


def test_simulate_a_file_of_targets(files, tmp_path, capsys):
    """One pulse per row of --targets: each equals the single-target run with the same seed, bit for bit."""
    tg = tmp_path / "targets.csv"
    tg.write_text("x,y\n0.5,-0.25\n-1,1\n")
    out = tmp_path / "many.npz"
    base = ["simulate", str(files / "scene.npz"), "--photons", "3000", "--seed", "4", "-q"]
    assert clsim_main(base + ["--targets", str(tg), "-o", str(out), "--plot", str(tmp_path / "many.png")]) == 0
    many = np.load(out)
    assert many["waveform"].shape[0] == 2 and np.allclose(many["targets"][:, :2], [[0.5, -0.25], [-1.0, 1.0]])
    for k, t in enumerate(("0.5,-0.25", "-1,1")):
        one = tmp_path / f"one{k}.npz"
        assert clsim_main(base + [f"--target={t}", "-o", str(one)]) == 0  # "=": argparse reads "-1,1" as an option
        w = np.load(one)["waveform"]
        assert np.array_equal(many["waveform"][k, :w.size], w)
    assert (tmp_path / "many.png").stat().st_size > 1000
    tg.write_text("x,y\n1,2\nthree,4\n")
    assert clsim_main(base + ["--targets", str(tg), "-o", str(tmp_path / "bad.npz")]) == 2
    assert "row 3" in capsys.readouterr().err and not (tmp_path / "bad.npz").exists()
