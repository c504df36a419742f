#!/usr/bin/env bash
# One-time set-up for voxlidar: system libraries that pip cannot bring, then .venv.
#
# Open3D's wheels link against a few system libraries (libusb, libGL, libEGL);
# headless rendering (OffscreenRenderer) also wants Mesa's EGL/Vulkan drivers.
# When they are missing we install them with apt-get if we are root, otherwise
# we print the exact command and stop.
set -euo pipefail
cd "$(dirname "$0")/.."

PY=${PYTHON:-python3}
SYS_LIBS="libusb-1.0-0 libgl1 libegl1 libgomp1 libegl-mesa0 libgl1-mesa-dri libvulkan1 mesa-vulkan-drivers"

missing=""
if command -v dpkg-query >/dev/null 2>&1; then
  for pkg in $SYS_LIBS; do
    if ! dpkg-query -W -f='${Status}' "$pkg" 2>/dev/null | grep -q "install ok installed"; then
      missing="$missing $pkg"
    fi
  done
fi
if [ -n "$missing" ]; then
  if [ "$(id -u)" = "0" ] && command -v apt-get >/dev/null 2>&1; then
    echo "setup: installing system libraries for Open3D:$missing"
    export DEBIAN_FRONTEND=noninteractive
    apt-get update -qq
    apt-get install -y -qq --no-install-recommends $missing >/dev/null
  else
    echo "setup: Open3D needs these system libraries, which are missing:$missing" >&2
    echo "setup: install them with:  sudo apt-get install -y$missing" >&2
    exit 1
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
  .venv/bin/python -m pip install -q -e ".[dev]"
  touch "$stamp"
fi
