"""mitsonar's Mitsuba plugins: sensor ``sonar``, BSDF ``acoustic``, integrators ``sonar_tof``, ``sonar_mlt``.

The plugin classes derive from the classes of the active Mitsuba variant, so their modules are
(re)loaded for each variant and the plugins registered again; `register()` does that and is
called by ``import mitsonar`` and on every variant change.
"""
from __future__ import annotations

import importlib

_MODULES = ("materials", "beam", "acoustic_bsdf", "sonar_sensor", "range_bins", "samples", "common", "sonar_tof",
            "sonar_mlt")
_current = None


def register(force: bool = False) -> None:
    """Register the plugins for the active variant (no-op if already done for it)."""
    import mitsuba as mi

    variant = mi.variant()
    if variant is None:
        raise RuntimeError("mitsonar.plugins.register(): set a Mitsuba variant first")
    global _current
    if variant == _current and not force:
        return
    mods = {}
    for name in _MODULES:
        mod = importlib.import_module(f"{__name__}.{name}")
        # Module-level classes were built against the variant active at import time.
        mods[name] = importlib.reload(mod) if getattr(mod, "_variant", variant) != variant else mod
        mods[name]._variant = variant
    mi.register_bsdf("acoustic", lambda props: mods["acoustic_bsdf"].AcousticBSDF(props))
    mi.register_sensor("sonar", lambda props: mods["sonar_sensor"].SonarSensor(props))
    mi.register_integrator("sonar_tof", lambda props: mods["sonar_tof"].SonarTOFIntegrator(props))
    mi.register_integrator("sonar_mlt", lambda props: mods["sonar_mlt"].SonarMLTIntegrator(props))
    _current = variant


def module(name: str):
    """The plugin module for the active variant (e.g. ``module('sonar_sensor').SonarSensor``)."""
    register()
    return importlib.import_module(f"{__name__}.{name}")
