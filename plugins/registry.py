"""Registering the plugins with Mitsuba: `register_plugin` (what each plugin module calls at its
end), `register` (the families' modules imported for the active variant), `unregister_plugin`,
`take_failure`."""
from __future__ import annotations

import importlib
import pkgutil
import sys

from mitsonar._moved import renamed_keyword

PACKAGE = "mitsonar.plugins"
FAMILIES = ("sensors", "bsdfs", "integrators")
_current = None

# XML plugin name -> (family, class), as `register_plugin` registered them for the active variant
_registered: dict = {}

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


#: What `register_plugin` registers as: a Mitsuba plugin type (the XML element) per family
PLUGIN_TYPES = ("sensor", "BSDF", "integrator")


@renamed_keyword("kind", "family", "register_plugin(kind=...)")
def register_plugin(family: str, name: str, cls) -> None:
    """Register ``cls`` with Mitsuba as the ``family`` (``"sensor"``, ``"BSDF"``, ``"integrator"``)
    ``name``: what a plugin module calls at its end. Its constructor refuses an XML parameter the
    class does not read (`props.check_all_read`) and keeps whatever it raised for `take_failure`.
    The old name of ``family``, ``kind``, still works until 0.4.0 with a DeprecationWarning."""
    if family not in PLUGIN_TYPES:
        raise ValueError(f"register_plugin 'family': {family!r} is not allowed (one of {', '.join(PLUGIN_TYPES)})")
    import mitsuba as mi

    from .props import check_all_read

    module, cls_name = sys.modules[cls.__module__], cls.__name__

    def construct(props):
        try:
            plugin = getattr(module, cls_name)   # the module's class now (a test may replace it)
            obj = plugin(props)
            check_all_read(props, family, name, parameters(plugin))
            return obj
        except Exception as exc:
            _failures[:] = [exc]
            raise

    {"sensor": mi.register_sensor, "BSDF": mi.register_bsdf, "integrator": mi.register_integrator}[family](name, construct)
    _registered[name] = (family, cls)



def unregister_plugin(name: str) -> None:
    """Forget a plugin `register_plugin` registered outside the families (a test's toy BSDF):
    `registered` no longer lists it. Mitsuba has no call to drop a plugin, so its XML name stays
    loadable in this process until a variant change (`register` then registers the families only)."""
    _registered.pop(name, None)


def family_modules() -> list:
    """The names of every module of the families (``mitsonar.plugins.sensors.sonar``, ...)."""
    names = []
    for family in FAMILIES:
        package = importlib.import_module(f"{PACKAGE}.{family}")
        names += [m.name for m in pkgutil.walk_packages(package.__path__, f"{package.__name__}.") if not m.ispkg]
    return names


def register(force: bool = False) -> None:
    """Import the families' modules for the active variant, which registers their plugins (no-op
    if already done for it). On a variant change every module of the families is dropped first and
    imported again, in the order their imports ask for, so no class of the old variant remains."""
    import mitsuba as mi

    variant = mi.variant()
    if variant is None:
        raise RuntimeError("mitsonar.plugins.register(): set a Mitsuba variant first")
    global _current
    if variant == _current and not force:
        return
    names = family_modules()
    if _current is not None or force:
        for name in names:
            sys.modules.pop(name, None)
        _registered.clear()
    for name in names:
        importlib.import_module(name)
    _current = variant


def registered() -> dict:
    """``{XML name: (family, class)}`` of the plugins registered for the active variant (after `register`)."""
    register()
    return dict(_registered)
