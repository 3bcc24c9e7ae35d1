"""Coherent sonar signals: pulses, element data and their processing.

``cw``/``lfm`` make a `Pulse`; `mitsonar.render_echoes` renders the complex baseband pressure at
each receive element of a head (`Echoes`); `matched_filter`, `delay_and_sum`, `beamform`,
`arrival_angle` and `sidescan_bathymetry` process it; `PointTarget` is an isotropic, deterministic
point scatterer of a given target strength (calibration targets, closed-form checks);
`Volumetric`, `beamform_3d` and `point_cloud` make a 3D imaging sonar's volume and point cloud from a
planar array's echoes (`mitsonar.signals.volumetric`). Which to use when, coherent or incoherent:
`mitsonar.signals.processing`. The pulses and the processing are numpy only; the renderer loads
Mitsuba on first use.
"""
from __future__ import annotations

from mitsonar.signals.arrays import check_elements, interferometer, line_array, read_elements
from mitsonar.signals.processing import (arrival_angle, compressed_autocorrelation, delay_and_sum,
                                         equivalent_duration, expected_power, look_directions, matched_filter,
                                         phase_difference)
from mitsonar.signals.pulses import Pulse, cw, lfm
from mitsonar.signals.synthesis import synthesize
from mitsonar.signals.targets import PointTarget

_LAZY = {"Echoes": "echoes", "render_echoes": "echoes", "beamform": "products",
         "sidescan_bathymetry": "products", "beamform_3d": "volumetric", "point_cloud": "volumetric",
         "Volumetric": "volumetric"}


def __getattr__(name):
    if name in _LAZY:
        import importlib

        return getattr(importlib.import_module(f"mitsonar.signals.{_LAZY[name]}"), name)
    raise AttributeError(f"module 'mitsonar.signals' has no attribute {name!r}")


__all__ = ["Pulse", "cw", "lfm", "matched_filter", "compressed_autocorrelation", "equivalent_duration",
           "expected_power", "look_directions", "delay_and_sum", "phase_difference", "arrival_angle",
           "synthesize", "PointTarget", "check_elements", "read_elements", "line_array", "interferometer", *_LAZY]
