"""Refracted transport: echo paths through a horizontally stratified sound-speed profile.

The water is `mitsonar.acoustics.profile.SoundSpeedProfile`'s: speed against depth ``z = -world
z`` (the sea surface at world z = 0), linear between samples, constant beyond. A ray keeps
Snell's invariant ``a = cos(theta) / c`` and stays in its vertical launch plane; in a layer of
constant gradient ``g`` it is an exact circular arc (Jensen, Kuperman, Porter & Schmidt,
*Computational Ocean Acoustics*, 2nd ed. 2011, sec. 3.2; the closed forms are the ones of
``mitsonar/acoustics/profile.py``'s docstring, ported to Dr.Jit here: `_piece` gives the time and
horizontal distance through a layer, `_inside` the state after a time ``tau`` in it).

What a path does (`common.SonarIntegrator._sample_primal` calls these when a profile is set):

* **Outgoing segments** (`trace`): the exact ray state is advanced in time steps of ``dt``
  (`advance`, arithmetic only: as many layers as the step crosses); the scene is intersected along
  the straight *chord* between two successive exact points (``ray_intersect_preliminary`` with
  ``t_max`` = chord length). The only approximation: between its end points the ray is taken as
  that chord (sagitta ``l^2 kappa / 8`` for a chord ``l`` and curvature ``kappa = a |g|``: 3 mm
  for a 10 m chord where ``g = 0.5 /s``) and the time along it grows as through a speed linear
  along the chord (``t(f) = dt ln(1 + r f) / ln(1 + r)``, ``r = c_end / c_start - 1``). ``dt``
  is ``range_max / (chords * c_sensor)``: ``chords`` (XML ``svp_chords``, default 4) chords per
  range window. A segment stops once its time leaves no echo inside the window. The time to the
  hit itself is one Newton step on the exact arc: the arc's state at the interpolated time
  (`advance` from the hit chord's start), moved along its tangent to the surface's tangent plane
  at the hit (exact for a plane up to the square of the interpolation's error times the
  curvature; the interpolation alone erred by 0.7 bins where a long chord crosses a change of
  gradient). Echo ranges then no longer depend on ``chords``; the chords still set where a ray
  meets the scene (within the sagitta).
* **Merged layers** (`merge_layers`): samples within `MERGE_TOL` (0.01 m/s) of the line between
  their kept neighbours are dropped, so a ray crosses fewer layers; the merged profile is within
  the tolerance everywhere, a travel time within ``tol / c_min`` of itself (Fermat: the path's
  change is of second order), 0.7 mm at 100 m. A profile resampled from a few knots (collinear
  samples) merges exactly to its knots.
* **The first bounce's way back** is the outgoing ray reversed (reciprocity: the segment left the
  transducer itself, and the same ray, time and length bring the echo back; its arrival
  direction is the launch direction, its direction at the surface the exact tangent
  `Refraction.reversed_at`); `trace` has already cleared it of obstacles, so it needs neither an
  eigenray nor visibility chords. Unlike an eigenray it also brings back echoes whose outgoing
  ray turned.
* **The way back from a later bounce** (`eigenray`): the ray joining a surface point to the transducer without a
  turning point. With ``c_max`` the largest speed between the two depths and ``sigma`` the sine
  of the grazing angle where the speed is ``c_max`` (``a = cos / c_max``), the horizontal distance
  ``X(sigma)`` (a sum over the layers between the depths, unrolled) is solved for the true
  distance by `EIGEN_STEPS` secant steps: on ``1 / X(sigma) - 1 / X`` from the horizontal limit
  ``sigma = 0`` and the straight-line guess for rays flatter than 45 deg, on ``X(v) - X`` with
  ``v = cot`` of that angle from the straight guess ``v = X / dz`` for steeper ones. A point that no direct ray
  reaches within ``EIGEN_TOL`` (it would need a turn: a nearly horizontal path at the head's
  depth in a gradient) gives no echo. Visibility is tested along chords of that ray, with the
  same ``dt``.
* Travel times, not lengths, set the range: ``range = c_sensor (t_out + t_back) / 2``.
  Absorption runs over the curved length (chord lengths out, the exact arc length back).
* **Spreading back along the ray tube** (`Refraction.tube`): the way back (the first bounce's
  reversed ray, a later bounce's eigenray) is weighted by the pressure of a point source re 1 m
  carried along its ray tube, ``|p|^2 = c_p cos(theta_o) / (c_o x q)`` (Jensen, Kuperman, Porter &
  Schmidt 2011, ch. 3, the geometrical-acoustics amplitude; Porter & Bucker 1987, JASA 82(4),
  1349-1359; `mitsonar.acoustics.propagation` derives it), where ``theta_o`` is the ray's angle
  at the transducer, ``x`` the horizontal distance, ``c_p``, ``c_o`` the speeds at the two ends
  and ``q`` the tube's width per radian of launch angle normal to the ray at the far end: the two
  rays launched ``TUBE_STEP`` either side, advanced in closed form (`advance`) for the same time,
  are ``2 TUBE_STEP q`` apart across the ray (at equal time the wavefront is normal to the ray).
  By reciprocity the tube from the transducer gives the way back's level. In uniform water it is
  ``1 / L^2``; focusing and defocusing by the profile (up to about 10 dB within 2 km in a shallow
  thermocline) are in it. At a caustic ``q`` is floored at a Fresnel zone,
  ``sqrt(lambda L)`` (``lambda`` at the sensor's ``frequency``; the focusing gain over spherical
  spreading is capped at ``5 log10(L / lambda)`` dB); shadow zones have no eigenray and stay
  silent. The outgoing legs need no such weight: their rays are sampled over the launch directions,
  and how many reach an area is their tube's spreading already.
"""
from __future__ import annotations

import drjit as dr
import mitsuba as mi

#: Depth standing for "no boundary" above the first sample and below the last one (m).
FAR = 1.0e7
#: Secant steps of the eigenray solve (after the two starting points).
EIGEN_STEPS = 4
#: A direct eigenray is accepted when it misses the point by at most this fraction of ``X + dz``.
EIGEN_TOL = 2e-4
#: Layers one time step may cross, beyond those of the profile (turns re-enter a layer).
EXTRA_CROSSINGS = 4
#: Samples within this many m/s of the line between their kept neighbours are merged (`merge_layers`).
MERGE_TOL = 0.01
#: Default chords per range window (XML ``svp_chords``).
DEFAULT_CHORDS = 4
#: rad: the half-step in launch angle of the ray tube's central difference (`Refraction.tube`).
TUBE_STEP = 2e-3
#: Weigh the way back by its ray tube (`Refraction.tube`); False gives the ``1 / L^2`` of before
#: (``benchmarks/ray_tube.py`` times both). Read when a render makes its `Refraction` (kept on it
#: as ``ray_tube``, so that a frozen pass recorded with the other setting is not replayed).
RAY_TUBE = True


#: Below this ``|y|``, `log1p_over` sums the series instead of dividing ``log(1 + y)`` (CUDA).
SERIES_BELOW = 0.25


def log1p_over(y, series=None):
    """``log1p(y) / y`` (1 at 0) without cancellation.

    On the ``llvm`` variants: Goldberg's trick ``log(u) / (u - 1)`` with ``u = 1 + y`` rounded
    (Goldberg 1991, "What every computer scientist should know about floating-point arithmetic",
    thm. 4), exact to rounding because Dr.Jit's ``log`` is. On the ``cuda`` variants Dr.Jit's
    float32 ``log`` is the GPU's ``lg2.approx`` (absolute error about 2^-22), so near ``u = 1``
    the quotient lost up to four digits (travel times 1e-4 too long through a 20-layer profile,
    measured on an H100): there (or wherever ``series`` is True), for ``|y| < SERIES_BELOW``,
    ``log1p(y) = 2 atanh(t)`` with ``t = y / (2 + y)`` and ``atanh`` by its series (Abramowitz
    and Stegun 4.6.33) to ``t^10`` (``|t| <= 1/7``: truncation below 1e-9), in float32
    arithmetic alone. ``series`` None: by the backend."""
    u = 1.0 + y
    goldberg = dr.select(u == 1.0, 1.0, dr.log(u) / (u - 1.0))
    if series is None:
        series = dr.backend_v(y) == dr.JitBackend.CUDA
    if not series:
        return goldberg
    inv = 1.0 / (2.0 + y)
    t2 = dr.square(y * inv)
    poly = 1.0 / 11.0
    for c in (1.0 / 9.0, 1.0 / 7.0, 1.0 / 5.0, 1.0 / 3.0, 1.0):
        poly = dr.fma(poly, t2, c)
    return dr.select(dr.abs(y) < SERIES_BELOW, 2.0 * inv * poly, goldberg)


def _sinhc(x):
    return dr.select(dr.abs(x) < 1e-2, 1.0 + x * x * (1.0 / 6.0), dr.sinh(x) / x)


def _sin_at(a, c):
    ac = a * c
    return dr.safe_sqrt((1.0 - ac) * (1.0 + ac))


def _sin_below(a, c, u_ref, c_ref):
    """`_sin_at` for a ray whose ``1 - a c_ref`` is known as ``u_ref`` (no cancellation):
    ``1 - a c = u_ref + a (c_ref - c)`` (the speeds' difference is exact), ``sin^2 = u (2 - u)``.
    Near-horizontal eigenrays need it: ``1 - a c`` formed from a rounded ``a`` lost its digits
    there (float32; on an H100, whose division rounds less well, a point 50 m off and 1 m below
    the head was declared unreachable)."""
    u = u_ref + a * (c_ref - c)
    return dr.safe_sqrt(u * (2.0 - u))


def _piece(dz, c1, s1, c2, s2, a, g):
    """Horizontal distance and time between depths ``z1 < z1 + dz`` on one side of a turn
    (profile.py ``_piece``: ``dx = a dz (c1 + c2) / (s1 + s2)``, ``dt = (1/g) log1p(y)``)."""
    ssum = s1 + s2
    dx = a * dz * (c1 + c2) / ssum
    K = (1.0 + s1) + c1 * a * a * (c1 + c2) / ssum
    D = c1 * (1.0 + s2)
    y = g * dz * K / D
    dt = dz * K / D * log1p_over(y)
    zero = dz <= 0
    return dr.select(zero, 0.0, dx), dr.select(zero, 0.0, dt)


def _arc(dz, c1, s1, c2, s2, a, g):
    """Arc length between the same two depths: ``(asin(a c2) - asin(a c1)) / (a g)`` written as
    ``dz (c1 + c2) / (c2 s1 + c1 s2) * asin(w) / w``, ``w = a g dz (c1 + c2) / (c2 s1 + c1 s2)``."""
    q = dz * (c1 + c2) / (c2 * s1 + c1 * s2)
    w = a * g * q
    ratio = dr.select(dr.abs(w) < 1e-3, 1.0 + w * w * (1.0 / 6.0), dr.safe_asin(w) / w)
    return dr.select(dz <= 0, 0.0, q * ratio)


def _opaque_array(values):
    out = mi.Float(values)
    dr.make_opaque(out)
    return out


class Refraction:
    """A profile's layers as Dr.Jit arrays (the chord tracer gathers them) and as opaque scalars
    per layer (the eigenray's layer sum is unrolled over them: the layer count shapes the kernel,
    the values do not, so another profile of as many samples reuses the compiled kernels), with
    the chord time step of one render."""

    def __init__(self, depths, speeds, sensor_speed, range_max, chords=DEFAULT_CHORDS, frequency=700e3):
        d = [float(v) for v in depths]
        c = [float(v) for v in speeds]
        n = len(d)
        self.samples = tuple(zip(d, c))
        top = [-FAR] + d
        bot = d + [FAR]
        ct = [c[0]] + c
        g = [0.0] + [(c[i + 1] - c[i]) / (d[i + 1] - d[i]) for i in range(n - 1)] + [0.0]
        opaque = lambda v: dr.opaque(mi.Float, v)  # noqa: E731
        self.layers = tuple(tuple(opaque(v) for v in layer) for layer in zip(top, bot, ct, g))
        # (depth, speed, slope to the next sample): the slopes in float64 here, as the literals were
        self.samples_o = tuple((opaque(da), opaque(ca), opaque((cb - ca) / (db - da)), opaque(db))
                               for (da, ca), (db, cb) in zip(self.samples, self.samples[1:]))
        self.speed0 = opaque(c[0])
        self.sample_points = tuple((opaque(dd), opaque(cc)) for dd, cc in self.samples)
        self.n_layers = n + 1
        self.max_crossings = 2 * (n + 1) + EXTRA_CROSSINGS
        self.top, self.bot, self.ct, self.g = (_opaque_array(v) for v in (top, bot, ct, g))
        self.depth_o = [dr.opaque(mi.Float, v) for v in d]
        self.sensor_speed = float(sensor_speed)
        self.chords = int(chords)
        self.dt = dr.opaque(mi.Float, float(range_max) / (self.chords * self.sensor_speed))
        self.t_window = dr.opaque(mi.Float, 2.0 * float(range_max) / self.sensor_speed)
        self.ray_tube = bool(RAY_TUBE)
        # the caustic floor of the ray tube's width: sqrt(lambda L), lambda at the sensor's frequency
        self.wavelength = dr.opaque(mi.Float, self.sensor_speed / float(frequency))

    # ------------------------------------------------------------------------------- the medium
    def speed(self, z):
        """Sound speed at depth ``z`` (m, positive down): linear between samples, constant beyond."""
        out = mi.Float(self.speed0)
        for da, ca, slope, db in self.samples_o:
            out = dr.select(z > da, ca + slope * (dr.minimum(z, db) - da), out)
        return out

    def layer(self, z, down):
        """Index of the layer a ray at depth ``z`` heading ``down`` is in (profile.py ``_step``)."""
        j = mi.UInt32(0)
        for d in self.depth_o:
            j += mi.UInt32(dr.select(down, z >= d, z > d))
        return j

    def _step(self, z, s, down, a, j=None):
        """One layer traversal from ``(z, s)`` in layer ``j`` (default `layer`): ``j, c, z_exit,
        s_exit, down_exit, dt, dx`` (``c`` the speed at ``z``; the next layer is ``j + 1`` where
        ``down_exit``, else ``j - 1``)."""
        if j is None:
            j = self.layer(z, down)
        zt, zb = dr.gather(mi.Float, self.top, j), dr.gather(mi.Float, self.bot, j)
        ct, g = dr.gather(mi.Float, self.ct, j), dr.gather(mi.Float, self.g, j)
        cb = ct + g * (zb - zt)
        cb = dr.select(g == 0, ct, cb)
        c = dr.select(g == 0, ct, ct + g * (z - zt))
        sa = dr.abs(s)
        st, sb = _sin_at(a, ct), _sin_at(a, cb)
        flat = (g == 0) | (a == 0)
        reach_b = flat | (a * cb <= 1.0)
        reach_t = flat | (a * ct <= 1.0)
        # straight on: down to the bottom (z -> zb) or up to the top (zt <- z), one piece
        dx_s, dt_s = _piece(dr.select(down, zb - z, z - zt), dr.select(down, c, ct), dr.select(down, sa, st),
                            dr.select(down, cb, c), dr.select(down, sb, sa), a, g)
        # a turn, out through the side it came in by with sine s_far: w = atanh(sin) falls at the
        # rate g from atanh(s) to atanh(-s_far), dx = (s1 - s2) / (a g) (no cancellation: the two
        # sines have opposite signs)
        s_far = dr.select(down, st, sb)
        inv_ag = dr.rcp(a * dr.abs(dr.select(flat, 1.0, g)))
        dx_t = (sa + s_far) * inv_ag
        dt_t = (dr.atanh(dr.minimum(sa, 1.0 - 1e-7)) + dr.atanh(s_far)) * a * inv_ag
        straight = dr.select(down, reach_b, reach_t)
        dx = dr.select(straight, dx_s, dx_t)
        dt = dr.select(straight, dt_s, dt_t)
        down_exit = dr.select(straight, down, ~down)
        z_exit = dr.select(down_exit, zb, zt)
        s_exit = dr.select(down_exit, sb, -st)
        endless = ~dr.isfinite(dt) | ~dr.isfinite(dx) | (dr.abs(z_exit) >= FAR)
        dt = dr.select(endless, dr.inf, dt)
        return j, c, z_exit, s_exit, down_exit, dt, dx

    def _inside(self, j, c, s, a, tau):
        """State after ``tau`` s in layer ``j`` from speed ``c``, sine ``s``: ``dx, dz, s2``
        (profile.py ``_inside``: ``w2 = w1 - g tau``)."""
        g = dr.gather(mi.Float, self.g, j)
        phi = g * tau
        ch, sh = dr.cosh(phi), dr.sinh(phi)
        den = ch - s * sh
        dz = c * tau * (s * _sinhc(phi) - 0.5 * phi * dr.square(_sinhc(0.5 * phi))) / den
        dx = a * c * c * tau * _sinhc(phi) / den
        s2 = dr.clip((s * ch - sh) / den, -1.0, 1.0)
        return dx, dz, s2

    @dr.syntax
    def advance(self, z, s, down, a, tau, active=True):
        """The ray state ``tau`` seconds later: ``(dx, z, s, down, ok, c)`` (``dx`` horizontal
        distance gone, ``c`` the speed there); ``ok`` False where it crossed more layers than a
        ray can (a channel axis)."""
        x = mi.Float(0.0)
        left = mi.Float(tau)
        z, s, down = mi.Float(z), mi.Float(s), mi.Bool(down)
        n = mi.UInt32(0)
        todo = mi.Bool(active) & (left > 0)
        done = mi.Bool(False)
        j = self.layer(z, down)
        while todo:      # whole layers (no cosh/sinh here: the rest of the step is done once, below)
            j, c, z_e, s_e, d_e, dt, dx = self._step(z, s, down, a, j)
            last = left <= dt
            j = dr.select(last, j, dr.select(d_e, j + 1, j - 1))
            x += dr.select(last, 0.0, dx)
            z = dr.select(last, z, z_e)
            s = dr.select(last, s, s_e)
            down = dr.select(last, down, d_e)
            left = dr.select(last, left, left - dt)
            done |= last
            n += 1
            todo &= ~last & (n < self.max_crossings)
        # the time left, inside the layer the ray is now in (closed form of `_inside`)
        zt, zb = dr.gather(mi.Float, self.top, j), dr.gather(mi.Float, self.bot, j)
        g = dr.gather(mi.Float, self.g, j)
        c = dr.select(g == 0, dr.gather(mi.Float, self.ct, j), dr.gather(mi.Float, self.ct, j) + g * (z - zt))
        ddx, ddz, s2 = self._inside(j, c, s, a, dr.select(done, left, 0.0))
        x += dr.select(done, ddx, 0.0)
        z = dr.select(done, dr.clip(z + ddz, zt, zb), z)
        down = dr.select(done, dr.select(s2 == 0, down, s2 > 0), down)
        s = dr.select(done, s2, s)
        left = dr.select(done, 0.0, left)
        c_end = dr.select(done, c + g * ddz, c)
        return x, z, s, down, (left == 0) | ~mi.Bool(active), c_end

    # ------------------------------------------------------------------------- outgoing segments
    @dr.syntax
    def trace(self, scene, p, d, t_budget, active, exact=True):
        """Follow the ray launched from ``p`` along unit ``d`` for at most ``t_budget`` s: the
        first surface it meets, as ``(si, t, length)``: the interaction (``si.wi`` from the chord
        that reached it), the one-way travel time (s) and the curved length (m) to it."""
        horiz = dr.sqrt(dr.square(d.x) + dr.square(d.y))
        h = dr.select(horiz > 0, mi.Vector3f(d.x, d.y, 0.0) / dr.maximum(horiz, 1e-30), mi.Vector3f(1.0, 0.0, 0.0))
        z = -p.z
        s = -d.z
        c1 = self.speed(z)
        a = horiz / c1
        down = s >= 0
        x = mi.Float(0.0)
        t = mi.Float(0.0)
        length = mi.Float(0.0)
        start = mi.Point3f(p)
        found = mi.Bool(False)
        hit_o, hit_d, hit_t = mi.Point3f(p), mi.Vector3f(d), mi.Float(0.0)
        t_hit, l_hit = mi.Float(0.0), mi.Float(0.0)
        t0_hit, x0_hit, z0_hit, s0_hit, dn0_hit = (mi.Float(0.0), mi.Float(0.0), mi.Float(0.0), mi.Float(0.0),
                                                   mi.Bool(False))
        active = mi.Bool(active)
        while active:
            tau = dr.minimum(self.dt, t_budget - t)
            dx, z2, s2, down2, ok, c2 = self.advance(z, s, down, a, tau, active)
            x2 = x + dx
            end = mi.Point3f(p.x + h.x * x2, p.y + h.y * x2, -z2)
            chord = end - start
            L = dr.norm(chord)
            ray = mi.Ray3f(start, chord / dr.maximum(L, 1e-30))
            ray.maxt = L
            pi = scene.ray_intersect_preliminary(ray, active & ok & (L > 0))
            hit = pi.is_valid() & active
            f = dr.clip(pi.t / dr.maximum(L, 1e-30), 0.0, 1.0)
            r = c2 / c1 - 1.0
            frac = f * log1p_over(r * f) / log1p_over(r)
            hit_o = dr.select(hit, start, hit_o)
            hit_d = dr.select(hit, ray.d, hit_d)
            hit_t = dr.select(hit, L, hit_t)
            t_hit = dr.select(hit, t + tau * frac, t_hit)
            l_hit = dr.select(hit, length + pi.t, l_hit)
            # the hit chord's start state, for the exact time to the hit (below)
            t0_hit = dr.select(hit, t, t0_hit)
            x0_hit = dr.select(hit, x, x0_hit)
            z0_hit = dr.select(hit, z, z0_hit)
            s0_hit = dr.select(hit, s, s0_hit)
            dn0_hit = dr.select(hit, down, dn0_hit)
            found |= hit
            x, z, s, down, c1 = x2, z2, s2, down2, c2
            t += tau
            length += L
            start = mi.Point3f(end)
            active &= ~hit & ok & (t < t_budget)
        ray = mi.Ray3f(hit_o, hit_d)
        ray.maxt = hit_t
        si = scene.ray_intersect(ray, found)
        if exact:
            # The chord's time interpolation assumes a speed linear along the chord, wrong where
            # it crosses a change of gradient (a 25 m chord across a thermocline's foot: 0.3
            # bins). One Newton step on the exact arc instead: its state at the interpolated time
            # (`advance` from the hit chord's start), then the time along its tangent to the
            # surface's tangent plane at the hit (exact for a plane up to the square of the
            # interpolation's error times the curvature). Kept where the tangent meets the plane
            # at more than 6 deg and the step stays inside the chord.
            tau_g = t_hit - t0_hit
            dx, z1, s1, _, ok1, c1 = self.advance(z0_hit, s0_hit, dn0_hit, a, tau_g, found)
            xa = x0_hit + dx
            pa = mi.Point3f(p.x + h.x * xa, p.y + h.y * xa, -z1)
            cos1 = a * c1
            tan1 = mi.Vector3f(h.x * cos1, h.y * cos1, -s1)
            n = si.n
            tn = dr.dot(tan1, n)
            corr = dr.dot(si.p - pa, n) / (c1 * tn)
            use = found & ok1 & (dr.abs(tn) > 0.1) & (dr.abs(corr) < self.dt) & dr.isfinite(corr)
            t_hit = dr.select(use, t0_hit + tau_g + corr, t_hit)
        return si, t_hit, l_hit

    # ----------------------------------------------------------------------------- the way back
    def tube(self, o, launch, tau, x_far, s_far, z_far, length, active):
        """``|p|^2`` re 1 m at the far end of the ray launched from ``o`` along unit ``launch``
        that arrives after ``tau`` s at horizontal distance ``x_far`` and depth ``z_far`` heading
        with sine ``s_far`` (positive down): ``c_p cos(theta_o) / (c_o x q)``, ``q`` the tube's
        width across the ray per radian of launch angle, from the rays launched ``TUBE_STEP``
        either side advanced for the same ``tau`` (module docstring), floored at ``sqrt(lambda
        length)``. ``1 / length^2`` where the ray is vertical or a neighbour is lost (a channel
        axis)."""
        horiz = dr.sqrt(dr.square(launch.x) + dr.square(launch.y))
        z_o = -o.z
        c_o = self.speed(z_o)
        c_p = self.speed(z_far)
        s_o = -launch.z
        theta = dr.atan2(s_o, horiz)
        ends = []
        for sign in (1.0, -1.0):
            th = theta + sign * TUBE_STEP
            sn, cs = dr.sin(th), dr.cos(th)
            dx, z2, _, _, ok, _ = self.advance(z_o, sn, sn >= 0, dr.abs(cs) / c_o, tau, active)
            ends.append((dx, z2, ok))
        (xp, zp, okp), (xm, zm, okm) = ends
        a = horiz / c_o
        cos_p = dr.minimum(a * c_p, 1.0)
        q = dr.abs((xp - xm) * s_far - (zp - zm) * cos_p) * (0.5 / TUBE_STEP)
        q = dr.maximum(q, dr.sqrt(self.wavelength * length))
        p2 = c_p * a / (dr.maximum(x_far, 1e-30) * q)
        good = okp & okm & (horiz > 1e-4) & (x_far > 0) & dr.isfinite(p2)
        return dr.select(good, p2, dr.rcp(dr.square(length)))

    def reversed_at(self, si, o, launch):
        """Unit direction leaving the surface point of ``si`` back along the ray launched from
        ``o`` along unit ``launch`` that reached it (`trace`): the exact tangent there by Snell,
        ``cos = a c(z)`` with ``a`` the launch's invariant, the vertical sense that of the chord
        that met the surface (``-si.wi`` in world)."""
        horiz = dr.sqrt(dr.square(launch.x) + dr.square(launch.y))
        h = dr.select(horiz > 0, mi.Vector3f(launch.x, launch.y, 0.0) / dr.maximum(horiz, 1e-30),
                      mi.Vector3f(1.0, 0.0, 0.0))
        a = horiz / self.speed(-o.z)
        cos_p = dr.minimum(a * self.speed(-si.p.z), 1.0)
        sin_p = dr.safe_sqrt((1.0 - cos_p) * (1.0 + cos_p))
        chord = si.to_world(si.wi)              # towards where the chord came from
        up = dr.select(chord.z >= 0, 1.0, -1.0)
        return dr.normalize(mi.Vector3f(-h.x * cos_p, -h.y * cos_p, up * sin_p))

    def _sum(self, a, z_lo, z_hi, full=True, u_ref=None, c_ref=None):
        """Horizontal distance, time and arc length of the direct ray of invariant ``a`` between
        depths ``z_lo < z_hi`` (layers unrolled); the distance alone unless ``full``. With
        ``u_ref = 1 - a c_ref`` the sines come from `_sin_below` (no cancellation)."""
        X, T, L = mi.Float(0.0), mi.Float(0.0), mi.Float(0.0)
        for top, bot, ct, g in self.layers:
            za = dr.maximum(z_lo, top)
            zb = dr.minimum(z_hi, bot)
            dz = dr.maximum(zb - za, 0.0)
            c1 = dr.select(g == 0, ct, ct + g * (za - top))
            c2 = dr.select(g == 0, ct, ct + g * (zb - top))
            if u_ref is None:
                s1, s2 = _sin_at(a, c1), _sin_at(a, c2)
            else:
                s1, s2 = _sin_below(a, c1, u_ref, c_ref), _sin_below(a, c2, u_ref, c_ref)
            if not full:     # dx = a dz (c1 + c2) / (s1 + s2), `_piece`'s first half
                X += dr.select(dz <= 0, 0.0, a * dz * (c1 + c2) / (s1 + s2))
                continue
            dx, dt = _piece(dz, c1, s1, c2, s2, a, g)
            X += dx
            T += dt
            L += _arc(dz, c1, s1, c2, s2, a, g)
        return X, T, L

    def eigenray(self, p, o, active):
        """The direct ray between a point ``p`` and the transducer at ``o``: ``(ok, t, L, back,
        rx)``: found, one-way time (s), arc length (m), unit direction leaving ``p`` towards the
        transducer, unit direction leaving the transducer towards ``p`` (the arrival direction
        the receive beam weighs)."""
        z1, z2 = -p.z, -o.z
        hv = mi.Vector3f(o.x - p.x, o.y - p.y, 0.0)
        X = dr.norm(hv)
        h_back = dr.select(X > 0, hv / dr.maximum(X, 1e-30), mi.Vector3f(1.0, 0.0, 0.0))
        z_lo, z_hi = dr.minimum(z1, z2), dr.maximum(z1, z2)
        dz = z_hi - z_lo
        c_max = dr.maximum(self.speed(z_lo), self.speed(z_hi))
        for dd, cc in self.sample_points:
            c_max = dr.select((dd > z_lo) & (dd < z_hi), dr.maximum(c_max, cc), c_max)

        # Two variables, chosen per lane by the straight guess, each making X (or 1/X) nearly
        # linear where it is used: steep (dz >= X): v = cot of the grazing angle where the speed
        # is c_max, X ~ v dz; flat: sigma = its sine, 1/X ~ sigma / dz in uniform water and
        # a g / (s - sigma) in a gradient, finite at the horizontal limit sigma = 0.
        steep = dz >= X
        inv_X = dr.rcp(dr.maximum(X, 1e-30))

        def at(q):
            cos_m = dr.select(steep, q * dr.rsqrt(1.0 + q * q), dr.safe_sqrt((1.0 - q) * (1.0 + q)))
            # 1 - cos at c_max: steep, cos <= 1/sqrt(2) (no cancellation); flat, sin^2 / (1 + cos)
            u_m = dr.select(steep, 1.0 - cos_m, q * q / (1.0 + cos_m))
            a = cos_m / c_max
            Xs = self._sum(a, z_lo, z_hi, full=False, u_ref=u_m, c_ref=c_max)[0]
            return a, u_m, Xs, dr.select(steep, Xs - X, dr.rcp(dr.maximum(Xs, 1e-30)) - inv_X)

        q0 = dr.select(steep, X / dr.maximum(dz, 1e-30), 0.0)
        a0, u0, X0, F0 = at(q0)
        q1 = dr.select(steep, q0 * X / dr.maximum(X0, 1e-30),
                       dr.minimum(dz * dr.rsqrt(dr.square(X) + dr.square(dz)), 1.0 - 1e-7))
        q1 = dr.select(dr.isfinite(q1), q1, q0)
        a1, u1, X1, F1 = at(q1)
        top = dr.select(steep, dr.inf, 1.0 - 1e-7)
        for _ in range(EIGEN_STEPS):
            den = F1 - F0
            q2 = q1 - F1 * (q1 - q0) / den
            q2 = dr.select(dr.isfinite(q2) & (den != 0), dr.clip(q2, 0.0, top), q1)
            q0, F0 = q1, F1
            q1 = q2
            a1, u1, X1, F1 = at(q1)
        X1, T1, L1 = self._sum(a1, z_lo, z_hi, u_ref=u1, c_ref=c_max)
        vertical = X <= 1e-6 * (dz + 1.0)        # straight down or up: a = 0
        a_v, X_v, T_v, L_v = (mi.Float(0.0),) + self._sum(mi.Float(0.0), z_lo, z_hi)
        a1, X1, T1, L1 = (dr.select(vertical, u, v) for u, v in ((a_v, a1), (X_v, X1), (T_v, T1), (L_v, L1)))
        ok = mi.Bool(active) & (dr.abs(X1 - X) <= EIGEN_TOL * (X + dz) + 1e-5) & dr.isfinite(T1)
        # directions at both ends: cos = a c, the vertical sense from which end is deeper
        deeper = z1 > z2                       # the point below the transducer: the way back climbs
        cos_p, cos_o = a1 * self.speed(z1), a1 * self.speed(z2)
        sin_p = dr.safe_sqrt(1.0 - dr.square(cos_p))
        sin_o = dr.safe_sqrt(1.0 - dr.square(cos_o))
        up = dr.select(deeper, 1.0, -1.0)
        back = mi.Vector3f(h_back.x * cos_p, h_back.y * cos_p, up * sin_p)
        rx = mi.Vector3f(-h_back.x * cos_o, -h_back.y * cos_o, -up * sin_o)
        return ok, T1, L1, dr.normalize(back), dr.normalize(rx)

    @dr.syntax
    def visible(self, scene, o, rx, p, t_total, active):
        """No surface between ``o`` and ``p`` along the ray leaving ``o`` along ``rx`` that reaches
        ``p`` after ``t_total`` s (chords of time step ``dt``; the last chord ends at ``p``, short
        of it by Mitsuba's shadow epsilon). Called from the surface point (offset off its surface)
        towards the transducer."""
        horiz = dr.sqrt(dr.square(rx.x) + dr.square(rx.y))
        h = dr.select(horiz > 0, mi.Vector3f(rx.x, rx.y, 0.0) / dr.maximum(horiz, 1e-30), mi.Vector3f(1.0, 0.0, 0.0))
        z = -o.z
        s = -rx.z
        a = horiz / self.speed(z)
        down = s >= 0
        x = mi.Float(0.0)
        t = mi.Float(0.0)
        start = mi.Point3f(o)
        blocked = mi.Bool(False)
        active = mi.Bool(active)
        while active:
            tau = dr.minimum(self.dt, t_total - t)
            final = t + tau >= t_total
            dx, z2, s2, down2, ok, _ = self.advance(z, s, down, a, tau, active & ~final)
            x2 = x + dx
            end = dr.select(final, p, mi.Point3f(o.x + h.x * x2, o.y + h.y * x2, -z2))
            chord = end - start
            L = dr.norm(chord)
            ray = mi.Ray3f(start, chord / dr.maximum(L, 1e-30))
            ray.maxt = dr.select(final, L * (1.0 - 1e-4), L)
            blocked |= scene.ray_test(ray, active & (L > 0))
            x, z, s, down = x2, z2, s2, down2
            t += tau
            start = mi.Point3f(end)
            active &= ~blocked & ~final
        return ~blocked


def from_profile(profile, sensor, chords=None):
    """The `Refraction` of a profile (anything with ``depths`` and ``speeds``) for ``sensor``'s
    window, or None where the profile is constant at the sensor's own speed (straight rays: the
    straight path function runs, the same scan bit for bit)."""
    if profile is None:
        return None
    speeds = [float(v) for v in profile.speeds]
    if all(v == float(sensor.sound_speed) for v in speeds):
        return None
    chords = DEFAULT_CHORDS if chords is None else check_chords(chords, "sound_speed_profile")
    depths, speeds = merge_layers([float(v) for v in profile.depths], speeds)
    return Refraction(depths, speeds, sensor.sound_speed, sensor.range_max, chords,
                      float(getattr(sensor, "frequency", 700e3)))


def merge_layers(depths, speeds, tol=MERGE_TOL):
    """The profile's samples less those within ``tol`` m/s of the straight line between the kept
    samples around them (greedy from the top): runs of layers of nearly equal gradient become one
    layer, so that a ray crosses fewer. The merged profile is within ``tol`` of the given one at
    every depth (both are linear between samples), so a travel time changes by at most
    ``tol / c_min`` of itself (the path's own change is of second order by Fermat's principle):
    0.7 mm of range at 100 m for the default 0.01 m/s."""
    keep = [0]
    n = len(depths)
    while keep[-1] < n - 1:
        i = keep[-1]
        d0, c0 = depths[i], speeds[i]
        lo, hi = -float("inf"), float("inf")      # the slopes from sample i that fit those passed
        k = i + 1
        while k + 1 < n:
            dd = depths[k] - d0
            lo = max(lo, (speeds[k] - tol - c0) / dd)
            hi = min(hi, (speeds[k] + tol - c0) / dd)
            slope = (speeds[k + 1] - c0) / (depths[k + 1] - d0)
            if not lo <= slope <= hi:
                break
            k += 1
        keep.append(k)
    return [depths[i] for i in keep], [speeds[i] for i in keep]


def check_chords(value, source):
    """``value`` if it is a whole number of chords per range window, 1 to 1024."""
    from mitsonar._limits import check

    return check(source, "svp_chords", value)


def read_profile(props, source, refracts):
    """The XML ``<string name="sound_speed_profile" value="svp.csv"/>`` of an integrator: the CSV
    file (a path relative to the scene file, resolved as Mitsuba resolves its other files) read by
    `SoundSpeedProfile.from_csv` (its one-line errors name the file, the row and the field), or
    None when absent. An integrator that does not refract refuses it in one line."""
    if "sound_speed_profile" not in props:
        return None
    from mitsonar.acoustics.profile import SoundSpeedProfile

    from mitsonar.plugins.props import text

    name = text(props, "sound_speed_profile", "", source)
    if not refracts:
        raise ValueError(f"{source} 'sound_speed_profile': refracted paths are traced by the sonar_tof "
                         "integrator only")
    if not name:
        raise ValueError(f"{source} 'sound_speed_profile': an empty file name (a CSV file depth,sound_speed)")
    path = str(mi.file_resolver().resolve(name))
    return SoundSpeedProfile.from_csv(path)


@dr.syntax
def sample_path(setup, ping, samples, record, active=True):
    """`common.SonarIntegrator._sample_primal` through the profile ``setup.refraction``: the same
    echoes (``record(k, range, energy, valid, hit[, hard])``) with every segment refracted
    (`Refraction.trace`), the way back an eigenray (`Refraction.eigenray`, visibility along it),
    the range ``c_sensor * two-way time / 2``, absorption over the curved length and the beam
    patterns at the launch and arrival directions."""
    from . import image_guide
    from .emission import DB_TO_LOG2, start
    from .samples import DIMS_EMIT, DIMS_PER_BOUNCE

    refr = setup.refraction
    scene = setup.scene
    (x_ax, y_ax, z_ax, origin, d_local, weight, ray), (cx, cy, cz, c_beam) = start(setup, ping, samples, active)
    throughput = mi.Float(weight)
    t_path = mi.Float(0.0)
    l_path = mi.Float(0.0)
    depth = mi.UInt32(0)
    active = mi.Bool(active) & (weight > 0)
    atten = setup.absorption * DB_TO_LOG2
    half_c = dr.opaque(mi.Float, 0.5 * refr.sensor_speed)
    max_depth = setup.depth_o
    ctx = mi.BSDFContext(mi.TransportMode.Importance)
    guide = setup.guide
    chain = image_guide.start_chain(origin)
    tag = getattr(setup, "tag_hard", False)
    hard = mi.Bool(False)
    ray_o, ray_d = mi.Point3f(ray.o), mi.Vector3f(ray.d)

    while dr.hint(active, label="sonar_refracted_path"):
        si, t_seg, l_seg = refr.trace(scene, ray_o, ray_d, refr.t_window - t_path, active)
        active &= si.is_valid()
        t_path += t_seg
        l_path += l_seg

        # The way back. First bounce (monostatic: the segment left the transducer itself): the
        # outgoing ray reversed (reciprocity: the same ray, the same time and length), already
        # cleared of obstacles by `trace` itself, so neither an eigenray nor visibility chords.
        # Later bounces: the eigenray, tested along its chords.
        first = depth == 0
        if first:
            ok, t_back, l_back = mi.Bool(active), mi.Float(t_seg), mi.Float(l_seg)
            back, rx = refr.reversed_at(si, origin, ray_d), mi.Vector3f(ray_d)
        else:
            ok, t_back, l_back, back, rx = refr.eigenray(si.p, origin, active)
        # the way back's spreading along its ray tube (the ray from the transducer along rx that
        # arrives at si.p heading -back, by reciprocity), instead of 1 / l_back^2
        if refr.ray_tube:
            x_far = dr.sqrt(dr.square(si.p.x - origin.x) + dr.square(si.p.y - origin.y))
            spread = refr.tube(origin, rx, t_back, x_far, back.z, -si.p.z, l_back, active & ok)
        else:
            spread = dr.rcp(dr.square(l_back))
        bsdf = si.bsdf()
        f = bsdf.eval(ctx, si, si.to_local(back), active).x
        gain = c_beam.eval_dir(mi.Vector3f(dr.dot(rx, cx), dr.dot(rx, cy), dr.dot(rx, cz)))
        energy = throughput * f * gain * spread * dr.exp2(-atten * (l_path + l_back))
        echo = active & ok & (energy > 0)
        if ~first:
            echo &= refr.visible(scene, si.spawn_ray(back).o, back, origin, t_back, echo)
        rng = half_c * (t_path + t_back)
        # While ``record`` runs, ``refr.arrival`` is the direction the echo reaches the head from
        # (`shared_beams.SharedFrame.score` picks the receive beams by it); gone after, so that no
        # traced variable outlives this loop on the setup a frozen pass walks.
        refr.arrival = rx
        try:
            if dr.hint(tag, mode="scalar"):
                record(depth, rng, energy, echo, si, hard)
            else:
                record(depth, rng, energy, echo, si)
        finally:
            del refr.arrival

        nxt, bounce_weight, chain, was_chained = image_guide.scatter(
            bsdf, ctx, si, samples, DIMS_EMIT + DIMS_PER_BOUNCE * depth, guide, chain, origin, l_seg, active)
        throughput *= bounce_weight
        if was_chained is not None:
            hard |= was_chained
        ray_o, ray_d = mi.Point3f(nxt.o), mi.Vector3f(nxt.d)
        depth += 1
        active &= (depth < max_depth) & (throughput > 0)


__all__ = ["Refraction", "RAY_TUBE", "TUBE_STEP", "from_profile", "merge_layers", "MERGE_TOL", "check_chords", "read_profile", "sample_path", "DEFAULT_CHORDS"]
