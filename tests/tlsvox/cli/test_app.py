"""The tlsvox command line, run in-process."""

import json

import numpy as np
import pytest

from tlsvox.cli.app import build_parser, main
from tlsvox.scan import Scan


def test_help_reads_like_a_man_page(capsys):
    with pytest.raises(SystemExit) as exc:
        main(["--help"])
    assert exc.value.code == 0
    text = capsys.readouterr().out
    for word in ("tree", "scan", "view", "Examples"):
        assert word in text
    for sub in ("tree", "scan", "view"):
        with pytest.raises(SystemExit):
            main([sub, "--help"])
        assert "usage: tlsvox " + sub in capsys.readouterr().out


def test_tree_scan_view(tmp_path, capsys):
    ply = tmp_path / "oak.ply"
    assert main(["tree", "-o", str(ply), "--seed", "2", "--height", "5", "--crown-radius", "1.5",
                 "--leaf-area", "3"]) == 0
    meta = json.loads((tmp_path / "oak.json").read_text())
    assert meta["leaf_area_m2"] == pytest.approx(3.0)
    las = tmp_path / "s.laz"
    assert main(["scan", str(tmp_path / "oak.json"), "-o", str(las), "--position", "0,-8,1.7",
                 "--yaw", "20", "--step", "0.2", "--quiet"]) == 0
    scan = Scan.read(las)
    assert len(scan) > 1000 and scan.pose_true is not None
    np.testing.assert_allclose(scan.pose_true[:3, 3], [0, -8, 1.7])
    png = tmp_path / "s.png"
    assert main(["view", str(las), "--color", "material", "--screenshot", str(png)]) == 0
    assert png.stat().st_size > 1000
    assert "wrote" in capsys.readouterr().out


def test_errors_are_reported_not_raised(tmp_path, capsys):
    assert main(["scan", str(tmp_path / "missing.json"), "-o", str(tmp_path / "x.laz")]) == 2
    err = capsys.readouterr().err
    assert "does not exist" in err and "tlsvox tree" in err
    assert not (tmp_path / "x.laz").exists()


def test_parser_lists_subcommands():
    sub = [a for a in build_parser()._actions if a.dest == "command"][0]
    assert {"tree", "scan", "view"} <= set(sub.choices)


def test_versions_lists_opencl_devices(capsys):
    assert main(["versions"]) == 0
    out = capsys.readouterr().out
    assert "open3d" in out and "OpenCL" in out and "numpy" in out


def test_view_a_voxel_scene_headless(tmp_path, monkeypatch, capsys):
    """A scene's voxels by LAD (and by wood), as a picture with a title and a colour scale."""
    from clsim.validation.testscenes import homogeneous_layer

    monkeypatch.setenv("VOXLIDAR_NO_O3D_RENDER", "1")  # the matplotlib renderer: quick, and the same decorations
    scene = homogeneous_layer(width=2.0, voxel_size=0.5)
    scene.save(tmp_path / "layer.npz")
    assert main(["view", str(tmp_path / "layer.npz"), "--screenshot", str(tmp_path / "lad.png")]) == 0
    assert (tmp_path / "lad.png").stat().st_size > 1000
    assert main(["view", str(tmp_path / "layer.npz"), "--color", "wood", "--screenshot",
                 str(tmp_path / "wood.png")]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "no voxel has wood" in err[0] and not (tmp_path / "wood.png").exists()


def test_wood_view_says_it_leaves_out_the_bark_directions(tmp_path):
    """--color wood colours the amount of wood; a scene whose bark has directions says in the title
    that they are not drawn (and one without says nothing of them)."""
    import dataclasses

    from clsim.validation.testscenes import homogeneous_layer
    from tlsvox.cli.app import _scene_items

    layer = homogeneous_layer(width=2.0, voxel_size=0.5)
    m = layer.n_voxels
    beta = np.where(np.arange(m) % 2 == 0, 1.0, 0.0)
    woody = dataclasses.replace(layer, wood=np.full(m, 0.5), wood_kind="probability",
                                wood_axis=np.tile([1.0, 0.0, 0.0], (m, 1)), wood_beta=beta)
    woody.save(tmp_path / "woody.npz")
    _, _, (title, bar) = _scene_items(tmp_path / "woody.npz", "wood")
    assert f"the bark directions of {int(beta.sum()):,} voxels (wood_axis) are not drawn" in title
    assert bar[-1] == "wood probability"
    dataclasses.replace(woody, wood_beta=np.zeros(m)).save(tmp_path / "plain.npz")
    assert "directions" not in _scene_items(tmp_path / "plain.npz", "wood")[2][0]


@pytest.mark.parametrize("given, expected", [
    ([], (0.0, -20.0, 1.7)), (["--position", "3,-8,1.5"], (3.0, -8.0, 1.5)),
    (["--position=-5,0,1.7"], (-5.0, 0.0, 1.7))])
def test_scan_position_takes_commas(given, expected):
    from tlsvox.cli.app import build_parser

    assert build_parser().parse_args(["scan", "t.json", "-o", "s.laz", *given]).position == expected


def test_scan_position_before_the_tree_file():
    """One token: ``--position`` does not swallow the positional TREE that follows it."""
    from tlsvox.cli.app import build_parser

    args = build_parser().parse_args(["scan", "--position", "0,-20,1.7", "t.json", "-o", "s.laz"])
    assert args.position == (0.0, -20.0, 1.7) and args.tree == "t.json"


@pytest.mark.parametrize("given", ["1,2", "1", "0,0,1,4", "nan,0,1.7", "1,2,x"])
def test_scan_position_refuses_other_counts_in_one_line(given, capsys):
    from tlsvox.cli.app import build_parser

    with pytest.raises(SystemExit) as stop:
        build_parser().parse_args(["scan", "t.json", "-o", "s.laz", "--position", given])
    err = capsys.readouterr().err
    assert stop.value.code == 2 and err.count("\n") == 1
    assert "--position: must be X,Y,Z in metres" in err and repr(given) in err
