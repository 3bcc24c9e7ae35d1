"""The `Scan`: one sonar scan as numpy arrays plus everything needed to reinterpret it.

A `Scan` is what `render_scan` returns, what the SeaNet driver assembles from a real head, and
what `hilbertmap` learns from (through the documented attributes only).
"""
from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

import numpy as np


def bearing_rotation(bearing) -> np.ndarray:
    """4x4 rotation(s) of the beam frame for bearing(s) in radians: right-handed about the frame's
    +y (scan) axis, so +z (the boresight) turns towards +x. Ping k's pose is ``T @ R(b_k)``.

    The one definition of the bearing convention: the renderer, the SeaNet driver and the virtual
    sonar all build poses with it.
    """
    b = np.asarray(bearing, dtype=np.float64)
    c, s = np.cos(b), np.sin(b)
    m = np.zeros(b.shape + (4, 4))
    m[..., 0, 0] = c
    m[..., 0, 2] = s
    m[..., 2, 0] = -s
    m[..., 2, 2] = c
    m[..., 1, 1] = 1.0
    m[..., 3, 3] = 1.0
    return m


@dataclass
class Scan:
    """One scan: ``n_pings`` pings of ``n_bins`` range bins.

    Attributes
    ----------
    intensity : float32 (n_pings, n_bins)
        Noise-free linear echo energy per bin (on-axis source intensity 1 W/sr, on-axis
        receive aperture 1 m^2). Zero for scans read from a device, which only sends `data`.
    data : uint8 (n_pings, n_bins)
        What the device outputs: level after TVG, gain, noise and 8/4-bit quantisation.
    ranges : float64 (n_bins,)
        Bin-centre ranges in metres.
    bearings : float64 (n_pings,)
        Bearing of each ping in radians, ``radians(bearing_start + k * bearing_step)``, not wrapped.
    poses : float64 (n_pings, 4, 4)
        World transform of each ping's beam frame (column vectors): ``[:3, 2]`` is the
        boresight, ``[:3, 1]`` the scan axis, ``[:3, 3]`` the transducer position.
    range_min, range_max : float
        Range window in metres; bins are ``(range_max - range_min) / n_bins`` wide.
    beam_pattern : str
    beamwidth_h, beamwidth_v : float
        Full beam widths in degrees (-3 dB one way).
    kind : str
        ``mechanical`` or ``multibeam``.
    sound_speed : float  (m/s)
    absorption : float  (dB/m)
    electronics : dict
        The device-electronics settings that turned `intensity` into `data`.
    meta : dict
        Provenance: scene, seed, spp, integrator, max_depth, mitsonar version, ...
    """

    intensity: np.ndarray
    data: np.ndarray
    ranges: np.ndarray
    bearings: np.ndarray
    poses: np.ndarray
    range_min: float
    range_max: float
    beam_pattern: str = "gaussian"
    beamwidth_h: float = 3.0
    beamwidth_v: float = 35.0
    kind: str = "mechanical"
    sound_speed: float = 1500.0
    absorption: float = 0.0
    electronics: dict[str, Any] = field(default_factory=dict)
    meta: dict[str, Any] = field(default_factory=dict)

    def __post_init__(self) -> None:
        self.intensity = np.asarray(self.intensity, dtype=np.float32)
        data = np.asarray(self.data)
        if data.dtype != np.uint8 and data.size and (np.nanmin(data) < 0 or np.nanmax(data) > 255
                                                     or not np.all(np.isfinite(data))):
            raise ValueError("Scan: data must hold device bytes 0..255 "
                             f"(got values from {np.nanmin(data)} to {np.nanmax(data)})")
        self.data = data.astype(np.uint8)
        self.ranges = np.asarray(self.ranges, dtype=np.float64)
        self.bearings = np.asarray(self.bearings, dtype=np.float64)
        self.poses = np.asarray(self.poses, dtype=np.float64)
        n_pings, n_bins = self.intensity.shape
        if self.data.shape != (n_pings, n_bins):
            raise ValueError(f"Scan: data has shape {self.data.shape}, intensity {self.intensity.shape}; they must match")
        if self.ranges.shape != (n_bins,):
            raise ValueError(f"Scan: ranges has shape {self.ranges.shape}, expected ({n_bins},)")
        if self.bearings.shape != (n_pings,):
            raise ValueError(f"Scan: bearings has shape {self.bearings.shape}, expected ({n_pings},)")
        if self.poses.shape != (n_pings, 4, 4):
            raise ValueError(f"Scan: poses has shape {self.poses.shape}, expected ({n_pings}, 4, 4)")

    @property
    def n_pings(self) -> int:
        return int(self.intensity.shape[0])

    @property
    def row_name(self) -> str:
        """What the rows are: the pings of a rotating head, the receive beams of a multibeam one."""
        return "beams" if self.kind == "multibeam" else "pings"

    @property
    def n_bins(self) -> int:
        return int(self.intensity.shape[1])

    @property
    def bin_width(self) -> float:
        return (self.range_max - self.range_min) / self.n_bins

    @property
    def boresights(self) -> np.ndarray:
        """(n_pings, 3) world boresight of each ping."""
        return self.poses[:, :3, 2]

    @property
    def positions(self) -> np.ndarray:
        """(n_pings, 3) world transducer position of each ping."""
        return self.poses[:, :3, 3]

    def save(self, path) -> None:
        """Write the scan to ``.exr`` (range-intensity image, lossless header) or ``.npz``."""
        from .io import save_scan

        save_scan(self, path)

    def __repr__(self) -> str:
        return (f"Scan(kind={self.kind!r}, n_pings={self.n_pings}, n_bins={self.n_bins}, "
                f"range=[{self.range_min:g}, {self.range_max:g}) m, beam={self.beam_pattern} "
                f"{self.beamwidth_h:g}x{self.beamwidth_v:g} deg)")
