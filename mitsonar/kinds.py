"""Sonar kinds as classes: what differs between a mechanical, a multibeam and a side-scan head.

A scan's or a sensor's ``kind`` stays a string (the XML ``kind``, ``Scan.kind``, the files'
header), and this module is the one place that string is read: `lookup` (or `kind_of`, or
``Scan.sonar_kind``, or the sensor's ``sonar_kind``) gives the `SonarKind` instance, and every
behaviour that differs between kinds is asked of it (what the rows are, where they point, when
they fire, the default ping period, the default beam, which products and pictures apply, how the
ROS export and the survey treat them, which device protocols can serve them). No other module of
mitsonar or of its plugins compares a kind string or keeps a table keyed by kind names
(tests/test_architecture.py checks).

A new kind is a subclass of `SonarKind` with its ``name`` and the attributes and methods that
differ, made known with `register`: the sensor plugin, `Scan`, the files and the CLI then accept
it. `names` lists the registered kinds in registration order (``mechanical``, ``multibeam``,
``sidescan``, ``volumetric``; the first three are the tuple the old ``mitsonar.geometry.frames.KINDS`` held, which moved here and is
still importable as ``mitsonar.kinds.KINDS``, a tuple of today's names).

The echo sounders of `mitsonar.scenes.echosounders` are not kinds of their own: they differ from
these only in their published figures and their downward mount, so they stay presets there. A
bathymetric multibeam (MBES) preset configures a `MULTIBEAM` head; the ``altimeter`` preset
(``tritech_pa500``, a single-beam echo sounder) configures a `MECHANICAL` head with one fixed
ping. ``EchoSounder.kind`` holds that `SonarKind`.

numpy only (and `mitsonar.geometry.frames`), so the plugins may use it.
"""
from __future__ import annotations

import math
from collections.abc import Mapping

import numpy as np

from mitsonar._registry import Registry
from mitsonar.geometry.frames import STARBOARD, bearing_rotation, elevation_rotation, sidescan_rotation

__all__ = ["SonarKind", "Mechanical", "Multibeam", "Sidescan", "Volumetric", "MECHANICAL", "MULTIBEAM", "SIDESCAN",
           "VOLUMETRIC",
           "DEFAULT", "register", "unregister", "lookup", "get", "kind_of", "names", "which", "by_name"]


class SonarKind:
    """One kind of sonar head: the defaults and the behaviour that tell it from the others.

    Attributes (class-level; a subclass overrides what differs):

    ================== ==============================================================================
    name               the ``kind`` string (XML, ``Scan.kind``, files)
    row_name           what a scan's rows are: ``pings`` or ``beams``
    steered            rows point at ``bearing_start + k bearing_step`` (the sensor reads both)
    sided              port and starboard channels (the sensor reads ``side``, ``depression``,
                       ``preset``; ``Scan.channel`` says which row is which)
    transmit_fan       rows are receive beams formed across one transmit fan (``tx_*``, shared
                       transmit paths, one frame fired at once)
    head_overhead      s per ping beyond the two-way flight to ``range_max`` (default period)
    default_beamwidths (beamwidth_h, beamwidth_v) in deg when the XML gives none
    max_swath          deg the rows' bearings may span (None: any)
    pictures           the pictures that make sense; the first is the default (was ``plot_kinds``,
                       which still works with a DeprecationWarning until 0.4.0)
    has_fan            the rows spread over bearings of one fan (the ROS fan image)
    bathymetry_method  the default bottom detection of `bathymetry` surveys
    max_sounding_fan   deg of bearings a bathymetric fan may span (None: not checked)
    scanlines          rows are a mechanically scanned head's scanlines (SeaNet and Ping360 serve
                       only these)
    world_picture      a survey draws its first scan over the scene's mesh
    mosaic             a survey makes waterfalls and a mosaic of it
    head_frame_mount   ``to_world`` is the head frame itself (x forward, y port, z up), so the
                       dataset jobs mount it with the identity
    share_beams        the receive beams lie in one fan about +y, so ``sonar_tof`` may score a
                       frame's shared transmit paths into them (`plugins/integrators/paths/shared_beams.py`)
    fan_frame          rows are one fan of receive beams fired at once: the frame a multibeam head
                       (the Oculus) serves and logs
    grid               rows are beams over an elevation x azimuth grid (the sensor reads
                       ``n_azimuth``, ``n_elevation``, ``elevation_start``, ``elevation_step``;
                       ``Scan.volume`` reshapes the rows)
    ================== ==============================================================================
    """

    name: str = ""
    row_name = "pings"
    steered = True
    sided = False
    transmit_fan = False
    head_overhead = 0.0
    default_beamwidths = (3.0, 35.0)
    max_swath = None
    pictures = ("polar", "cartesian", "ascan")
    has_fan = True
    bathymetry_method = "leading_edge"
    max_sounding_fan = None
    scanlines = False
    world_picture = False
    mosaic = False
    head_frame_mount = False
    share_beams = False
    fan_frame = False
    grid = False

    # ------------------------------------------------------------------ rows
    def bearings_deg(self, start: float, step: float, n_rows: int) -> np.ndarray:
        """(n_rows,) deg: each row's bearing, ``start + k step``."""
        return start + np.arange(n_rows) * step

    def channels(self, side, pings: int):
        """(rows,) channel of each row (0 port, 1 starboard) for ``pings`` pings per channel; None
        for a kind without channels."""
        return None

    def ping_times(self, ping_period: float, pings: int, n_rows: int) -> np.ndarray:
        """(n_rows,) seconds of each row's ping from the scan start: ``k * ping_period``."""
        return np.arange(n_rows) * ping_period

    def scan_period(self, ping_period: float, pings: int) -> float:
        """Seconds from one scan's start to the next one's: ``pings`` pings."""
        return ping_period * pings

    def elevations_deg(self, start: float, step: float, n_rows: int, n_azimuth: int) -> np.ndarray:
        """(n_rows,) deg: each row's elevation; zeros, the rows lie in the plane of bearings."""
        return np.zeros(n_rows)

    def rotations(self, bearings_deg, channels, depression, elevations_deg=None) -> np.ndarray:
        """(n_rows, 4, 4) rotation from the head's frame to each row's beam frame: the bearing
        rotation (`mitsonar.geometry.frames.bearing_rotation`), then the elevation's
        (`mitsonar.geometry.frames.elevation_rotation`) where rows have one."""
        r = bearing_rotation(np.radians(bearings_deg))
        return r if elevations_deg is None else r @ elevation_rotation(np.radians(elevations_deg))

    def ascan_row(self, n_rows: int) -> int:
        """The row an A-scan picture shows when none is asked for."""
        return 0

    def render_meta(self, sonar) -> dict:
        """What `render_scan` records in ``Scan.meta`` for this kind beyond every scan's fields."""
        return {}

    def __repr__(self) -> str:
        return f"<sonar kind {self.name!r}>"

    # ------------------------------------------------------------------ old names (until 0.4.0)
    def __init_subclass__(cls, **kwargs):
        super().__init_subclass__(**kwargs)
        if "plot_kinds" in cls.__dict__:      # a kind written for 0.2: its pictures, warned
            from mitsonar._moved import warn_renamed

            warn_renamed("SonarKind.plot_kinds")
            cls.pictures = cls.__dict__["plot_kinds"]
            delattr(cls, "plot_kinds")

    @property
    def plot_kinds(self) -> tuple:
        """The pictures: `pictures` (the old name, removed in 0.4.0)."""
        from mitsonar._moved import warn_renamed

        warn_renamed("SonarKind.plot_kinds")
        return self.pictures


class Mechanical(SonarKind):
    """A mechanically scanned imaging sonar (MSIS, e.g. Tritech Micron, Ping360): one monostatic
    beam stepped ping by ping; ping ``k`` at bearing ``bearing_start + k bearing_step`` fires at
    ``k * ping_period``. 30 ms per ping beyond the flight (stepping the transducer, sending the
    data): a Micron then steps every 43 ms at 10 m and 46 ms at 12 m, within its observed 43 to
    65 ms."""

    name = "mechanical"
    head_overhead = 0.030
    scanlines = True
    world_picture = True


class Multibeam(SonarKind):
    """A multibeam head (forward-looking sonar, bathymetric MBES): one transmit fan fixed in the
    head frame and one receive beam per row, all rows fired at once (a frame), frames
    ``ping_period`` apart. 50 ms per frame beyond the flight (beamforming)."""

    name = "multibeam"
    row_name = "beams"
    transmit_fan = True
    head_overhead = 0.050
    max_swath = 360.0
    bathymetry_method = "centroid"
    max_sounding_fan = 180.0
    share_beams = True
    fan_frame = True

    def ping_times(self, ping_period, pings, n_rows):
        """Zeros: the rows of a frame fire together."""
        return np.zeros(n_rows)

    def scan_period(self, ping_period, pings):
        """One frame."""
        return ping_period

    def ascan_row(self, n_rows):
        """The fan's centre row."""
        return n_rows // 2


class Sidescan(SonarKind):
    """A side-scan head: port and starboard channels (``side``), each turned down by
    ``depression`` (`mitsonar.geometry.frames.sidescan_rotation`), both channels of ping ``k``
    fired together at ``k * ping_period``; rows are the port pings then the starboard pings. No
    overhead beyond the flight. Its rows are not bearings: no fan to draw."""

    name = "sidescan"
    steered = False
    sided = True
    default_beamwidths = (1.0, 50.0)   # narrow along track, a wide fan across it
    pictures = ("waterfall", "ascan")
    has_fan = False
    mosaic = True
    head_frame_mount = True

    def bearings_deg(self, start, step, n_rows):
        """Zeros: fixed channels, each row's direction is in its pose."""
        return np.zeros(n_rows)

    def channels(self, side, pings):
        sides = {"port": [0], "starboard": [STARBOARD], "both": [0, STARBOARD]}[side]
        return np.repeat(np.array(sides, dtype=np.int64), pings)

    def ping_times(self, ping_period, pings, n_rows):
        return np.tile(np.arange(pings) * ping_period, n_rows // pings)

    def rotations(self, bearings_deg, channels, depression):
        """Each row's channel turned down by ``depression`` deg."""
        return sidescan_rotation(channels, math.radians(depression))

    def render_meta(self, sonar):
        """Which rows are which channel (``Scan.channel``) and the channels' tilt."""
        meta = dict(side=sonar.side, depression=float(sonar.depression), pings_per_channel=int(sonar.pings))
        if sonar.preset is not None:
            meta["preset"] = sonar.preset
        return meta


class Volumetric(Multibeam):
    """A 3D imaging head (e.g. Coda Octopus Echoscope, Water Linked Sonar 3D-15): one wide transmit
    beam and a receive beam per row over an elevation x azimuth grid, all fired at once (a frame,
    like a multibeam's). Row ``k = i n_azimuth + j`` looks at azimuth ``bearing_start + j
    bearing_step`` and elevation ``elevation_start + i elevation_step``: its beam frame is the
    head's turned by ``bearing_rotation(az) @ elevation_rotation(el)``, so its boresight is
    ``(cos el sin az, sin el, cos el cos az)`` in the head frame
    (`mitsonar.signals.volumetric.directions`). A frame's rows reshape to the volume
    ``(n_elevation, n_azimuth, n_bins)`` (``Scan.volume``). The rows do not lie in one fan:
    ``sonar_tof`` traces them per row (no shared beams) and there is no fan image to draw."""

    name = "volumetric"
    grid = True
    share_beams = False
    fan_frame = False
    has_fan = False
    pictures = ("ascan",)
    max_sounding_fan = None

    def bearings_deg(self, start, step, n_rows, n_azimuth=None):
        """Row ``i n_azimuth + j``'s azimuth: ``start + j step``."""
        n = n_rows if n_azimuth is None else int(n_azimuth)
        return start + (np.arange(n_rows) % n) * step

    def elevations_deg(self, start, step, n_rows, n_azimuth):
        """Row ``i n_azimuth + j``'s elevation: ``start + i step``."""
        return start + (np.arange(n_rows) // int(n_azimuth)) * step

    def render_meta(self, sonar):
        """The grid: ``n_azimuth``, ``n_elevation``, ``elevation_start``, ``elevation_step``."""
        return dict(n_azimuth=int(sonar.n_azimuth), n_elevation=int(sonar.n_elevation),
                    elevation_start=float(sonar.elevation_start), elevation_step=float(sonar.elevation_step))


_KINDS = Registry(SonarKind, "a SonarKind", "sonar kind")
_REGISTRY = _KINDS.items


def register(kind):
    """Make a `SonarKind` (a subclass or an instance) known by its ``name``; returns it (usable as
    a class decorator). A name already taken is refused."""
    return _KINDS.register(kind)


def unregister(name: str) -> None:
    """Forget the kind called ``name`` (for tests that register a toy kind)."""
    _KINDS.unregister(name)


MECHANICAL, MULTIBEAM, SIDESCAN, VOLUMETRIC = Mechanical(), Multibeam(), Sidescan(), Volumetric()
for _k in (MECHANICAL, MULTIBEAM, SIDESCAN, VOLUMETRIC):
    register(_k)
#: The kind of a head (and a `Scan`) that names none.
DEFAULT = MECHANICAL.name


def names() -> tuple:
    """The registered kinds' names, in registration order."""
    return tuple(_REGISTRY)


def lookup(name):
    """The `SonarKind` called ``name``, or None when no kind has that name (or it is no string)."""
    return _REGISTRY.get(name) if isinstance(name, str) else None


def get(name, where: str = "kind") -> SonarKind:
    """The `SonarKind` called ``name``; a ValueError naming ``where`` and the kinds otherwise."""
    kind = lookup(name)
    if kind is None:
        raise ValueError(f"{where}: {name!r} is not allowed (one of {', '.join(names())})")
    return kind


def kind_of(obj, default=None):
    """The `SonarKind` of anything with a ``kind`` string (a `Scan`, a sensor); ``default`` (a
    name) for an object without one; None for an unknown name."""
    return lookup(getattr(obj, "kind", default))


def which(attr: str) -> str:
    """The quoted names of the kinds whose ``attr`` is true, for messages: ``'multibeam'``."""
    return " or ".join(repr(k.name) for k in _REGISTRY.values() if getattr(k, attr))


class _View(Mapping):
    """A read-only, live ``{name: attribute}`` view of the registered kinds."""

    def __init__(self, attr):
        self.attr = attr

    def __getitem__(self, name):
        kind = lookup(name)
        if kind is None:
            raise KeyError(name)
        return getattr(kind, self.attr)

    def __iter__(self):
        return iter(names())

    def __len__(self):
        return len(_REGISTRY)

    def __repr__(self):
        return repr(dict(self))


def by_name(attr: str) -> Mapping:
    """``{kind name: its attr}`` for every registered kind, live (a kind registered later appears)."""
    return _View(attr)


def __getattr__(name):
    if name == "KINDS":      # the old mitsonar.geometry.frames.KINDS
        return names()
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
