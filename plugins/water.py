"""The water around a sonar head: ``absorption`` and ``sound_speed`` as numbers or ``auto``.

``<string name="absorption" value="auto"/>`` computes the head's absorption, dB/m, from its
``frequency`` and the water's ``temperature``, ``salinity`` and ``ph`` at the head's depth with
Francois and Garrison (1982) (`mitsonar.acoustics.seawater.absorption`); ``sound_speed`` ``auto``
is Mackenzie (1981)'s nine-term equation there (`mitsonar.acoustics.seawater.sound_speed`). World
z is up and the sea surface is the plane ``z = surface_z``, so the depth is ``surface_z - z`` of
the origin of the sensor's ``to_world``.

The head's depth is the one of ``to_world``: a render given a ``pose`` (a trajectory, a moving
head) is refused while either is ``auto`` (`check_pose`), rather than quietly keeping the
water of a place the head has left; give numbers for a survey.

Every out-of-range value is refused before the scene loads, in one line naming the sensor field
and the range of the equation, e.g. ``sonar 'temperature': 35 deg C is outside Francois and
Garrison (1982)'s -2 to 22 deg C (absorption 'auto')``.
"""
from __future__ import annotations

import math

from mitsonar._checks import not_allowed
from mitsonar.acoustics.seawater import FRANCOIS_GARRISON_RANGE, MACKENZIE_RANGE, absorption, sound_speed

from .props import number, text

#: Defaults of the water fields: a temperate sea, the standard ocean salinity, open-ocean pH.
WATER_DEFAULTS = {"temperature": 10.0, "salinity": 35.0, "ph": 8.0, "surface_z": 0.0}
WATER_FIELDS = tuple(WATER_DEFAULTS)
AUTO = "auto"
_UNITS = {"temperature": "deg C", "salinity": "ppt", "ph": "", "depth": "m", "frequency": "Hz"}
_SOURCES = {"absorption": ("Francois and Garrison (1982)", FRANCOIS_GARRISON_RANGE),
            "sound_speed": ("Mackenzie (1981)", MACKENZIE_RANGE)}


def number_or_auto(props, name: str, default):
    """A ``<float>`` property, or the string ``auto`` (returned as ``"auto"``)."""
    if name in props and props.type(name).name == "String" and text(props, name, None, "sonar").strip() == AUTO:
        return AUTO
    return number(props, name, default, "sonar", expected='<float> or <string value="auto"/>')


def read_water(props, absorption_value, sound_speed_value) -> dict | None:
    """The water fields (``temperature``, ``salinity``, ``ph``, ``surface_z``) when either value is
    ``auto``, else None (and the fields are refused: they would change nothing)."""
    if AUTO not in (absorption_value, sound_speed_value):
        given = [n for n in WATER_FIELDS if n in props]
        if given:
            raise ValueError(f"sonar '{given[0]}': only used with absorption or sound_speed 'auto' "
                             f"(both are numbers here)")
        return None
    if absorption_value != AUTO and "ph" in props:
        raise ValueError("sonar 'ph': only used with absorption 'auto' (Mackenzie's sound speed has no pH)")
    water = {n: number(props, n, d, "sonar") for n, d in WATER_DEFAULTS.items()}
    for name, value in water.items():
        if not math.isfinite(value):
            raise not_allowed("sonar", name, value, "a finite number")
    return water


def _check(field: str, value: float, what: str, sensor_field: str, label: str = "", note: str = "") -> None:
    source, ranges = _SOURCES[what]
    lo, hi = ranges[field]
    if not (lo <= value <= hi):
        unit = _UNITS[field]
        u = f" {unit}" if unit else ""
        raise ValueError(f"sonar '{sensor_field}': {label}{value:g}{u}{note} is outside {source}'s {lo:g} to "
                         f"{hi:g}{u} ({what} 'auto')")


def resolve(water: dict | None, absorption_value, sound_speed_value, frequency: float, z: float):
    """``(absorption dB/m, sound_speed m/s)`` with each ``auto`` computed at depth
    ``surface_z - z``; every input checked against its equation's range first."""
    if water is None:
        return absorption_value, sound_speed_value
    depth = water["surface_z"] - z
    where = dict(label="the head's depth ", note=f" (surface_z {water['surface_z']:g} - the head's z {z:g})")
    if sound_speed_value == AUTO:
        for f in ("temperature", "salinity"):
            _check(f, water[f], "sound_speed", f)
        _check("depth", depth, "sound_speed", "surface_z", **where)
        sound_speed_value = float(sound_speed(water["temperature"], water["salinity"], depth))
    if absorption_value == AUTO:
        for f in ("temperature", "salinity", "ph"):
            _check(f, water[f], "absorption", f)
        _check("frequency", frequency, "absorption", "frequency")
        _check("depth", depth, "absorption", "surface_z", **where)
        absorption_value = float(absorption(frequency, water["temperature"], water["salinity"], depth, water["ph"]))
    return absorption_value, sound_speed_value


def check_pose(auto_fields, pose) -> None:
    """Refuse a render ``pose`` while the water was computed at ``to_world``'s depth."""
    if pose is not None and auto_fields:
        raise ValueError(f"sonar '{auto_fields[0]}': 'auto' is computed at the depth of the sensor's to_world "
                         "and a render given a pose (a trajectory) moves the head: give "
                         f"{' and '.join(auto_fields)} as numbers (dB/m, m/s)")
