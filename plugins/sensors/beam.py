"""Transducer beam patterns: one-way directivity B(az, el) and its importance sampling.

A direction (x, y, z) in the beam frame has azimuth ``atan2(x, z)`` and elevation ``asin(y)``;
+z is the boresight, +y the scan axis. B is an intensity ratio in [0, 1], 1 on the boresight;
the two-way gain of a monostatic transducer is ``B(d_tx) * B(d_rx)``.

Patterns
--------
``gaussian``  ``2^-((2 az / bw_h)^2 + (2 el / bw_v)^2)``: -3 dB at half the beam width, so the
              two-way -6 dB full width equals the beam width.
``sinc``      baffled rectangular piston of apertures ``a_h x a_v`` at ``frequency``:
              ``[sinc(pi a_h x / lambda) sinc(pi a_v y / lambda)]^2`` with x, y the direction
              cosines, zero behind the baffle. Apertures default to the ones whose main lobe has
              the requested -3 dB widths.
``uniform``   1 inside ``|az| <= bw_h / 2, |el| <= bw_v / 2``, 0 outside (for validation).
``table``     measured: a CSV with columns ``axis`` (``h`` or ``v``), ``angle_deg``, ``gain_db``
              (one way, 0 dB on the boresight); ``B = 10^((G_h(az) + G_v(el)) / 10)``, linear in dB
              between rows, 0 outside the tabulated angles.

Emission samples directions in proportion to ``B(az, el)`` (times the solid-angle Jacobian
``cos el``) from a piecewise-bilinear table over the pattern's support, so the emission weight
``B / pdf`` stays close to the beam's solid angle for every sample.
"""
from __future__ import annotations

import copy
import csv
import io
import math
import os

import drjit as dr
import mitsuba as mi
import numpy as np

from mitsonar._compat import trapezoid
from mitsonar._registry import Registry
from mitsonar.acoustics.water import SOUND_SPEED
from mitsonar.plugins.jit_arrays import upload

# Solves sinc(t)^2 = 1/2: the -3 dB point of a piston's one-way pattern.
_SINC_HALF_POWER = 1.3915573


def line_aperture(beamwidth_deg: float, frequency: float, sound_speed: float) -> float:
    """Length (m) of the uniform line aperture whose one-way -3 dB full width is ``beamwidth_deg``
    at ``frequency`` (Hz): ``D = 1.3916 lam / (pi sin(beta / 2))``, ``lam = c / f``."""
    lam = sound_speed / frequency
    return _SINC_HALF_POWER * lam / (math.pi * math.sin(math.radians(beamwidth_deg) / 2))

# Gaussian beams are sampled out to where B < 3e-8 (2.5 beam widths from the axis); the
# energy beyond is below float32 resolution of the total.
_GAUSS_SUPPORT = 2.5


#: Directivity indices by pattern parameters (`BeamPattern.directivity_index`).
_DI_CACHE: dict = {}


class BeamPatternError(ValueError):
    pass


#: pi in three float32 parts (Cody and Waite 1980; Cephes ``sinf``'s ``DP1..DP3`` times 4): ``k pi``
#: subtracted part by part is exact for the ``k`` a beam pattern meets (|k| < 2^8).
_PI_PARTS = (3.140625, 9.67502593994140625e-4, 1.509957990978376432e-7)


def sin_over_x(x):
    """``sin(x) / x`` (1 at 0) to float32 rounding for any ``|x| < 2^8 pi``, from float32 arithmetic
    alone: ``x = k pi + r`` with ``|r| <= pi/2`` (Cody-Waite reduction, `_PI_PARTS`), ``sin x =
    (-1)^k sin r``, ``sin r`` by its Taylor series to ``r^13`` (truncation below 7e-10 on
    ``[-pi/2, pi/2]``; Abramowitz and Stegun 4.3.65).

    Used on the ``cuda`` variants, where Dr.Jit's ``sin`` of a float32 is the GPU's approximate
    ``sin.approx`` (absolute error about 2^-21 only inside ``[-pi, pi]``, growing with ``|x|``
    outside): a piston's side lobes take ``x`` to 20 and more, and ``sin(x) / x`` there lost three
    significant digits (measured on an H100). The ``llvm`` variants keep Dr.Jit's own ``sin``
    (Cephes' reduction and polynomial: already accurate), so their scans keep their bytes."""
    k = dr.round(x * (1.0 / math.pi))
    r = x
    for part in _PI_PARTS:
        r = dr.fma(-k, part, r)
    r2 = dr.square(r)
    poly = 1.0 / 6227020800.0
    for c in (-1.0 / 39916800.0, 1.0 / 362880.0, -1.0 / 5040.0, 1.0 / 120.0, -1.0 / 6.0):
        poly = dr.fma(poly, r2, c)
    sin_r = dr.fma(r * r2, poly, r)
    odd = (mi.Int32(k) & 1) != 0
    out = dr.select(odd, -sin_r, sin_r) / x
    return dr.select(dr.abs(x) > 1e-6, out, 1.0)


def _approximate_sin():
    """True where Dr.Jit's float32 ``sin`` is the hardware approximation (the CUDA backend)."""
    return dr.backend_v(mi.Float) == dr.JitBackend.CUDA


def _sinc(t):
    t = np.asarray(t, dtype=np.float64)
    out = np.ones_like(t)
    nz = np.abs(t) > 1e-12
    out[nz] = np.sin(t[nz]) / t[nz]
    return out


def resolve_path(path: str) -> tuple[str | None, list[str]]:
    """Find a file the way Mitsuba's own plugins do: a relative path is looked up in the file
    resolver's folders (while a scene loads the first is the scene file's folder), then in the
    working directory. Returns (the path found or None, the absolute paths tried)."""
    if os.path.isabs(path):
        return (path if os.path.exists(path) else None), [path]
    tried = []
    for folder in [str(d) for d in mi.file_resolver()] + [os.getcwd()]:
        candidate = os.path.abspath(os.path.join(folder, path))
        if candidate not in tried:
            tried.append(candidate)
    return next((c for c in tried if os.path.exists(c)), None), tried


_TABLE_FORMAT = "expected CSV with columns axis,angle_deg,gain_db"
_TABLE_MAX_BYTES = 16 << 20  # a measured pattern is a few hundred rows


def read_beam_table(path: str):
    """Read a beam table CSV into ``{'h': (angles_deg, gain_db), 'v': (...)}`` with checks.

    A relative ``path`` is resolved against the scene file's folder first (see `resolve_path`)."""
    found, tried = resolve_path(path)
    if found is None:
        raise BeamPatternError(f"sonar 'beam_table': file {path!r} does not exist (tried {', '.join(tried)})")
    if os.path.isdir(found):
        raise BeamPatternError(f"sonar 'beam_table': {found} is a directory, not a CSV file")
    path = found
    try:
        with open(path, "rb") as fh:
            data = fh.read(_TABLE_MAX_BYTES + 1)
    except OSError as exc:
        raise BeamPatternError(f"{path}: cannot read the beam table ({exc.strerror or exc})") from None
    if len(data) > _TABLE_MAX_BYTES:
        raise BeamPatternError(f"{path}: beam table is larger than {_TABLE_MAX_BYTES >> 20} MiB ({_TABLE_FORMAT})")
    try:
        # utf-8-sig: a spreadsheet's byte-order mark must not become part of the first column's name
        content = data.decode("utf-8-sig")
    except UnicodeDecodeError:
        content = None
    if content is None or "\x00" in content:  # NUL decodes, but no text file holds it
        raise BeamPatternError(f"{path}: beam table is not UTF-8 text ({_TABLE_FORMAT})")
    rows = {"h": [], "v": []}
    reader = csv.DictReader(io.StringIO(content, newline=""))
    need = {"axis", "angle_deg", "gain_db"}
    try:
        if reader.fieldnames is None:
            raise BeamPatternError(f"{path}: beam table is empty ({_TABLE_FORMAT})")
        if not need.issubset({f.strip() for f in reader.fieldnames}):
            raise BeamPatternError(
                f"{path}: beam table needs the columns axis, angle_deg, gain_db; found {reader.fieldnames}")
        for lineno, row in enumerate(reader, start=2):
            _table_row(path, lineno, row, rows)
    except csv.Error as exc:
        raise BeamPatternError(f"{path}, line {reader.reader.line_num}: not CSV ({exc}; {_TABLE_FORMAT})") from None
    out = {}
    for axis, limit in (("h", 180.0), ("v", 90.0)):
        pts = sorted(rows[axis])
        if len(pts) < 2:
            raise BeamPatternError(f"{path}: axis {axis!r} needs at least 2 rows, found {len(pts)}")
        ang = np.array([p[0] for p in pts])
        if np.any(np.diff(ang) <= 0):
            raise BeamPatternError(f"{path}: axis {axis!r} repeats an angle_deg value")
        if ang[0] < -limit or ang[-1] > limit:
            raise BeamPatternError(f"{path}: axis {axis!r} angles must lie in [-{limit:g}, {limit:g}] deg")
        if not (ang[0] <= 0.0 <= ang[-1]):
            raise BeamPatternError(f"{path}: axis {axis!r} must cover the boresight (angle 0)")
        out[axis] = (ang, np.array([p[1] for p in pts]))
    return out


def _table_row(path, lineno, row, rows):
    """Check one CSV row of a beam table and add it to ``rows[axis]``."""
    row = {k.strip(): (v or "").strip() for k, v in row.items() if k is not None}
    axis = row["axis"].lower()
    if axis not in rows:
        raise BeamPatternError(f"{path}, line {lineno}: axis {row['axis']!r} is not one of h, v")
    try:
        a, g = float(row["angle_deg"]), float(row["gain_db"])
    except ValueError:
        raise BeamPatternError(
            f"{path}, line {lineno}: angle_deg and gain_db must be numbers, got "
            f"{row['angle_deg']!r}, {row['gain_db']!r}") from None
    if not (math.isfinite(a) and math.isfinite(g)):
        raise BeamPatternError(f"{path}, line {lineno}: angle_deg and gain_db must be finite")
    if g > 0.01:
        raise BeamPatternError(
            f"{path}, line {lineno}: gain_db {g} > 0: gains are one-way and relative to the boresight (0 dB)")
    rows[axis].append((a, g))


class Pattern:
    """One beam pattern's law: what differs between ``gaussian``, ``sinc``, ``uniform`` and
    ``table`` (the ``beam_pattern`` and ``tx_pattern`` strings of the XML).

    A `BeamPattern` holds the widths, frequency and sound speed every pattern shares, and asks its
    ``shape`` (the registered `Pattern` named by its ``pattern``) for the rest; this class and its
    subclasses are the one place a pattern's name is read (`register`, `lookup`, `get`). A new
    pattern is a subclass with its ``name``, the attributes and the methods that differ, made known
    with `register`: the sensor's ``beam_pattern`` (and, if it ``transmits``, ``tx_pattern``) then
    accept it.

    Attributes (class-level):

    ================== ==============================================================================
    name               the XML string
    transmits          may be a multibeam's transmit fan (``tx_pattern``)
    apertures          reads ``aperture_h``/``aperture_v`` (refused for the others)
    measured           reads a ``beam_table`` CSV (a scan records no more than its name, so its
                       directivity index cannot be recomputed from the scan)
    separable          ``B(az, el) = B_h(az) B_v(el)``: the solid angle is two 1D integrals
    traversed_widths   the sensor traverses ``beamwidth_h``/``_v`` as differentiable parameters
    bounded            lies within a window either side of the bearing (`share_window`): receive
                       beams may share transmit paths
    ================== ==============================================================================
    """

    name: str = ""
    transmits = True
    apertures = False
    measured = False
    separable = True
    traversed_widths = False
    bounded = True

    def setup(self, beam, aperture_h, aperture_v, table, source) -> None:
        """Set the pattern's own parameters on ``beam`` (apertures, table), or refuse them."""
        beam.aperture_h = beam.aperture_v = None
        beam.table = None

    def support(self, beam):
        """Angular rectangle (radians) holding all of the pattern: az_lo, az_hi, el_lo, el_hi."""
        raise NotImplementedError

    def eval_np(self, beam, az, el):
        """B(az, el) in float64 numpy (radians)."""
        raise NotImplementedError

    def axis_gains(self, beam, az, el):
        """(B(az, 0), B(0, el)) in numpy: the two factors of a separable pattern."""
        return beam.eval_np(az, np.zeros_like(az)), beam.eval_np(np.zeros_like(el), el)

    def build(self, beam) -> None:
        """Upload what the kernel of `eval` needs beyond the widths."""

    def eval(self, beam, az, el):
        """B(az, el) inside a kernel (radians)."""
        raise NotImplementedError

    def share_window(self, beam) -> float:
        """Radians either side of a receive beam's bearing that hold its pattern, for the receive
        beams sharing transmit paths (``plugins/integrators/paths/shared_beams.py``); a ValueError where the pattern
        has no such window."""
        lo, hi, _, _ = beam.support()
        return max(-lo, hi)

    def __repr__(self) -> str:
        return f"<beam pattern {self.name!r}>"


class Gaussian(Pattern):
    """``2^-((2 az / bw_h)^2 + (2 el / bw_v)^2)``."""

    name = "gaussian"
    traversed_widths = True
    #: A receive beam sharing transmit paths is scored within this many beam widths of its axis
    #: (beyond, B < 2^-16: ``plugins/integrators/paths/shared_beams.py``).
    SHARE_WINDOW = 2.0

    def support(self, beam):
        bh, bv = math.radians(beam.beamwidth_h), math.radians(beam.beamwidth_v)
        ah = min(math.pi, _GAUSS_SUPPORT * bh)
        av = min(math.pi / 2, _GAUSS_SUPPORT * bv)
        return -ah, ah, -av, av

    def eval_np(self, beam, az, el):
        bh, bv = math.radians(beam.beamwidth_h), math.radians(beam.beamwidth_v)
        return np.exp2(-((2 * az / bh) ** 2 + (2 * el / bv) ** 2))

    def eval(self, beam, az, el):
        return dr.exp2(-(dr.square(2 * az / beam._p_bh) + dr.square(2 * el / beam._p_bv)))

    def share_window(self, beam) -> float:
        return self.SHARE_WINDOW * math.radians(beam.beamwidth_h)


class Sinc(Pattern):
    """Baffled rectangular piston of apertures ``a_h x a_v``."""

    name = "sinc"
    apertures = True
    separable = False
    bounded = False

    def setup(self, beam, aperture_h, aperture_v, table, source) -> None:
        if aperture_h is None:
            aperture_h = line_aperture(beam.beamwidth_h, beam.frequency, beam.sound_speed)
        if aperture_v is None:
            aperture_v = line_aperture(beam.beamwidth_v, beam.frequency, beam.sound_speed)
        for name, a in (("aperture_h", aperture_h), ("aperture_v", aperture_v)):
            if not a > 0:
                raise BeamPatternError(f"{source} '{name}': {a} m must be > 0")
        beam.aperture_h, beam.aperture_v = float(aperture_h), float(aperture_v)
        beam.table = None

    def support(self, beam):
        return -math.pi / 2, math.pi / 2, -math.pi / 2, math.pi / 2

    def eval_np(self, beam, az, el):
        lam = beam.sound_speed / beam.frequency
        x = np.cos(el) * np.sin(az)
        y = np.sin(el)
        b = (_sinc(math.pi * beam.aperture_h * x / lam) * _sinc(math.pi * beam.aperture_v * y / lam)) ** 2
        return np.where(np.abs(az) <= math.pi / 2, b, 0.0)

    def build(self, beam) -> None:
        lam = beam.sound_speed / beam.frequency
        beam._p_kh = dr.opaque(mi.Float, math.pi * beam.aperture_h / lam)
        beam._p_kv = dr.opaque(mi.Float, math.pi * beam.aperture_v / lam)

    def eval(self, beam, az, el):
        x = beam._p_kh * dr.cos(el) * dr.sin(az)
        y = beam._p_kv * dr.sin(el)
        if _approximate_sin():
            sx, sy = sin_over_x(x), sin_over_x(y)
        else:
            sx = dr.select(dr.abs(x) > 1e-6, dr.sin(x) / x, 1.0)
            sy = dr.select(dr.abs(y) > 1e-6, dr.sin(y) / y, 1.0)
        return dr.select(dr.abs(az) <= dr.pi / 2, dr.square(sx * sy), 0.0)

    def share_window(self, beam) -> float:
        raise ValueError(f"sonar_tof 'share_beams': a {self.name!r} receive beam has side lobes over the whole "
                         f"half-space; use beam_pattern {_quoted('bounded')}, or share_beams false")


class Uniform(Pattern):
    """1 inside ``|az| <= bw_h / 2, |el| <= bw_v / 2``, 0 outside."""

    name = "uniform"

    def support(self, beam):
        bh, bv = math.radians(beam.beamwidth_h), math.radians(beam.beamwidth_v)
        return -bh / 2, bh / 2, -min(bv / 2, math.pi / 2), min(bv / 2, math.pi / 2)

    def eval_np(self, beam, az, el):
        bh, bv = math.radians(beam.beamwidth_h), math.radians(beam.beamwidth_v)
        return ((np.abs(az) <= bh / 2) & (np.abs(el) <= bv / 2)).astype(np.float64)

    def eval(self, beam, az, el):
        inside = (dr.abs(az) <= 0.5 * beam._p_bh) & (dr.abs(el) <= 0.5 * beam._p_bv)
        return dr.select(inside, 1.0, 0.0)


class Table(Pattern):
    """Measured: a CSV of one-way gains per axis (`read_beam_table`)."""

    name = "table"
    transmits = False
    measured = True

    def setup(self, beam, aperture_h, aperture_v, table, source) -> None:
        if table is None:
            raise BeamPatternError(f"{source} 'beam_table': a CSV file is required for beam_pattern {self.name!r}")
        beam.aperture_h = beam.aperture_v = None
        beam.table = table

    def support(self, beam):
        h, v = beam.table["h"][0], beam.table["v"][0]
        return (math.radians(h[0]), math.radians(h[-1]), math.radians(v[0]), math.radians(v[-1]))

    def eval_np(self, beam, az, el):
        (ha, hg), (va, vg) = beam.table["h"], beam.table["v"]
        deg_az, deg_el = np.degrees(az), np.degrees(el)
        g = np.interp(deg_az, ha, hg) + np.interp(deg_el, va, vg)
        inside = (deg_az >= ha[0]) & (deg_az <= ha[-1]) & (deg_el >= va[0]) & (deg_el <= va[-1])
        return np.where(inside, 10.0 ** (g / 10.0), 0.0)

    def axis_gains(self, beam, az, el):
        (ha, hg), (va, vg) = beam.table["h"], beam.table["v"]
        return 10.0 ** (np.interp(np.degrees(az), ha, hg) / 10.0), 10.0 ** (np.interp(np.degrees(el), va, vg) / 10.0)

    def build(self, beam) -> None:
        # Resample each axis onto a uniform grid (dB) so the kernel interpolates with one gather.
        beam._tab = {}
        for axis in ("h", "v"):
            ang, g = beam.table[axis]
            u = np.linspace(ang[0], ang[-1], 2049)
            beam._tab[axis] = (dr.opaque(mi.Float, math.radians(ang[0])),
                               dr.opaque(mi.Float, (len(u) - 1) / math.radians(ang[-1] - ang[0])),
                               upload(mi.Float, np.interp(u, ang, g), np.float32), len(u))

    def eval(self, beam, az, el):
        g, inside = mi.Float(0.0), mi.Bool(True)
        for axis, ang in (("h", az), ("v", el)):
            lo, scale, vals, n = beam._tab[axis]
            t = (ang - lo) * scale
            inside &= (t >= 0) & (t <= n - 1)
            i = mi.UInt32(dr.clip(dr.floor(t), 0, n - 2))
            w = dr.clip(t - mi.Float(i), 0.0, 1.0)
            g += dr.lerp(dr.gather(mi.Float, vals, i), dr.gather(mi.Float, vals, i + 1), w)
        return dr.select(inside, dr.exp2(g * (math.log2(10.0) / 10.0)), 0.0)


_PATTERNS = Registry(Pattern, "a beam Pattern", "beam pattern")
_REGISTRY = _PATTERNS.items


def register(pattern):
    """Make a `Pattern` (a subclass or an instance) known by its ``name``; returns it (usable as a
    class decorator). A name already taken is refused."""
    return _PATTERNS.register(pattern)


def unregister(name: str) -> None:
    """Forget the pattern called ``name`` (for tests that register a toy pattern)."""
    _PATTERNS.unregister(name)


GAUSSIAN, SINC, UNIFORM, TABLE = Gaussian(), Sinc(), Uniform(), Table()
for _p in (GAUSSIAN, SINC, UNIFORM, TABLE):
    register(_p)
#: The receive pattern (and transmit fan) of a head whose XML names none.
DEFAULT = GAUSSIAN.name


def names(**having) -> tuple:
    """The registered patterns' names in registration order; ``names(transmits=True)``: those whose
    attributes have the values given."""
    return tuple(n for n, p in _REGISTRY.items() if all(getattr(p, a) == v for a, v in having.items()))


def lookup(name):
    """The `Pattern` called ``name``, or None when no pattern has that name (or it is no string)."""
    return _REGISTRY.get(name) if isinstance(name, str) else None


def get(name, source: str = "sonar", field: str = "beam_pattern", **having) -> Pattern:
    """The `Pattern` called ``name`` among those `names` (``**having``) lists; otherwise a
    `BeamPatternError` naming ``source``, ``field`` and the allowed names."""
    allowed = names(**having)
    if not isinstance(name, str) or name not in allowed:
        raise BeamPatternError(f"{source} '{field}': {name!r} is not one of {', '.join(allowed)}")
    return _REGISTRY[name]


def which(attr: str) -> str:
    """The quoted names of the patterns whose ``attr`` is true, for messages: ``'sinc'``."""
    return " or ".join(repr(p.name) for p in _REGISTRY.values() if getattr(p, attr))


def _quoted(attr) -> str:
    """``'gaussian', 'uniform' or 'table'``: the patterns whose ``attr`` is true, for messages."""
    q = [repr(p.name) for p in _REGISTRY.values() if getattr(p, attr)]
    return q[0] if len(q) == 1 else ", ".join(q[:-1]) + " or " + q[-1]


class BeamPattern:
    """One-way directivity of a transducer and its importance sampler.

    Parameters (angles in degrees, as in the XML)

    ============== =====================================================================
    pattern        the name of a registered `Pattern`: ``gaussian``, ``sinc``, ``uniform``
                   or ``table``
    beamwidth_h    full -3 dB width across the scan plane (about the beam frame's x)
    beamwidth_v    full -3 dB width along the scan axis (y)
    frequency      Hz (``sinc``)
    aperture_h/_v  m (``sinc``); derived from the beam widths when None
    sound_speed    m/s (``sinc``: wavelength)
    table          parsed beam table (``table``)
    ============== =====================================================================

    ``pattern`` stays the name; ``shape`` is its `Pattern`, asked for everything that differs.
    """

    def __init__(self, pattern="gaussian", beamwidth_h=3.0, beamwidth_v=35.0, frequency=700e3,
                 aperture_h=None, aperture_v=None, sound_speed=SOUND_SPEED, table=None, source="sonar"):
        shape = get(pattern, source)
        for name, v, hi in (("beamwidth_h", beamwidth_h, 360.0), ("beamwidth_v", beamwidth_v, 180.0)):
            if not (0.0 < v <= hi):
                raise BeamPatternError(f"{source} '{name}': {v} deg is outside (0, {hi:g}]")
        # Impossible values are refused whatever the pattern, and apertures where no pattern uses them.
        if not (math.isfinite(frequency) and frequency > 0):
            raise BeamPatternError(f"{source} 'frequency': {frequency} Hz must be > 0")
        for name, a in (("aperture_h", aperture_h), ("aperture_v", aperture_v)):
            if a is not None and not (math.isfinite(a) and a > 0):
                raise BeamPatternError(f"{source} '{name}': {a} m must be > 0")
            if a is not None and not shape.apertures:
                raise BeamPatternError(f"{source} '{name}' is only used with beam_pattern {which('apertures')} "
                                       f"(got {pattern!r})")
        self.pattern = pattern
        self.shape = shape
        self.beamwidth_h = float(beamwidth_h)
        self.beamwidth_v = float(beamwidth_v)
        self.frequency = float(frequency)
        self.sound_speed = float(sound_speed)
        shape.setup(self, aperture_h, aperture_v, table, source)
        self._build()

    @property
    def kind(self) -> str:
        """The pattern's name: `pattern` (deprecated name, goes in the next release)."""
        import warnings

        warnings.warn("BeamPattern.kind is now BeamPattern.pattern; the old name goes in the next release",
                      DeprecationWarning, stacklevel=2)
        return self.pattern

    # ---------------------------------------------------------------- support and numpy eval
    def across_aperture(self) -> float:
        """m, the aperture across the narrow beam: a ``sinc`` piston's own ``aperture_h``, else the
        line aperture whose one-way -3 dB width is ``beamwidth_h`` at ``frequency`` (what scene
        speckle decorrelates over as the head moves, `mitsonar.receiver.speckle`)."""
        if self.aperture_h is not None:
            return self.aperture_h
        return line_aperture(self.beamwidth_h, self.frequency, self.sound_speed)

    def support(self):
        """Angular rectangle (radians) holding all of the pattern: az_lo, az_hi, el_lo, el_hi."""
        return self.shape.support(self)

    def eval_np(self, az, el):
        """B(az, el) in float64 numpy (radians)."""
        az, el = np.asarray(az, np.float64), np.asarray(el, np.float64)
        return self.shape.eval_np(self, az, el)

    def solid_angle(self, n=2048):
        """Integral of B over the sphere (sr), by quadrature on the sampling grid."""
        az_lo, az_hi, el_lo, el_hi = self.support()
        az = np.linspace(az_lo, az_hi, 2 * n + 1)
        el = np.linspace(el_lo, el_hi, n + 1)
        A, E = np.meshgrid(az, el)
        f = self.eval_np(A, E) * np.cos(E)
        return float(trapezoid(trapezoid(f, az, axis=1), el))

    def directivity_index(self) -> float:
        """dB, ``DI = 10 log10(4 pi / integral of B over the sphere)`` (Urick 1983, eq. 3.10),
        computed numerically for this pattern. ``gaussian``, ``uniform`` and ``table`` are
        separable in (az, el) with the measure ``cos(el) daz del``: two 1D integrals on fine grids;
        ``sinc`` (not separable in these angles) on a 2D grid of at least 30 samples per main
        lobe width on each axis, side lobes included (checked against ``10 log10(4 pi a_h a_v /
        lambda^2)`` for a large piston)."""
        if self.shape.measured:
            return 10.0 * math.log10(4.0 * math.pi / self.beam_solid_angle())
        # Renders record it every scan (surveys: every ping): computed once per pattern.
        key = (self.pattern, self.beamwidth_h, self.beamwidth_v, self.frequency, self.aperture_h, self.aperture_v,
               self.sound_speed)
        if key not in _DI_CACHE:
            if len(_DI_CACHE) > 256:
                _DI_CACHE.clear()
            _DI_CACHE[key] = 10.0 * math.log10(4.0 * math.pi / self.beam_solid_angle())
        return _DI_CACHE[key]

    def beam_solid_angle(self) -> float:
        """sr, the integral of B over the sphere (see `directivity_index`)."""
        az_lo, az_hi, el_lo, el_hi = self.support()
        bh, bv = math.radians(self.beamwidth_h), math.radians(self.beamwidth_v)
        if self.shape.separable:
            az = np.linspace(az_lo, az_hi, max(4097, int(200 * (az_hi - az_lo) / bh)) | 1)
            el = np.linspace(el_lo, el_hi, max(4097, int(200 * (el_hi - el_lo) / bv)) | 1)
            bh_, bv_ = self.shape.axis_gains(self, az, el)
            return float(trapezoid(bh_, az) * trapezoid(bv_ * np.cos(el), el))
        n_az = min(max(1025, int(30 * math.pi / bh)), 20001) | 1
        n_el = min(max(513, int(30 * math.pi / bv)), 20001) | 1
        az = np.linspace(az_lo, az_hi, n_az)
        el = np.linspace(el_lo, el_hi, n_el)
        rows = np.empty(n_el)
        step = max(1, 4_000_000 // n_az)
        for k in range(0, n_el, step):
            e = el[k:k + step, None]
            rows[k:k + step] = trapezoid(self.eval_np(az[None, :], e), az, axis=1) * np.cos(e[:, 0])
        return float(trapezoid(rows, el))

    # ---------------------------------------------------------------- Dr.Jit side
    def _build(self):
        az_lo, az_hi, el_lo, el_hi = self.support()
        # Resolve the narrow axis with ~40 cells per beam width (enough that bilinear
        # interpolation of B cos(el) leaves the emission weight within a few percent of constant).
        n_az = int(np.clip(math.ceil((az_hi - az_lo) / math.radians(self.beamwidth_h) * 40), 64, 4096))
        n_el = int(np.clip(math.ceil((el_hi - el_lo) / math.radians(self.beamwidth_v) * 40), 64, 2048))
        az = np.linspace(az_lo, az_hi, n_az)
        el = np.linspace(el_lo, el_hi, n_el)
        A, E = np.meshgrid(az, el)
        grid = self.eval_np(A, E) * np.maximum(np.cos(E), 0.0)
        if not np.any(grid > 0):
            raise BeamPatternError("sonar beam pattern is zero everywhere: nothing would be emitted")
        # A floor of 1e-6 of the peak bounds B / pdf in the far tails, where the float32 CDF
        # inversion can land in cells of vanishing density.
        grid = np.maximum(grid, 1e-6 * grid.max())
        self._distr = mi.MarginalContinuous2D0(np.ascontiguousarray(grid, dtype=np.float32))
        self._az_lo, self._el_lo = az_lo, el_lo
        self._az_span, self._el_span = az_hi - az_lo, el_hi - el_lo
        # Opaque copies so that a changed beam reuses the compiled kernels.
        self._p_az = dr.opaque(mi.Float, az_lo)
        self._p_el = dr.opaque(mi.Float, el_lo)
        self._p_saz = dr.opaque(mi.Float, self._az_span)
        self._p_sel = dr.opaque(mi.Float, self._el_span)
        bh, bv = math.radians(self.beamwidth_h), math.radians(self.beamwidth_v)
        self._p_bh = dr.opaque(mi.Float, bh)
        self._p_bv = dr.opaque(mi.Float, bv)
        self.shape.build(self)

    def eval(self, az: mi.Float, el: mi.Float) -> mi.Float:
        """B(az, el) inside a kernel (radians)."""
        return self.shape.eval(self, az, el)


    def eval_dir(self, d: mi.Vector3f) -> mi.Float:
        """B of a unit direction in the beam frame."""
        az = dr.atan2(d.x, d.z)
        el = dr.safe_asin(d.y)
        return self.eval(az, el)

    def sample(self, u: mi.Point2f, active=True):
        """Sample a beam-frame direction in proportion to B. Returns (direction, B / pdf)."""
        pos, _ = self._distr.sample(u, active=active)
        # The pdf is evaluated at the position the inversion returned, not taken from the
        # inversion: in float32 the cumulative sums of the far tail cells round to the same value
        # near 1, and there the inversion returns a position and a pdf that disagree by orders of
        # magnitude (docs/benchmarks.rst, "Which references to trust"). Evaluated here, B / pdf stays within
        # the interpolation error of the table's; what the inversion cannot resolve is the tail's
        # mass (< 1e-6 of the beam's).
        pdf = self._distr.eval(pos, active=active)
        az = self._p_az + pos.x * self._p_saz
        el = self._p_el + pos.y * self._p_sel
        cos_el = dr.cos(el)
        d = mi.Vector3f(cos_el * dr.sin(az), dr.sin(el), cos_el * dr.cos(az))
        # pdf is per unit square; per solid angle divide by the angular spans and cos(el).
        pdf_w = pdf / (self._p_saz * self._p_sel * cos_el)
        b = self.eval(az, el)
        weight = dr.select((pdf_w > 0) & (b > 0), b / pdf_w, 0.0)
        return d, weight

    # ---------------------------------------------------------------- gradients
    def attached(self, beamwidth_h=None, beamwidth_v=None):
        """A view of this pattern whose kernel widths carry the derivatives of ``beamwidth_h`` and
        ``beamwidth_v`` (mi.Float, degrees, e.g. the sensor's traversed parameters) while keeping
        this pattern's values bit for bit (``dr.replace_grad``), for the gradient passes of
        ``mitsonar.plugins.integrators.paths.path_replay``. The sampling table is shared and stays detached: emission
        weights ``B / pdf`` then differentiate as ``dB / pdf`` (detached sampling)."""
        view = copy.copy(self)
        deg = math.pi / 180.0
        if beamwidth_h is not None:
            view._p_bh = dr.replace_grad(self._p_bh, beamwidth_h * deg)
        if beamwidth_v is not None:
            view._p_bv = dr.replace_grad(self._p_bv, beamwidth_v * deg)
        return view
