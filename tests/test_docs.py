"""The tutorials of the docs site run start to finish, as a user pastes them.

Each tutorial page's ``sh`` and ``python`` blocks run in order in one fresh
folder: shell lines through bash with ``.venv/bin`` on the PATH (the page's
``source .venv/bin/activate``), Python blocks through this interpreter.
"""

from __future__ import annotations

import os
import re
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
BLOCK = re.compile(r"```(sh|python)\n(.*?)```", re.S)


def blocks(page: Path) -> list[tuple[str, str]]:
    return [(kind, code) for kind, code in BLOCK.findall(page.read_text(encoding="utf-8"))]


def run_page(page: Path, where: Path) -> None:
    """Run the page's blocks in order in ``where``; consecutive Python blocks as one session."""
    env = dict(os.environ, PATH=f"{Path(sys.executable).parent}{os.pathsep}{os.environ['PATH']}",
               MPLBACKEND="Agg")
    (where / "out").mkdir(exist_ok=True)
    groups: list[tuple[str, list[str]]] = []
    for kind, code in blocks(page):
        if groups and groups[-1][0] == kind == "python":
            groups[-1][1].append(code)
        else:
            groups.append((kind, [code]))
    for kind, codes in groups:
        if kind == "sh":
            lines = [ln for ln in codes[0].splitlines() if ln.strip() and not ln.startswith("source .venv/")]
            for line in lines:
                r = subprocess.run(["bash", "-c", line], cwd=where, env=env, capture_output=True, text=True,
                                   timeout=900)
                assert r.returncode == 0, f"{page.name}: {line}\n{r.stderr[-2000:]}"
        else:
            r = subprocess.run([sys.executable, "-c", "\n".join(codes)], cwd=where, env=env, capture_output=True,
                               text=True, timeout=1800)
            assert r.returncode == 0, f"{page.name}: python blocks\n{r.stderr[-2000:]}"


def test_tutorial_pages_have_code():
    assert [k for k, _ in blocks(ROOT / "docs" / "tutorials" / "decompose.md")].count("sh") >= 3


@pytest.mark.slow
def test_tutorial_decompose_runs(tmp_path):
    run_page(ROOT / "docs" / "tutorials" / "decompose.md", tmp_path)
    assert (tmp_path / "out" / "tutorial-survey" / "survey.las").stat().st_size > 0
    rows = (tmp_path / "out" / "tutorial-echoes.csv").read_text().splitlines()
    assert len(rows) > 100  # a header and echoes of most of the 300 waveforms
    assert (tmp_path / "out" / "tutorial-echoes.png").stat().st_size > 0


@pytest.mark.slow
def test_tutorial_guide_runs(tmp_path):
    """The user guide's Python, the synthetic oak from the tree to a waveform (a few minutes)."""
    run_page(ROOT / "docs" / "guide.md", tmp_path)
    for name in ("oak.ply", "scan1.laz", "scan2.laz"):
        assert (tmp_path / "out" / name).stat().st_size > 0, name


@pytest.mark.slow
def test_tutorial_own_scans_runs(tmp_path):
    run_page(ROOT / "docs" / "tutorials" / "own_scans.md", tmp_path)
    for name in ("merged.transforms.json", "scene.npz", "scene.vox", "scene.png"):
        assert (tmp_path / "out" / "mine" / name).stat().st_size > 0, name


@pytest.mark.slow
def test_tutorial_survey_plot_runs(tmp_path):
    run_page(ROOT / "docs" / "tutorials" / "survey_plot.md", tmp_path)
    for name in ("tutorial-plot.png", "tutorial-plot-survey/survey.las", "tutorial-radargram.png",
                 "tutorial-points.png"):
        assert (tmp_path / "out" / name).stat().st_size > 0, name


HOWTOS = sorted(p for p in (ROOT / "docs" / "howto").glob("*.md") if p.name != "index.md")


def command_lines(page: Path) -> list[list[str]]:
    """Every ``tlsvox``/``clsim`` line of a page's ``sh`` blocks, split as the shell would."""
    import shlex

    out = []
    for kind, code in blocks(page):
        for line in code.splitlines():
            words = shlex.split(line, comments=True)
            while words and "=" in words[0] and not words[0].startswith("-"):  # VAR=value before the command
                words = words[1:]
            if kind == "sh" and words and words[0] in ("tlsvox", "clsim"):
                out.append(words)
    return out


@pytest.mark.parametrize("page", HOWTOS, ids=lambda p: p.stem)
def test_howto_commands_parse(page):
    """Each how-to's commands name options their parsers have (a renamed flag fails here, not for a user)."""
    from clsim.cli import build_parser as clsim_parser
    from tlsvox.cli import build_parser as tlsvox_parser

    lines = command_lines(page)
    assert lines, f"{page.name} runs no tlsvox or clsim command"
    parsers = {"tlsvox": tlsvox_parser(), "clsim": clsim_parser()}
    for words in lines:
        try:
            parsers[words[0]].parse_args(words[1:])
        except SystemExit as err:  # --help exits 0
            if err.code in (0, None):
                continue
            pytest.fail(f"{page.name}: {' '.join(words)} is refused by the parser (exit {err.code})")


@pytest.mark.slow
@pytest.mark.parametrize("page", HOWTOS, ids=lambda p: p.stem)
def test_howto_runs(page, tmp_path):
    """Each how-to runs start to finish on the small synthetic tree it makes (10-50 s each)."""
    run_page(page, tmp_path)
    assert (tmp_path / "out" / "small" / "oak.ply").stat().st_size > 0
