"""mitsonar's Mitsuba plugins, by family: the sensor ``sonar`` (`sensors`), the BSDFs ``acoustic``
and ``acoustic_material`` (`bsdfs`), the integrators ``sonar_tof``, ``sonar_mlt`` and
``sonar_bdpt`` (`integrators`, their path machinery in `integrators.paths`). The helpers the
families share and that need no variant (`props`, `water`, `jit_arrays`) stay here.

Each plugin module registers its plugin at its end through `registry.register_plugin`, as Mitsuba's own
Python integrators call ``mi.register_integrator``. The families' classes derive from the classes
of the active Mitsuba variant, so `registry.register` imports every module of the families for the
variant (found by walking the packages), again when the variant changes: ``mitsonar.set_variant``
and ``mitsonar.ensure_variant`` (the first ``load_scene``, ``render_scan``, ...) call it, and then
every variant change does (never ``import mitsonar``). After that, import a plugin module directly
(``from mitsonar.plugins.integrators import sonar_tof``).
"""
from __future__ import annotations

from .registry import parameters, register, register_plugin, registered, take_failure, unregister_plugin  # noqa: F401
