"""The echo sounders' published figures: two bathymetric multibeams (MBES) and an altimeter
(`EchoSounder`, `PRESETS`, `preset`); `mitsonar.scenes.echosounders` makes ``sonar`` sensors of them.

Published figures (frequency, beam count, beam widths, swath), and where they come from:

``r2sonic_2024``  R2Sonic Sonic 2024: 200 to 400 kHz selectable, 256 beams over a selectable
                  sector of 10 to 160 deg (R2Sonic, "Sonic 2024/2022 Broadband Multibeam
                  Echosounders, Operation Manual" V5.0, 2014, section 1.1, checked); beam widths
                  0.5 deg across x 1 deg along at 400 kHz (R2Sonic Sonic 2024 data sheet).
``kongsberg_em2040``  Kongsberg EM 2040: 200 to 400 kHz, modular beam widths 0.5 x 1 deg or
                  1 x 1 deg (transmit along x receive across; Kongsberg Maritime, "EM 2040
                  multibeam echo sounder" product leaflet, checked); 400 soundings per ping
                  (single swath) and a 140 deg swath for one receiver (Kongsberg EM 2040
                  data sheet).
``tritech_pa500`` Tritech PA500 altimeter: 500 kHz, 6 deg conical beam, 0.1 to 50 m, 1 mm
                  resolution (Tritech PA500 data sheet).

Source levels (``source_level``, dB re 1 uPa at 1 m) are typical values, not found in the sheets
cited above: 215 dB for the two multibeams (high-frequency MBES: 200..230 dB, Lurton, *An
Introduction to Underwater Acoustics*, 2nd ed. 2010, sec. 8.3), 205 dB for the altimeter. Each
preset's ``receiver_sensitivity`` is ``52 - source_level`` (the shared A/D calibration, so the
bytes are as before levels had units) and its ``noise_level`` the ambient noise at its frequency
(`mitsonar.sonar_equation.ambient_noise_level`, wind 5 m/s, rounded).

Figures marked "data sheet" are as the makers publish them but were not re-checked against the
sheet for this module.
"""
from __future__ import annotations

import dataclasses

from mitsonar._checks import not_allowed
from mitsonar.kinds import MECHANICAL, MULTIBEAM, SonarKind

__all__ = ["EchoSounder", "PRESETS", "preset"]

WHERE = "echosounder"


@dataclasses.dataclass(frozen=True)
class EchoSounder:
    """One echo sounder's published figures (angles in degrees, lengths in metres)."""

    name: str
    model: str
    kind: SonarKind        # MULTIBEAM (an MBES) or MECHANICAL, one fixed ping (an altimeter)
    frequency: float       # Hz
    n_beams: int
    rx_across: float       # receive beam width across track (altimeter: the cone's width)
    tx_along: float        # transmit width along track (altimeter: the cone's width)
    swath: float           # default angle between the outermost beams' centres (altimeter: 0)
    swath_range: tuple     # (smallest, widest) swath the head allows
    range_max: float       # default end of the range window
    bin_width: float       # range bin (a simulation choice, see the module docstring)
    source: str
    source_level: float = 215.0    # dB re 1 uPa at 1 m (typical: see the module docstring)
    noise_level: float = 37.0      # dB re 1 uPa^2/Hz, ambient at the frequency


PRESETS = {
    "r2sonic_2024": EchoSounder(
        "r2sonic_2024", "R2Sonic Sonic 2024", MULTIBEAM, 400e3, 256, 0.5, 1.0, 130.0, (10.0, 160.0),
        40.0, 0.0125, "R2Sonic Sonic 2024/2022 Operation Manual V5.0 (2014) sec. 1.1; Sonic 2024 data sheet"),
    "kongsberg_em2040": EchoSounder(
        "kongsberg_em2040", "Kongsberg EM 2040", MULTIBEAM, 400e3, 400, 1.0, 0.5, 140.0, (10.0, 140.0),
        40.0, 0.0125, "Kongsberg Maritime EM 2040 product leaflet; EM 2040 data sheet"),
    "tritech_pa500": EchoSounder(
        "tritech_pa500", "Tritech PA500 altimeter", MECHANICAL, 500e3, 1, 6.0, 6.0, 0.0, (0.0, 0.0),
        50.0, 0.001, "Tritech PA500 data sheet", source_level=205.0, noise_level=39.0),
}


def preset(name) -> EchoSounder:
    """The `EchoSounder` called ``name`` (a key of `PRESETS`), or one line naming the choices."""
    if isinstance(name, EchoSounder):
        return name
    if name not in PRESETS:
        raise not_allowed(WHERE, "preset", name, "one of " + ", ".join(sorted(PRESETS)))
    return PRESETS[name]
