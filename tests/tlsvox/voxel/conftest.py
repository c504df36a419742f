"""Fixtures of the voxel-stage tests."""

from __future__ import annotations

import sys
from pathlib import Path

import pytest


@pytest.fixture(scope="module")
def bench():
    """``benchmarks/bench_echo_weights.py`` as a module: the leaf box of known LAD that
    makes the table of docs/voxelize.md (needs Open3D, for the scanner)."""
    pytest.importorskip("open3d")
    sys.path.insert(0, str(Path(__file__).resolve().parents[3] / "benchmarks"))
    try:
        import bench_echo_weights
    finally:
        sys.path.pop(0)
    return bench_echo_weights
