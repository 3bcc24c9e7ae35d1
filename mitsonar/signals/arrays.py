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

#: m: elements closer than this are the same element (overlapping).
MIN_SEPARATION = 1e-6


def check_elements(elements, source="render_echoes") -> np.ndarray:
    """float64 (n, 3) element positions, or a ValueError naming ``source``'s ``elements`` in one line:
    a finite (n, 3) array of n >= 1 positions in m, no two within `MIN_SEPARATION`."""
    try:
        e = np.asarray(elements, dtype=np.float64)
    except (TypeError, ValueError):
        raise ValueError(f"{source} 'elements': not an array of numbers (allowed: an (n, 3) array of positions "
                         "in m in the beam frame)") from None
    if e.ndim != 2 or e.shape[1] != 3 or len(e) < 1:
        raise ValueError(f"{source} 'elements': shape {e.shape} is not allowed (an (n, 3) array of n >= 1 "
                         "positions in m in the beam frame)")
    bad = ~np.isfinite(e).all(axis=1)
    if bad.any():
        raise ValueError(f"{source} 'elements': element {int(np.argmax(bad))} is {e[bad][0].tolist()} (allowed: "
                         "finite positions in m)")
    if len(e) > 1:
        d = np.linalg.norm(e[:, None, :] - e[None, :, :], axis=2) + np.eye(len(e)) * 1e9
        if d.min() < MIN_SEPARATION:
            i, j = np.unravel_index(int(np.argmin(d)), d.shape)
            raise ValueError(f"{source} 'elements': elements {min(i, j)} and {max(i, j)} overlap at "
                             f"{e[i].tolist()} (allowed: positions at least {MIN_SEPARATION:g} m apart)")
    return e


def read_elements(path, source=None) -> np.ndarray:
    """Element positions from a CSV of ``x,y,z`` rows in m (a header line without numbers is skipped),
    checked by `check_elements`."""
    import csv

    source = source or str(path)
    rows = []
    with open(path, newline="") as fh:
        for n, row in enumerate(csv.reader(fh)):
            cells = [c.strip() for c in row if c.strip()]
            if not cells or cells[0].startswith("#"):
                continue
            try:
                rows.append([float(c) for c in cells])
            except ValueError:
                if n == 0 and not rows:
                    continue   # a header
                raise ValueError(f"{source}: line {n + 1} {row!r} is not allowed (x,y,z in m)") from None
    return check_elements(rows, source)


def line_array(n=64, spacing=None, frequency=700e3, sound_speed=1500.0) -> np.ndarray:
    """(n, 3): a uniform line array along +x centred on the origin (module docstring)."""
    d = 0.5 * sound_speed / frequency if spacing is None else float(spacing)
    x = (np.arange(int(n)) - 0.5 * (int(n) - 1)) * d
    return check_elements(np.stack([x, np.zeros_like(x), np.zeros_like(x)], axis=1), "line_array")


def interferometer(n=2, spacing=None, frequency=700e3, sound_speed=1500.0) -> np.ndarray:
    """(n, 3): ``n`` elements along +y from the origin (module docstring); default spacing half a
    wavelength (unambiguous angles)."""
    d = 0.5 * sound_speed / frequency if spacing is None else float(spacing)
    y = np.arange(int(n)) * d
    return check_elements(np.stack([np.zeros_like(y), y, np.zeros_like(y)], axis=1), "interferometer")


def wavelength(frequency, sound_speed=1500.0) -> float:
    return float(sound_speed) / float(frequency)


__all__ = ["MIN_SEPARATION", "check_elements", "interferometer", "line_array", "read_elements", "wavelength"]
