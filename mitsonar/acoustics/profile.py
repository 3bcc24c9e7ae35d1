"""Sound-speed profiles: refracted rays, their travel times, and the inverse a hydrographer needs.

A `SoundSpeedProfile` is sound speed (m/s) against depth (m, positive down from the sea surface at
z = 0), linear between its samples and constant beyond its first and last ones (a cast need not
reach the transducer or the seabed). The water is horizontally stratified: a ray keeps Snell's
invariant ``a = cos(theta) / c(z)`` (``theta`` the grazing angle below the horizontal, positive
downward) and stays in its vertical launch plane.

Rays in a layer of constant gradient
------------------------------------
In a layer where ``c(z) = c1 + g (z - z1)`` the ray's grazing angle changes along its arc length
``s`` at the constant rate ``d theta / ds = -a g`` (from ``d(cos theta)/ds = a dc/ds = a g sin
theta``): the ray is an arc of a circle of radius ``R = 1 / (a g) = c / (g cos theta)`` whose
centre lies at the depth where ``c`` extrapolates to zero (Jensen, Kuperman, Porter & Schmidt,
*Computational Ocean Acoustics*, 2nd ed., Springer 2011, sec. 3.2, "ray tracing in a layered
medium with constant gradients"; Lurton, *An Introduction to Underwater Acoustics*, 2nd ed.,
Springer 2010, sec. 2.7.2). Integrating ``dx = cos theta ds``, ``dz = sin theta ds`` and
``dt = ds / c = -d theta / (g cos theta)`` from state 1 to state 2 gives

    dx = (sin theta1 - sin theta2) / (a g)
    dz = (c2 - c1) / g
    dt = (1 / g) ln[ c2 (1 + sin theta1) / (c1 (1 + sin theta2)) ]
       = (w1 - w2) / g,     w = atanh(sin theta) = ln tan(pi/4 + theta/2)

(``ln tan(pi/4 + theta/2)`` is the integral of ``sec theta``). The last line inverts in closed
form: after a time ``tau`` in the layer, ``u2 = u1 exp(-g tau)`` with ``u = tan(pi/4 + theta/2)``,
i.e. ``w2 = w1 - g tau``. With ``phi = g tau``, ``d = cosh phi - sin theta1 sinh phi`` (> 0) and
``S(x) = sinh x / x``, this is, written so that it holds as ``g -> 0`` (straight rays), for a
vertical ray (``a = 0``) and through a turning point alike:

    sin theta2 = (sin theta1 cosh phi - sinh phi) / d,      cos theta2 = cos theta1 / d,
    dz = c1 tau [sin theta1 S(phi) - (phi / 2) S(phi / 2)^2] / d,
    dx = a c1^2 tau S(phi) / d.

A ray whose ``a c`` reaches 1 inside a layer turns there (horizontal at the depth where
``c = 1 / a``) and goes back; the turn is part of the same circle, so the formulas above hold
across it. Between two depths on the same side of a turn, ``dx`` and ``dt`` are evaluated in the
cancellation-free forms ``dx = a dz (c1 + c2) / (sin theta1 + sin theta2)`` and
``dt = (1 / g) log1p(y)`` (see `_piece`), which stay exact when ``g`` is tiny or zero.
"""
from __future__ import annotations

import csv
import math
import os
import tempfile
from dataclasses import dataclass

import numpy as np

from mitsonar.acoustics._checks import ProfileError

__all__ = ["SoundSpeedProfile", "ProfileError", "RayPath", "SPEED_RANGE", "DEPTH_RANGE"]

#: Sound speeds this module accepts, m/s: every sea and fresh water there is (0 to 40 deg C,
#: 0 to 42 ppt, surface to 11 km: about 1400 to 1650 m/s), with margin.
SPEED_RANGE = (1300.0, 1700.0)
#: Depths of a profile's samples, m (positive down from the sea surface at z = 0).
DEPTH_RANGE = (0.0, 12000.0)

_FIELDS = ("depth", "sound_speed")


@dataclass(frozen=True)
class RayPath:
    """One traced ray (`SoundSpeedProfile.trace`): ``x`` horizontal distance from the launch
    point (m), ``depth`` (m, positive down), ``time`` one-way travel time from the launch (s),
    ``grazing`` the grazing angle there (rad, positive downward), all of the same length, and
    ``invariant`` Snell's ``cos(grazing) / c`` (s/m) of the whole ray."""

    x: np.ndarray
    depth: np.ndarray
    time: np.ndarray
    grazing: np.ndarray
    invariant: float


def _where(source, index, row_word):
    return f"{source}, {row_word} {index}"


def _check_samples(depths, speeds, source, rows, row_word):
    """Refuse a profile with one line: ``<source>, <row_word> <n>: <field> <value> ...``."""
    if len(depths) == 0:
        raise ProfileError(f"{source}: no samples (a profile needs at least one {'/'.join(_FIELDS)} pair)")
    lo_d, hi_d = DEPTH_RANGE
    lo_c, hi_c = SPEED_RANGE
    for i, (d, c) in enumerate(zip(depths, speeds)):
        where = _where(source, rows[i], row_word)
        if not math.isfinite(d):
            raise ProfileError(f"{where}: depth {d} is not a finite number (m, {lo_d:g} to {hi_d:g})")
        if not lo_d <= d <= hi_d:
            raise ProfileError(f"{where}: depth {d:g} m is outside {lo_d:g} to {hi_d:g} m "
                               "(positive down from the sea surface)")
        if i and not d > depths[i - 1]:
            raise ProfileError(f"{where}: depth {d!r} m is not greater than the previous {depths[i - 1]!r} m "
                               "(depths strictly increasing)")
        if not math.isfinite(c):
            raise ProfileError(f"{where}: sound_speed {c} is not a finite number (m/s, {lo_c:g} to {hi_c:g})")
        if not lo_c <= c <= hi_c:
            raise ProfileError(f"{where}: sound_speed {c:g} m/s is outside {lo_c:g} to {hi_c:g} m/s")


def _log1p_over(y):
    """``log1p(y) / y``, 1 at ``y = 0`` (exact to rounding for small ``|y|``)."""
    y = np.asarray(y, dtype=float)
    small = np.abs(y) < 1e-8
    with np.errstate(divide="ignore", invalid="ignore"):
        out = np.log1p(y) / np.where(small, 1.0, y)
    return np.where(small, 1.0 - y / 2.0 + y * y / 3.0, out)


def _sinhc(x):
    """``sinh(x) / x``, 1 at 0."""
    x = np.asarray(x, dtype=float)
    small = np.abs(x) < 1e-6
    with np.errstate(invalid="ignore", over="ignore"):
        out = np.sinh(x) / np.where(small, 1.0, x)
    return np.where(small, 1.0 + x * x / 6.0, out)


def _piece(dz, c1, s1, c2, s2, a, g):
    """Horizontal distance and travel time of a ray between depths ``z1 < z2 = z1 + dz`` on one
    side of any turn, oriented downward: ``(c1, s1)`` speed and ``sin(grazing) >= 0`` at the top,
    ``(c2, s2)`` at the bottom, gradient ``g`` (``c2 - c1 = g dz``). An upward ray takes the same
    time and distance (the reversed ray).

    ``dx = (s1 - s2) / (a g)`` with ``s1^2 - s2^2 = a^2 (c2^2 - c1^2)`` is ``a dz (c1 + c2) / (s1 + s2)``;
    ``dt = (1/g) ln[c2 (1 + s1) / (c1 (1 + s2))] = (1/g) log1p(y)`` with
    ``y = g dz K / (c1 (1 + s2))``, ``K = (1 + s1) + c1 a^2 (c1 + c2) / (s1 + s2)``: no cancellation
    as ``g -> 0`` (then ``dt = dz / (c sin theta)``, a straight ray).
    """
    # float64 arrays, not Python floats: a zero-length piece (a ray launched horizontally where it
    # turns, ``s1 = s2 = 0``) divides 0 by 0 under errstate and is then set to 0 below, instead of
    # raising ZeroDivisionError from a scalar division
    dz, c1, s1, c2, s2, a, g = (np.asarray(v, dtype=np.float64) for v in (dz, c1, s1, c2, s2, a, g))
    with np.errstate(divide="ignore", invalid="ignore"):
        ssum = s1 + s2
        dx = a * dz * (c1 + c2) / ssum
        K = (1.0 + s1) + c1 * a * a * (c1 + c2) / ssum
        D = c1 * (1.0 + s2)
        y = g * dz * K / D
        dt = dz * K / D * _log1p_over(y)
    zero = dz == 0
    return np.where(zero, 0.0, dx), np.where(zero, 0.0, dt)


def _sin_at(a, c):
    """``|sin(grazing)|`` where the speed is ``c``: ``sqrt((1 - a c)(1 + a c))``, 0 past a turn."""
    ac = a * c
    return np.sqrt(np.clip((1.0 - ac) * (1.0 + ac), 0.0, None))


class SoundSpeedProfile:
    """Sound speed against depth: ``SoundSpeedProfile(depths, speeds)``.

    ``depths`` (m, positive down from the sea surface at z = 0, strictly increasing, 0 to 12 km)
    and ``speeds`` (m/s, 1300 to 1700): linear between samples, constant beyond the first and the
    last. Build one from arrays, `from_csv` (header ``depth,sound_speed``), `from_ctd` (a CTD cast
    through Mackenzie 1981) or `constant`. Refused input raises `ProfileError` (a ValueError) with
    one line naming the source, the sample and the field.

    See the module docstring for the ray equations `trace` and `locate` use.
    """

    def __init__(self, depths, speeds, *, source="SoundSpeedProfile", rows=None, row_word="sample"):
        try:
            d = np.atleast_1d(np.asarray(depths, dtype=float))
            c = np.atleast_1d(np.asarray(speeds, dtype=float))
        except (TypeError, ValueError):
            raise ProfileError(f"{source}: depths and speeds must be arrays of numbers") from None
        if d.ndim != 1 or c.shape != d.shape:
            raise ProfileError(f"{source}: depths {d.shape} and speeds {c.shape} must be 1-D arrays of one length")
        rows = list(range(len(d))) if rows is None else list(rows)
        _check_samples(d.tolist(), c.tolist(), source, rows, row_word)
        d.setflags(write=False)
        c.setflags(write=False)
        self.depths, self.speeds, self.source = d, c, source
        n = len(d)
        # Layer j spans [top[j], bottom[j]]: layer 0 is above the first sample, layer n below the
        # last (both constant), layers 1..n-1 between samples.
        self._top = np.concatenate([[-np.inf], d])
        self._bottom = np.concatenate([d, [np.inf]])
        self._ct = np.concatenate([[c[0]], c])
        self._cb = np.concatenate([c, [c[-1]]])
        g = np.zeros(n + 1)
        if n > 1:
            g[1:n] = np.diff(c) / np.diff(d)
        self._g = g

    # ------------------------------------------------------------------------------------------
    # construction, files

    @classmethod
    def constant(cls, speed):
        """A uniform water column at ``speed`` m/s (straight rays)."""
        return cls([0.0], [speed], source="SoundSpeedProfile.constant")

    @classmethod
    def from_ctd(cls, depths, temperature, salinity, *, model="mackenzie", latitude=45.0, strict=False):
        """A profile from a CTD cast: sound speed at each sample by Mackenzie (1981), or the
        ``model`` named (`mitsonar.acoustics.sound_speed`: ``"unesco"``, ``"del_grosso"``, at
        ``latitude``; temperature in deg C, salinity in ppt, depth in m). A sample outside the
        equation's range warns once (refused with ``strict=True``)."""
        from mitsonar.acoustics.seawater import sound_speed

        try:
            c = sound_speed(temperature, salinity, depths, model=model, latitude=latitude, strict=strict)
        except ValueError as exc:
            raise ProfileError(f"SoundSpeedProfile.from_ctd: {exc}") from None
        d = np.broadcast_to(np.asarray(depths, dtype=float), np.shape(c))
        return cls(d, c, source="SoundSpeedProfile.from_ctd")

    @classmethod
    def from_csv(cls, path):
        """Read a CSV file: a header ``depth,sound_speed`` then one sample per row (m, m/s).
        Blank lines are skipped. Errors name the file, the row (counting the header as row 1, as a
        spreadsheet does) and the field, e.g. ``svp.csv, row 4: depth 10.0 m is not greater than
        the previous 12.0 m (depths strictly increasing)``."""
        name = os.fspath(path)
        try:
            with open(name, newline="") as f:
                lines = list(csv.reader(f))
        except OSError as exc:
            raise ProfileError(f"{name}: cannot read the sound-speed profile ({exc.strerror or exc})") from None
        except (csv.Error, UnicodeDecodeError) as exc:
            raise ProfileError(f"{name}: not a CSV file ({exc})") from None
        rows = [(i + 1, [v.strip() for v in r]) for i, r in enumerate(lines) if any(v.strip() for v in r)]
        if not rows:
            raise ProfileError(f"{name}: empty file (a header depth,sound_speed and at least one row)")
        head_row, header = rows[0]
        if [h.lower() for h in header] != list(_FIELDS):
            raise ProfileError(f"{name}, row {head_row}: header {','.join(header)!r} is not depth,sound_speed")
        depths, speeds, numbers = [], [], []
        for row, values in rows[1:]:
            if len(values) != 2:
                raise ProfileError(f"{name}, row {row}: {len(values)} fields, expected 2 (depth,sound_speed)")
            parsed = []
            for field, v in zip(_FIELDS, values):
                try:
                    parsed.append(float(v))
                except ValueError:
                    raise ProfileError(f"{name}, row {row}: {field} {v!r} is not a number") from None
            depths.append(parsed[0])
            speeds.append(parsed[1])
            numbers.append(row)
        if not depths:
            raise ProfileError(f"{name}: no samples after the header (at least one depth,sound_speed row)")
        return cls(depths, speeds, source=name, rows=numbers, row_word="row")

    def to_csv(self, path):
        """Write the profile as `from_csv` reads it (full precision: it reads back exactly), under
        a temporary name renamed at the end."""
        path = os.fspath(path)
        folder = os.path.dirname(os.path.abspath(path))
        fd, tmp = tempfile.mkstemp(prefix=".svp-", suffix=".csv", dir=folder)
        try:
            with os.fdopen(fd, "w", newline="") as f:
                f.write("depth,sound_speed\n")
                for d, c in zip(self.depths, self.speeds):
                    f.write(f"{float(d)!r},{float(c)!r}\n")
            os.replace(tmp, path)
        except BaseException:
            if os.path.exists(tmp):
                os.remove(tmp)
            raise

    def __repr__(self):
        return (f"SoundSpeedProfile({len(self.depths)} samples, {self.depths[0]:g} to {self.depths[-1]:g} m, "
                f"{self.speeds.min():.2f} to {self.speeds.max():.2f} m/s)")

    def __eq__(self, other):
        return (isinstance(other, SoundSpeedProfile) and np.array_equal(self.depths, other.depths)
                and np.array_equal(self.speeds, other.speeds))

    __hash__ = None

    def speed(self, depth):
        """Sound speed (m/s) at ``depth`` (m; any shape): linear between samples, constant beyond."""
        out = np.interp(np.asarray(depth, dtype=float), self.depths, self.speeds)
        return out[()] if isinstance(out, np.ndarray) else out

    # ------------------------------------------------------------------------------------------
    # rays

    def _start(self, func, depth, grazing):
        z = np.asarray(depth, dtype=float)
        th = np.asarray(grazing, dtype=float)
        if not np.isfinite(z).all():
            raise ProfileError(f"{func}: depth {z[~np.isfinite(z)].flat[0]} is not a finite number (m)")
        if (z < 0).any():
            raise ProfileError(f"{func}: depth {z[z < 0].flat[0]:g} m is above the sea surface "
                               "(a start depth >= 0 m, positive down)")
        ok = np.isfinite(th) & (np.abs(th) <= np.pi / 2 + 1e-12)
        if not ok.all():
            raise ProfileError(f"{func}: grazing {th[~ok].flat[0]} is not allowed "
                               "(radians from the horizontal, -pi/2 to pi/2, positive downward)")
        th = np.clip(th, -np.pi / 2, np.pi / 2)
        s = np.sin(th)
        cos = np.cos(th)
        c = np.interp(z, self.depths, self.speeds)
        # a vertical ray: cos(pi/2) is 6e-17, not 0
        cos = np.where(np.abs(th) == np.pi / 2, 0.0, cos)
        s = np.where(np.abs(th) == np.pi / 2, np.sign(th), s)
        return z, s, cos / c

    def _step(self, z, s, a, down):
        """One layer traversal of each ray from depth ``z`` with ``sin(grazing) = s`` heading
        ``down`` (bool; a horizontal ray heads down unless the layer below turns it at once):
        ``layer, z_exit, s_exit, down_exit, dt, dx`` (infinite ``dt``/``dx`` for a ray that never
        leaves its layer)."""
        with np.errstate(divide="ignore", invalid="ignore", over="ignore"):
            return self._step_quiet(z, s, a, down)

    def _step_quiet(self, z, s, a, down):
        D = self.depths
        j = np.where(down, np.searchsorted(D, z, side="right"), np.searchsorted(D, z, side="left"))
        zt, zb, ct, cb, g = self._top[j], self._bottom[j], self._ct[j], self._cb[j], self._g[j]
        c = np.interp(z, D, self.speeds)
        s_abs = np.abs(s)
        st, sb = _sin_at(a, ct), _sin_at(a, cb)
        reach_b = a * cb <= 1.0
        reach_t = a * ct <= 1.0
        with np.errstate(divide="ignore", invalid="ignore"):
            inv_a = 1.0 / a
            z_turn = np.where(down, zt, zb) + (inv_a - np.where(down, ct, cb)) / np.where(g == 0, np.inf, g)
        # straight on: down to the bottom, or up to the top
        dx_d, dt_d = _piece(zb - z, c, s_abs, cb, sb, a, g)
        dx_u, dt_u = _piece(z - zt, ct, st, c, s_abs, a, g)
        # a turn: (down) z -> z_turn, then z_turn -> top; (up) z -> z_turn, then z_turn -> bottom
        zero = np.zeros_like(z)
        dx_a, dt_a = _piece(np.where(down, z_turn - z, z - z_turn), np.where(down, c, inv_a),
                            np.where(down, s_abs, zero), np.where(down, inv_a, c), np.where(down, zero, s_abs), a, g)
        dx_b, dt_b = _piece(np.where(down, z_turn - zt, zb - z_turn), np.where(down, ct, inv_a),
                            np.where(down, st, zero), np.where(down, inv_a, cb), np.where(down, zero, sb), a, g)
        straight = np.where(down, reach_b, reach_t)
        dx = np.where(straight, np.where(down, dx_d, dx_u), dx_a + dx_b)
        dt = np.where(straight, np.where(down, dt_d, dt_u), dt_a + dt_b)
        down_exit = np.where(straight, down, ~down)
        z_exit = np.where(down_exit, zb, zt)
        s_exit = np.where(down_exit, sb, -st)
        endless = ~np.isfinite(z_exit) | ~np.isfinite(dt)
        dt = np.where(endless, np.inf, dt)
        dx = np.where(endless, np.inf, dx)
        return j, z_exit, s_exit, down_exit, dt, dx

    def _inside(self, j, z, s, a, tau):
        """State after ``tau`` seconds in layer ``j`` from ``(z, s)``: ``dx, z2, s2, cos2`` (closed
        form of the module docstring: ``w2 = w1 - g tau``)."""
        g = self._g[j]
        c = np.interp(z, self.depths, self.speeds)
        phi = g * tau
        ch, sh = np.cosh(phi), np.sinh(phi)
        den = ch - s * sh
        dz = c * tau * (s * _sinhc(phi) - 0.5 * phi * _sinhc(0.5 * phi) ** 2) / den
        dx = a * c * c * tau * _sinhc(phi) / den
        s2 = np.clip((s * ch - sh) / den, -1.0, 1.0)
        cos2 = (a * c) / den
        z2 = np.clip(z + dz, self._top[j], self._bottom[j])
        return dx, z2, s2, cos2

    def eigenrays(self, source_depth, receiver_depth, range, **kwargs):
        """Every ray joining the source and the receiver at horizontal ``range`` (m), with travel
        time, launch and arrival angles, one-way transmission loss and phase (float64): a table of
        `mitsonar.acoustics.propagation.ARRIVAL_DTYPE`; keywords (``water_depth``, ``bottom``,
        ``absorption``, ``max_bounces``, ...) as in `mitsonar.acoustics.propagation.eigenrays`."""
        from mitsonar.acoustics.propagation import eigenrays

        return eigenrays(self, source_depth, receiver_depth, range, **kwargs)

    def arrivals(self, source_depth, receiver_depth, range, **kwargs):
        """`eigenrays` as a list of dicts, one per arrival in time order
        (`mitsonar.acoustics.propagation.arrivals`)."""
        from mitsonar.acoustics.propagation import arrivals

        return arrivals(self, source_depth, receiver_depth, range, **kwargs)

    def transmission_loss(self, source_depth, receiver_depth, range, **kwargs):
        """One-way incoherent transmission loss, dB re 1 m
        (`mitsonar.acoustics.propagation.transmission_loss`)."""
        from mitsonar.acoustics.propagation import transmission_loss

        return transmission_loss(self, source_depth, receiver_depth, range, **kwargs)

    def locate(self, depth, grazing, travel_time):
        """Where rays are after a one-way ``travel_time`` (s): ``(x, depth)``, horizontal distance
        from the launch point and depth (m), broadcast over ``depth`` (start depth, m),
        ``grazing`` (launch angle below the horizontal, rad, -pi/2 to pi/2) and ``travel_time``.

        Whole layers are crossed with the closed forms of the module docstring, the last one solved
        for the time left (``u2 = u1 exp(-g dt)``). The water column has no boundary: a ray that
        turns and climbs above the first sample goes on straight (there is no sea surface here).
        """
        z0, s0, a0 = self._start("locate", depth, grazing)
        t = np.asarray(travel_time, dtype=float)
        if not np.isfinite(t).all() or (t < 0).any():
            bad = t[~(np.isfinite(t) & (t >= 0))].flat[0]
            raise ProfileError(f"locate: travel_time {bad} is not allowed (a one-way time >= 0 s)")
        z, s, a, tau = (np.array(v, dtype=float).ravel() for v in np.broadcast_arrays(z0, s0, a0, t))
        shape = np.broadcast_shapes(z0.shape, s0.shape, a0.shape, t.shape)
        x = np.zeros_like(z)
        down = s >= 0
        idle = np.zeros(z.shape, dtype=int)       # consecutive zero-time turns: a ray on a channel axis
        todo = np.arange(z.size)
        while todo.size:
            zi, si, ai, di, ti = z[todo], s[todo], a[todo], down[todo], tau[todo]
            j, z_e, s_e, d_e, dt, dx = self._step(zi, si, ai, di)
            # the sign of a horizontal ray's sine is its heading in the closed form below
            s_signed = np.where((si == 0) & ~di, -0.0, si)
            last = ti <= dt
            if last.any():
                k = todo[last]
                ddx, z2, _, _ = self._inside(j[last], zi[last], s_signed[last], ai[last], ti[last])
                x[k] += ddx
                z[k] = z2
            go = ~last
            stuck = go & (dt == 0)
            idle[todo[go]] = np.where(stuck[go], idle[todo[go]] + 1, 0)
            axis = go & (idle[todo] >= 3)
            if axis.any():       # horizontal along a speed minimum: straight on at that speed
                k = todo[axis]
                x[k] += np.interp(z[k], self.depths, self.speeds) * tau[k]
                go &= ~axis
            k = todo[go]
            tau[k] = ti[go] - dt[go]
            x[k] += dx[go]
            z[k], s[k], down[k] = z_e[go], s_e[go], d_e[go]
            todo = k
        return x.reshape(shape), z.reshape(shape)

    def _time_to_depth(self, j, z, s, a, down, target):
        """First time (s) the ray starting this traversal reaches ``target`` inside layer ``j``, or
        None. Scalars."""
        zt, zb = self._top[j], self._bottom[j]
        if not zt <= target <= zb:
            return None
        c = float(np.interp(z, self.depths, self.speeds))
        ct_ = float(np.interp(target, self.depths, self.speeds))
        if a * ct_ > 1.0:
            return None
        s_t = float(_sin_at(a, ct_))
        g = self._g[j]
        if down:
            reach = a * self._cb[j] <= 1.0 or not math.isfinite(zb)
            z_far = zb if reach else zt + (1.0 / a - self._ct[j]) / g
            if z <= target <= z_far:
                return float(_piece(np.float64(target - z), c, abs(s), ct_, s_t, a, g)[1])
            if not reach and zt <= target <= z_far:        # after the turn, on the way up
                dt_a = _piece(np.float64(z_far - z), c, abs(s), 1.0 / a, 0.0, a, g)[1]
                return float(dt_a + _piece(np.float64(z_far - target), ct_, s_t, 1.0 / a, 0.0, a, g)[1])
        else:
            reach = a * self._ct[j] <= 1.0 or not math.isfinite(zt)
            z_far = zt if reach else zb + (1.0 / a - self._cb[j]) / g
            if z_far <= target <= z:
                return float(_piece(np.float64(z - target), ct_, s_t, c, abs(s), a, g)[1])
            if not reach and z_far <= target <= zb:
                dt_a = _piece(np.float64(z - z_far), 1.0 / a, 0.0, c, abs(s), a, g)[1]
                return float(dt_a + _piece(np.float64(target - z_far), 1.0 / a, 0.0, ct_, s_t, a, g)[1])
        return None

    def trace(self, depth, grazing, *, travel_time=None, to_depth=None, samples=16, max_layers=100000):
        """Trace one ray from ``depth`` (m) launched at ``grazing`` (rad below the horizontal,
        positive downward) until the one-way ``travel_time`` (s) or until it first reaches
        ``to_depth`` (m), whichever comes first (at least one of them): a `RayPath` with a point at
        the launch, at every layer boundary and turning point it passes, ``samples`` points inside
        each layer crossing (evaluated with the closed form, exact on the circular arc) and at the
        end. A ray that can never reach ``to_depth`` (it turns above it, or runs horizontally)
        with no ``travel_time`` is refused with one line."""
        if travel_time is None and to_depth is None:
            raise ProfileError("trace: give travel_time (s) or to_depth (m): where the ray stops")
        if travel_time is not None and not (math.isfinite(travel_time) and travel_time >= 0):
            raise ProfileError(f"trace: travel_time {travel_time!r} is not allowed (a one-way time >= 0 s)")
        if to_depth is not None and not math.isfinite(to_depth):
            raise ProfileError(f"trace: to_depth {to_depth!r} is not a finite depth (m)")
        if not (isinstance(samples, int) and samples >= 0):
            raise ProfileError(f"trace: samples {samples!r} is not allowed (a count >= 0)")
        z0, s0, a0 = self._start("trace", float(depth), float(grazing))
        z, s, a = np.array([z0]), np.array([s0]), float(a0)
        down = np.array([s0 >= 0])
        xs, zs, ts, gs = [0.0], [float(z0)], [0.0], [float(grazing)]
        x, t, idle = 0.0, 0.0, 0
        t_end = math.inf if travel_time is None else float(travel_time)
        if to_depth is not None and float(to_depth) == float(z0):
            t_end = 0.0
        never = (f"trace: the ray from {float(depth):g} m at {math.degrees(float(grazing)):g} deg never reaches "
                 f"depth {to_depth!r} m (it turns or runs horizontally before it); give travel_time to stop it")

        def sample(j, span, s_signed):
            tau = np.linspace(0.0, span, samples + 2)[1:]
            g = self._g[j]
            if g != 0 and abs(s_signed) < 1:      # the turning point (w = atanh(sin) reaches 0), if on the way
                t_turn = math.atanh(s_signed) / g
                if 0 < t_turn < span:
                    tau = np.sort(np.append(tau, t_turn))
            ddx, z2, s2, cos2 = self._inside(np.full(tau.shape, j), np.full(tau.shape, z[0]),
                                             np.full(tau.shape, s_signed), np.full(tau.shape, a), tau)
            xs.extend(x + ddx)
            zs.extend(z2)
            ts.extend(t + tau)
            gs.extend(np.arctan2(s2, cos2))

        for _ in range(max_layers):
            j, z_e, s_e, d_e, dt, dx = self._step(z, s, np.array([a]), down)
            j, dt = int(j[0]), float(dt[0])
            s_signed = -0.0 if (s[0] == 0 and not down[0]) else float(s[0])
            stop, hit = t_end - t, False
            if to_depth is not None:
                t_hit = self._time_to_depth(j, float(z[0]), float(s[0]), a, bool(down[0]), float(to_depth))
                if t_hit is not None and t_hit <= dt and t_hit <= stop:
                    stop, hit = t_hit, True
            if stop <= dt:                       # the ray stops in this layer
                if not math.isfinite(stop):
                    raise ProfileError(never)
                if stop > 0:
                    sample(j, stop, s_signed)
                    if hit:
                        zs[-1] = float(to_depth)     # exactly there (the closed form rounds)
                t += stop
                break
            if dt == 0:
                idle += 1
                if idle >= 3:          # horizontal on a speed minimum: straight on at that speed
                    if not math.isfinite(t_end):
                        raise ProfileError(never)
                    c = float(np.interp(z[0], self.depths, self.speeds))
                    tau = np.linspace(0.0, t_end - t, samples + 2)[1:]
                    xs.extend(x + c * tau)
                    zs.extend([float(z[0])] * len(tau))
                    ts.extend(t + tau)
                    gs.extend([0.0] * len(tau))
                    break
            else:
                idle = 0
                sample(j, dt, s_signed)
            x += float(dx[0])
            t += dt
            z, s, down = z_e, s_e, d_e
            if dt > 0:   # the boundary point, from the boundary state itself
                xs[-1], zs[-1], ts[-1] = x, float(z[0]), t
                gs[-1] = float(np.arctan2(s[0], a * np.interp(z[0], self.depths, self.speeds)))
        else:
            raise ProfileError(f"trace: the ray crossed {max_layers} layers without stopping")
        return RayPath(np.array(xs), np.array(zs), np.array(ts), np.array(gs), a)
