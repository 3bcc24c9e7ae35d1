"""Typed reading of plugin properties: every numeric or string field of every plugin refuses a
wrong XML type or a fractional count the same way, naming the plugin, the field and the tag.

Mitsuba hands a Python plugin whatever the XML held (``<string name="n_bins" value="50"/>`` is a
str, ``<float name="n_pings" value="8.7"/>`` a float, ``<rgb>`` a colour); converting those with
``int()``/``float()`` truncates counts silently or fails with Python's own words.
"""
from __future__ import annotations

import math

# Property types as their XML tags, for "expected <float>, got <rgb>".
_TAGS = {"Bool": "<boolean>", "Integer": "<integer>", "Float": "<float>", "String": "<string>",
         "Color": "<rgb>", "Spectrum": "<spectrum>", "Vector": "<point>/<vector>", "Transform": "<transform>"}


def _got(kind: str, value) -> str:
    if kind == "String":
        return f"<string> {value!r}"
    if kind == "Bool":
        return f"<boolean> {str(value).lower()}"
    if kind in ("Float", "Integer"):
        return f"{_TAGS[kind]} {value!r}"
    # Nested objects (a <texture>, a <bsdf>) are named by their class.
    return _TAGS.get(kind) or f"<{type(value).__name__.lower()}>"


def _wrong_type(name: str, kind: str, value, source: str, expected: str) -> ValueError:
    """The error for a property written with another XML tag than ``expected``."""
    if kind == "String":
        try:
            float(value)
        except ValueError:
            return ValueError(f"{source} '{name}': {value!r} is not a number (expected {expected})")
    return ValueError(f"{source} '{name}': expected {expected}, got {_got(kind, value)}")


def number(props, name: str, default, source: str, expected: str = "<float>"):
    """A ``<float>`` property (an ``<integer>`` counts as its value); ``default`` when absent."""
    if name not in props:
        return default
    kind, value = props.type(name).name, props.get(name)
    if kind in ("Float", "Integer"):
        return float(value)
    raise _wrong_type(name, kind, value, source, expected)


def count(props, name: str, default, source: str):
    """An ``<integer>`` property; a whole ``<float>`` (8.0) is taken, a fraction (8.7) refused."""
    if name not in props:
        return default
    kind, value = props.type(name).name, props.get(name)
    if kind == "Integer":
        return int(value)
    if kind == "Float":
        if not (math.isfinite(value) and float(value).is_integer()):
            raise ValueError(f"{source} '{name}': {value!r} is not a whole number (counts are <integer>)")
        return int(value)
    raise _wrong_type(name, kind, value, source, "<integer>")


def text(props, name: str, default, source: str):
    """A ``<string>`` property; ``default`` when absent."""
    if name not in props:
        return default
    kind, value = props.type(name).name, props.get(name)
    if kind != "String":
        raise ValueError(f"{source} '{name}': expected <string>, got {_got(kind, value)}")
    return value
