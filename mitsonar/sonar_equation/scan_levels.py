"""The levels of a `Scan` in physical units: functions of the scan's data and recorded settings.

A `Scan` is data (`mitsonar.scan`); what the sonar equation says of it is computed here, from its
``intensity``, ``ranges``, ``sound_speed``, beam fields, ``electronics`` (defaults where a setting
is absent: `mitsonar.receiver.electronics.Electronics`) and ``meta``:

* `scan_echo_level`: the noise-free echo level at the receiver, dB re 1 uPa, per bin;
* `directivity_index`: the receive beam's DI, dB (recorded by `render_scan`, else computed from
  the beam pattern, which starts Mitsuba);
* `snr`: ``echo level - (NL + 10 log10 B - DI)`` per bin (Urick 1983, eq. 2.2);
* `scan_levels`: all of them, and the noise in band, at once (`ScanLevels`).
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from mitsonar.acoustics.levels import noise_band_level as _noise_band_level
from mitsonar.scan.electronics import ElectronicsSettings
from mitsonar.scan.meta import ScanFieldError, ScanMeta

_WHERE = "Scan 'electronics'"


def receiver_of(scan):
    """The receiver of the scan's recorded settings (a dict's too), defaults where absent."""
    from mitsonar.receiver.electronics import Electronics

    return Electronics.from_dict(ElectronicsSettings.from_dict(scan.electronics).to_dict(), _WHERE)


def scan_echo_level(scan) -> np.ndarray:
    """float32 (n_pings, n_bins): the noise-free echo level at the receiver, dB re 1 uPa, per bin
    (``-inf`` where no echo): ``source_level + 10 log10`` of ``scan.intensity`` convolved with the
    transmit pulse as a boxcar of ones over ``c pulse_length / 2``, the source level and pulse
    from ``scan.electronics`` (defaults where absent; `Electronics.echo_level`). It always agrees
    with the saved intensity and settings."""
    return receiver_of(scan).echo_level(scan.intensity, scan.ranges, scan.sound_speed)


def directivity_index(scan) -> float:
    """dB, the receive beam's ``10 log10(4 pi / Int B)``: recorded by `render_scan` in
    ``scan.meta.directivity_index``, else computed from ``scan.beam_pattern`` and its widths (and
    ``meta.frequency``, ``meta.aperture_h`` for ``sinc``), which starts Mitsuba. A measured
    (``table``) pattern's is only the recorded one: a `ScanFieldError` without it."""
    meta = ScanMeta.from_dict(scan.meta)
    if meta.directivity_index is not None:
        return float(meta.directivity_index)
    from mitsonar.sim.variant import ensure_variant

    ensure_variant()
    from mitsonar.plugins.sensors import beam as patterns

    shape = patterns.lookup(scan.beam_pattern)
    if shape is not None and shape.measured:
        raise ScanFieldError("meta", f"a {shape.name!r} beam pattern's directivity_index is not recorded")
    own = shape is not None and shape.apertures     # the pattern reads the recorded aperture
    beam = patterns.BeamPattern(scan.beam_pattern, scan.beamwidth_h, scan.beamwidth_v,
                                float(700e3 if meta.frequency is None else meta.frequency),
                                float(meta.aperture_h) if own and meta.aperture_h is not None else None,
                                None, scan.sound_speed)
    return beam.directivity_index()


@dataclass(frozen=True)
class ScanLevels:
    """The sonar equation's terms of one scan (`scan_levels`): ``echo_level`` and ``snr`` float32
    (n_pings, n_bins) dB (``-inf`` where no echo), ``directivity_index`` dB and
    ``noise_band_level`` dB re 1 uPa (``NL + 10 log10 B - DI``, ``noise_level`` and
    ``receiver_bandwidth`` from the electronics)."""

    echo_level: np.ndarray
    directivity_index: float
    noise_band_level: float
    snr: np.ndarray


def scan_levels(scan) -> ScanLevels:
    """Echo level, directivity index, noise in band and SNR of ``scan`` (see `ScanLevels`)."""
    e = receiver_of(scan)
    di = directivity_index(scan)
    noise = _noise_band_level(e.noise_level, e.noise_bandwidth(scan.bin_width, scan.sound_speed), di)
    el = e.echo_level(scan.intensity, scan.ranges, scan.sound_speed)
    return ScanLevels(echo_level=el, directivity_index=di, noise_band_level=noise,
                      snr=(el - np.float32(noise)).astype(np.float32))


def snr(scan) -> np.ndarray:
    """float32 (n_pings, n_bins), dB: ``echo_level - (NL + 10 log10 B - DI)`` per bin (the active
    sonar equation's signal-to-noise ratio, Urick 1983, eq. 2.2); ``-inf`` where no echo."""
    return scan_levels(scan).snr
