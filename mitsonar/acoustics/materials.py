"""Acoustic material presets in physical units: density, compressional sound speed, attenuation.

The sediment presets are rows of the APL-UW handbook's Table 2 (:data:`~mitsonar.acoustics.seabed.SEDIMENTS`,
density and sound speed ratios from Hamilton's measurements, APL-UW TR 9407 sec. IV.A) turned into
physical units against a reference sea water of :data:`WATER_DENSITY` and
:data:`WATER_SOUND_SPEED`; steel and concrete are engineering handbook values.
"""
from __future__ import annotations

from dataclasses import dataclass

from mitsonar.acoustics._checks import at_least
from mitsonar.acoustics.interface import DB_PER_WAVELENGTH_PER_DELTA, reflection_coefficient
from mitsonar.acoustics.seabed import SEDIMENTS

__all__ = ["Material", "MATERIALS", "material", "WATER_DENSITY", "WATER_SOUND_SPEED"]

#: Reference sea water density, kg/m^3: EOS-80 at 10 deg C, 35 ppt, the surface (1026.95).
WATER_DENSITY = 1027.0
#: Reference sea water sound speed, m/s: the ``c1`` APL-UW TR 9407 formed its ratios with (sec. IV.A.4).
WATER_SOUND_SPEED = 1528.0


@dataclass(frozen=True)
class Material:
    """A fluid (compressional-wave) description of a reflector.

    Attributes
    ----------
    name : str
    density : float
        kg/m^3, > 0.
    sound_speed : float
        Compressional sound speed, m/s, > 0.
    attenuation : float
        Compressional attenuation, dB per wavelength, >= 0.
    lambert_mu : float or None
        Lambert parameter (dB) where a published one applies, else None.
    source : str
        Where the numbers come from.
    """
    name: str
    density: float
    sound_speed: float
    attenuation: float
    lambert_mu: float | None = None
    source: str = ""

    def __post_init__(self):
        where = f"Material {self.name!r}"
        at_least(where, "density", self.density, 0.0, "kg/m^3", strict=True)
        at_least(where, "sound_speed", self.sound_speed, 0.0, "m/s", strict=True)
        at_least(where, "attenuation", self.attenuation, 0.0, "dB/wavelength")

    def ratios(self, water_density=WATER_DENSITY, water_sound_speed=WATER_SOUND_SPEED):
        """``(density_ratio, sound_speed_ratio)`` against the given water."""
        rho = float(at_least("Material.ratios", "water_density", water_density, 0.0, "kg/m^3", strict=True))
        c = float(at_least("Material.ratios", "water_sound_speed", water_sound_speed, 0.0, "m/s", strict=True))
        return self.density / rho, self.sound_speed / c

    def reflection_coefficient(self, grazing, water_density=WATER_DENSITY, water_sound_speed=WATER_SOUND_SPEED):
        """The complex plane-wave reflection coefficient of water over this material
        (:func:`~mitsonar.acoustics.interface.reflection_coefficient`)."""
        m, nu = self.ratios(water_density, water_sound_speed)
        return reflection_coefficient(grazing, m, nu, self.attenuation)


def _from_sediment(name: str, row: str, lambert_mu: float | None = None, note: str = "") -> Material:
    sed = SEDIMENTS[row]
    where = f"APL-UW TR 9407 Table 2, {row!r}" + (f" (Mz {sed.grain_size:g} phi)" if sed.grain_size is not None else "")
    return Material(name, density=sed.density_ratio * WATER_DENSITY,
                    sound_speed=sed.sound_speed_ratio * WATER_SOUND_SPEED,
                    attenuation=DB_PER_WAVELENGTH_PER_DELTA * sed.loss, lambert_mu=lambert_mu,
                    source=where + note)


#: Presets by name. Sediments: APL-UW TR 9407 Table 2 rows (ratios times the reference water).
MATERIALS: dict[str, Material] = {
    "steel": Material("steel", density=7850.0, sound_speed=5900.0, attenuation=0.0,
                      source="carbon steel: 7850 kg/m^3 (EN 1991-1-1 Annex A, 77-78.5 kN/m^3); longitudinal "
                             "speed 5900 m/s (ultrasonic testing tables, e.g. Krautkraemer and Krautkraemer, "
                             "Ultrasonic Testing of Materials, 1990); absorption negligible at sonar "
                             "frequencies, taken as 0"),
    "concrete": Material("concrete", density=2400.0, sound_speed=3700.0, attenuation=0.0,
                         source="normal-weight concrete: 2400 kg/m^3 (EN 1991-1-1 Annex A, 24 kN/m^3); "
                                "pulse velocity 3700 m/s (sound concrete reads 3.5-4.5 km/s, BS EN 12504-4 / "
                                "Neville, Properties of Concrete); absorption not modelled, taken as 0"),
    "rock": _from_sediment("rock", "rock"),
    "gravel": _from_sediment("gravel", "sandy gravel"),
    "sand": _from_sediment("sand", "medium sand"),
    "silt": _from_sediment("silt", "medium silt"),
    "mud": _from_sediment("mud", "clayey silt", lambert_mu=-27.0,
                          note="; Lambert mu -27 dB: Mackenzie (1961), J. Acoust. Soc. Am. 33, 1498 "
                               "(deep-ocean sediment floor)"),
    "clay": _from_sediment("clay", "clay"),
}


def material(name: str) -> Material:
    """The :data:`MATERIALS` preset called ``name`` (case insensitive)."""
    key = str(name).strip().lower()
    if key not in MATERIALS:
        raise ValueError(f"material: unknown name {name!r} (known: {', '.join(MATERIALS)})")
    return MATERIALS[key]
