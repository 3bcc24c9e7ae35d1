"""Range binning: which bin of the sensor's range window an echo lands in.

An echo of range ``r`` (half its total path length) lands in bin
``floor((r - range_min) / bin_width)``; echoes outside ``[range_min, range_max)`` are dropped,
not clamped. The window's values are opaque, so a new window never recompiles a kernel.
"""
from __future__ import annotations

import drjit as dr
import mitsuba as mi


class RangeBins:
    def __init__(self, sensor):
        self.n_bins = sensor.n_bins
        self.r_min = dr.opaque(mi.Float, sensor.range_min)
        self.inv_width = dr.opaque(mi.Float, 1.0 / sensor.bin_width)
        self.n_bins_o = dr.opaque(mi.UInt32, sensor.n_bins)

    def index(self, rng, valid):
        """(bin index, valid & inside the window) for echo ranges ``rng``."""
        t = (rng - self.r_min) * self.inv_width
        valid = valid & (t >= 0) & (t < mi.Float(self.n_bins_o))
        return mi.UInt32(dr.maximum(t, 0.0)), valid

    def flat(self, ping, b):
        """Index into a flat ``(n_pings, n_bins)`` histogram."""
        return ping * self.n_bins_o + b
