"""The one table of moved public modules: each old path (documented in an earlier release) is a
small module that re-exports its new home's names and warns, once per import, with a
`DeprecationWarning` naming the new path and the release that removes the old one.

An old path is three statements (tests/test_moved.py checks every row)::

    from mitsonar._moved import warn
    from mitsonar.live.outputs import *  # noqa: F401,F403
    warn(__name__)

Internal paths that moved are removed outright (the CHANGELOG says which).

`RENAMED` is the same table for public names that were renamed in place (an attribute, a keyword
argument, a command-line flag): the old name keeps working until the release it names, with a
`DeprecationWarning` naming the new one (`warn_renamed`, `renamed_keyword`).
"""
from __future__ import annotations

import warnings

__all__ = ["MOVED", "warn", "RENAMED", "warn_renamed", "renamed_keyword"]

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


# ---- renamed names ------------------------------------------------------------------------------
# A public attribute, keyword argument or command-line flag whose name said ``kind`` for something
# other than the sonar kind keeps working for one release under its old name, with a
# DeprecationWarning naming the new one (tests/test_deprecations.py exercises every row).

#: old public name -> (new name, the release that removes the old one)
RENAMED = {
    "Pulse.kind": ("Pulse.waveform", "0.4.0"),
    "Pulse(kind=...)": ("Pulse(waveform=...)", "0.4.0"),
    "SonarKind.plot_kinds": ("SonarKind.pictures", "0.4.0"),
    "register_plugin(kind=...)": ("register_plugin(family=...)", "0.4.0"),
    "RawLogWriter.write(kind=...)": ("RawLogWriter.write(record_type=...)", "0.4.0"),
    "mitsonar render/plot --kind": ("--picture", "0.4.0"),
}


def warn_renamed(old: str, stacklevel: int = 3) -> None:
    """Warn that the public name ``old`` (a row of `RENAMED`) is now its new name, and when the old
    one goes."""
    new, removal = RENAMED[old]
    warnings.warn(f"{old} is now {new}; the old name is removed in mitsonar {removal}",
                  DeprecationWarning, stacklevel=stacklevel)


def renamed_keyword(old: str, new: str, row: str):
    """A decorator: the function accepts its keyword ``new`` under the old name ``old`` too,
    warning (`warn_renamed` of ``row``); both at once is a TypeError."""
    import functools

    def decorate(func):
        @functools.wraps(func)
        def wrapper(*args, **kwargs):
            if old in kwargs:
                if new in kwargs:
                    raise TypeError(f"{func.__qualname__}() got both '{new}' and its old name '{old}'")
                warn_renamed(row)
                kwargs[new] = kwargs.pop(old)
            return func(*args, **kwargs)

        return wrapper

    return decorate
