"""The water a sonar works in, as one value: `Water` (temperature, salinity, pH, the depth
reference, latitude and the names of the sound-speed and absorption equations), and
`SOUND_SPEED`, the nominal sound speed every ``sound_speed`` default of mitsonar takes.

`Water`'s defaults are the ``sonar`` sensor's (a temperate sea, the standard ocean salinity,
open-ocean pH, the surface at world z 0), and `Water.sensor_parameters` are the sensor's XML
parameters of the same names (``temperature``, ``salinity``, ``ph``, ``surface_z``: what its
``sound_speed`` and ``absorption`` ``auto`` read; ``plugins/water.py``). `Water.sound_speed` and
`Water.absorption` compute the water's figures at a depth with the named equations
(`mitsonar.acoustics.seawater`). The sensor's ``auto`` uses Mackenzie (1981) for the sound speed
and Francois and Garrison (1982) for absorption inside their ranges, Chen and Millero (UNESCO) and
Ainslie and McColm outside them; `Water` names one equation each and keeps to it (it warns once
outside that equation's range, as `mitsonar.acoustics.seawater` does).

NumPy and mitsonar's value checks only: the plugins may use it.
"""
from __future__ import annotations

import dataclasses
import math

from mitsonar._checks import is_number, not_allowed
import mitsonar.acoustics.seawater as seawater

__all__ = ["SOUND_SPEED", "Water"]

#: m/s: the nominal sound speed of sea water every ``sound_speed`` default takes (the sensor's,
#: the heads' settings, the receiver's, the scans'), the round figure sonar heads assume when
#: not told (Mackenzie's equation gives 1490 m/s at 10 deg C, 35 ppt near the surface)
SOUND_SPEED = 1500.0


@dataclasses.dataclass(frozen=True)
class Water:
    """Sea water: its temperature (deg C), salinity (ppt), pH, the world z of its surface
    (``surface_z``, m: a point at world z lies ``surface_z - z`` deep), the latitude (deg, for the
    pressure at a depth, `mitsonar.acoustics.seawater.depth_to_pressure`) and the names of its
    sound-speed (``sound_speed_model``: one of `mitsonar.acoustics.seawater.SOUND_SPEED_MODELS`)
    and absorption (``absorption_model``: one of `mitsonar.acoustics.seawater.ABSORPTION_MODELS`)
    equations. A field that is not allowed is refused in one line naming it and what is allowed."""

    temperature: float = 10.0
    salinity: float = 35.0
    ph: float = 8.0
    surface_z: float = 0.0
    latitude: float = 45.0
    sound_speed_model: str = "mackenzie"
    absorption_model: str = "auto"

    def __post_init__(self):
        for name in ("temperature", "salinity", "ph", "surface_z", "latitude"):
            value = getattr(self, name)
            if not (is_number(value) and math.isfinite(value)):
                raise not_allowed("Water", name, value, "a finite number")
        if not 0.0 <= self.salinity:
            raise not_allowed("Water", "salinity", self.salinity, "a salinity >= 0 ppt")
        if not -90.0 <= self.latitude <= 90.0:
            raise not_allowed("Water", "latitude", self.latitude, "-90 to 90 deg")
        for name, names in (("sound_speed_model", seawater.SOUND_SPEED_MODELS),
                            ("absorption_model", seawater.ABSORPTION_MODELS)):
            if getattr(self, name) not in names:
                raise not_allowed("Water", name, getattr(self, name), "one of " + ", ".join(names))

    def depth(self, z):
        """The depth (m) of world height ``z``: ``surface_z - z``."""
        return self.surface_z - z

    def sound_speed(self, depth=0.0):
        """The sound speed (m/s) at ``depth`` (m) by ``sound_speed_model``."""
        return seawater.sound_speed(self.temperature, self.salinity, depth, model=self.sound_speed_model,
                                    latitude=self.latitude)

    def absorption(self, frequency, depth=0.0):
        """The absorption (dB/m) of ``frequency`` (Hz) at ``depth`` (m) by ``absorption_model``."""
        return seawater.absorption(frequency, self.temperature, self.salinity, depth, self.ph,
                                   model=self.absorption_model)

    def sensor_parameters(self) -> dict:
        """The ``sonar`` sensor's XML parameters of this water: ``temperature``, ``salinity``,
        ``ph``, ``surface_z`` (read with its ``sound_speed`` or ``absorption`` ``auto``)."""
        return {name: float(getattr(self, name)) for name in SENSOR_PARAMETERS}

    @classmethod
    def from_sensor_parameters(cls, params) -> "Water":
        """The water of a sensor's XML parameters (a mapping; those absent take the defaults)."""
        return cls(**{name: params[name] for name in SENSOR_PARAMETERS if name in params})


#: the `Water` fields that are the ``sonar`` sensor's XML parameters of the same names
SENSOR_PARAMETERS = ("temperature", "salinity", "ph", "surface_z")
