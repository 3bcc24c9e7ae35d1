"""The `Scan`: one sonar scan as numpy arrays plus everything needed to reinterpret it.

A `Scan` is what `render_scan` returns, what the SeaNet driver assembles from a real head, and
what `hilbertmap` learns from (through the documented attributes only).
"""
from __future__ import annotations

import dataclasses
import math
import os
from dataclasses import dataclass, field

import numpy as np

from mitsonar._checks import not_allowed
from mitsonar.scan import fileformat as scanfile
from mitsonar.scan.electronics import ElectronicsSettings
from mitsonar.scan.meta import ScanFieldError, ScanMeta

# The frames' helpers and the kinds live below the Scan (the sensor plugin uses them too); they
# stay importable from here.
import mitsonar.kinds as kinds
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


def data_full_scale(data) -> int:
    """The largest code of device data ``data`` (uint8, uint16 or uint32: 255, 65535, 4294967295)."""
    return int(np.iinfo(np.asarray(data).dtype).max)


def data_as(data, dtype, top=None) -> np.ndarray:
    """Device data ``data`` (uint8, uint16 or uint32) on the codes of ``dtype`` (one of those):
    ``round(code x top' / top)`` (halves up), the same levels on the other A/D's scale; ``data``
    itself when the types agree. ``top``: the codes' full scale when it is not their type's (an
    Oculus's 24-bit samples held in uint32: 2^24 - 1)."""
    a = np.asarray(data)
    dtype = np.dtype(dtype)
    if a.dtype == dtype and top is None:
        return a
    top, to = data_full_scale(a) if top is None else int(top), int(np.iinfo(dtype).max)
    return ((a.astype(np.uint64) * to + top // 2) // top).astype(dtype)


def data_bytes(data) -> np.ndarray:
    """Device data ``data`` (uint8, uint16 or uint32) as bytes 0..255: ``round(255 code / full
    scale)`` (halves up; the bytes themselves for uint8). `Scan.data_bytes`."""
    return data_as(data, np.uint8)


def data_levels(data) -> np.ndarray:
    """Device data ``data`` (uint8, uint16 or uint32) as float64 levels on the bytes' 0..255 scale:
    the bytes themselves, a wider A/D's codes as ``code x 255 / full scale`` (not rounded), so that
    products of any width agree."""
    a = np.asarray(data)
    levels = a.astype(np.float64)
    return levels if a.dtype == np.uint8 else levels * (255.0 / data_full_scale(a))


def require_bytes(scan, who: str, sends: str) -> None:
    """Refuse, in one line, a scan whose ``data`` is not bytes (uint8) for ``who``, a head that
    ``sends`` only 8-bit (or 4-bit) samples: a wider A/D's codes are not what it sends."""
    dtype = np.asarray(scan.data).dtype
    if dtype != np.uint8:
        raise not_allowed(who, "data", str(dtype), f"{sends}: uint8 data, a scan rendered with electronics "
                                                   f"bit_depth 8 (or 4), not {8 * dtype.itemsize}")


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
        (`mitsonar.kinds`), which says what differs between kinds.
    sound_speed : float  (m/s)
    absorption : float  (dB/m)
    electronics : ElectronicsSettings
        The device-electronics settings that turned `intensity` into `data`, typed
        (`mitsonar.scan.electronics`; None fields take the receiver's defaults). A dict given here
        (or assigned later) becomes an `ElectronicsSettings`.
    meta : ScanMeta
        Provenance and schedule, typed (`mitsonar.scan.meta`): scene, seed, spp, integrator,
        max_depth, mitsonar_version, ..., ``start_time`` (s, the scan's start on its clock: a
        trajectory's, or a real head's wall clock), a real head's source, log, settings, ...; other
        keys in ``meta.extra``. A dict given here (or assigned later) becomes a `ScanMeta`; the
        dict reading (``meta["seed"]``, ``meta.get(...)``) still works for this release.

    A Scan is data: its levels (echo level, directivity index, SNR) are functions of it in
    `mitsonar.sonar_equation` (`scan_levels`, `snr`, `directivity_index`); `mitsonar.load_scan`
    reads one from a file.
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
    electronics: ElectronicsSettings = field(default_factory=ElectronicsSettings)
    meta: ScanMeta = field(default_factory=ScanMeta)
    times: np.ndarray | None = None

    def __setattr__(self, name, value):
        # a caller's or a file's dict: typed here
        if name == "meta" and isinstance(value, dict):
            value = ScanMeta.from_dict(value)
        elif name == "electronics" and isinstance(value, dict):
            value = ElectronicsSettings.from_dict(value)
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
        for name, typed in (("electronics", ElectronicsSettings), ("meta", ScanMeta)):
            if not isinstance(getattr(self, name), typed):
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
        """The `mitsonar.kinds.SonarKind` of `kind` (the string): what differs between kinds."""
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
        volume, row ``i n_azimuth + j`` at ``[i, j]`` (`mitsonar.kinds.Volumetric`; the grid
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
    def data_full_scale(self) -> int:
        """The largest code of `data`: 255 (uint8), 65535 (uint16) or 4294967295 (uint32)."""
        return data_full_scale(self.data)

    def data_bytes(self) -> np.ndarray:
        """`data` as bytes 0..255, uint8: itself for uint8; the codes of a wider A/D
        ``round(255 code / full scale)``, the same levels at 8 bits (a 16-bit code / 257, a 32-bit
        one / 16843009, to the nearest), for consumers that show or send bytes only."""
        return data_bytes(self.data)

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
            # is written that `mitsonar.load_scan` would refuse.
            checked = dataclasses.replace(self)
        except ScanFieldError as exc:
            raise scanfile.ScanFileError(f"{path}: not saved: {exc}") from None
        scanfile.write(checked, path)

    @classmethod
    def load(cls, path) -> "Scan":
        """Deprecated: `mitsonar.load_scan` (the one way to read a scan file; the same result)."""
        import warnings

        warnings.warn("Scan.load is deprecated: use mitsonar.load_scan(path)", DeprecationWarning, stacklevel=2)
        return read(path)

    def __repr__(self) -> str:
        return (f"Scan(kind={self.kind!r}, n_pings={self.n_pings}, n_bins={self.n_bins}, "
                f"range=[{self.range_min:g}, {self.range_max:g}) m, beam={self.beam_pattern} "
                f"{self.beamwidth_h:g}x{self.beamwidth_v:g} deg)")


def read(path) -> Scan:
    """The scan in ``path`` (``.exr`` or ``.npz``), what `mitsonar.load_scan` returns."""
    path = os.fspath(path)
    fields, stored_as = scanfile.read(path)
    try:
        return Scan(**fields)
    except ScanFieldError as exc:
        arrays = ("ranges", "bearings", "poses", "times") if stored_as == "array" else ()
        where = stored_as if exc.field in ("intensity", "data", *arrays) else "header"
        raise scanfile.ScanFileError(f"{path}: {where} '{exc.field}': {exc.reason}") from None


def as_scans(scans) -> list:
    """A list of scans from one scan or an iterable of them (what "a `Scan` or a list" parameters
    take). One scan is a `Scan` or a scan-like object: one with ``data``, ``intensity`` or ``poses``."""
    if isinstance(scans, Scan) or any(hasattr(scans, a) for a in ("data", "intensity", "poses")):
        return [scans]
    return list(scans)
