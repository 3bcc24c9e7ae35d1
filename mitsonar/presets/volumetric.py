"""3D sonars' published figures, by name: the keyword arguments of
`mitsonar.signals.volumetric.Volumetric` (which makes `mitsonar.signals.volumetric.PRESETS` of them).

``echoscope``: the Coda Octopus Echoscope, a field of view of 50 x 50 deg in 128 x 128 beams (16384;
up to 12 pings a second: QPS, Qinsy driver notes "CodaOctopus Echoscope", quoting the maker), to 120 m. Its carrier (375 kHz, the
maker's standard model, not checked against a data sheet here), its array (48 x 48 elements at
half a wavelength: 2.1 deg beams at broadside, which the 0.4 deg beam spacing oversamples) and
its 10 % band are this preset's assumptions.

``sonar3d15_navigation`` and ``sonar3d15_inspection``: the Water Linked Sonar 3D-15's two modes, as
the maker's documentation publishes them (docs.waterlinked.com, "Sonar 3D-15" specifications and
"Integration API Sonar 3D-15"): navigation 1.2 MHz, 90 x 40 deg, 0.2 to 15 m, range resolution 4 mm,
angular resolution 0.6 deg (H) x 2.4 deg (V), 5 Hz; inspection 2.4 MHz, 40 x 40 deg, 0.2 to 4 m,
1.5 mm, 0.4 x 1.1 deg, 20 Hz; both 256 x 64 beams (the range image's width x height; beam
separation 0.35 / 0.16 deg by 0.6 deg) and 1491 m/s (the head's default sound speed). Derived here:
the band ``c / (2 resolution)`` (the compressed pulse's cell, `mitsonar.signals.pulses.Pulse.range_resolution`)
and the bins, one per range resolution cell. Assumed here (the maker publishes no array): a filled
array at half a wavelength whose 0.886 lambda / (N d) widths (`mitsonar.signals.volumetric.Volumetric.beamwidths`) are the published
angular resolutions, N = 0.886 / (0.5 resolution in rad), rounded.
"""
from __future__ import annotations

import math

__all__ = ["FIGURES"]

_WL_C = 1491.0


def _sonar3d15(frequency, fov_azimuth, range_max, resolution, res_h, res_v):
    n = lambda res: int(round(0.886 / (0.5 * math.radians(res))))  # noqa: E731
    return dict(rows=n(res_v), columns=n(res_h), frequency=frequency, bandwidth=_WL_C / (2.0 * resolution),
                n_azimuth=256, n_elevation=64, fov_azimuth=fov_azimuth, fov_elevation=40.0,
                range_max=range_max, n_bins=int(round((range_max - 0.2) / resolution)), sound_speed=_WL_C,
                range_min=0.2)


#: name -> `Volumetric` keyword arguments
FIGURES = {
    "echoscope": dict(rows=48, columns=48, frequency=375e3, bandwidth=37.5e3, n_azimuth=128,
                      n_elevation=128, fov_azimuth=50.0, fov_elevation=50.0, range_max=120.0, n_bins=1000),
    "sonar3d15_navigation": _sonar3d15(1.2e6, 90.0, 15.0, 0.004, 0.6, 2.4),
    "sonar3d15_inspection": _sonar3d15(2.4e6, 40.0, 4.0, 0.0015, 0.4, 1.1),
}
