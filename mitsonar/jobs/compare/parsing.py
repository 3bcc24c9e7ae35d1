"""Command-line text to the values `mitsonar.jobs.compare.compare` takes (``mitsonar compare``'s options).

Every parser raises `CompareError` with one line naming the option and an example of good input.
"""
from __future__ import annotations

import math
import re

from mitsonar.jobs.compare.common import CompareError

_NAME = re.compile(r"^[A-Za-z_][A-Za-z0-9_]*$")


def parse_budgets(text) -> list[float]:
    """Time budgets in seconds from ``"2,4,8,16"`` (or a sequence of numbers), sorted, distinct.

    Raises `CompareError` unless every entry is a finite positive number.
    """
    items = text.split(",") if isinstance(text, str) else list(text)
    out = []
    for item in items:
        try:
            value = float(item.strip() if isinstance(item, str) else item)
        except (TypeError, ValueError):
            value = float("nan")
        if not (math.isfinite(value) and value > 0):
            raise CompareError(f"--budget {text if isinstance(text, str) else ','.join(map(str, items))!r}: "
                               f"{item!r} is not a positive number of seconds (expected e.g. 2,4,8,16)")
        out.append(value)
    if not out:
        raise CompareError("--budget: no budgets given (expected e.g. 2,4,8,16)")
    return sorted(set(out))


def parse_integrators(text) -> list[str]:
    """Integrator plugin names from ``"sonar_tof,sonar_mlt"`` (or a sequence of names)."""
    items = text.split(",") if isinstance(text, str) else list(text)
    names = [str(i).strip() for i in items]
    if not names or any(not n for n in names):
        raise CompareError(f"--integrators {text!r}: expected comma-separated plugin names, "
                           "e.g. sonar_tof,sonar_mlt")
    for n in names:
        if not _NAME.match(n):
            raise CompareError(f"--integrators: {n!r} is not an integrator plugin name")
    return names


def _number(text):
    for conv in (int, float):
        try:
            return conv(text)
        except ValueError:
            continue
    return text


def parse_params(items) -> dict:
    """``LABEL.NAME=VALUE`` strings to ``{label: {name: value}}`` (numbers become int/float)."""
    out: dict = {}
    for item in items or []:
        m = re.match(r"^([A-Za-z_][\w#]*)\.([A-Za-z_]\w*)=(.*)$", item)
        if not m:
            raise CompareError(f"--param {item!r}: expected INTEGRATOR.NAME=VALUE, e.g. sonar_mlt.chains=1024")
        out.setdefault(m.group(1), {})[m.group(2)] = _number(m.group(3))
    return out


def parse_regions(items) -> dict:
    """``NAME=LO:HI`` strings (metres) to ``{name: (lo, hi)}``: bins with centre range in [lo, hi)."""
    out = {}
    for item in items or []:
        m = re.match(r"^([A-Za-z_][\w.-]*)=([^:]+):(.+)$", item)
        try:
            lo, hi = float(m.group(2)), float(m.group(3))
        except (AttributeError, ValueError):
            lo = hi = float("nan")
        if not (m and math.isfinite(lo) and math.isfinite(hi) and hi > lo):
            raise CompareError(f"--region {item!r}: expected NAME=LO:HI in metres with LO < HI, e.g. chamber=3.5:12")
        out[m.group(1)] = (lo, hi)
    return out


__all__ = ["parse_budgets", "parse_integrators", "parse_params", "parse_regions"]
