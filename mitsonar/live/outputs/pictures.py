"""The sonar picture of a live head, as Foxglove and ROS 2 viewers show it: the fan seen as
`mitsonar.export.ros.messages.fan_pixels` draws it (seen from above: the boresight up the
picture, positive bearings counter-clockwise, bearing ``b`` at ``atan2(-x, y_up) = b`` with
``x`` to the right), so that a live session, an exported bag and `mitsonar.products.plots`
look the same.

A mechanical head's pings (one row each) are gathered into its sweep (`SweepPicture`): a polar
grid of ``slots`` bearings around the circle, each ping overwriting the slots its beam covers
(its ``beamwidth_h``, at least the one nearest its bearing), drawn through a table of each
pixel's slot and bin made once per range window. A multibeam frame (all its beams) is drawn
alone, with ``fan_pixels``; a side-scan ping as its waterfall rows.

Pictures are bytes (mono8): a 16- or 32-bit A/D's uint16, uint32 codes are drawn as the same
levels on 8 bits (`mitsonar.scan.model.data_bytes`: ``round(255 code / full scale)``).
"""
from __future__ import annotations

import math

import numpy as np

from mitsonar.scan.model import data_bytes

__all__ = ["Pictures", "SweepPicture"]

#: Pixels across a picture (the circle's diameter for a sweep).
SIZE = 400
#: Bearings a sweep's polar grid holds around the circle (a Ping360's gradian is 400 of them).
SLOTS = 400


class SweepPicture:
    """The accumulated sweep of a mechanical head (module doc): `add` a one-row scan, read
    ``pixels`` (uint8, ``size`` x ``size``; 0 outside the circle and where no ping fell yet)."""

    def __init__(self, size: int = SIZE, slots: int = SLOTS):
        self.size, self.slots = int(size), int(slots)
        self._window = None
        self.polar = None
        self.pixels = np.zeros((self.size, self.size), np.uint8)

    def _table(self, range_min: float, range_max: float, n_bins: int) -> None:
        """Each pixel's slot and bin for this range window (the circle of radius ``range_max``)."""
        px = 2.0 * range_max / self.size
        c = (np.arange(self.size) + 0.5) * px
        x = c - range_max
        up = range_max - c
        xx, uu = np.meshgrid(x, up)
        r = np.hypot(xx, uu)
        a = np.arctan2(-xx, uu)
        self._slot = np.round(a / (2 * math.pi / self.slots)).astype(np.int64) % self.slots
        width = (range_max - range_min) / n_bins
        b = np.floor((r - range_min) / width).astype(np.int64)
        self._inside = (b >= 0) & (b < n_bins) & (r <= range_max)
        self._bin = np.where(self._inside, b, 0)
        self.polar = np.zeros((self.slots, n_bins), np.uint8)
        self._window = (range_min, range_max, n_bins)

    def add(self, scan) -> np.ndarray:
        """Put each row of ``scan`` in its slots; returns ``pixels`` (redrawn)."""
        data = data_bytes(scan.data)
        window = (float(scan.range_min), float(scan.range_max), data.shape[1])
        if window != self._window:
            self._table(*window)
        step = 2 * math.pi / self.slots
        half = math.radians(float(scan.beamwidth_h)) / 2
        for row, bearing in zip(data, np.asarray(scan.bearings, np.float64)):
            k0 = int(math.floor((bearing - half) / step + 0.5))
            k1 = max(int(math.ceil((bearing + half) / step - 0.5)), k0)
            centre = int(round(bearing / step))
            ks = {k % self.slots for k in range(k0, k1 + 1)} | {centre % self.slots}
            self.polar[sorted(ks)] = row
        self.pixels = np.where(self._inside, self.polar[self._slot, self._bin], 0).astype(np.uint8)
        return self.pixels


class Pictures:
    """The picture after each ping (module doc): a mechanical head's sweep so far, a multibeam
    frame's fan, a side-scan ping's rows. `of` remembers the last scan it drew, so that outputs
    sharing one `Pictures` draw each ping once."""

    def __init__(self, size: int = SIZE, slots: int = SLOTS):
        self.sweep = SweepPicture(size, slots)
        self.size = int(size)
        self._last = (None, None)

    def of(self, scan) -> np.ndarray:
        """The picture (uint8, rows x columns) after ``scan``."""
        if self._last[0] is scan:
            return self._last[1]
        kind = scan.sonar_kind
        if kind.scanlines:
            pixels = self.sweep.add(scan).copy()
        elif kind.has_fan:
            from mitsonar.export.ros.messages import fan_pixels
            pixels = np.ascontiguousarray(data_bytes(fan_pixels(scan, self.size)))
        else:
            pixels = np.ascontiguousarray(data_bytes(scan.data))
        self._last = (scan, pixels)
        return pixels
