"""The README's shell block on the synthetic oak runs verbatim."""

from __future__ import annotations

import os
import re
import shlex
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]


def readme_commands() -> list[str]:
    """The commands of the first ``sh`` block after "Use it from the shell"."""
    text = (ROOT / "README.md").read_text()
    section = text[text.index("## Use it from the shell"):]
    block = re.search(r"```sh\n(.*?)```", section, re.S).group(1)
    # the block's first line activates .venv; the test puts .venv/bin on the PATH instead
    return [line.strip() for line in block.splitlines() if line.strip() and not line.startswith("source .venv/")]


def test_readme_block_starts_by_activating_the_venv():
    text = (ROOT / "README.md").read_text()
    section = text[text.index("## Use it from the shell"):]
    block = re.search(r"```sh\n(.*?)```", section, re.S).group(1)
    assert block.splitlines()[0].startswith("source .venv/bin/activate")


def test_readme_block_names_only_commands_of_the_project():
    cmds = readme_commands()
    assert len(cmds) >= 6
    assert {shlex.split(c, comments=True)[0] for c in cmds} <= {"tlsvox", "clsim"}


@pytest.mark.slow
def test_readme_shell_block_runs_verbatim(tmp_path):
    env = dict(os.environ, PATH=f"{Path(sys.executable).parent}{os.pathsep}{os.environ['PATH']}")
    for cmd in readme_commands():
        r = subprocess.run(["bash", "-c", cmd], cwd=tmp_path, env=env, capture_output=True, text=True, timeout=900)
        assert r.returncode == 0, f"{cmd}\n{r.stderr[-2000:]}"
    for name in ("oak.ply", "scan1.laz", "scan2.laz", "scan1.png", "merged.laz", "scene.npz", "wf.npz", "wf.png",
                 "classified/histograms.png"):
        assert (tmp_path / "out" / name).stat().st_size > 0, name


@pytest.mark.slow
def test_readme_python_block_runs(tmp_path):
    """The README's Python quickstart, as a user pastes it (about 30 s: two scans of the oak)."""
    text = (ROOT / "README.md").read_text()
    section = text[text.index("## Use it from Python"):]
    code = re.search(r"```python\n(.*?)```", section, re.S).group(1)
    (tmp_path / "out").mkdir()
    r = subprocess.run([sys.executable, "-c", code], cwd=tmp_path, capture_output=True, text=True, timeout=900)
    assert r.returncode == 0, r.stderr[-2000:]
    assert (tmp_path / "out" / "scan1.laz").stat().st_size > 0
