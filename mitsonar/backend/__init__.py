"""The Dr.Jit backend: choosing and activating the Mitsuba variant (without mitsonar's plugins), and
making sure Dr.Jit finds a libLLVM that works. A room below every other, importing nothing of
mitsonar, so the receiver chain and the signals may use it; `mitsonar.sim.variant` adds the
plugins' registration.

Dr.Jit's ``llvm`` variants JIT-compile through a shared libLLVM found at run time. Debian 12's
default LLVM 15 crashes (``Cannot select ... fminimum``); version 16 or newer works. When mitsonar
first chooses a variant (`set_variant`, or `ensure_variant` on first use; never at ``import
mitsonar``) and Dr.Jit is not imported yet, it points ``DRJIT_LIBLLVM_PATH`` at the newest libLLVM
on the system (unless the user set it), and it refuses to start on a version that is known to
fail. A program that imported ``drjit`` (or ``mitsuba``) before that keeps the libLLVM Dr.Jit
found by itself: set ``DRJIT_LIBLLVM_PATH`` before importing them, or let mitsonar choose the
variant first.
"""
from __future__ import annotations

import glob
import os
import re

DEFAULT_VARIANT = "llvm_ad_mono"
SUPPORTED = ("llvm_ad_mono", "cuda_ad_mono")
MIN_LLVM = 16
FIX = ("install Debian's libllvm19 (as root: apt-get install -y libllvm19), or set "
       "DRJIT_LIBLLVM_PATH to a libLLVM.so of version 16 or newer")


class VariantError(RuntimeError):
    pass


#: Where `find_libllvm` looks (glob patterns): Debian/Ubuntu's multiarch folder and ``llvm-N``
#: folders, other distributions' library folders, Homebrew.
LIBLLVM_PATTERNS = ("/usr/lib/*-linux-gnu/libLLVM*.so*", "/usr/lib/llvm-*/lib/libLLVM*.so*",
                    "/usr/lib64/libLLVM*.so*", "/usr/local/lib/libLLVM*.so*",
                    "/opt/homebrew/opt/llvm/lib/libLLVM.dylib")


def _llvm_version(path: str):
    """The major version of a libLLVM file: its name (``libLLVM-19.so``, ``libLLVM-16.so.1``), its
    ``llvm-N`` folder, or the soname LLVM 18 and later use (``libLLVM.so.19.1``); None if none."""
    name = os.path.basename(path)
    m = re.search(r"LLVM[-.]?(\d+)", name) or re.search(r"llvm-(\d+)", path) or re.search(r"LLVM\.so\.(\d{2,})", name)
    return int(m.group(1)) if m else None


def find_libllvm(patterns=None):
    """Newest libLLVM shared library on the system as (path, major version), or (None, None).

    ``patterns``: the glob patterns searched (default `LIBLLVM_PATTERNS`); of equal versions the
    first path in pattern order, then name order, is taken."""
    best = (None, None)
    for pat in LIBLLVM_PATTERNS if patterns is None else patterns:
        for path in sorted(glob.glob(pat)):
            v = _llvm_version(path)
            if v is not None and (best[1] is None or v > best[1]):
                best = (path, v)
    return best


def prepare_llvm_environment() -> None:
    """Point Dr.Jit at a working libLLVM (``DRJIT_LIBLLVM_PATH``, unless set); does nothing once
    drjit is imported (it has found its libLLVM then)."""
    import sys

    if os.environ.get("DRJIT_LIBLLVM_PATH") or "drjit" in sys.modules:
        return
    path, version = find_libllvm()
    if path is not None and version >= MIN_LLVM:
        os.environ["DRJIT_LIBLLVM_PATH"] = path


def requested_variant(name=None) -> str:
    name = name or os.environ.get("MITSONAR_VARIANT") or DEFAULT_VARIANT
    if name == "auto":
        import drjit as dr

        name = "cuda_ad_mono" if dr.has_backend(dr.JitBackend.CUDA) else "llvm_ad_mono"
    if name not in SUPPORTED:
        raise VariantError(f"variant {name!r} is not supported (MITSONAR_VARIANT / --variant): use one of "
                           f"{', '.join(SUPPORTED)} or auto; sonar intensity is monochrome and needs a JIT variant")
    return name


def check_backend(name: str) -> None:
    import drjit as dr

    if name.startswith("llvm"):
        if not dr.has_backend(dr.JitBackend.LLVM):
            raise VariantError(f"Dr.Jit found no usable libLLVM for variant {name!r}: {FIX}")
        path = os.environ.get("DRJIT_LIBLLVM_PATH")
        version = _llvm_version(path) if path else find_libllvm()[1]
        if version is not None and version < MIN_LLVM:
            raise VariantError(f"libLLVM {version} is too old for Dr.Jit (it crashes on LLVM 15): {FIX}")
    elif name.startswith("cuda") and not dr.has_backend(dr.JitBackend.CUDA):
        raise VariantError(f"variant {name!r} needs an NVIDIA GPU with a CUDA driver; none was found "
                           "(use llvm_ad_mono)")


def activate(name=None) -> str:
    """Point Dr.Jit at a working libLLVM (`prepare_llvm_environment`), check and activate the
    requested variant (``name``, else ``MITSONAR_VARIANT``, else ``llvm_ad_mono``). Returns it."""
    prepare_llvm_environment()
    import mitsuba as mi

    name = requested_variant(name)
    check_backend(name)
    if mi.variant() != name:
        mi.set_variant(name)
    return name


def ensure_active() -> None:
    """A supported variant active: the requested one when ``MITSONAR_VARIANT`` is set, else the
    active one if supported, else `activate`'s default."""
    prepare_llvm_environment()
    import mitsuba as mi

    if mi.variant() not in SUPPORTED or os.environ.get("MITSONAR_VARIANT"):
        if mi.variant() != requested_variant():
            activate()
