#!/usr/bin/env bash
# Set up the peer renderer for benchmarks/bench_mitransient.py in its own environment.
#
#   bash benchmarks/peers/setup_mitransient.sh            # -> .peer-venv/mitransient
#   PEER_ENV=/some/dir bash benchmarks/peers/setup_mitransient.sh
#
# What it does (nothing outside PEER_ENV is changed, the project's .venv is not touched):
#  1. python3 -m venv "$PEER_ENV" and pip install mitransient (pulls mitsuba and drjit wheels), numpy.
#  2. Dr.Jit's LLVM back end needs a libLLVM newer than Debian 12's LLVM 15 (with 15 the JIT aborts with
#     "Cannot select ... fminimum"). Debian ships libllvm19 (bookworm main, 1:19.1.x); the .deb is fetched
#     with `apt-get download` and unpacked with `dpkg -x` into "$PEER_ENV/llvm" (no system install).
#  3. Writes "$PEER_ENV/env.sh", which exports DRJIT_LIBLLVM_PATH to that libLLVM; the benchmark sources
#     nothing itself, it reads the path from "$PEER_ENV/llvm-path.txt".
#  4. Checks that mitsuba's llvm_ad_mono variant loads and renders one tiny transient image.
set -euo pipefail
ROOT="$(cd "$(dirname "$0")/../.." && pwd)"
PEER_ENV="${PEER_ENV:-$ROOT/.peer-venv/mitransient}"
MITRANSIENT_VERSION="${MITRANSIENT_VERSION:-1.3.1}"
LLVM_PKG="${LLVM_PKG:-libllvm19}"

mkdir -p "$PEER_ENV"
if [ ! -x "$PEER_ENV/bin/python" ]; then
    python3 -m venv "$PEER_ENV"
fi
"$PEER_ENV/bin/pip" install -q --upgrade pip
"$PEER_ENV/bin/pip" install -q "mitransient==$MITRANSIENT_VERSION" numpy

mkdir -p "$PEER_ENV/llvm"
LIB="$(find "$PEER_ENV/llvm" -name 'libLLVM*.so.1' -o -name 'libLLVM.so.*' 2>/dev/null | head -n1 || true)"
if [ -z "$LIB" ]; then
    tmp="$(mktemp -d)"
    ( cd "$tmp" && apt-get download "$LLVM_PKG" ) || {
        echo "setup_mitransient: 'apt-get download $LLVM_PKG' failed; run 'apt-get update' first" \
             "(the package is in Debian 12 bookworm main) or set LLVM_PKG to another libllvmNN >= 16" >&2
        exit 1; }
    dpkg -x "$tmp"/"$LLVM_PKG"_*.deb "$PEER_ENV/llvm"
    rm -rf "$tmp"
    LIB="$(find "$PEER_ENV/llvm" \( -name 'libLLVM*.so.1' -o -name 'libLLVM.so.*' \) | head -n1)"
fi
[ -n "$LIB" ] || { echo "setup_mitransient: no libLLVM found in $PEER_ENV/llvm after unpacking" >&2; exit 1; }
printf '%s\n' "$LIB" > "$PEER_ENV/llvm-path.txt"
printf 'export DRJIT_LIBLLVM_PATH=%q\n' "$LIB" > "$PEER_ENV/env.sh"

DRJIT_LIBLLVM_PATH="$LIB" "$PEER_ENV/bin/python" - <<'PY'
import mitsuba as mi
mi.set_variant("llvm_ad_mono")
import mitransient  # noqa: F401
import drjit as dr
print("mitsuba", mi.__version__, "drjit", dr.__version__, "mitransient", mitransient.__version__)
PY
echo "setup_mitransient: ready; DRJIT_LIBLLVM_PATH=$LIB"
