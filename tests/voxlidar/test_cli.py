"""The shared command-line conventions: negative numbers as values, malformed numbers named."""

from __future__ import annotations

import pytest

from voxlidar.cli import join_negative_values


def test_negative_values_after_an_option_are_values():
    from clsim.cli.app import build_parser as clsim_parser
    from tlsvox.cli.app import build_parser as tlsvox_parser

    args = clsim_parser().parse_args(join_negative_values(["survey", "s.npz", "-o", "out", "--start", "-20,0",
                                                           "--end", "-1.5,2"]))
    assert args.start == pytest.approx((-20.0, 0.0)) and args.end == pytest.approx((-1.5, 2.0))
    args = tlsvox_parser().parse_args(join_negative_values(["voxelize", "a.laz", "-o", "s.npz", "--bounds",
                                                            "-0.5,-0.5,0,1,1,2", "--scan-origin", "-5,0,0.5"]))
    assert args.bounds[:3] == pytest.approx((-0.5, -0.5, 0.0)) and args.scan_origin == pytest.approx((-5, 0, 0.5))
    # a flag before a word, an option with '=', and '--' are left alone
    assert join_negative_values(["-q", "--x=-1", "--", "-2"]) == ["-q", "--x=-1", "--", "-2"]


def test_the_commands_take_negative_values(tmp_path, capsys):
    from clsim.cli.app import main

    # reaches the handler (which refuses the missing scene), not argparse's "expected one argument"
    assert main(["survey", str(tmp_path / "none.npz"), "-o", str(tmp_path / "o"), "--start", "-20,0"]) == 2
    err = capsys.readouterr().err
    assert "expected one argument" not in err and "none.npz" in err


def test_a_non_numeric_cell_in_a_waveform_csv_is_named(tmp_path, capsys):
    from clsim.cli.app import main

    bad = tmp_path / "w.csv"
    bad.write_text("V1,V2,V3,V4,V5\n1,2,3,4,5\n1,2,x3,4,5\n")
    assert main(["decompose", str(bad), "-o", str(tmp_path / "e.csv")]) == 2
    err = capsys.readouterr().err
    assert "row 3, column 3 is 'x3', not a number" in err
    assert not (tmp_path / "e.csv").exists()
