"""The `Scan`: one sonar scan as numpy arrays plus everything needed to reinterpret it.

A `Scan` is what `render_scan` returns, what the SeaNet driver assembles from a real head, and
what `hilbertmap` learns from (through the documented attributes only).
"""
from __future__ import annotations

import dataclasses
import math
import os
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from mitsonar.scan import fileformat as scanfile
from mitsonar.scan.meta import ScanFieldError, ScanMeta

# The frames' helpers and the kinds live below the Scan (the sensor plugin uses them too); they
# stay importable from here.
from mitsonar.geometry import kinds
from mitsonar.geometry.frames import SIDES, _not_rigid, bearing_rotation, check_rigid, check_rigid_stack  # noqa: F401

_RIGID = "only rigid transforms: rotation + translation, no scale, shear or mirror"


def reception_times(row_times: np.ndarray):
    """``Scan.times`` of a scan assembled from a real head's replies (SeaNet, Ping360), given each
    row's reception time (NaN for a row never received): each row's reception time from the first one's (s),
    a missing row's interpolated between its neighbours'. None (times zero) when no row has a
    time, or when the rows' times do not increase along the sweep (a revisited bearing)."""
    known = np.isfinite(row_times)
    if not known.any():
        return None
    k = np.arange(len(row_times))
    t = np.interp(k, k[known], row_times[known]) - row_times[known].min()
    return t if np.all(np.diff(t) >= 0) else None


def sidescan_channels(side, n_rows: int) -> np.ndarray:
    """(n_rows,) channel of each row of a side-scan scan with ``side`` (``meta['side']``): 0 port,
    1 starboard; with ``both`` the first half of the rows is port, the second starboard."""
    if side not in SIDES:
        raise ScanFieldError("meta", f"side {side!r} is not allowed (a side-scan scan's side: one of {', '.join(SIDES)})")
    if side == "both":
        if n_rows % 2:
            raise ScanFieldError("intensity", f"{n_rows} rows is not allowed (a two-sided side-scan scan has "
                                              "port then starboard rows: an even number)")
        return np.repeat(np.array([0, 1]), n_rows // 2)
    return np.full(n_rows, 0 if side == "port" else 1)


def _show(value) -> str:
    return repr(value.item() if isinstance(value, np.generic) else value)


def _first(mask: np.ndarray) -> str:
    """Index of the first True of mask, as ``3`` or ``(3, 4)``."""
    idx = tuple(int(i) for i in np.argwhere(mask)[0])
    return str(idx[0]) if len(idx) == 1 else str(idx)


def _array(name: str, value, dtype) -> np.ndarray:
    try:
        a = np.asarray(value)
    except (TypeError, ValueError):  # ragged nested lists
        raise ScanFieldError(name, "not an array of numbers (ragged nesting)") from None
    if a.dtype.kind not in "iuf":  # strings, objects, bools, complex
        raise ScanFieldError(name, f"an array of {a.dtype} is not allowed (numbers only)")
    return a if dtype is None else a.astype(dtype, copy=False)


def _device_bytes(value) -> np.ndarray:
    a = _array("data", value, None)
    if a.dtype in (np.uint16, np.uint32):   # the codes of a wider A/D (bit_depth 16 or 32), kept
        return a
    if a.dtype != np.uint8:
        # Casting would wrap 256 to 0 or cut 3.7 to 3: only exact bytes convert.
        bad = ~(np.isfinite(a) & (a >= 0) & (a <= 255) & (a == np.round(a)))
        if bad.any():
            raise ScanFieldError("data", f"{_show(a[bad][0])} at index {_first(bad)} is not allowed "
                                         "(device bytes: integers 0 to 255)")
        a = a.astype(np.uint8)
    return a


def _number(name: str, value, ok, allowed: str) -> None:
    if isinstance(value, (bool, np.bool_)) or not isinstance(value, (int, float, np.integer, np.floating)):
        raise ScanFieldError(name, f"{_show(value)} is not a number")
    if not (math.isfinite(value) and ok(value)):
        raise ScanFieldError(name, f"{_show(value)} is not allowed ({allowed})")


@dataclass
class Scan:
    """One scan: ``n_pings`` pings of ``n_bins`` range bins.

    Attributes
    ----------
    intensity : float32 (n_pings, n_bins)
        Noise-free linear echo energy per bin (on-axis source intensity 1 W/sr, on-axis
        receive aperture 1 m^2). Zero for scans read from a device, which only sends `data`.
    data : uint8, uint16 or uint32 (n_pings, n_bins)
        What the device outputs: level after TVG, gain, noise and 8/4-bit quantisation (uint8);
        uint16 or uint32 for a wider A/D (electronics ``bit_depth`` 16 or 32: the same levels on
        0..65535 or 0..4294967295). Other integer arrays are taken as bytes 0..255.
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
        ``mechanical``, ``multibeam`` or ``sidescan`` (then ``meta['side']``: ``port``,
        ``starboard`` or ``both``, default ``both``; see `channel`). `sonar_kind` is its class
        (`mitsonar.geometry.kinds`), which says what differs between kinds.
    sound_speed : float  (m/s)
    absorption : float  (dB/m)
    electronics : dict
        The device-electronics settings that turned `intensity` into `data`.
    meta : ScanMeta
        Provenance and schedule, typed (`mitsonar.scan.meta`): scene, seed, spp, integrator,
        max_depth, mitsonar_version, ..., ``start_time`` (s, the scan's start on its clock: a
        trajectory's, or a real head's wall clock), a real head's source, log, settings, ...; other
        keys in ``meta.extra``. A dict given here (or assigned later) becomes a `ScanMeta`; the
        dict reading (``meta["seed"]``, ``meta.get(...)``) still works for this release.
    times : float64 (n_pings,)
        Seconds of each row's ping from the scan start, finite and non-decreasing: a mechanical
        head's ``k * ping_period``, zeros for the rows of one multibeam frame; a side-scan head's
        ``k * ping_period`` per channel (non-decreasing within each channel's run of rows, the
        starboard run starting again at 0). None (the default,
        for scans built without a schedule, and for files written before scans had times) means
        zeros: every row at the scan start.
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
    kind: str = kinds.DEFAULT
    sound_speed: float = 1500.0
    absorption: float = 0.0
    electronics: dict[str, Any] = field(default_factory=dict)
    meta: ScanMeta = field(default_factory=ScanMeta)
    times: np.ndarray | None = None

    def __setattr__(self, name, value):
        if name == "meta" and isinstance(value, dict):   # a caller's or a file's dict: typed here
            value = ScanMeta.from_dict(value)
        object.__setattr__(self, name, value)

    def __post_init__(self) -> None:
        # The one place a Scan's fields are checked: the renderer, the SeaNet driver, load_scan
        # and users all build scans here, so a bad value stops before it reaches a file or a map.
        _number("range_min", self.range_min, lambda v: v >= 0, "a range >= 0 m")
        _number("range_max", self.range_max, lambda v: v > self.range_min,
                f"a range > range_min = {self.range_min:g} m")
        _number("beamwidth_h", self.beamwidth_h, lambda v: 0 < v <= 360, "a width in (0, 360] deg")
        _number("beamwidth_v", self.beamwidth_v, lambda v: 0 < v <= 180, "a width in (0, 180] deg")
        _number("sound_speed", self.sound_speed, lambda v: v > 0, "a speed > 0 m/s")
        _number("absorption", self.absorption, lambda v: v >= 0, "an attenuation >= 0 dB/m")
        if kinds.lookup(self.kind) is None:
            raise ScanFieldError("kind", f"{self.kind!r} is not allowed (one of {', '.join(kinds.names())})")
        if not isinstance(self.beam_pattern, str) or not self.beam_pattern:
            raise ScanFieldError("beam_pattern", f"{self.beam_pattern!r} is not a pattern name")
        for name in ("electronics", "meta"):
            if not isinstance(getattr(self, name), dict if name == "electronics" else ScanMeta):
                raise ScanFieldError(name, f"a {type(getattr(self, name)).__name__} is not a dict")
        self.intensity = _array("intensity", self.intensity, np.float32)
        if self.intensity.ndim != 2:
            raise ScanFieldError("intensity", f"shape {self.intensity.shape} is not (n_pings, n_bins)")
        n_pings, n_bins = self.intensity.shape
        self.data = _device_bytes(self.data)
        self.ranges = _array("ranges", self.ranges, np.float64)
        self.bearings = _array("bearings", self.bearings, np.float64)
        self.poses = _array("poses", self.poses, np.float64)
        self.times = np.zeros(n_pings) if self.times is None else _array("times", self.times, np.float64)
        for name, shape, what in (("data", (n_pings, n_bins), "(n_pings, n_bins) like intensity"),
                                  ("ranges", (n_bins,), "(n_bins,)"), ("bearings", (n_pings,), "(n_pings,)"),
                                  ("poses", (n_pings, 4, 4), "(n_pings, 4, 4)"), ("times", (n_pings,), "(n_pings,)")):
            if getattr(self, name).shape != shape:
                raise ScanFieldError(name, f"shape {getattr(self, name).shape} is not {what} = {shape}")
        for name in ("intensity", "ranges", "bearings", "poses", "times"):
            bad = ~np.isfinite(getattr(self, name))
            if bad.any():
                raise ScanFieldError(name, f"{_show(getattr(self, name)[bad][0])} at index {_first(bad)} "
                                           "is not allowed (finite values only)")
        if (self.intensity < 0).any():
            raise ScanFieldError("intensity", f"{_show(self.intensity[self.intensity < 0][0])} at index "
                                              f"{_first(self.intensity < 0)} is not allowed (echo energy >= 0)")
        # A two-sided side-scan scan's rows are two runs of pings (port, then starboard): each channel's
        # times do not decrease.
        runs = np.diff(self.channel) == 0 if self.sonar_kind.sided else True
        back = (np.diff(self.times) < 0) & runs
        if back.any():
            k = int(np.argmax(back)) + 1
            raise ScanFieldError("times", f"{_show(self.times[k])} at index {k} is not allowed (ping times do "
                                          f"not decrease; the previous is {_show(self.times[k - 1])})")
        not_rigid = _not_rigid(self.poses)
        if not_rigid.any():
            raise ScanFieldError("poses", f"pose {_first(not_rigid)} is not allowed ({_RIGID})")
        outside = (self.ranges < self.range_min) | (self.ranges > self.range_max)
        if outside.any():
            raise ScanFieldError("ranges", f"{_show(self.ranges[outside][0])} at index {_first(outside)} is not "
                                           f"allowed (inside the window [{self.range_min:g}, {self.range_max:g}] m)")

    @property
    def n_pings(self) -> int:
        return int(self.intensity.shape[0])

    @property
    def sonar_kind(self) -> kinds.SonarKind:
        """The `mitsonar.geometry.kinds.SonarKind` of `kind` (the string): what differs between kinds."""
        return kinds.get(self.kind, "Scan 'kind'")

    @property
    def row_name(self) -> str:
        """What the rows are: the pings of a rotating head, the receive beams of a multibeam one."""
        return self.sonar_kind.row_name

    @property
    def channel(self) -> np.ndarray | None:
        """(n_pings,) channel of each row of a side-scan scan, 0 port and 1 starboard (port rows
        first); None for the other kinds. `mitsonar.products.sidescan.select_side` takes one side's rows."""
        if not self.sonar_kind.sided:
            return None
        return sidescan_channels("both" if self.meta.side is None else self.meta.side, self.n_pings)

    def volume(self) -> np.ndarray:
        """(n_elevation, n_azimuth, n_bins) float32: a volumetric scan's rows (one frame) as its
        volume, row ``i n_azimuth + j`` at ``[i, j]`` (`mitsonar.geometry.kinds.Volumetric`; the grid
        is ``meta.n_elevation`` x ``meta.n_azimuth``). A ValueError for the other kinds, or for a
        scan whose rows are not that grid."""
        if not self.sonar_kind.grid:
            raise ValueError(f"Scan.volume: a {self.kind!r} scan has no volume (kind {kinds.which('grid')})")
        n_el, n_az = self.meta.n_elevation, self.meta.n_azimuth
        if n_el is None or n_az is None or n_el * n_az != self.n_pings:
            raise ScanFieldError("meta", f"n_elevation x n_azimuth = {n_el} x {n_az} is not allowed (the scan's "
                                         f"{self.n_pings} rows)")
        return self.intensity.reshape(n_el, n_az, self.n_bins)

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

    @property
    def echo_level(self) -> np.ndarray:
        """float32 (n_pings, n_bins): the noise-free echo level at the receiver, dB re 1 uPa, per
        bin (``-inf`` where no echo): ``source_level + 10 log10`` of `intensity` convolved with
        the transmit pulse as a boxcar of ones over ``c pulse_length / 2``, the source level and
        pulse from `electronics` (defaults where absent). Derived, not stored: it always agrees
        with the saved intensity and settings (`Electronics.echo_level`)."""
        from mitsonar.receiver.electronics import Electronics

        return Electronics.from_dict(self.electronics, "Scan 'electronics'").echo_level(
            self.intensity, self.ranges, self.sound_speed)

    @property
    def directivity_index(self) -> float:
        """dB, the receive beam's ``10 log10(4 pi / Int B)``: recorded by `render_scan` in
        ``meta['directivity_index']``, else computed from `beam_pattern` and its widths (and
        ``meta['frequency']``, ``meta['aperture_h']`` for ``sinc``)."""
        if self.meta.directivity_index is not None:
            return float(self.meta.directivity_index)
        from mitsonar.sim.variant import ensure_variant

        ensure_variant()
        from mitsonar.plugins.sensors import beam as patterns

        shape = patterns.lookup(self.beam_pattern)
        if shape is not None and shape.measured:
            raise ScanFieldError("meta", f"a {shape.name!r} beam pattern's directivity_index is not recorded")
        own = shape is not None and shape.apertures     # the pattern reads the recorded aperture
        beam = patterns.BeamPattern(self.beam_pattern, self.beamwidth_h, self.beamwidth_v,
                                    float(700e3 if self.meta.frequency is None else self.meta.frequency),
                                    float(self.meta.aperture_h) if own and self.meta.aperture_h is not None else None,
                                    None, self.sound_speed)
        return beam.directivity_index()

    @property
    def noise_band_level(self) -> float:
        """dB re 1 uPa: ``NL + 10 log10 B - DI``, the receiver's noise in its band after the
        beam's directivity (``noise_level`` and ``receiver_bandwidth`` from `electronics`)."""
        from mitsonar.receiver.electronics import Electronics
        from mitsonar.sonar_equation.levels import noise_band_level

        e = Electronics.from_dict(self.electronics, "Scan 'electronics'")
        return noise_band_level(e.noise_level, e.noise_bandwidth(self.bin_width, self.sound_speed),
                                self.directivity_index)

    @property
    def snr(self) -> np.ndarray:
        """float32 (n_pings, n_bins), dB: ``echo_level - (NL + 10 log10 B - DI)`` per bin (the
        active sonar equation's signal-to-noise ratio, Urick 1983, eq. 2.2); ``-inf`` where no echo."""
        return (self.echo_level - np.float32(self.noise_band_level)).astype(np.float32)

    def save(self, path) -> None:
        """Write the scan losslessly to ``.exr`` (range-intensity image, lossless header) or ``.npz``
        (chosen by the extension), atomically; the format is described in `mitsonar.scan.fileformat`.

        Raises `ScanFileError` (a ValueError naming the file) for an unknown extension, a path
        that is a directory or in a missing folder, an empty scan, a field that `Scan` does not
        allow (assigned after construction), or metadata that JSON cannot hold exactly.
        """
        path = os.fspath(path)
        scanfile.extension(path)
        try:
            # Fields may have been assigned since construction: check them again, so that nothing
            # is written that `load` would refuse.
            checked = dataclasses.replace(self)
        except ScanFieldError as exc:
            raise scanfile.ScanFileError(f"{path}: not saved: {exc}") from None
        scanfile.write(checked, path)

    @classmethod
    def load(cls, path) -> "Scan":
        """Read a scan written by `save` (``.exr`` or ``.npz``): bit-identical arrays, equal scalars
        and dicts. A missing, truncated, corrupt or foreign file, or content that `Scan` does not
        allow, raises `ScanFileError` naming the file and the header field, channel or array."""
        path = os.fspath(path)
        fields, stored_as = scanfile.read(path)
        try:
            return cls(**fields)
        except ScanFieldError as exc:
            arrays = ("ranges", "bearings", "poses", "times") if stored_as == "array" else ()
            where = stored_as if exc.field in ("intensity", "data", *arrays) else "header"
            raise scanfile.ScanFileError(f"{path}: {where} '{exc.field}': {exc.reason}") from None

    def __repr__(self) -> str:
        return (f"Scan(kind={self.kind!r}, n_pings={self.n_pings}, n_bins={self.n_bins}, "
                f"range=[{self.range_min:g}, {self.range_max:g}) m, beam={self.beam_pattern} "
                f"{self.beamwidth_h:g}x{self.beamwidth_v:g} deg)")


def as_scans(scans) -> list:
    """A list of scans from one scan or an iterable of them (what "a `Scan` or a list" parameters
    take). One scan is a `Scan` or a scan-like object: one with ``data``, ``intensity`` or ``poses``."""
    if isinstance(scans, Scan) or any(hasattr(scans, a) for a in ("data", "intensity", "poses")):
        return [scans]
    return list(scans)
