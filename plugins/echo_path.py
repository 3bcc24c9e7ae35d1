"""Deprecated: the echo-path function is `SonarIntegrator.sample` in ``mitsonar.plugins.common``,
the primary samples (`HashSamples`, `n_dims`) live in ``mitsonar.plugins.samples``. The old names
stay importable from here for one release, with a DeprecationWarning."""
from __future__ import annotations

import warnings

from . import common, samples

_MOVED = {"HashSamples": samples, "n_dims": samples, "DIMS_EMIT": samples, "DIMS_PER_BOUNCE": samples}


def trace_echoes(scene, frames, beam, ping, samples_, max_depth, absorption, record, active=True, connect=None):
    """Deprecated: use ``integrator.sample(integrator.setup(scene, sensor), ping, samples, record)``."""
    warnings.warn("mitsonar.plugins.echo_path.trace_echoes is deprecated: use SonarIntegrator.sample "
                  "(mitsonar.plugins.common)", DeprecationWarning, stacklevel=2)
    setup = common.PathSetup.__new__(common.PathSetup)
    setup.scene, setup.frames, setup.connect, setup.depth_o, setup.absorption = \
        scene, frames, connect, max_depth, absorption
    setup.guide = False
    setup.sensor = type("_Beam", (), {"beam": beam})()
    common.SonarIntegrator.sample(None, setup, ping, samples_, lambda k, rng, e, valid, hit: record(k, rng, e, valid),
                                  active)


def __getattr__(name):
    if name in _MOVED:
        warnings.warn(f"mitsonar.plugins.echo_path.{name} is deprecated: import it from "
                      f"{_MOVED[name].__name__}", DeprecationWarning, stacklevel=2)
        return getattr(_MOVED[name], name)
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
