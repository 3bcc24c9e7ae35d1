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


_TYPE_NAME = object()


def first_line(exc: BaseException, default=_TYPE_NAME, *, traceback_reason: bool = False):
    """An exception's reason on one line, for a one-line error: its message's first non-blank
    line, stripped. A message with no text gives ``default``, the exception's type name unless
    given. ``traceback_reason``: when the message is a whole traceback (Mitsuba wraps an exception
    raised in a Python plugin into a RuntimeError whose text is the traceback), its last line."""
    text = str(exc).strip()
    lines = [ln.strip() for ln in text.splitlines() if ln.strip()]
    if not lines:
        return type(exc).__name__ if default is _TYPE_NAME else default
    return lines[-1] if traceback_reason and "Traceback (most recent call last)" in text else lines[0]
