"""`tlsvox register` and `tlsvox classify`, run in-process."""

from __future__ import annotations

import json

import numpy as np
import pytest
from test_register import P_A, P_B, pose, toy_scan  # noqa: E402 - test helpers

from tlsvox.cli.app import main
from tlsvox.register import pose_error, true_relative_transform
from tlsvox.scan import Scan


def run(argv):
    """The ``tlsvox`` command in-process: its exit code."""
    return main([str(a) for a in argv])


@pytest.fixture(scope="module")
def toy_files(tmp_path_factory):
    d = tmp_path_factory.mktemp("scans")
    A, B = toy_scan(1, P_A, "A"), toy_scan(2, P_B, "B")
    A.write(d / "A.laz")
    B.write(d / "B.laz")
    return d, A, B


def test_register_command_writes_merged_cloud_and_transforms(toy_files, tmp_path, capsys):
    d, A, B = toy_files
    out = tmp_path / "merged.laz"
    tj = tmp_path / "T.json"
    assert run(["register", str(d / "A.laz"), str(d / "B.laz"), "-o", str(out), "--transforms", str(tj)]) == 0
    assert "vs truth" in capsys.readouterr().out
    doc = json.loads(tj.read_text())
    assert [s["name"] for s in doc["scans"]] == ["A", "B"]
    T = np.array(doc["scans"][1]["pose"])
    rot, tr = pose_error(T, true_relative_transform(B, A))
    assert rot < 0.05 and tr < 0.005
    merged = Scan.read(out)
    assert len(merged) == len(A) + len(B)


def test_register_command_fails_cleanly_without_overlap(toy_files, tmp_path, capsys):
    d, A, _ = toy_files
    far = toy_scan(3, pose(190.0, 10.0, 1.7, 80.0), "far", other_plot=True, crown_seed=99,
                   shift=(200.0, 0.0), layout=np.array([[7.0, 1.0, 0.5], [-2.0, 6.0, 1.0], [1.0, -4.0, 0.3]]))
    far.write(tmp_path / "far.laz")
    out = tmp_path / "merged.laz"
    # targets only (fast): the far plot's 3 targets do not match A's 4
    assert run(["register", str(d / "A.laz"), str(tmp_path / "far.laz"), "-o", str(out),
                "--method", "targets"]) == 1
    assert "no 3 targets in common" in capsys.readouterr().err
    assert not out.exists() and not out.with_suffix(".transforms.json").exists()


def test_classify_command(toy_files, tmp_path, capsys):
    d, A, _ = toy_files
    out = tmp_path / "cls"
    assert run(["classify", str(d / "A.laz"), "-o", str(out), "--refine", "--plot", str(out / "histograms.png")]) == 0
    assert "leaf P/R" in capsys.readouterr().out
    doc = json.loads((out / "classification.json").read_text())
    assert doc["scans"][0]["refined"] is True
    assert "confusion" in doc["scans"][0]["score"]
    las = Scan.read(out / "A.classified.laz")
    assert len(las) == len(A)
    assert (out / "histograms.png").stat().st_size > 1000
    assert doc["scans"][0]["components"] in (2, 3)  # the default: chosen by BIC
    out2 = tmp_path / "cls2"
    assert run(["classify", str(d / "A.laz"), "-o", str(out2), "--components", "2"]) == 0
    assert json.loads((out2 / "classification.json").read_text())["scans"][0]["components"] == 2
    with pytest.raises(SystemExit) as e:
        run(["classify", str(d / "A.laz"), "-o", str(tmp_path / "cls3"), "--components", "one"])
    assert e.value.code == 2
    assert "--components: 'one': give an integer >= 2 or 'bic'" in capsys.readouterr().err
    assert not (tmp_path / "cls3").exists()


def test_classify_command_rejects_scan_without_reflectance(tmp_path, capsys):
    Scan(xyz=np.random.default_rng(0).normal(size=(100, 3)), name="plain").write(tmp_path / "plain.las")
    assert run(["classify", str(tmp_path / "plain.las"), "-o", str(tmp_path / "out")]) == 2  # input error
    assert "neither reflectance" in capsys.readouterr().err
    assert not (tmp_path / "out").exists()


def test_help_reads_like_a_man_page(capsys):
    with pytest.raises(SystemExit):
        run(["register", "--help"])
    text = capsys.readouterr().out
    assert "retro-reflective" in text and "--transforms" in text


def test_classify_raw_intensity_needs_and_takes_the_relative_flag(toy_files, tmp_path, capsys):
    """A scan with raw intensity only: refused with the flag named, classified with --intensity relative,
    the same labels as from its reflectance (the split does not depend on the scale), the mode stated."""
    import dataclasses

    d, A, _ = toy_files
    r = np.linalg.norm(A.xyz, axis=1)
    raw = dataclasses.replace(A, reflectance_db=None,
                              intensity=np.round(5e4 * 10 ** (A.reflectance_db / 10.0) / r ** 2))  # within uint16
    raw.write(tmp_path / "raw.laz")
    assert run(["classify", str(tmp_path / "raw.laz"), "-o", str(tmp_path / "no")]) == 2
    assert "--intensity relative" in capsys.readouterr().err and not (tmp_path / "no").exists()
    # two Gaussians for both: the toy's reflectances are two exact values, which the BIC reads as two or three
    # once the intensity is rounded to whole counts (the synthetic oak's test runs the default)
    assert run(["classify", str(tmp_path / "raw.laz"), "-o", str(tmp_path / "rel"), "--intensity", "relative",
                "--components", "2"]) == 0
    assert run(["classify", str(d / "A.laz"), "-o", str(tmp_path / "db"), "--components", "2"]) == 0
    rel, db = (json.loads((tmp_path / k / "classification.json").read_text())["scans"][0] for k in ("rel", "db"))
    assert "relative intensity" in rel["feature"] and rel["settings"]["reflectance"]["allow_relative"] is True
    assert rel["counts"]["target"] == db["counts"]["target"] > 0
    a, b = (Scan.read(tmp_path / k / f"{n}.classified.laz").classification for k, n in (("rel", "raw"), ("db", "A")))
    assert np.mean(a == b) > 0.98, np.mean(a == b)  # intensity stored as whole numbers: a few echoes move
