"""A survey's place on the Earth: a geodetic origin and a projected CRS (`GeoFrame`).

The world frame of a georeferenced survey is a local grid, as survey software's are: x and y are
offsets in a projected CRS from the origin's projected coordinates (``x = E - E0``, ``y = N - N0``,
metres of that CRS's grid, x east and y north of the grid), z up from the origin's height. Scans
stay in these local metres (their poses unchanged) and carry the origin and the CRS in their
metadata (``meta.origin`` = [lat, lon, height], ``meta.crs`` = ``"EPSG:NNNN"``); the products
(XTF navigation, LAS points, GeoTIFF grids) are written in the CRS or in WGS 84 lat/lon.

    frame = GeoFrame.make((43.642567, -79.387139), None)      # default CRS: the origin's UTM zone
    frame.crs                                                  # 'EPSG:32617'
    lon, lat = frame.to_lonlat(x, y)                           # grid offsets -> WGS 84 degrees
    e, n = frame.to_grid(x, y)                                 # -> eastings, northings of the CRS

The conversions go through pyproj (PROJ; the ``geo`` extra). The default UTM zone is the plain
6-degree zone of the origin's longitude, ``floor((lon + 180) / 6) + 1`` (EPSG 326zz north of the
equator, 327zz south; the Norway and Svalbard exceptions are not applied: give ``--crs`` there);
north of 84 N or south of 80 S, outside UTM, the default is the polar stereographic UPS North
(EPSG:32661) or South (EPSG:32761).

A CRS must hold the origin (`check_crs` with ``origin``): the origin inside the CRS's area of use
(pyproj's ``area_of_use``), a grid in metres, and a scale error at the origin of at most
`SCALE_ERROR_ALLOWED` (Web Mercator, EPSG:3857, stretches distances by 1/cos(lat): +62 % at
52 N). Otherwise it is refused in one line that suggests the origin's own zone (`suggested_crs`).
Grid north differs from true north by the meridian convergence: `GeoFrame.true_heading` turns a
direction in the grid into an azimuth from true north (pyproj's geodesic on the WGS 84 ellipsoid).
"""
from __future__ import annotations

import math
import os
import xml.etree.ElementTree as ET
from dataclasses import dataclass, field

import numpy as np

#: The flags' words, repeated in every refusal.
ORIGIN_ALLOWED = "LAT LON [HEIGHT]: latitude in [-90, 90] deg, longitude in [-180, 180] deg, height in m"
CRS_ALLOWED = "a projected CRS as EPSG:NNNN, e.g. EPSG:32631 (WGS 84 / UTM 31N); default the origin's UTM zone"
WGS84 = "EPSG:4326"


class GeoError(ValueError):
    """A bad origin or CRS: one line naming the flag (or field) and the allowed values."""


def _pyproj(where):
    try:
        import pyproj
    except ImportError:
        raise GeoError(f"{where}: georeferencing needs pyproj: pip install 'mitsonar[geo]'") from None
    return pyproj


def utm_epsg(lat: float, lon: float) -> str:
    """The EPSG code of the WGS 84 UTM zone of (lat, lon): ``EPSG:326zz`` north, ``EPSG:327zz``
    south, zone ``floor((lon + 180) / 6) + 1`` (1..60; lon = 180 is zone 60)."""
    zone = min(60, int(math.floor((lon + 180.0) / 6.0)) + 1)
    return f"EPSG:{(32600 if lat >= 0 else 32700) + zone}"


def suggested_crs(lat: float, lon: float) -> str:
    """The default CRS of an origin: its UTM zone (`utm_epsg`) between 80 S and 84 N (UTM's
    extent), else UPS North (EPSG:32661) or South (EPSG:32761)."""
    if -80.0 <= lat <= 84.0:
        return utm_epsg(lat, lon)
    return "EPSG:32661" if lat > 0 else "EPSG:32761"


#: The largest scale error of a grid at the origin (distance on the grid / distance on the
#: ellipsoid - 1): UTM's is under 0.1 % within its zones, a national grid's under 0.5 %.
SCALE_ERROR_ALLOWED = 0.01


def _where_on_earth(lat, lon) -> str:
    return f"{abs(lat):g} {'N' if lat >= 0 else 'S'} {abs(lon):g} {'E' if lon >= 0 else 'W'}"


def _covers(bounds, lat, lon) -> bool:
    """Whether pyproj's area of use ``(west, south, east, north)`` holds (lat, lon); an area
    across the antimeridian has west > east."""
    west, south, east, north = bounds
    if not south <= lat <= north:
        return False
    return west <= lon <= east if west <= east else (lon >= west or lon <= east)


def _scale(obj, lat, lon) -> float:
    """Distance on the grid of ``obj`` over distance on the WGS 84 ellipsoid, 100 m from the
    origin east and north (the larger error of the two)."""
    pyproj = _pyproj("crs")
    to_grid = pyproj.Transformer.from_crs(WGS84, obj, always_xy=True)
    geod = pyproj.Geod(ellps="WGS84")
    e0, n0 = to_grid.transform(lon, lat, errcheck=False)
    worst = 1.0
    for azimuth in (0.0, 90.0):
        lon1, lat1, _ = geod.fwd(lon, lat, azimuth, 100.0)
        e1, n1 = to_grid.transform(lon1, lat1, errcheck=False)
        k = math.hypot(e1 - e0, n1 - n0) / 100.0
        if not math.isfinite(k):
            return k
        worst = k if abs(k - 1.0) > abs(worst - 1.0) else worst
    return worst


def check_origin(origin, where="--origin") -> tuple[float, float, float]:
    """``(lat, lon, height)`` of ``origin`` (2 or 3 numbers), or a `GeoError` naming ``where``."""
    try:
        values = [float(v) for v in origin]
    except (TypeError, ValueError):
        raise GeoError(f"{where} {origin!r}: not allowed ({ORIGIN_ALLOWED})") from None
    shown = " ".join(f"{v:g}" for v in values)
    if len(values) not in (2, 3) or not all(math.isfinite(v) for v in values):
        raise GeoError(f"{where} {shown}: not allowed ({ORIGIN_ALLOWED})")
    lat, lon = values[:2]
    if not (-90.0 <= lat <= 90.0 and -180.0 <= lon <= 180.0):
        raise GeoError(f"{where} {shown}: off the Earth ({ORIGIN_ALLOWED})")
    return lat, lon, values[2] if len(values) == 3 else 0.0


def check_crs(crs, where="--crs", origin=None):
    """The `pyproj.CRS` of ``crs`` (``"EPSG:NNNN"``, or an int), refused unless it is a known EPSG
    code of a projected CRS with its grid in metres; with ``origin`` (lat, lon), also unless the
    origin lies in the CRS's area of use and the grid's scale error there is at most
    `SCALE_ERROR_ALLOWED` (the refusal suggests `suggested_crs`). Returns ``(name "EPSG:NNNN",
    pyproj.CRS)``. The one check of an output CRS: `GeoFrame.make` runs it for every command."""
    pyproj = _pyproj(where)
    text = f"EPSG:{crs}" if isinstance(crs, (int, np.integer)) else str(crs).strip()
    head, _, code = text.partition(":")
    if head.upper() != "EPSG" or not code.isdigit():
        raise GeoError(f"{where} {crs}: not allowed ({CRS_ALLOWED})")
    try:
        obj = pyproj.CRS.from_epsg(int(code))
    except pyproj.exceptions.CRSError:
        raise GeoError(f"{where} {crs}: unknown EPSG code ({CRS_ALLOWED})") from None
    if not obj.is_projected:
        crs_type = "geographic" if obj.is_geographic else "not projected"
        raise GeoError(f"{where} {crs}: {obj.name} is {crs_type}, without a projection to a grid in metres "
                       f"({CRS_ALLOWED})")
    units = sorted({a.unit_name for a in obj.axis_info if a.unit_name != "metre"})
    if units:
        raise GeoError(f"{where} {crs}: {obj.name} has its grid in {' and '.join(units)}; surveys need metres "
                       f"({CRS_ALLOWED})")
    name = f"EPSG:{int(code)}"
    if origin is not None:
        _check_holds(name, obj, float(origin[0]), float(origin[1]), where)
    return name, obj


def _check_holds(name, obj, lat, lon, where) -> None:
    """Refuse a CRS whose area of use leaves out the origin, or whose scale error there exceeds
    `SCALE_ERROR_ALLOWED`, naming the origin's own CRS."""
    own = suggested_crs(lat, lon)
    instead = f"use the origin's {'UPS grid' if own in ('EPSG:32661', 'EPSG:32761') else 'UTM zone'}, {own}"
    at = _where_on_earth(lat, lon)
    area = obj.area_of_use
    if area is not None and not _covers(area.bounds, lat, lon):
        w, s, e, n = area.bounds
        raise GeoError(f"{where} {name}: the origin {at} is outside the area of use of {obj.name} "
                       f"(lon {w:g}..{e:g}, lat {s:g}..{n:g}); {instead}")
    k = _scale(obj, lat, lon)
    if not (math.isfinite(k) and abs(k - 1.0) <= SCALE_ERROR_ALLOWED):
        error = "no finite scale" if not math.isfinite(k) else f"a scale error of {100 * (k - 1):+.0f} %"
        why = " (Web Mercator stretches distances by 1/cos(lat))" if "Pseudo Mercator" in (
            getattr(obj.coordinate_operation, "method_name", "") or "") else ""
        raise GeoError(f"{where} {name}: {obj.name} has {error} at the origin {at}{why}; surveys need true "
                       f"metres: {instead}")


@dataclass(frozen=True)
class GeoFrame:
    """A geodetic origin (WGS 84 ``lat``, ``lon`` in degrees, ``height`` in m) and a projected
    ``crs`` (``"EPSG:NNNN"``); world x, y are grid offsets from the origin's ``(e0, n0)``."""

    lat: float
    lon: float
    height: float
    crs: str
    e0: float = field(default=0.0, compare=False)
    n0: float = field(default=0.0, compare=False)

    @classmethod
    def make(cls, origin, crs=None, where=("--origin", "--crs")) -> "GeoFrame":
        """Checked: ``origin`` (lat, lon[, height]), ``crs`` (None: the origin's UTM zone,
        `suggested_crs`), the CRS against the origin (`check_crs`)."""
        lat, lon, h = check_origin(origin, where[0])
        name, _ = check_crs(suggested_crs(lat, lon) if crs is None else crs, where[1], origin=(lat, lon))
        pyproj = _pyproj(where[1])
        e0, n0 = pyproj.Transformer.from_crs(WGS84, name, always_xy=True).transform(lon, lat, errcheck=False)
        if not (math.isfinite(e0) and math.isfinite(n0)):
            raise GeoError(f"{where[1]} {crs}: the origin {lat:g} {lon:g} has no coordinates in it ({CRS_ALLOWED})")
        return cls(lat, lon, h, name, float(e0), float(n0))

    @classmethod
    def from_meta(cls, meta, where="scan meta") -> "GeoFrame | None":
        """The frame a scan's metadata holds (``origin`` and ``crs``), or None without an origin."""
        origin = getattr(meta, "origin", None) if not isinstance(meta, dict) else meta.get("origin")
        crs = getattr(meta, "crs", None) if not isinstance(meta, dict) else meta.get("crs")
        if origin is None:
            return None
        return cls.make(origin, crs, (f"{where} 'origin'", f"{where} 'crs'"))

    def meta(self) -> dict:
        """What a scan's metadata holds: ``{"origin": [lat, lon, height], "crs": "EPSG:NNNN"}``."""
        return {"origin": [self.lat, self.lon, self.height], "crs": self.crs}

    @property
    def pyproj_crs(self):
        return _pyproj("crs").CRS.from_user_input(self.crs)

    def wkt(self) -> str:
        """The CRS as OGC WKT 1 (what LAS and GeoTIFF readers take)."""
        from pyproj.enums import WktVersion

        return self.pyproj_crs.to_wkt(WktVersion.WKT1_GDAL)

    def to_grid(self, x, y):
        """Eastings and northings of the CRS of world ``x``, ``y``: ``(x + e0, y + n0)``."""
        return np.asarray(x, np.float64) + self.e0, np.asarray(y, np.float64) + self.n0

    def from_grid(self, e, n):
        return np.asarray(e, np.float64) - self.e0, np.asarray(n, np.float64) - self.n0

    def _transformer(self, inverse):
        pyproj = _pyproj("crs")
        src, dst = (self.crs, WGS84) if not inverse else (WGS84, self.crs)
        return pyproj.Transformer.from_crs(src, dst, always_xy=True)

    def to_lonlat(self, x, y):
        """WGS 84 ``(lon, lat)`` in degrees of world ``x``, ``y``."""
        e, n = self.to_grid(x, y)
        lon, lat = self._transformer(False).transform(e, n)
        return np.asarray(lon, np.float64), np.asarray(lat, np.float64)

    def from_lonlat(self, lon, lat):
        """World ``(x, y)`` of WGS 84 ``lon``, ``lat`` (degrees)."""
        e, n = self._transformer(True).transform(np.asarray(lon, np.float64), np.asarray(lat, np.float64))
        return self.from_grid(e, n)

    def true_heading(self, x, y, dx, dy, step=1.0):
        """Azimuth (deg clockwise from true north, [0, 360)) of the grid direction ``(dx, dy)`` at
        world ``(x, y)``: the geodesic azimuth from the point to the point ``step`` m along it."""
        pyproj = _pyproj("crs")
        x, y, dx, dy = np.broadcast_arrays(*(np.asarray(v, np.float64) for v in (x, y, dx, dy)))
        norm = np.hypot(dx, dy)
        norm = np.where(norm > 0, norm, 1.0)
        lon0, lat0 = self.to_lonlat(x, y)
        lon1, lat1 = self.to_lonlat(x + step * dx / norm, y + step * dy / norm)
        az, _, _ = pyproj.Geod(ellps="WGS84").inv(lon0, lat0, lon1, lat1)
        return np.mod(np.asarray(az, np.float64), 360.0)


def add_geo_options(parser):
    """``--origin LAT LON [HEIGHT]`` and ``--crs EPSG:NNNN`` (read back by `frame_from_args`)."""
    parser.add_argument("--origin", nargs="+", type=float, metavar="LAT/LON/HEIGHT",
                        help="LAT LON [HEIGHT]: the geodetic origin of the world frame (WGS 84 deg, height m): world x, y are "
                             "grid offsets in --crs from it")
    parser.add_argument("--crs", metavar="EPSG:NNNN",
                        help="projected CRS of the grid (default: the origin's UTM zone)")


def frame_from_args(args) -> "GeoFrame | None":
    """The `GeoFrame` of ``--origin``/``--crs`` (None without ``--origin``; ``--crs`` alone is refused).
    A command with a scene (``args.scene``) whose XML records a frame (`scene_frame`)
    takes it without the flags; flags that name another frame are refused."""
    origin, crs = getattr(args, "origin", None), getattr(args, "crs", None)
    scene = getattr(args, "scene", None)
    if isinstance(scene, str):
        recorded = scene_frame(scene)
        if recorded is not None:
            given = None if origin is None else GeoFrame.make(origin, crs)
            if given is not None and given != recorded or given is None and crs is not None and \
                    check_crs(crs)[0] != recorded.crs:
                shown = " ".join(f"{v:.9g}" for v in (recorded.lat, recorded.lon, recorded.height))
                raise GeoError(f"{scene} records origin {shown} and crs {recorded.crs}; --origin/--crs name another "
                               "frame: drop them (the scene's frame is used) or convert the scene again")
            return recorded
    if origin is None:
        if crs is not None:
            raise GeoError(f"--crs {crs}: needs --origin LAT LON [HEIGHT] (the point the world frame starts at)")
        return None
    return GeoFrame.make(origin, crs)


# ---- the frame a scene records ----
#
# Where a scene keeps its place on the Earth: two Mitsuba ``<default>`` parameters.
#
# A scene written by ``mitsonar scene from-grid`` or ``from-sdf`` (`mitsonar.scenes.grid`,
# `mitsonar.scenes.sdf`) carries the origin and CRS of its world frame (the
# `mitsonar.geometry.geodesy.GeoFrame` that ``--origin``/``--crs`` give the survey and export
# commands) as two parameter defaults at the top of its XML::
#
#     <default name="mitsonar_origin" value="52.0000000001 4.49999999 0"/>   <!-- lat lon height -->
#     <default name="mitsonar_crs" value="EPSG:32631"/>
#
# Mitsuba's parser takes a ``<default>`` of any name and uses it only where the scene says
# ``$mitsonar_origin`` (nowhere), so the file stays a plain Mitsuba scene (an attribute on
# ``<scene>`` would be refused: "unexpected attribute"). `scene_frame` reads them back;
# `frame_from_args` falls back on it when a command that takes a scene
# (``survey``, ``bathymetry``) gets no ``--origin``, so the products come out in the scene's CRS.

ORIGIN_PARAM = "mitsonar_origin"
CRS_PARAM = "mitsonar_crs"


def frame_defaults(frame) -> str:
    """The two ``<default>`` elements that record ``frame`` (a `GeoFrame`) in a scene."""
    lat, lon, h = (repr(float(v)) for v in (frame.lat, frame.lon, frame.height))
    return (f'<default name="{ORIGIN_PARAM}" value="{lat} {lon} {h}"/>\n'
            f'    <default name="{CRS_PARAM}" value="{frame.crs}"/>')


def scene_frame(path_or_xml):
    """The `GeoFrame` a scene file (or XML text) records (`frame_defaults`), or None when it
    records none (or is not readable XML: loading it says why). A recorded origin or CRS that is
    not allowed is refused in one line naming the file and the parameter."""
    text = str(path_or_xml)
    where = "XML string"
    if not text.lstrip().startswith("<"):
        if not os.path.isfile(text):
            return None
        where = text
        with open(text, "rb") as f:
            text = f.read()
    try:
        root = ET.fromstring(text)
    except ET.ParseError:
        return None
    values = {el.get("name"): el.get("value", "") for el in root.findall("default")}
    if ORIGIN_PARAM not in values:
        return None
    origin = values[ORIGIN_PARAM].split()
    return GeoFrame.make(origin, values.get(CRS_PARAM),
                         (f"{where}: <default name=\"{ORIGIN_PARAM}\">", f"{where}: <default name=\"{CRS_PARAM}\">"))
