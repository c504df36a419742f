"""Versions of everything voxlidar runs on, and the OpenCL devices found."""

from __future__ import annotations

import importlib
import platform
import sys

__all__ = ["show_versions", "versions"]

_PACKAGES = ("numpy", "scipy", "open3d", "pyopencl", "laspy", "lazrs", "matplotlib", "tqdm")


def versions() -> dict:
    """Python, platform and package versions, and OpenCL platforms/devices."""
    out = {"python": sys.version.split()[0], "platform": platform.platform(), "machine": platform.machine()}
    for name in _PACKAGES:
        try:
            out[name] = getattr(importlib.import_module(name), "__version__", "installed")
        except Exception as err:  # noqa: BLE001 - report, never fail
            out[name] = f"not available ({type(err).__name__})"
    devices = []
    try:
        import pyopencl as cl

        for p in cl.get_platforms():
            for d in p.get_devices():
                devices.append(f"{p.name} | {d.name.strip()} | {cl.device_type.to_string(d.type)} | "
                               f"{d.max_compute_units} CU | fp64 {'yes' if d.double_fp_config else 'no'}")
    except Exception as err:  # noqa: BLE001
        devices.append(f"none ({type(err).__name__}: {err})")
    out["opencl_devices"] = devices
    return out


def show_versions(file=None) -> None:
    """Print :func:`versions` (for bug reports)."""
    info = versions()
    devices = info.pop("opencl_devices")
    for key, value in info.items():
        print(f"{key:>12}: {value}", file=file)
    print(f"{'OpenCL':>12}:", file=file)
    for d in devices:
        print(f"{'':>12}  {d}", file=file)
