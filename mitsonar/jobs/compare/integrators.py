"""Loading the integrators to compare and describing them."""
from __future__ import annotations

from mitsonar.jobs.compare.common import CompareError


def load_integrator(name, params=None):
    """``mi.load_dict({"type": name, **params})``, checked to be a sonar integrator.

    Raises `CompareError` (one line) for a plugin that is not registered, parameters it refuses,
    or an integrator that is not a sonar integrator.
    """
    import mitsuba as mi

    from mitsonar.sim.render import sonar_integrators
    from mitsonar.sim.scene import mitsuba_error
    from mitsonar.sim.variant import ensure_variant

    ensure_variant()
    from mitsonar.plugins.integrators.common import SonarIntegrator

    ours = ", ".join(sonar_integrators())

    try:
        obj = mi.load_dict({"type": name, **(params or {})})
    except Exception as exc:
        text = str(exc)
        if "not found" in text and "Plugin" in text:
            raise CompareError(f"integrator {name!r} is not available (no Mitsuba plugin of that name is "
                               f"registered; mitsonar provides {ours})") from None
        raise CompareError(f"integrator {name!r}: {mitsuba_error(exc)}") from None
    if not isinstance(obj, SonarIntegrator):
        raise CompareError(f"integrator {name!r} is not a sonar integrator; use one of {ours}")
    return obj


def describe(obj) -> str:
    """The plugin's ``to_string()`` (its settings), or its type name."""
    try:
        return obj.to_string()
    except Exception:
        return type(obj).__name__


def min_spp(obj, n_pings) -> int:
    """The least spp ``obj`` accepts for ``n_pings`` pings (``sonar_mlt.min_spp``: explicit chain
    counts set a floor), 1 for an integrator without such a floor."""
    return int(getattr(obj, "min_spp", lambda n: 1)(n_pings))
