"""Shared pytest fixtures.

Real measured data lives in ``../shared/data`` beside the project root (never
copied into the repository).  Tests that need it take the ``shared_data``
fixture, which skips with the reason when the folder is absent.  Set
``VOXLIDAR_SHARED_DATA`` to point elsewhere.
"""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np
import pytest

PROJECT_ROOT = Path(__file__).resolve().parents[1]


def shared_data_dir() -> Path:
    env = os.environ.get("VOXLIDAR_SHARED_DATA")
    if env:
        return Path(env)
    return PROJECT_ROOT.parent / "shared" / "data"


@pytest.fixture(scope="session")
def shared_data() -> Path:
    """Path of ../shared/data; skips the test when it is absent."""
    path = shared_data_dir()
    if not path.is_dir():
        pytest.skip(f"real data folder {path} is absent (a user's clone has no ../shared); "
                    "set VOXLIDAR_SHARED_DATA to its location to run this test")
    return path


@pytest.fixture
def rng() -> np.random.Generator:
    return np.random.default_rng(12345)


@pytest.fixture(scope="session")
def sim():
    """A clsim Simulator on the default OpenCL device; skips when there is none."""
    from clsim.errors import DeviceError
    from clsim.simulator import Simulator

    try:
        return Simulator()
    except DeviceError as err:
        pytest.skip(str(err))
