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


def _got(prop_type: str, value) -> str:
    if prop_type == "String":
        return f"<string> {value!r}"
    if prop_type == "Bool":
        return f"<boolean> {str(value).lower()}"
    if prop_type in ("Float", "Integer"):
        return f"{_TAGS[prop_type]} {value!r}"
    # Nested objects (a <texture>, a <bsdf>) are named by their class.
    return _TAGS.get(prop_type) or f"<{type(value).__name__.lower()}>"


def _wrong_type(name: str, prop_type: str, value, source: str, expected: str) -> ValueError:
    """The error for a property written with another XML tag than ``expected``."""
    if prop_type == "String":
        try:
            float(value)
        except ValueError:
            return ValueError(f"{source} '{name}': {value!r} is not a number (expected {expected})")
    return ValueError(f"{source} '{name}': expected {expected}, got {_got(prop_type, value)}")


def number(props, name: str, default, source: str, expected: str = "<float>"):
    """A ``<float>`` property (an ``<integer>`` counts as its value); ``default`` when absent."""
    if name not in props:
        return default
    prop_type, value = props.type(name).name, props.get(name)
    if prop_type in ("Float", "Integer"):
        return float(value)
    raise _wrong_type(name, prop_type, value, source, expected)


def count(props, name: str, default, source: str):
    """An ``<integer>`` property; a whole ``<float>`` (8.0) is taken, a fraction (8.7) refused."""
    if name not in props:
        return default
    prop_type, value = props.type(name).name, props.get(name)
    if prop_type == "Integer":
        return int(value)
    if prop_type == "Float":
        if not (math.isfinite(value) and float(value).is_integer()):
            raise ValueError(f"{source} '{name}': {value!r} is not a whole number (counts are <integer>)")
        return int(value)
    raise _wrong_type(name, prop_type, value, source, "<integer>")


def text(props, name: str, default, source: str):
    """A ``<string>`` property; ``default`` when absent."""
    if name not in props:
        return default
    prop_type, value = props.type(name).name, props.get(name)
    if prop_type != "String":
        raise ValueError(f"{source} '{name}': expected <string>, got {_got(prop_type, value)}")
    return value


def table_parameters(doc: str | None) -> list:
    """The XML parameter names of a plugin, read from its docstring's parameter table (the first
    column of the rows between the second and third ``====`` rules): the table is the
    documentation, so the two cannot disagree. ``aperture_h/_v`` names two parameters."""
    names, rules = [], 0
    for line in (doc or "").splitlines():
        row = line.strip()
        if row.startswith("===="):
            rules += 1
            continue
        if rules == 2 and row and not line.startswith(" " * 12):  # body rows, not continuation lines
            stem, _, alt = row.split()[0].partition("/")
            names.append(stem)
            if alt.startswith("_"):
                names.append(stem.rsplit("_", 1)[0] + alt)
    return names


def check_all_read(props, family: str, plugin: str, known) -> None:
    """Refuse the properties a plugin did not read (a misspelled parameter), naming the nearest
    known parameter and listing them all, before Mitsuba's own, less helpful, check does."""
    import difflib

    unread = [name for name in props.unqueried()]
    if not unread:
        return
    parts = []
    for name in unread:
        hint = difflib.get_close_matches(name, known, n=1)
        parts.append(f'"{name}"' + (f' (did you mean "{hint[0]}"?)' if hint else ""))
    raise ValueError(f'the {family} "{plugin}" has no parameter {", ".join(parts)}; '
                     f'its parameters: {", ".join(known)}')
