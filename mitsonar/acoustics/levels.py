"""Acoustic levels in physical units: the terms of the active sonar equation, as plain numbers.

``EL = SL - TL + TS`` (a target) or ``SL - TL + S_b + 10 log10 A`` (a seabed), with the two-way
transmission loss ``TL = 40 log10 r + 2 alpha r``, and ``SNR = EL - (NL + 10 log10 B - DI)``
(Urick, *Principles of Underwater Sound*, 3rd ed. 1983, eqs. 2.1 and 2.2; Lurton, *An
Introduction to Underwater Acoustics*, 2nd ed. 2010, sec. 3.1). Levels are dB re 1 uPa (source
level: at 1 m on axis), noise spectrum levels dB re 1 uPa^2/Hz.

A scan's ``intensity`` is normalised to an on-axis source of 1 W/sr and a 1 m^2 receive aperture
(DESIGN.md "Units of scan.intensity"): a point echo of backscattering cross-section sigma (m^2,
``TS = 10 log10 sigma``) at range r on the axis holds ``sigma r^-4 10^(-2 alpha r / 10)``, so
``SL + 10 log10(intensity)`` is its echo level. This module imports nothing from mitsonar but the
migrations' `CALIBRATION_UNTIL` (the electronics build on it). The levels of a `Scan` (echo level, directivity index, SNR) are
`mitsonar.sonar_equation.scan_levels`; the migrations of old files' settings are
`mitsonar.scan.migrations`.
"""
from __future__ import annotations

import math

import numpy as np

from mitsonar.scan.migrations import CALIBRATION_UNTIL  # the release whose source_level was the constant

#: Source levels a head may be given, dB re 1 uPa at 1 m (real heads: 180..230).
SOURCE_LEVELS = (150.0, 260.0)
#: Micron defaults. Tritech does not publish the Micron's source level: 200 dB re 1 uPa at 1 m is
#: typical of a small 700 kHz imaging head (Urick 1983, sec. 4.3: ``SL = 170.8 + 10 log10 P + DI``,
#: about 1 W acoustic into the 3 x 35 deg beam's DI of 26 dB gives 197 dB).
DEFAULT_SOURCE_LEVEL = 200.0
#: The calibration constant of mitsonar up to `CALIBRATION_UNTIL` (``source_level`` then): SL + sensitivity.
CALIBRATION_DB = 52.0
#: dB: the receiver's response referred to the A/D's dB scale (an equivalent constant: the A/D
#: level of a 0 dB re 1 uPa echo after the head's fixed gains), chosen so that SL + sensitivity
#: is `CALIBRATION_DB` and the default bytes stay those the Micron statistics were fitted with.
DEFAULT_RECEIVER_SENSITIVITY = CALIBRATION_DB - DEFAULT_SOURCE_LEVEL
#: dB re 1 uPa^2/Hz at 700 kHz: ``ambient_noise_level(700e3)`` (thermal noise dominates there),
#: rounded; the Micron's self noise is not published, so the receiver is taken as ambient-limited.
DEFAULT_NOISE_LEVEL = 42.0


def source_level_error(source: str, value) -> str:
    """The one line refusing a ``source_level`` outside `SOURCE_LEVELS` (most likely an old
    calibration constant such as 52)."""
    return (f"{source} 'source_level': {value:g} dB is not allowed: it is the head's source level in dB re "
            f"1 uPa at 1 m ({SOURCE_LEVELS[0]:g}..{SOURCE_LEVELS[1]:g}; real heads 180..230); the calibration "
            f"constant it was up to mitsonar {CALIBRATION_UNTIL} is now source_level + receiver_sensitivity "
            f"(e.g. source_level={DEFAULT_SOURCE_LEVEL:g}, receiver_sensitivity={value - DEFAULT_SOURCE_LEVEL:g})")


def pulse_boxcar(length: float, bin_width: float) -> np.ndarray:
    """Weights of a boxcar of ones over ``[0, length)`` (m) on bins of ``bin_width`` centred on
    offsets 0, 1, ...: offset k's weight is the fraction of bin ``[(k - 1/2), (k + 1/2)) bin_width``
    the boxcar covers. An echo at a bin centre keeps weight 1 on the bins the pulse fills."""
    if not length > 0 or not bin_width > 0:
        return np.ones(1)
    m = int(math.ceil(length / bin_width + 0.5))
    lo = (np.arange(m + 1) - 0.5) * bin_width
    w = np.clip(np.minimum(lo + bin_width, length) - np.maximum(lo, 0.0), 0.0, None) / bin_width
    return np.trim_zeros(w, "b")


def echo_level(intensity, ranges, source_level: float, pulse_length: float, sound_speed: float) -> np.ndarray:
    """dB re 1 uPa per bin: ``SL + 10 log10`` of the histogram convolved along range with the
    pulse as a boxcar of ones over ``c pulse_length / 2`` (`pulse_boxcar`; echoes pushed past the
    last bin are dropped), so a bin's value is the echo's mean-square pressure over it. A
    ``pulse_length`` of 0 (or a single bin) counts as filling one bin. float32, ``-inf`` where no
    echo."""
    inten = np.array(intensity, dtype=np.float64, ndmin=2)
    r = np.asarray(ranges, dtype=np.float64)
    width = float((r[-1] - r[0]) / (r.size - 1)) if r.size > 1 else 0.0
    w = pulse_boxcar(sound_speed * pulse_length / 2.0, width)
    n = inten.shape[-1]
    out = np.zeros_like(inten)
    for k, wk in enumerate(w[:n]):
        if wk > 0:
            out[..., k:] += wk * inten[..., :n - k]
    with np.errstate(divide="ignore"):
        level = (10.0 * np.log10(out) + source_level).astype(np.float32)
    return level[0] if np.ndim(intensity) == 1 else level


def two_way_transmission_loss(ranges, absorption: float = 0.0) -> np.ndarray:
    """dB, two-way: ``40 log10 r + 2 alpha r`` (spherical spreading out and back, Urick 1983,
    eq. 5.3, with absorption ``alpha`` in dB/m over both legs). In refracting water, the one-way
    loss along the eigenrays is `mitsonar.acoustics.transmission_loss`."""
    r = np.asarray(ranges, dtype=np.float64)
    with np.errstate(divide="ignore"):
        return 40.0 * np.log10(r) + 2.0 * absorption * r


def transmission_loss(ranges, absorption: float = 0.0) -> np.ndarray:
    """Deprecated name of `two_way_transmission_loss` (the same two-way loss, with a
    DeprecationWarning): "transmission loss" is one way in the literature, as
    `mitsonar.acoustics.transmission_loss` is."""
    import warnings

    warnings.warn("mitsonar.sonar_equation.transmission_loss is the two-way loss and is renamed "
                  "two_way_transmission_loss; the one-way loss in refracting water is "
                  "mitsonar.acoustics.transmission_loss", DeprecationWarning, stacklevel=2)
    return two_way_transmission_loss(ranges, absorption)


def ambient_noise_level(frequency, wind_speed: float = 5.0, shipping: float = 0.5) -> np.ndarray:
    """dB re 1 uPa^2/Hz: the ocean's ambient noise spectrum level at ``frequency`` (Hz), the sum
    of the empirical turbulence, shipping, wind (Wenz curves) and thermal terms of Coates (1990)
    as given by Stojanovic (2007, "On the relationship between capacity and distance in an
    underwater acoustic communication channel", ACM MC2R 11(4), eq. 7), f in kHz:
    ``17 - 30 log f``; ``40 + 20 (s - 0.5) + 26 log f - 60 log(f + 0.03)``;
    ``50 + 7.5 w^0.5 + 20 log f - 40 log(f + 0.4)``; ``-15 + 20 log f`` (thermal, Mellen 1952).
    Above about 100 kHz the thermal term dominates: 41.9 dB at 700 kHz."""
    f = np.asarray(frequency, dtype=np.float64) / 1e3
    if np.any(f <= 0) or not (math.isfinite(wind_speed) and wind_speed >= 0) or not 0 <= shipping <= 1:
        raise ValueError("ambient_noise_level: frequency > 0 Hz, wind_speed >= 0 m/s, shipping in [0, 1]")
    lf = np.log10(f)
    terms = (17.0 - 30.0 * lf,
             40.0 + 20.0 * (shipping - 0.5) + 26.0 * lf - 60.0 * np.log10(f + 0.03),
             50.0 + 7.5 * math.sqrt(wind_speed) + 20.0 * lf - 40.0 * np.log10(f + 0.4),
             -15.0 + 20.0 * lf)
    return 10.0 * np.log10(sum(10.0 ** (t / 10.0) for t in terms))


def noise_band_level(noise_level: float, bandwidth: float, directivity_index: float) -> float:
    """dB re 1 uPa: the noise an echo competes with at the receiver's output,
    ``NL + 10 log10 B - DI`` (Urick 1983, eq. 2.2)."""
    return float(noise_level + 10.0 * math.log10(bandwidth) - directivity_index)


def phong_sphere_cross_section(radius: float, specular: float = 1.0, shininess: float = 1e4) -> float:
    """m^2: the backscattering cross-section of a sphere of ``radius`` whose surface has the
    ``acoustic`` BSDF's Phong lobe ``specular (n + 2) / (2 pi) cos^n(alpha)`` (monostatic, far
    field): ``s a^2 (n + 2) Int_0^(pi/4) cos^n(2 t) cos^2 t sin t dt`` (t the incidence angle on the
    sphere; the mirror direction is 2t off the backward one). As n grows it tends to the geometric
    (mirror) sphere's ``a^2 / 4`` (TS = 20 log10(a / 2); Urick 1983, Table 9.1)."""
    n = float(shininess)
    # Gauss-Legendre over [0, min(pi/4, 8 / sqrt(n + 1))]: cos^n(2t) is below exp(-128) beyond.
    width = min(math.pi / 4, 8.0 / math.sqrt(n + 1.0))
    x, w = np.polynomial.legendre.leggauss(400)
    t = 0.5 * width * (x + 1.0)
    f = np.cos(2 * t) ** n * np.cos(t) ** 2 * np.sin(t)
    integral = 0.5 * width * float(np.sum(w * f))
    return specular * radius ** 2 * (n + 2.0) * integral
