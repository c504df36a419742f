"""Versions of everything voxlidar runs on, and the OpenCL devices found."""

from __future__ import annotations

import importlib
import importlib.metadata
import platform
import sys

__all__ = ["show_versions", "versions"]

_PACKAGES = ("numpy", "scipy", "open3d", "pyopencl", "laspy", "lazrs", "matplotlib", "tqdm")
_RUNTIMES = ("pocl-binary-distribution", "intel-opencl-rt")


def versions(kernels=("tlsvox",)) -> dict:
    """Python, platform and package versions, and the OpenCL devices with their
    state for the given kernel sets (``tlsvox versions``: the tracer's;
    ``clsim versions``: both stages')."""
    out = {"python": sys.version.split()[0], "platform": platform.platform(), "machine": platform.machine()}
    for name in _PACKAGES:
        try:
            out[name] = getattr(importlib.import_module(name), "__version__", "installed")
        except Exception as err:  # noqa: BLE001 - report, never fail
            out[name] = f"not available ({type(err).__name__})"
    for name in _RUNTIMES:  # OpenCL runtimes installed by pip (no importable module)
        try:
            out[name] = importlib.metadata.version(name)
        except importlib.metadata.PackageNotFoundError:
            out[name] = "not installed"
    devices = []
    try:
        from voxlidar.devices import device_report, state_text

        for info, verdict in device_report(tuple(kernels)):
            devices.append(f"{info.key} {info.label} | {info.runtime} | {info.kind} | {info.compute_units} CU | "
                           f"fp64 {'yes' if info.fp64 else 'no'} | {state_text(verdict)}")
        if not devices:
            devices.append("none found")
    except Exception as err:  # noqa: BLE001 - report, never fail
        devices.append(f"none ({type(err).__name__}: {err})")
    out["opencl_devices"] = devices
    return out


def show_versions(file=None, kernels=("tlsvox",)) -> None:
    """Print :func:`versions` (for bug reports)."""
    info = versions(kernels)
    devices = info.pop("opencl_devices")
    for key, value in info.items():
        print(f"{key:>12}: {value}", file=file)
    print(f"{'OpenCL':>12}:", file=file)
    for d in devices:
        print(f"{'':>12}  {d}", file=file)
