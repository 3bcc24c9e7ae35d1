"""Input checks shared by the acoustics modules: one line naming the function, the field and the range.

NumPy only; nothing from mitsonar, so every acoustics module may use it.
"""
from __future__ import annotations

import numpy as np


class ProfileError(ValueError):
    """A sound-speed profile (or a propagation request) that is not allowed: one line naming the
    file (or the call), the row (or sample) and the field. (`mitsonar.acoustics.ProfileError`;
    defined here so that `mitsonar.acoustics.propagation` need not import the profile module.)"""


def as_array(func: str, field: str, value) -> np.ndarray:
    """``value`` as a float array, or a ValueError naming ``func`` and ``field``."""
    try:
        arr = np.asarray(value, dtype=float)
    except (TypeError, ValueError):
        raise ValueError(f"{func}: {field} {value!r} is not a number (or an array of numbers)") from None
    return arr


def in_range(func: str, field: str, value, lo: float, hi: float, unit: str, source: str) -> np.ndarray:
    """``value`` as a float array, refused unless every element is finite and in ``[lo, hi]``.

    The message names the first offending element, e.g.
    ``sound_speed: temperature 35 deg C is outside Mackenzie (1981)'s -2 to 30 deg C``.
    """
    arr = as_array(func, field, value)
    u = f" {unit}" if unit else ""
    finite = np.isfinite(arr)
    if not finite.all():
        bad = arr[~finite].flat[0]
        raise ValueError(f"{func}: {field} {bad} is not a finite number ({source}'s {lo:g} to {hi:g}{u})")
    outside = (arr < lo) | (arr > hi)
    if outside.any():
        bad = arr[outside].flat[0]
        raise ValueError(f"{func}: {field} {bad:g}{u} is outside {source}'s {lo:g} to {hi:g}{u}")
    return arr


def at_least(func: str, field: str, value, lo: float, unit: str, strict: bool = False) -> np.ndarray:
    """``value`` as a float array, refused unless finite and ``>= lo`` (``> lo`` when ``strict``)."""
    arr = as_array(func, field, value)
    finite = np.isfinite(arr)
    if not finite.all():
        raise ValueError(f"{func}: {field} {arr[~finite].flat[0]} is not a finite number")
    low = arr <= lo if strict else arr < lo
    if low.any():
        rel = ">" if strict else ">="
        raise ValueError(f"{func}: {field} {arr[low].flat[0]:g}{' ' + unit if unit else ''} is not allowed "
                         f"(a value {rel} {lo:g}{' ' + unit if unit else ''})")
    return arr


def grazing_angle(func: str, value) -> np.ndarray:
    """Grazing angles in radians, refused outside ``[0, pi/2]`` (a hair of rounding allowed at pi/2)."""
    arr = as_array(func, "grazing", value)
    finite = np.isfinite(arr)
    if not finite.all():
        raise ValueError(f"{func}: grazing {arr[~finite].flat[0]} is not a finite angle (0 to pi/2 rad)")
    outside = (arr < 0.0) | (arr > np.pi / 2 + 1e-12)
    if outside.any():
        raise ValueError(f"{func}: grazing {arr[outside].flat[0]:g} rad is outside 0 to pi/2 rad "
                         f"(radians, measured from the interface)")
    return np.minimum(arr, np.pi / 2)
