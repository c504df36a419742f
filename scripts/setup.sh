#!/usr/bin/env bash
# One-time set-up for voxlidar: system libraries that pip cannot bring (Open3D's,
# and a CPU OpenCL runtime), then .venv with voxlidar and Intel's CPU runtime.
#
# Open3D's wheels link against a few system libraries (libusb, libGL, libEGL);
# headless rendering (OffscreenRenderer) also wants Mesa's EGL/Vulkan drivers.
# When they are missing we install them with apt-get if we are root, otherwise
# we print the exact command and stop.
set -euo pipefail
cd "$(dirname "$0")/.."

PY=${PYTHON:-python3}
SYS_LIBS="libusb-1.0-0 libgl1 libegl1 libgomp1 libegl-mesa0 libgl1-mesa-dri libvulkan1 mesa-vulkan-drivers"
# A CPU OpenCL runtime that knows current CPUs: Debian's PoCL (3.1, LLVM 15).
# PyPI's PoCL (LLVM 14) cannot compile for CPUs newer than its LLVM (recent
# AMD EPYC/Zen 4); voxlidar's device layer then skips it and says why.
OPENCL_PKGS="pocl-opencl-icd"
# A virtual X server for the Open3D window sessions' tests (`clsim pick` under
# xvfb-run); optional: without it those tests skip and say why.
OPTIONAL_PKGS="xvfb xauth"

missing_of() {
  local out=""
  if command -v dpkg-query >/dev/null 2>&1; then
    for pkg in "$@"; do
      if ! dpkg-query -W -f='${Status}' "$pkg" 2>/dev/null | grep -q "install ok installed"; then
        out="$out $pkg"
      fi
    done
  fi
  echo "$out"
}

missing=$(missing_of $SYS_LIBS)
missing_cl=$(missing_of $OPENCL_PKGS)
missing_opt=$(missing_of $OPTIONAL_PKGS)
if [ -n "$missing_opt" ] && [ "$(id -u)" != "0" ]; then
  echo "setup: optional (window-session tests under a virtual display):  sudo apt-get install -y$missing_opt" >&2
  missing_opt=""
fi
if [ -n "$missing$missing_cl$missing_opt" ]; then
  if [ "$(id -u)" = "0" ] && command -v apt-get >/dev/null 2>&1; then
    echo "setup: installing system packages:$missing$missing_cl$missing_opt"
    export DEBIAN_FRONTEND=noninteractive
    apt-get update -qq
    apt-get install -y -qq --no-install-recommends $missing $missing_cl >/dev/null
    if [ -n "$missing_opt" ]; then
      apt-get install -y -qq --no-install-recommends $missing_opt >/dev/null \
        || echo "setup: could not install$missing_opt (optional; the window-session tests will skip)" >&2
    fi
  else
    if [ -n "$missing_cl" ]; then
      echo "setup: no system OpenCL CPU runtime (Debian's PoCL); install it with:  sudo apt-get install -y$missing_cl" >&2
      echo "setup: (continuing: the PoCL and Intel runtimes from PyPI serve most CPUs; \`clsim devices\` shows what works)" >&2
    fi
    if [ -n "$missing" ]; then
      echo "setup: Open3D needs these system libraries, which are missing:$missing" >&2
      echo "setup: install them with:  sudo apt-get install -y$missing" >&2
      exit 1
    fi
  fi
fi

if [ ! -x .venv/bin/python ]; then
  echo "setup: creating .venv with $($PY --version)"
  $PY -m venv .venv
fi
stamp=.venv/.voxlidar-installed
if [ ! -f "$stamp" ] || [ pyproject.toml -nt "$stamp" ]; then
  echo "setup: installing voxlidar and its dependencies into .venv (first time: a few minutes)"
  .venv/bin/python -m pip install -q --upgrade pip
  # dev: pytest, ruff, mypy; survey: Dask distributed for clsim survey (its tests run in CI);
  # docs: the docs site (`make docs`, built by CI)
  extras="dev,survey,docs"
  # Intel's CPU OpenCL runtime (x86-64 Linux wheels only): a second, independent
  # compiler for the kernel tests; voxlidar finds its ICD in .venv by itself.
  if [ "$(uname -s)-$(uname -m)" = "Linux-x86_64" ] && [ "${VOXLIDAR_NO_INTEL:-0}" != "1" ]; then
    extras="dev,survey,docs,intel"
  fi
  .venv/bin/python -m pip install -q -e ".[$extras]"
  touch "$stamp"
fi
