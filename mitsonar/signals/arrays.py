"""Element layouts: checks and presets (positions in the sensor's beam frame, +z boresight).

Presets:

* `line_array`: a forward-looking uniform line array, ``n`` elements along the beam frame's +x
  (the axis the bearings turn towards, so the receive beams of a multibeam head are formed across
  it) at spacing ``spacing`` (default half a wavelength of ``frequency`` at ``sound_speed``), centred
  on the transmitter;
* `interferometer`: an interferometric side-scan's rows, ``n`` elements stacked along the beam
  frame's +y (a side-scan channel's across-track fan) at ``spacing``, the first at the origin.
"""
from __future__ import annotations

import numpy as np

from mitsonar.acoustics.water import SOUND_SPEED
from mitsonar.geometry.elements import MIN_SEPARATION, check_elements, read_elements


def line_array(n=64, spacing=None, frequency=700e3, sound_speed=SOUND_SPEED) -> np.ndarray:
    """(n, 3): a uniform line array along +x centred on the origin (module docstring)."""
    d = 0.5 * sound_speed / frequency if spacing is None else float(spacing)
    x = (np.arange(int(n)) - 0.5 * (int(n) - 1)) * d
    return check_elements(np.stack([x, np.zeros_like(x), np.zeros_like(x)], axis=1), "line_array")


def interferometer(n=2, spacing=None, frequency=700e3, sound_speed=SOUND_SPEED) -> np.ndarray:
    """(n, 3): ``n`` elements along +y from the origin (module docstring); default spacing half a
    wavelength (unambiguous angles)."""
    d = 0.5 * sound_speed / frequency if spacing is None else float(spacing)
    y = np.arange(int(n)) * d
    return check_elements(np.stack([np.zeros_like(y), y, np.zeros_like(y)], axis=1), "interferometer")


def wavelength(frequency, sound_speed=SOUND_SPEED) -> float:
    return float(sound_speed) / float(frequency)


__all__ = ["MIN_SEPARATION", "check_elements", "interferometer", "line_array", "read_elements", "wavelength"]
