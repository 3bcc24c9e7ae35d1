"""The one table of moved public modules: each old path (documented in an earlier release) is a
small module that re-exports its new home's names and warns, once per import, with a
`DeprecationWarning` naming the new path and the release that removes the old one.

An old path is three statements (tests/test_moved.py checks every row)::

    from mitsonar._moved import warn
    from mitsonar.live.outputs import *  # noqa: F401,F403
    warn(__name__)

Internal paths that moved are removed outright (the CHANGELOG says which).
"""
from __future__ import annotations

import warnings

__all__ = ["MOVED", "warn"]

#: old module -> (new module, the release that removes the old path)
MOVED = {
    "mitsonar.devices.outputs": ("mitsonar.live.outputs", "0.4.0"),
    "mitsonar.jobs.refine": ("mitsonar.inverse.height_field", "0.4.0"),
    "mitsonar.jobs.refine_room": ("mitsonar.inverse.room", "0.4.0"),
    "mitsonar.jobs.refine_piles": ("mitsonar.inverse.piles", "0.4.0"),
    "mitsonar.devices.oculus.presets": ("mitsonar.presets.oculus", "0.4.0"),
    "mitsonar.acoustics.raydiagram": ("mitsonar.products.raydiagram", "0.4.0"),
}


def warn(old: str) -> None:
    """Warn that ``old`` (a row of `MOVED`) moved, naming its new home and its removal release."""
    new, removal = MOVED[old]
    warnings.warn(f"{old} moved to {new}; the old path is removed in mitsonar {removal}",
                  DeprecationWarning, stacklevel=3)
