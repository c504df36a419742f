"""Load the environment's oneTBB before anything else can load an older one.

Intel's CPU OpenCL runtime (``pip install intel-opencl-rt``) needs the oneTBB
that pip installs beside it (``sys.prefix/lib/libtbb.so.12``).  Open3D ships
an older ``libtbb.so.12`` of its own; when Open3D is imported first, the
dynamic linker keeps that one and Intel's runtime fails to load ("undefined
symbol ... tbb ...") and silently disappears from the device list.  Loading
the newer library first (global symbols) makes both use it: oneTBB keeps
``libtbb.so.12`` backward compatible.  Runs once, at ``import voxlidar``,
and only where Intel's runtime is installed in the environment.
"""

from __future__ import annotations

import ctypes
import sys
from pathlib import Path


def preload_tbb() -> bool:
    """True when the environment's oneTBB was loaded (or had been)."""
    lib = Path(sys.prefix) / "lib" / "libtbb.so.12"
    icd = Path(sys.prefix) / "etc" / "OpenCL" / "vendors"
    if not (lib.exists() and icd.is_dir() and any(icd.glob("intel*.icd"))):
        return False
    try:
        ctypes.CDLL(str(lib), mode=ctypes.RTLD_GLOBAL)
    except OSError:
        return False
    return True
