"""mitsonar: physically based underwater imaging-sonar simulation on Mitsuba 3 / Dr.Jit.

``import mitsonar`` selects the Mitsuba variant (``llvm_ad_mono`` unless ``MITSONAR_VARIANT``
says otherwise) and registers the plugins ``sonar``, ``acoustic`` and ``sonar_tof`` for it.
"""
from __future__ import annotations

from .variant import prepare_llvm_environment

prepare_llvm_environment()

from ._version import __version__  # noqa: E402

from .scan import Scan  # noqa: E402
from .render import (SceneError, init_on_import, load_scene, render_scan, scene_mesh,  # noqa: E402
                     set_variant, variant)
from .variant import VariantError  # noqa: E402

init_on_import()


def load_scan(path) -> Scan:
    """Read a scan written by `Scan.save` (``.exr`` or ``.npz``)."""
    from .io import load_scan as _load

    return _load(path)


_LAZY = {"MicronSonar": "micron", "VirtualMicron": "virtual_sonar", "HeadSettings": "seanet.settings",
         "StreamParser": "seanet.stream", "record": "micron", "replay": "recording"}


def __getattr__(name):
    # Serial devices load on first use: pyserial is not needed to render.
    if name in _LAZY:
        import importlib

        return getattr(importlib.import_module(f".{_LAZY[name]}", __name__), name)
    raise AttributeError(f"module 'mitsonar' has no attribute {name!r}")


__all__ = ["Scan", "SceneError", "VariantError", "load_scan", "load_scene", "render_scan", "scene_mesh",
           "set_variant", "variant", "__version__", *_LAZY]
