"""Presets of commercial side-scan heads for the ``sonar`` sensor's ``preset`` (``kind='sidescan'``).

Each preset sets the defaults of ``frequency``, ``beam_pattern`` (``sinc``: a rectangular piston
whose apertures give the published -3 dB widths at the published frequency), ``beamwidth_h``
(along track), ``beamwidth_v`` (across-track fan), ``range_max`` (the longest range scale per
side) and ``depression`` (the tilt of the transducers below the horizontal); any of them given in
the XML overrides the preset.

Published values (manufacturers' datasheets):

* **Klein System 3000** (Klein Associates / L-3 Klein, "System 3000 Digital Side Scan Sonar"
  datasheet): dual frequency 100 kHz and 500 kHz; horizontal beam 1 deg at 100 kHz and 0.2 deg
  at 500 kHz; vertical beam 40 deg; transducer tilt 5 to 25 deg in 5 deg steps (presets: 10 deg);
  range scales up to 600 m (100 kHz) and 150 m (500 kHz) per side.
  Presets ``klein3000_100k`` and ``klein3000_500k``.
* **Tritech StarFish 450** (Tritech / Blueview StarFish, "What is a side scan sonar?",
  starfishsonar.com support pages, checked): 450 kHz CHIRP (425-475 kHz); the two transducers
  in the lower fins are angled 30 deg down from the horizontal and transmit a fan 2 deg wide
  (along track) by 100 deg vertically, "most of the acoustic energy confined to the centre
  60 deg" (the preset's -3 dB across-track width); maximum range 100 m per side (product sheet).
  Preset ``starfish450``, its ``bandwidth`` the published CHIRP band, 50 kHz.

The transducers' band (``bandwidth``): published for the StarFish (above); Klein's sheet gives none,
so the Klein presets take the sensor's rule, ``frequency / DEFAULT_Q`` (``sonar_sensor.DEFAULT_Q`` of the plugins).

Source levels (``source_level``, dB re 1 uPa at 1 m): neither Klein's System 3000 sheet nor
Tritech's StarFish pages at hand publish one, so the presets take typical values, stated here:
220 dB (Klein, 100 kHz), 215 dB (Klein, 500 kHz), 205 dB (StarFish 450, a small low-power head);
towed side-scan heads lie in 200..230 dB (Lurton, *An Introduction to Underwater Acoustics*, 2nd
ed. 2010, sec. 8.2). ``receiver_sensitivity`` is ``52 - source_level`` so that the bytes are
those of the shared A/D calibration (as before levels had units), and ``noise_level`` is the
ambient noise at the preset's frequency (`mitsonar.sonar_equation.ambient_noise_level`, wind
5 m/s, rounded).

The Klein figures and the StarFish's range are the datasheets' as recalled at the time of
writing; check them against the current datasheet before relying on a preset for a procurement
or a survey plan.
"""
from __future__ import annotations

__all__ = ["PRESETS"]

#: preset name -> the ``sonar`` sensor's defaults it sets (kind ``sidescan``)
PRESETS = {
    "klein3000_100k": dict(frequency=100e3, beam_pattern="sinc", beamwidth_h=1.0, beamwidth_v=40.0,
                           range_max=600.0, depression=10.0,
                           source_level=220.0, receiver_sensitivity=-168.0, noise_level=29.0),
    "klein3000_500k": dict(frequency=500e3, beam_pattern="sinc", beamwidth_h=0.2, beamwidth_v=40.0,
                           range_max=150.0, depression=10.0,
                           source_level=215.0, receiver_sensitivity=-163.0, noise_level=39.0),
    "starfish450": dict(frequency=450e3, beam_pattern="sinc", beamwidth_h=2.0, beamwidth_v=60.0,
                        range_max=100.0, depression=30.0, bandwidth=50e3,
                        source_level=205.0, receiver_sensitivity=-153.0, noise_level=38.0),
}
