#!/usr/bin/env bash
# Build the peer simulator HELIOS++ for benchmarks/peers/helios_worker.py in its own prefix.
#
#   bash benchmarks/peers/setup_helios.sh HELIOS_GIT LASTOOLS_GIT     # -> ~/.cache/voxlidar-peers/helios
#   HELIOS_PREFIX=/some/dir bash benchmarks/peers/setup_helios.sh HELIOS_GIT LASTOOLS_GIT
#   bash benchmarks/peers/setup_helios.sh                              # clones both from GitHub first
#
# HELIOS_GIT, LASTOOLS_GIT: git repositories (a bare one is fine) of
#   github:3dgeo-heidelberg/helios  (built at commit fd94d1ff, reports v2.2.3.dev0)
#   github:CGAL/LAStools            (CGAL's fork: LASlib + LASzip under one CMakeLists; commit 654f84e7)
# In the project's sandbox both come from the search tool's `fetch` (a bare git dir in its mirror folder);
# elsewhere, without arguments, they are cloned from https://github.com/ (needs network).
#
# What it does (Debian 12, as root, ~15 min on 2 cores; the project's .venv is not touched):
#  1. Runs the shared recipe ../shared/peers/build_helios.sh (in the shared folder beside the repository),
#     which apt-installs the build dependencies (cmake, ninja, boost, gdal, glm, tinyxml2, armadillo, ...),
#     builds and installs LASlib into PREFIX/lastools-install, and pip-installs HELIOS++ (pyhelios and
#     the helios++ executable) from PREFIX/src into the venv PREFIX/venv (build dir PREFIX/build-skb).
#  2. Checks that the executable runs and prints where it is; helios_worker.py finds it under PREFIX
#     (it reads $VOXLIDAR_HELIOS, default ~/.cache/voxlidar-peers/helios).
set -euo pipefail
ROOT="$(cd "$(dirname "$0")/../.." && pwd)"
HELIOS_PREFIX="${HELIOS_PREFIX:-$HOME/.cache/voxlidar-peers/helios}"
RECIPE="${HELIOS_RECIPE:-$ROOT/../shared/peers/build_helios.sh}"
[ -f "$RECIPE" ] || { echo "setup_helios: the shared recipe $RECIPE is missing (set HELIOS_RECIPE)" >&2; exit 1; }

SRC_H="${1:-}"; SRC_L="${2:-}"
if [ -z "$SRC_H" ] || [ -z "$SRC_L" ]; then
    tmp="$(mktemp -d)"
    git clone -q --bare https://github.com/3dgeo-heidelberg/helios "$tmp/helios.git"
    git clone -q --bare https://github.com/CGAL/LAStools "$tmp/lastools.git"
    SRC_H="$tmp/helios.git"; SRC_L="$tmp/lastools.git"
fi

bash "$RECIPE" "$SRC_H" "$SRC_L" "$HELIOS_PREFIX"

EXE="$(ls "$HELIOS_PREFIX"/venv/lib/python3*/site-packages/pyhelios/bin/helios++ 2>/dev/null | head -n1 || true)"
[ -n "$EXE" ] && [ -x "$EXE" ] || { echo "setup_helios: no helios++ executable in $HELIOS_PREFIX/venv" >&2; exit 1; }
"$EXE" --version
echo "setup_helios: ready; helios++ at $EXE (worker: VOXLIDAR_HELIOS=$HELIOS_PREFIX" \
     ".venv/bin/python benchmarks/peers/helios_worker.py)"
