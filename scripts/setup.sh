#!/usr/bin/env bash
# Set up mitsonar on a fresh Debian 12 machine: Debian's libLLVM 19 (Dr.Jit's
# llvm variants need libLLVM >= 16; Debian 12's default LLVM 15 crashes), a
# virtual environment in .venv, and the package with its test extras.
set -euo pipefail
cd "$(dirname "$0")/.."

# True when a libLLVM of version 16 or newer is installed. (A loop, not `ls | grep`: under
# pipefail a glob that matches nothing made ls fail and the check with it, so every run
# re-installed, and without root setup stopped although the library was there.)
have_llvm() {
  local f
  shopt -s nullglob
  for f in /usr/lib/*-linux-gnu/libLLVM*.so* /usr/lib/llvm-*/lib/libLLVM*.so*; do
    if [[ $f =~ LLVM-?(1[6-9]|[2-9][0-9]) ]]; then shopt -u nullglob; return 0; fi
  done
  shopt -u nullglob
  return 1
}
as_root_apt() { [ "$(id -u)" = 0 ] && command -v apt-get >/dev/null; }
apt_updated=
apt_install() {
  [ -n "$apt_updated" ] || { apt-get update -qq; apt_updated=1; }
  DEBIAN_FRONTEND=noninteractive apt-get install -y -qq "$@" >/dev/null
}

if [ -z "${DRJIT_LIBLLVM_PATH:-}" ] && ! have_llvm; then
  if as_root_apt; then
    echo "setup: installing Debian's libllvm19 (Dr.Jit needs libLLVM >= 16)"
    apt_install libllvm19
  else
    echo "setup: Dr.Jit's llvm variants need libLLVM >= 16. Run as root: apt-get install -y libllvm19" >&2
    echo "       (or point DRJIT_LIBLLVM_PATH at a libLLVM.so of version 16 or newer)" >&2
    exit 1
  fi
fi

PY=${PYTHON:-python3}
if [ ! -x .venv/bin/python ]; then
  # A bare Debian has python3 without venv/ensurepip (package python3.X-venv).
  if ! "$PY" -c 'import ensurepip, venv' 2>/dev/null; then
    pkg="python$("$PY" -c 'import sys; print(f"{sys.version_info[0]}.{sys.version_info[1]}")')-venv"
    if as_root_apt; then
      echo "setup: installing Debian's $pkg (python3 -m venv needs it)"
      apt_install "$pkg"
    else
      echo "setup: $PY cannot create virtual environments. Run as root: apt-get install -y $pkg" >&2
      exit 1
    fi
  fi
  "$PY" -m venv .venv
fi
.venv/bin/python -m pip install -q --upgrade pip >/dev/null
.venv/bin/python -m pip install -q -e '.[test]'
# oculus-python (bps_oculus, the Oculus tests' independent reader) asks for opencv-python, which
# would replace the opencv-python-headless of the test extra: installed without its dependencies
# (its readers import numpy, opencv (headless is enough), netCDF4 and rosbags, all in the extra).
.venv/bin/python -m pip install -q --no-deps 'oculus-python==0.0.2a1'
# Bellhop, the reference ray/beam model the propagation tests compare with (.bellhop/, gitignored)
.venv/bin/python scripts/fetch_bellhop.py ||
  echo "setup: Bellhop was not fetched (no network?); tests/test_propagation_bellhop.py will fail until it is" >&2
echo "setup: done (.venv ready)"
