"""Validators shared by the plugins, the electronics and the devices: one wording for a refused value.

Every setting a user gives (an XML property, a ``--set`` override, a head setting, a keyword
argument) is checked before any work starts and refused with one sentence naming where it came
from, the field, the value and what is allowed::

    sonar 'n_bins': 0 is not allowed (a count >= 1)

This module imports nothing from mitsonar, so every layer may use it.
"""
from __future__ import annotations

import math
import numbers


def not_allowed(where: str, name: str, value, allowed: str) -> ValueError:
    """``"<where> '<name>': <value> is not allowed (<allowed>)"`` as a ValueError (to raise)."""
    return ValueError(f"{where} '{name}': {value!r} is not allowed ({allowed})")


def not_a(where: str, name: str, value, what: str) -> ValueError:
    """``"<where> '<name>': <value> is not <what>"``, for a value of the wrong kind ("a number")."""
    return ValueError(f"{where} '{name}': {value!r} is not {what}")


def require(ok: bool, where: str, name: str, value, allowed: str) -> None:
    """Raise :func:`not_allowed` unless ``ok``."""
    if not ok:
        raise not_allowed(where, name, value, allowed)


def is_number(value) -> bool:
    """A real number that is finite (bool is not a number here)."""
    return (isinstance(value, numbers.Real) and not isinstance(value, bool)
            and math.isfinite(float(value)))


def is_whole(value) -> bool:
    """A finite number with no fractional part (``8`` and ``8.0``, not ``8.5`` or ``True``)."""
    return is_number(value) and float(value).is_integer()


def in_range(value, lo: float, hi: float) -> bool:
    """``lo <= value <= hi`` for a finite number, False for anything else."""
    return is_number(value) and lo <= float(value) <= hi
