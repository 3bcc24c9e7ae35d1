#!/usr/bin/env bash
# Set up mitsonar on a fresh Debian 12 machine: Debian's libLLVM 19 (Dr.Jit's
# llvm variants need libLLVM >= 16; Debian 12's default LLVM 15 crashes), a
# virtual environment in .venv, and the package with its test extras.
set -euo pipefail
cd "$(dirname "$0")/.."

have_llvm() { ls /usr/lib/*-linux-gnu/libLLVM-1[6-9]*.so* /usr/lib/*-linux-gnu/libLLVM-[2-9][0-9]*.so* /usr/lib/llvm-*/lib/libLLVM*.so* 2>/dev/null | grep -Eq 'LLVM-?(1[6-9]|[2-9][0-9])' ; }
if [ -z "${DRJIT_LIBLLVM_PATH:-}" ] && ! have_llvm; then
  if [ "$(id -u)" = 0 ] && command -v apt-get >/dev/null; then
    echo "setup: installing Debian's libllvm19 (Dr.Jit needs libLLVM >= 16)"
    apt-get update -qq
    DEBIAN_FRONTEND=noninteractive apt-get install -y -qq libllvm19 >/dev/null
  else
    echo "setup: Dr.Jit's llvm variants need libLLVM >= 16. Run as root: apt-get install -y libllvm19" >&2
    echo "       (or point DRJIT_LIBLLVM_PATH at a libLLVM.so of version 16 or newer)" >&2
    exit 1
  fi
fi

PY=${PYTHON:-python3}
if [ ! -x .venv/bin/python ]; then
  "$PY" -m venv .venv
fi
.venv/bin/python -m pip install -q --upgrade pip >/dev/null
.venv/bin/python -m pip install -q -e '.[test]'
echo "setup: done (.venv ready)"
