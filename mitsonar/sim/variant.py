"""Choosing and activating the Mitsuba variant and registering mitsonar's plugins for it.

The variant and its libLLVM are chosen by `mitsonar.backend` (`activate`, `ensure_active`;
its names are importable from here too); `set_variant` and `ensure_variant` add the plugins'
registration, again on every later variant change. Neither runs at ``import mitsonar``: the first
`load_scene`, `render_scan`, ... calls `ensure_variant`. A program that imported ``drjit`` (or
``mitsuba``) before that keeps the libLLVM Dr.Jit found by itself (`mitsonar.backend`).
"""
from __future__ import annotations

import os

from mitsonar.backend import (DEFAULT_VARIANT, FIX, MIN_LLVM, SUPPORTED, VariantError,  # noqa: F401
                              activate, check_backend, ensure_active, find_libllvm,
                              prepare_llvm_environment, requested_variant)


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
    name = activate(name)
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
    ensure_active()
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
