"""`ScanMeta`: a `Scan`'s metadata (provenance, schedule, the head's own words), typed.

Every key mitsonar writes is a field with its type and unit below; a field that is None is absent
(it is not written to files, ``"key" in meta`` is False). Keys mitsonar does not know (a user's
notes, a newer version's) are kept apart in `ScanMeta.extra`, unchanged, and saved with the scan.

One name for the scan's start: ``start_time`` (s). Real heads wrote ``time_start`` and
``time_end`` before; files that hold them load with ``start_time`` and ``end_time``, and reading
``meta["time_start"]`` still works, with a DeprecationWarning.

The mapping API (``meta["seed"]``, ``meta.get("side", "both")``, ``"key" in meta``, ``meta.items()``,
``meta.update(...)``, ``{**meta}``, ``dict(meta)``, ``meta == {...}``) is kept for this release,
silently: scans, files and user code of the dict era go on working. Attributes (``meta.seed``)
are the typed way and the one mitsonar uses. A value of the wrong type for a field is refused when
it is set, in one line: ``Scan 'meta': 'start_time': 'noon' is not allowed (a finite number, seconds)``.

`ScanFieldError`, the one error of a bad `Scan` field, lives here (the leaf of `mitsonar.scan`);
`mitsonar.scan.model` and `mitsonar.scan` export it. `TypedRecord` is the machinery of a record
of optional typed fields, shared with the electronics settings (`mitsonar.scan.electronics`).
This module imports nothing from mitsonar.
"""
from __future__ import annotations

import math
import numbers
import warnings
from collections.abc import Mapping, MutableMapping
from dataclasses import dataclass, field, fields
from typing import Any

import numpy as np

#: Old names still read (with a DeprecationWarning) and renamed when a file or dict is loaded.
RENAMED = {"time_start": "start_time", "time_end": "end_time"}

# What each type of field allows, as said in the refusal.
_FIELD_TYPES = {
    "number": "a finite number",
    "real": "a number, not NaN",
    "int": "a whole number",
    "whole": "a whole number (an int, or a float without fraction)",
    "str": "a string",
    "bool": "True or False",
    "list": "a list",
    "dict": "a dict",
}


class ScanFieldError(ValueError):
    """A `Scan` field with a value that is not allowed; `field` names it, `reason` says why."""

    def __init__(self, field: str, reason: str):
        super().__init__(f"Scan '{field}': {reason}")
        self.field, self.reason = field, reason

    def __reduce__(self):  # pickles (multiprocessing) with both arguments
        return type(self), (self.field, self.reason)


def _f(field_type: str, doc: str, *, positive: bool = False):
    """A field of `ScanMeta`: absent (None) by default; ``field_type`` one of `_FIELD_TYPES`; ``doc``
    its meaning and unit (shown in a refusal)."""
    return field(default=None, metadata={"field_type": field_type, "doc": doc, "positive": positive})


def _ok(field_type: str, value, positive: bool) -> bool:
    if field_type in ("real", "whole"):
        if isinstance(value, (bool, np.bool_)) or not isinstance(value, (numbers.Real, np.integer, np.floating)):
            return False
        return not math.isnan(value) and (field_type == "real" or (math.isfinite(value) and float(value).is_integer()))
    if field_type in ("number", "int"):
        if isinstance(value, (bool, np.bool_)) or not isinstance(value, (numbers.Real, np.integer, np.floating)):
            return False
        if field_type == "int" and not isinstance(value, (numbers.Integral, np.integer)):
            return False
        return math.isfinite(value) and (not positive or value > 0)
    if field_type == "str":
        return isinstance(value, str)
    if field_type == "bool":
        return isinstance(value, (bool, np.bool_))
    if field_type == "list":
        return isinstance(value, (list, tuple, np.ndarray))
    return isinstance(value, dict)


class TypedRecord(MutableMapping):
    """The machinery of a typed record of optional fields (`ScanMeta`, `ElectronicsSettings`): each
    dataclass field made with `_f` is checked when set (a `ScanFieldError` on ``WHERE``), None is
    absent, unknown keys go to ``extra``; `from_dict`/`to_dict` for files, and the mapping API of
    the dict era (``r["key"]``, ``r.get``, ``in``, ``items()``, ``update``, ``==`` a dict)."""

    #: the Scan field the record is (named in a refusal)
    WHERE = "meta"
    #: old key -> new key, read with a DeprecationWarning and renamed on `from_dict`
    RENAMED: dict = {}

    @classmethod
    def _spec(cls) -> dict:
        spec = cls.__dict__.get("_SPEC_CACHE")
        if spec is None:
            spec = {f.name: (f.metadata["field_type"], f.metadata["doc"], f.metadata["positive"])
                    for f in fields(cls) if f.name != "extra"}
            cls._SPEC_CACHE = spec
        return spec

    def __post_init__(self) -> None:  # the fields were checked as __init__ set them (__setattr__)
        if not isinstance(self.extra, dict):
            raise ScanFieldError(self.WHERE, f"extra: a {type(self.extra).__name__} is not a dict")

    def _check(self, name: str, value) -> None:
        if value is None:
            return
        field_type, doc, positive = self._spec()[name]
        if not _ok(field_type, value, positive):
            shown = value.item() if isinstance(value, np.generic) else value
            raise ScanFieldError(self.WHERE, f"'{name}': {shown!r} is not allowed ({_FIELD_TYPES[field_type]}"
                                 + (" > 0" if positive else "") + f", {doc})")

    def __setattr__(self, name, value):
        if name in self._spec():
            self._check(name, value)
        object.__setattr__(self, name, value)

    @classmethod
    def from_dict(cls, d: Mapping):
        """The record of a dict (a file's, a caller's): known keys to their fields, old names
        (`RENAMED`) to the new ones, every other key to `extra`."""
        if isinstance(d, cls):
            return d
        spec = cls._spec()
        known, extra = {}, {}
        for key, value in d.items():
            new = cls.RENAMED.get(key) if isinstance(key, str) else None
            if new is not None and new not in d:
                key = new
            (known if key in spec else extra)[key] = value
        return cls(**known, extra=extra)

    def to_dict(self) -> dict:
        """A plain dict: the fields that are set, then `extra` (what files hold)."""
        return dict(self.items())

    def replace(self, **changes):
        """A copy (its own `extra`) with the fields in ``changes`` set (None: absent)."""
        return type(self).from_dict({**self.to_dict(), **changes})

    # ---- the mapping API (one release; see the module docstring) --------------------------------

    def __getitem__(self, key):
        if isinstance(key, str) and key in self._spec():
            value = getattr(self, key)
            if value is None:
                raise KeyError(key)
            return value
        if key in self.extra:
            return self.extra[key]
        if key in self.RENAMED:
            value = self[self.RENAMED[key]]
            warnings.warn(f"Scan {self.WHERE} '{key}' is now '{self.RENAMED[key]}'", DeprecationWarning, stacklevel=2)
            return value
        raise KeyError(key)

    def __contains__(self, key) -> bool:
        # not through __getitem__: ``"time_start" in meta`` is False (the name is gone), no warning
        if isinstance(key, str) and key in self._spec():
            return getattr(self, key) is not None
        return key in self.extra

    def __setitem__(self, key, value) -> None:
        if isinstance(key, str) and key in self._spec():
            setattr(self, key, value)
        else:
            self.extra[key] = value

    def __delitem__(self, key) -> None:
        if isinstance(key, str) and key in self._spec():
            if getattr(self, key) is None:
                raise KeyError(key)
            setattr(self, key, None)
        else:
            del self.extra[key]

    def __iter__(self):
        for name in self._spec():
            if getattr(self, name) is not None:
                yield name
        yield from self.extra

    def __len__(self) -> int:
        return sum(getattr(self, n) is not None for n in self._spec()) + len(self.extra)

    def __eq__(self, other) -> bool:
        if isinstance(other, Mapping):
            return dict(self.items()) == dict(other.items())
        return NotImplemented

    __hash__ = None

    def __repr__(self) -> str:
        return f"{type(self).__name__}({dict(self.items())!r})"


@dataclass(eq=False, repr=False)
class ScanMeta(TypedRecord):
    """A `Scan`'s metadata. Fields (all optional; None: absent):

    Rendered scans (`render_scan`): ``scene``, ``seed``, ``spp``, ``integrator``, ``max_depth``,
    ``mitsonar_version``, ``variant``, ``electronics_seed`` (the receiver noise's), ``speckle``
    (``"scene"``: the echoes' speckle comes from the scene), ``bearing_start``/``bearing_step``
    (deg), ``ping_period`` (s), ``frequency`` (Hz), ``aperture_h`` (m), ``directivity_index`` (dB);
    side-scan ``side``, ``depression`` (deg), ``pings_per_channel``, ``preset``; multibeam
    ``tx_pattern``, ``tx_beamwidth_h``/``tx_beamwidth_v`` (deg); volumetric ``n_azimuth``,
    ``n_elevation``, ``elevation_start``/``elevation_step`` (deg); surveys ``survey_index``,
    ``survey_seed``.

    Georeference (`mitsonar.geometry.geodesy`): ``origin`` ([lat, lon, height], WGS 84 deg and m)
    and ``crs`` (``"EPSG:NNNN"``, projected): world x, y are grid offsets in that CRS from the
    origin's easting and northing; the poses stay in these local metres.

    Time: ``start_time`` (s): the scan's start on its clock (a trajectory's for a rendered scan, the
    wall clock of a real head's log or port); ``Scan.times`` count from it. ``end_time`` (s): a real
    head's last row received.

    Real heads: ``source`` (``seanet``, ``ping360``), ``sweep`` (``continuous``, ``sector``),
    ``missing`` (rows never received), ``log`` (the raw log replayed), ``partial`` (cut short at
    the log's end), ``port``, ``settings`` (the head settings, a dict), ``dst``, ``head_serial``,
    ``head_software``, ``head_firmware``; SeaNet ``wire_bearings`` (1/16 gradian), ``ad_interval``,
    ``step_size``, ``hd_ctrl``, ``device_type``, ``gain_byte``, ``ad_low_byte``, ``ad_span_byte``,
    ``nibble_order``, ``left_lim``/``right_lim``; Ping360 ``angles`` (gradian), ``gain_setting``,
    ``transmit_duration`` (us), ``sample_period`` (25 ns ticks), ``transmit_frequency`` (kHz).

    ``extra``: every other key, as given.
    """

    # provenance of a rendered scan
    scene: str | None = _f("str", "the scene's file name")
    seed: int | None = _f("int", "the render's seed")
    spp: int | None = _f("int", "samples per pixel")
    integrator: str | None = _f("str", "the integrator's class name")
    max_depth: int | None = _f("int", "path length limit")
    mitsonar_version: str | None = _f("str", "the version that made the scan")
    variant: str | None = _f("str", "the Mitsuba variant")
    electronics_seed: int | None = _f("int", "the receiver noise's seed")
    speckle: str | None = _f("str", "where the speckle comes from")
    bearing_start: float | None = _f("number", "deg")
    bearing_step: float | None = _f("number", "deg")
    ping_period: float | None = _f("number", "s", positive=True)
    frequency: float | None = _f("number", "Hz", positive=True)
    aperture_h: float | None = _f("number", "m", positive=True)
    directivity_index: float | None = _f("number", "dB")
    # side-scan, multibeam
    side: str | None = _f("str", "port, starboard or both")
    depression: float | None = _f("number", "deg")
    pings_per_channel: int | None = _f("int", "pings per side-scan channel")
    preset: str | None = _f("str", "the head preset's name")
    tx_pattern: str | None = _f("str", "the transmit beam's pattern")
    tx_beamwidth_h: float | None = _f("number", "deg", positive=True)
    tx_beamwidth_v: float | None = _f("number", "deg", positive=True)
    # volumetric: the rows' elevation x azimuth grid (`Scan.volume`)
    n_azimuth: int | None = _f("int", "beams across azimuth", positive=True)
    n_elevation: int | None = _f("int", "beams across elevation", positive=True)
    elevation_start: float | None = _f("number", "deg")
    elevation_step: float | None = _f("number", "deg")
    # time and surveys
    start_time: float | None = _f("number", "seconds")
    end_time: float | None = _f("number", "seconds")
    survey_index: int | None = _f("int", "the scan's index in its survey")
    survey_seed: int | None = _f("int", "the survey scan's seed")
    # georeference (`mitsonar.geometry.geodesy`): poses stay in local metres, x = E - E0, y = N - N0
    origin: list | None = _f("list", "[lat deg, lon deg, height m] of the world frame's origin, WGS 84")
    crs: str | None = _f("str", "the projected CRS of the world grid, 'EPSG:NNNN'")
    # real heads
    source: str | None = _f("str", "the head's protocol: seanet or ping360")
    sweep: str | None = _f("str", "continuous or sector")
    missing: list | None = _f("list", "row indices")
    log: str | None = _f("str", "the raw log's path")
    partial: bool | None = _f("bool", "cut short at the log's end")
    port: str | None = _f("str", "the head's port")
    settings: dict | None = _f("dict", "the head settings")
    dst: bool | None = _f("bool", "a DST head")
    head_serial: int | None = _f("int", "the head's serial number")
    head_software: int | None = _f("int", "the head's software version")
    head_firmware: str | None = _f("str", "the head's firmware version")
    wire_bearings: list | None = _f("list", "1/16 gradian")
    ad_interval: int | None = _f("int", "640 ns units")
    step_size: int | None = _f("int", "1/16 gradian")
    hd_ctrl: int | None = _f("int", "HdCtrl bits")
    device_type: int | None = _f("int", "SeaNet device type")
    gain_byte: int | None = _f("int", "0..210")
    ad_low_byte: int | None = _f("int", "0..255")
    ad_span_byte: int | None = _f("int", "0..255")
    nibble_order: str | None = _f("str", "low_first or high_first")
    left_lim: int | None = _f("int", "1/16 gradian")
    right_lim: int | None = _f("int", "1/16 gradian")
    angles: list | None = _f("list", "gradian")
    gain_setting: int | None = _f("int", "0..2")
    transmit_duration: int | None = _f("int", "us")
    sample_period: int | None = _f("int", "25 ns ticks")
    transmit_frequency: int | None = _f("int", "kHz")
    extra: dict[str, Any] = field(default_factory=dict)

    RENAMED = RENAMED   # the old names of the fields (a class attribute, not a field)

