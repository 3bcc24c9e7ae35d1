"""Choosing and activating the Mitsuba variant, and making sure Dr.Jit finds a libLLVM that works.

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


def _llvm_version(path: str):
    m = re.search(r"LLVM[-.]?(\d+)", os.path.basename(path))
    if m is None:
        m = re.search(r"llvm-(\d+)", path)
    return int(m.group(1)) if m else None


def find_libllvm():
    """Newest libLLVM shared library on the system as (path, major version), or (None, None)."""
    pats = ["/usr/lib/*-linux-gnu/libLLVM*.so*", "/usr/lib/llvm-*/lib/libLLVM*.so*",
            "/usr/lib64/libLLVM*.so*", "/usr/local/lib/libLLVM*.so*", "/opt/homebrew/opt/llvm/lib/libLLVM.dylib"]
    best = (None, None)
    for pat in pats:
        for path in glob.glob(pat):
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


# ---------------------------------------------------------------------------- activation
def _on_variant_change(old, new):
    if new in SUPPORTED:
        from mitsonar.plugins import register

        register()


_following = []


def _follow_variant_changes() -> None:
    """Register the plugins again whenever the variant changes (``mi.set_variant`` too); once."""
    if not _following:
        import mitsuba as mi

        mi.detail.add_variant_callback(_on_variant_change)
        _following.append(True)


def set_variant(name=None) -> str:
    """Activate a Mitsuba variant (default ``llvm_ad_mono`` or ``$MITSONAR_VARIANT``) and register
    the plugins for it, and again whenever the variant changes. Returns the variant's name.

    The first call (or `ensure_variant`'s) points Dr.Jit at a working libLLVM if drjit is not
    imported yet (`prepare_llvm_environment`)."""
    prepare_llvm_environment()
    import mitsuba as mi

    name = requested_variant(name)
    check_backend(name)
    if mi.variant() != name:
        mi.set_variant(name)
    from mitsonar.plugins import register

    register()
    _follow_variant_changes()
    return name


def variant():
    """The active Mitsuba variant (None before any is set)."""
    import mitsuba as mi

    return mi.variant()


def ensure_variant() -> None:
    """Make a supported variant active (the requested one when ``MITSONAR_VARIANT`` is set) and
    the plugins registered for it: what `load_scene`, `render_scan` and the other entry points
    call first, so that ``import mitsonar`` need not."""
    prepare_llvm_environment()
    import mitsuba as mi

    if mi.variant() not in SUPPORTED or os.environ.get("MITSONAR_VARIANT"):
        if mi.variant() != requested_variant():
            set_variant()
    from mitsonar.plugins import register

    register()
    _follow_variant_changes()


def init_on_import() -> None:
    """Activate the default variant if none is set, register the plugins, follow variant changes
    (what ``import mitsonar`` did before version 0.3; `ensure_variant` does it now on first use).

    A missing or too old libLLVM does not make ``import mitsonar`` fail (the command line must
    still start and explain); it is reported as a `VariantError` by the first `load_scene` or
    `render_scan`, and as a warning here.
    """
    import warnings

    prepare_llvm_environment()
    import mitsuba as mi

    try:
        if mi.variant() is None:
            set_variant()
        elif mi.variant() in SUPPORTED:
            from mitsonar.plugins import register

            register()
    except VariantError as exc:
        # The command line reports the same error as its one line; a warning would repeat it.
        import sys

        # (The console script's argv[0] is "mitsonar"; under `python -m mitsonar.cli` it is
        # still "-m" while the package imports.)
        if os.path.basename(sys.argv[0] if sys.argv else "") not in ("mitsonar", "-m"):
            warnings.warn(f"mitsonar: {exc}", RuntimeWarning, stacklevel=3)
    _follow_variant_changes()
