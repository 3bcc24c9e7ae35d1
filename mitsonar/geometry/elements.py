"""Receive-element layouts of a sonar head: checks and the CSV reader (numpy only).

Positions are in metres in the sensor's beam frame (+z boresight, the frame of ``to_world``). The
``sonar`` sensor reads its XML ``elements`` CSV with `read_elements` when the scene loads (a leaf
below the plugins, like `mitsonar.geometry.frames`); `mitsonar.signals.arrays` re-exports both and
adds the presets.
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
    """Element positions from a CSV of ``x,y,z`` rows in m (a header line without numbers is skipped,
    and lines starting with ``#``), checked by `check_elements`."""
    import csv

    source = source or str(path)
    rows = []
    try:
        with open(path, newline="", encoding="utf-8-sig") as fh:
            lines = list(csv.reader(fh))
    except (OSError, UnicodeDecodeError) as exc:
        raise ValueError(f"{source}: cannot read the elements CSV ({getattr(exc, 'strerror', None) or exc})") from None
    for n, row in enumerate(lines):
        cells = [c.strip() for c in row if c.strip()]
        if not cells or cells[0].startswith("#"):
            continue
        try:
            rows.append([float(c) for c in cells])
        except ValueError:
            if not rows and all(not _number(c) for c in cells):
                continue   # a header
            raise ValueError(f"{source}: line {n + 1} {row!r} is not allowed (x,y,z in m)") from None
        if len(rows[-1]) != 3:
            raise ValueError(f"{source}: line {n + 1} {row!r} is not allowed (x,y,z in m: three numbers)")
    if not rows:
        raise ValueError(f"{source}: no element (allowed: rows of x,y,z in m)")
    return check_elements(rows, source)


def _number(cell) -> bool:
    try:
        float(cell)
    except ValueError:
        return False
    return True


__all__ = ["MIN_SEPARATION", "check_elements", "read_elements"]
