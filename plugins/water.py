"""The water around a sonar head: ``absorption`` and ``sound_speed`` as numbers or ``auto``.

``<string name="absorption" value="auto"/>`` computes the head's absorption, dB/m, from its
``frequency`` and the water's ``temperature``, ``salinity`` and ``ph`` at the head's depth with
Francois and Garrison (1982) inside its range and Ainslie and McColm (1998) outside it (warm or
brackish water; `mitsonar.acoustics.seawater.absorption` ``model="auto"``); ``sound_speed``
``auto`` is Mackenzie (1981)'s nine-term equation there inside its range and Chen and Millero
(UNESCO 1983, pressure at 45 deg latitude) outside it (`mitsonar.acoustics.seawater.sound_speed`).
World z is up and the sea surface is the plane ``z = surface_z``, so the depth is ``surface_z - z``
of the origin of the sensor's ``to_world``.

The head's depth is the one of ``to_world``: a render given a ``pose`` (a trajectory, a moving
head) is refused while either is ``auto`` (`check_pose`), rather than quietly keeping the
water of a place the head has left; give numbers for a survey.

A value outside both equations' ranges is refused before the scene loads, in one line naming the
sensor field and the ranges, e.g. ``sonar 'temperature': 40 deg C is outside Ainslie and McColm
(1998)'s -6 to 35 deg C (absorption 'auto')``.
"""
from __future__ import annotations

import math

from mitsonar._checks import not_allowed
from mitsonar.acoustics.seawater import (AINSLIE_MCCOLM_RANGE, MACKENZIE_RANGE, UNESCO_RANGE, absorption,
                                         depth_to_pressure, sound_speed)
from mitsonar.acoustics.water import Water

from .props import number, text

#: Defaults of the water fields: `mitsonar.acoustics.water.Water`'s (a temperate sea, the standard
#: ocean salinity, open-ocean pH, the surface at z 0), as the sensor's XML parameters.
WATER_DEFAULTS = Water().sensor_parameters()
WATER_FIELDS = tuple(WATER_DEFAULTS)
AUTO = "auto"
_UNITS = {"temperature": "deg C", "salinity": "ppt", "ph": "", "depth": "m", "frequency": "Hz"}
_SOURCES = {"absorption": ("Ainslie and McColm (1998)", AINSLIE_MCCOLM_RANGE),
            "sound_speed": ("Mackenzie (1981)", MACKENZIE_RANGE)}
_UNESCO = "Chen and Millero (UNESCO 1983)"


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
        t, sal = water["temperature"], water["salinity"]
        if depth < 0:
            _check("depth", depth, "sound_speed", "surface_z", **where)
        bar = float(depth_to_pressure(depth)) / 10.0
        rows = (("temperature", t, "deg C", t, "deg C", {}, MACKENZIE_RANGE["temperature"], UNESCO_RANGE["temperature"]),
                ("salinity", sal, "ppt", sal, "ppt", {}, MACKENZIE_RANGE["salinity"], UNESCO_RANGE["salinity"]),
                ("surface_z", depth, "m", bar, "bar", where, MACKENZIE_RANGE["depth"], UNESCO_RANGE["pressure"]))
        if all(mk[0] <= v <= mk[1] for _, v, _, _, _, _, mk, _ in rows):
            sound_speed_value = float(sound_speed(t, sal, depth))
        else:
            for field, v, unit, u, unit_u, w, mk, un in rows:
                if not un[0] <= u <= un[1]:
                    raise ValueError(f"sonar '{field}': {w.get('label', '')}{v:g} {unit}{w.get('note', '')} is outside "
                                     f"Mackenzie (1981)'s {mk[0]:g} to {mk[1]:g} {unit} and {_UNESCO}'s {un[0]:g} to "
                                     f"{un[1]:g} {unit_u} (sound_speed 'auto')")
            sound_speed_value = float(sound_speed(t, sal, depth, model="unesco"))
    if absorption_value == AUTO:
        for f in ("temperature", "salinity", "ph"):
            _check(f, water[f], "absorption", f)
        _check("frequency", frequency, "absorption", "frequency")
        _check("depth", depth, "absorption", "surface_z", **where)
        absorption_value = float(absorption(frequency, water["temperature"], water["salinity"], depth, water["ph"],
                                            model="auto"))
    return absorption_value, sound_speed_value


def check_pose(auto_fields, pose) -> None:
    """Refuse a render ``pose`` while the water was computed at ``to_world``'s depth."""
    if pose is not None and auto_fields:
        raise ValueError(f"sonar '{auto_fields[0]}': 'auto' is computed at the depth of the sensor's to_world "
                         "and a render given a pose (a trajectory) moves the head: give "
                         f"{' and '.join(auto_fields)} as numbers (dB/m, m/s)")
