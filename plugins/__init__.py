"""mitsonar's Mitsuba plugins, by family: sensor ``sonar`` (`sensors`), BSDFs ``acoustic`` and ``acoustic_material`` (`bsdfs`), integrators ``sonar_tof``, ``sonar_mlt``, ``sonar_bdpt`` (`integrators`).

The plugin classes derive from the classes of the active Mitsuba variant, so their modules are
(re)loaded for each variant and the plugins registered again; `register()` does that and is
called by ``mitsonar.set_variant`` and ``mitsonar.ensure_variant`` (the first ``load_scene``,
``render_scan``, ...), and on every variant change after that (never by ``import mitsonar``).
"""
from __future__ import annotations

import importlib

_MODULES = ("bsdfs.materials", "sensors.beam", "bsdfs.acoustic", "bsdfs.acoustic_material", "sensors.sonar",
            "integrators.paths.range_bins", "integrators.paths.samples", "integrators.common", "integrators.sonar_tof",
            "integrators.sonar_mlt", "integrators.paths.bdpt_paths", "integrators.sonar_bdpt")
_current = None

# (kind, XML plugin name, module, class) of every plugin registered with Mitsuba
PLUGINS = (("BSDF", "acoustic", "bsdfs.acoustic", "AcousticBSDF"),
           ("BSDF", "acoustic_material", "bsdfs.acoustic_material", "AcousticMaterialBSDF"),
           ("sensor", "sonar", "sensors.sonar", "SonarSensor"),
           ("integrator", "sonar_tof", "integrators.sonar_tof", "SonarTOFIntegrator"),
           ("integrator", "sonar_mlt", "integrators.sonar_mlt", "SonarMLTIntegrator"),
           ("integrator", "sonar_bdpt", "integrators.sonar_bdpt", "SonarBDPTIntegrator"))

# The last exception raised by one of our plugins' constructors. Mitsuba turns it into a
# RuntimeError holding its traceback as text; `take_failure` hands the original back to whoever
# reports the error (mitsonar.sim.scene), so no message has to be recovered from that text.
_failures: list = []


def take_failure():
    """The last exception a plugin constructor raised since the previous call (or None)."""
    failure = _failures[-1] if _failures else None
    _failures.clear()
    return failure


def parameters(cls) -> list:
    """The XML parameter names of a plugin class (its ``parameters()``, or its docstring table)."""
    from .props import table_parameters

    return cls.parameters() if hasattr(cls, "parameters") else table_parameters(cls.__doc__)


def _constructor(kind, name, mod, cls_name):
    from .props import check_all_read

    def construct(props):
        try:
            cls = getattr(mod, cls_name)
            obj = cls(props)
            check_all_read(props, kind, name, parameters(cls))
            return obj
        except Exception as exc:
            _failures[:] = [exc]
            raise
    return construct


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
    for kind, name, module_name, cls_name in PLUGINS:
        register_kind = {"sensor": mi.register_sensor, "BSDF": mi.register_bsdf, "integrator": mi.register_integrator}
        register_kind[kind](name, _constructor(kind, name, mods[module_name], cls_name))
    _current = variant


def module(name: str):
    """The plugin module for the active variant (e.g. ``module('sensors.sonar').SonarSensor``)."""
    register()
    return importlib.import_module(f"{__name__}.{name}")
