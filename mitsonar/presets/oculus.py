"""The Oculus M-series models mitsonar knows: part numbers, frequencies, apertures, beams, ranges.

Part numbers: ``Oculus.h`` ``OculusPartNumberType`` (liboculus ``thirdparty/Oculus/Oculus.h``:
``partNumberM750d = 1032``, ``partNumberM1200d = 1042``, ``partNumberM3000d = 2203``). Per
frequency mode (``masterMode`` 1 low, 2 high): the centre frequency, the horizontal aperture and
the vertical beam width, the angular resolution and the largest range, as Blueprint's datasheets
give them and liboculus ``include/liboculus/Constants.h`` carries them (``Oculus_M750d::
Freq_750kHz`` ...: elevation beam width, azimuth beam width, ``MaxRange``). Every mode forms 256
beams, or 512 with the fire message's ``flags`` bit 6 (`mitsonar.devices.oculus.protocol.FLAG`).

=========  ======  ========  =========  ========  ===========  ==========
model      part    mode      frequency  aperture  vertical     max range
=========  ======  ========  =========  ========  ===========  ==========
M750d      1032    1 (LF)    750 kHz    130 deg   20 deg       120 m
M750d      1032    2 (HF)    1.2 MHz    70 deg    12 deg       40 m
M1200d     1042    1 (LF)    1.2 MHz    130 deg   20 deg       40 m
M1200d     1042    2 (HF)    2.1 MHz    60 deg    12 deg       10 m
M3000d     2203    1 (LF)    1.2 MHz    130 deg   20 deg       30 m
M3000d     2203    2 (HF)    3.0 MHz    40 deg    20 deg       5 m
=========  ======  ========  =========  ========  ===========  ==========

The head's bearing table (`bearing_table`) is its own, not ``start + k * step``: the beams of
a flat receive array are evenly spaced in the sine of the bearing, so they crowd towards the
centre of the fan in degrees.
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

__all__ = ["Mode", "Model", "MODELS", "PART_NUMBERS", "MIN_RANGE", "model", "bearing_table"]

#: the shortest range a fire message may ask for, m (datasheets: 0.1 m)
MIN_RANGE = 0.1


@dataclass(frozen=True)
class Mode:
    """One frequency mode of a model."""
    frequency: float          # Hz
    aperture: float           # horizontal, degrees
    beamwidth_v: float        # degrees
    beamwidth_h: float        # one beam's azimuth width, degrees
    max_range: float          # m


@dataclass(frozen=True)
class Model:
    name: str
    part_number: int
    modes: dict               # masterMode (1, 2) -> Mode

    def mode(self, master_mode: int) -> Mode:
        if master_mode not in self.modes:
            raise ValueError(f"{self.name}: masterMode {master_mode} is not allowed (1 low or 2 high frequency)")
        return self.modes[master_mode]


MODELS = {
    "M750d": Model("M750d", 1032, {1: Mode(750e3, 130.0, 20.0, 1.0, 120.0), 2: Mode(1.2e6, 70.0, 12.0, 0.6, 40.0)}),
    "M1200d": Model("M1200d", 1042, {1: Mode(1.2e6, 130.0, 20.0, 0.6, 40.0), 2: Mode(2.1e6, 60.0, 12.0, 0.4, 10.0)}),
    "M3000d": Model("M3000d", 2203, {1: Mode(1.2e6, 130.0, 20.0, 0.6, 30.0), 2: Mode(3.0e6, 40.0, 20.0, 0.4, 5.0)}),
}
PART_NUMBERS = {m.part_number: m for m in MODELS.values()}


def model(name_or_part) -> Model:
    """A model by name (``"M1200d"``) or part number (1042); ValueError naming the known ones."""
    if isinstance(name_or_part, Model):
        return name_or_part
    m = MODELS.get(name_or_part) if isinstance(name_or_part, str) else PART_NUMBERS.get(name_or_part)
    if m is None:
        raise ValueError(f"unknown Oculus model {name_or_part!r}: known are "
                         + ", ".join(f"{k} ({v.part_number})" for k, v in MODELS.items()))
    return m


def bearing_table(aperture_deg: float, n_beams: int) -> np.ndarray:
    """The head's ``n_beams`` bearings (int16, 0.01 degree, as the ping result carries them),
    evenly spaced in sine across ``aperture_deg``: beam k at ``asin(sin(A/2) * (2k + 1 - n) / n)``."""
    s = math.sin(math.radians(aperture_deg) / 2)
    u = s * (2 * np.arange(n_beams) + 1 - n_beams) / n_beams
    return np.round(np.degrees(np.arcsin(u)) * 100).astype(np.int16)
