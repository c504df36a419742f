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


# -- the OpenCL device matrix ---------------------------------------------------------
# Kernel tests take the ``cl_device`` (or ``sim``/``tracer``) fixture and run once per
# working device found: in CI at least Debian's PoCL and Intel's CPU runtime (two
# compilers), on a GPU machine the GPU too.  VOXLIDAR_TEST_DEVICES narrows the matrix
# to the devices matching a spec ("0:1", "intel", "gpu", ...); "best" keeps only the one
# the library would choose.
def _device_matrix():
    """[(DeviceInfo, {kernel set: reason or None})], best first; [] without pyopencl."""
    try:
        from voxlidar.devices import device_report
    except ImportError:
        return []
    try:
        return device_report(("clsim", "decompose", "tlsvox"))
    except Exception as err:  # noqa: BLE001 - reported in the header, tests skip
        return [(None, {"error": f"{type(err).__name__}: {err}"})]


MATRIX = _device_matrix()


def _selected(kernel):
    ok = [info for info, verdict in MATRIX if info is not None and verdict.get(kernel) is None]
    spec = os.environ.get("VOXLIDAR_TEST_DEVICES", "").strip()
    if spec and ok:
        from voxlidar.devices import _matches, choose_device

        ok = [choose_device(kernels=(kernel,), devices=ok)] if spec == "best" else _matches(spec, ok)
    return ok


def _device_id(info):
    name = info.name.replace(" ", "")[:24]
    return f"{info.key}-{info.runtime.split('+')[0].replace(' ', '')}-{name}"


def _params(kernel):
    ok = _selected(kernel)
    if not ok:
        reasons = "; ".join(f"{i.key if i else '?'}: {v}" for i, v in MATRIX) or "none found"
        return [pytest.param(None, marks=pytest.mark.skip(reason=f"no working OpenCL device ({reasons})"))]
    return [pytest.param(info, id=_device_id(info)) for info in ok]


def pytest_report_header(config):
    lines = ["OpenCL device matrix (kernel tests run on every device marked 'works'):"]
    try:
        from voxlidar.devices import unloadable_runtimes

        lines += [f"  NOT LOADED: {lib}: {why}" for lib, why in unloadable_runtimes()]
    except ImportError:
        pass
    if not MATRIX:
        lines.append("  no OpenCL device found")
    for info, verdict in MATRIX:
        if info is None:
            lines.append(f"  device discovery failed: {verdict['error']}")
            continue
        from voxlidar.devices import state_text

        state = state_text(verdict)
        lines.append(f"  {info.key}  {info.runtime:24s} {info.kind:4s} {info.name[:40]:40s} {state}")
    return lines


@pytest.fixture(scope="session", params=_params("clsim"))
def cl_device(request):
    """Each working OpenCL device in turn (a :class:`voxlidar.devices.DeviceInfo`)."""
    return request.param


@pytest.fixture(scope="session", params=_params("decompose"))
def cl_device_for_fits(request):
    """Each OpenCL device that builds the decomposition's fitting kernel in turn."""
    return request.param


@pytest.fixture(scope="session", params=[pytest.param("numpy", id="numpy")] + _params("decompose"))
def decompose_device(request):
    """Where ``decompose_batch`` fits: ``"numpy"``, then each working OpenCL device."""
    return request.param


@pytest.fixture(scope="session")
def sim(cl_device):
    """A clsim Simulator on each working OpenCL device in turn."""
    from clsim.transport.simulator import Simulator

    return Simulator(device=cl_device)


@pytest.fixture(scope="session", params=_params("tlsvox"))
def tracer(request):
    """A tlsvox Tracer on each device that runs the tracer (float64) in turn."""
    from tlsvox.voxel.trace import Tracer

    return Tracer(device=request.param)


def pytest_collection_modifyitems(config, items):
    """A test parametrised over ``backend`` runs its NumPy-oracle case once, not once per
    device: the oracle uses no device."""
    seen, keep, dropped = set(), [], []
    for item in items:
        params = getattr(getattr(item, "callspec", None), "params", {})
        if params.get("backend") == "oracle" and "cl_device" in params:
            key = (item.originalname, tuple(sorted((k, str(v)) for k, v in params.items() if k != "cl_device")))
            if key in seen:
                dropped.append(item)
                continue
            seen.add(key)
        keep.append(item)
    if dropped:
        config.hook.pytest_deselected(items=dropped)
        items[:] = keep
