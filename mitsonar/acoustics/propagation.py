"""Eigenrays, arrivals and one-way transmission loss in a horizontally stratified ocean (float64).

The questions an acoustician asks a propagation model first: which rays join this source and this
receiver, when do they arrive, at what angles and at what level. `eigenrays` answers them for a
`SoundSpeedProfile` between a flat sea surface (pressure release, ``R = -1``) and, optionally, a
flat or uniformly sloping bottom of given reflection coefficient; `transmission_loss` sums them incoherently;
`transmission_loss_field` gives the incoherent TL over a grid of ranges and depths for a plot.
`mitsonar.acoustics.bellhop` writes the same geometry as a Bellhop ``.env`` file and reads
Bellhop's arrivals back, so the answers can be checked against the reference ray/beam model.

**Rays.** Rays are traced layer by layer with the closed forms of `mitsonar.acoustics.profile` (circular
arcs in each layer of constant gradient; exact, no step size). The source and receiver depths,
the surface and the bottom are added to the profile's samples (the speed is interpolated there,
so the profile is unchanged), so that every crossing of the receiver depth and every reflection
falls on a layer boundary and is found exactly. An eigenray is a zero of ``x(theta0) - r``, the
range at which a ray launched at ``theta0`` crosses the receiver depth for the ``m``-th time with a
given number of surface and bottom bounces and a given heading, bracketed on a fan of launch
angles and refined by bisection to 1e-13 rad.

**Amplitude: ray-tube spreading.** The energy launched between ``theta0`` and ``theta0 + d theta0`` (solid angle ``2 pi cos(theta0)
d theta0`` at 1 m) flows along the ray tube; at the receiver the tube's section is ``2 pi r |q|
d theta0`` with ``q = (dx/d theta0)_z sin(theta_r)`` (the tube's horizontal width at the receiver
depth projected normal to the ray). With the intensity ``p^2 / (rho c)``, the pressure re its
value at 1 m is ::

    |p|^2 = c(z_r) cos(theta0) / (c(z_s) r |q|)

(Jensen, Kuperman, Porter & Schmidt, *Computational Ocean Acoustics*, 2nd ed. 2011, ch. 3: the
geometrical-acoustics amplitude from the transport equation, ``A = (1/4pi) |c cos(theta0) /
(c0 J)|^(1/2)`` with ``J = (r / sin theta) (dr/d theta0)`` the Jacobian of the ray map; Porter &
Bucker 1987, "Gaussian beam tracing for computing ocean acoustic fields", JASA 82(4), 1349-1359,
whose geometric beams Bellhop uses; the tests compare with Bellhop to 0.5 dB). ``(dx/d theta0)_z`` is the derivative of the eigenray's range along its own
family at the receiver depth, taken by central differences of exact ray ranges (``h = 1e-6``
rad); in an isovelocity ocean the formula gives ``1 / L^2`` (spherical spreading over the path
length ``L``), in a linear gradient the closed-form arcs' derivative. An eigenray that is
horizontal at the receiver's depth (source and receiver at one depth in water of constant speed,
or a receiver exactly at a ray's turning depth) crosses that depth tangentially and is not found.

At a caustic ``q`` vanishes and geometrical acoustics predicts an infinite level. Here ``|q|`` is
floored at the width of a Fresnel zone, ``sqrt(lambda L)`` per radian (``lambda = c(z_s) / f``):
the focusing gain over spherical spreading is capped at ``5 log10(L / lambda)`` dB (14 dB at 1 km
and 1.5 m), a documented cap in the spirit of a Gaussian beam's finite waist (Porter & Bucker
1987). Shadow zones have no eigenrays: `transmission_loss` is ``inf`` there.

**Losses.**

* absorption: ``alpha L`` with ``alpha`` in dB/m (e.g. `mitsonar.acoustics.absorption`) and ``L``
  the path length (``d theta / (a g)`` per layer, ``c dt`` where the arc is straight);
* surface: pressure release, ``R = -1`` (a phase of pi, no loss);
* bottom: ``R(theta)`` at each bottom bounce: 1 (rigid, the default), a number, a function of the
  grazing angle, or a `FluidBottom` (the Rayleigh coefficient of
  `mitsonar.acoustics.reflection_coefficient`).

``phase`` is the sum of the boundary reflections' phases (pi per surface bounce, ``arg R`` per
bottom bounce) and ``-pi/2`` per caustic the ray has passed (``caustics``, its KMAH index: the sign
changes of its ray-tube width along it; Jensen et al. 2011, ch. 3), with the time dependence
``exp(-i omega t)`` of `mitsonar.acoustics.reflection_coefficient`. Bellhop's arrivals file prints
the opposite sign.

A sloping bottom (``bottom_slope``) is not a sample: a traversal that goes below the line
``z = D + x tan(slope)`` is sampled and bisected to where it meets it, and the ray leaves at
``2 slope - theta`` (the image in the bottom's plane; checked against the closed form and
Bellhop's bathymetry file).

Out of scope: range-dependent profiles and bathymetry other than one uniform slope (the water is
horizontally stratified), coherent TL (phases are given per eigenray, `transmission_loss` sums
intensities), and a layered or elastic seabed beyond its plane-wave reflection coefficient.
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

# the profile's own class is taken from the profile given (type(profile)): the profile module
# imports this one for SoundSpeedProfile.eigenrays, so this one does not import it
from mitsonar.acoustics._checks import ProfileError

__all__ = ["ARRIVAL_DTYPE", "FluidBottom", "eigenrays", "arrivals", "transmission_loss", "transmission_loss_field"]

#: The fields of `eigenrays`' table (a NumPy structured array, sorted by arrival time): times in s,
#: angles in rad from the horizontal (positive downward; ``arrival`` is the ray's heading at the
#: receiver), ``caustics`` the caustics passed, losses in dB (one way, re 1 m), ``phase`` in rad,
#: ``amplitude`` the pressure re 1 m, ``length`` the path length in m.
ARRIVAL_DTYPE = np.dtype([("time", "f8"), ("launch", "f8"), ("arrival", "f8"), ("surface_bounces", "i4"),
                          ("bottom_bounces", "i4"), ("caustics", "i4"), ("transmission_loss", "f8"),
                          ("spreading_loss", "f8"),
                          ("absorption_loss", "f8"), ("boundary_loss", "f8"), ("phase", "f8"),
                          ("amplitude", "f8"), ("length", "f8")])

_H = 1e-6            # rad: the central difference of the ray ranges (spreading)
_TOL = 1e-13         # rad: bisection of the launch angles


@dataclass(frozen=True)
class FluidBottom:
    """A fluid half-space seabed: compressional ``sound_speed`` (m/s), ``density_ratio`` (seabed
    over water) and ``attenuation`` (dB per wavelength); its plane-wave reflection coefficient is
    `mitsonar.acoustics.reflection_coefficient` against the water's speed at the bottom (Jensen et
    al. 2011, ch. 1), as Bellhop's acousto-elastic half-space ``'A'`` without shear."""

    sound_speed: float
    density_ratio: float
    attenuation: float = 0.0

    def reflection(self, grazing, water_speed):
        from mitsonar.acoustics.interface import reflection_coefficient

        return reflection_coefficient(grazing, self.density_ratio, self.sound_speed / water_speed,
                                      self.attenuation)


def _number(func, field, value, lo=None, hi=None, unit="m"):
    try:
        v = float(value)
    except (TypeError, ValueError):
        raise ProfileError(f"{func}: {field} {value!r} is not a number ({unit})") from None
    if not math.isfinite(v) or (lo is not None and v < lo) or (hi is not None and v > hi):
        span = f"{lo:g} to {hi:g}" if hi is not None else f">= {lo:g}"
        raise ProfileError(f"{func}: {field} {value!r} is not allowed ({span} {unit})")
    return v


class _Ocean:
    """The profile with the source, receiver, surface and bottom depths as samples."""

    def __init__(self, func, profile, source_depth, receiver_depth, water_depth, bottom, frequency, absorption,
                 bottom_slope=0.0, reach=0.0):
        if not (hasattr(profile, "_step") and hasattr(profile, "depths")):
            raise ProfileError(f"{func}: profile {type(profile).__name__} is not a SoundSpeedProfile")
        self.D = None if water_depth is None else _number(func, "water_depth", water_depth, 0.0, 12000.0)
        if self.D is not None and not self.D > 0:
            raise ProfileError(f"{func}: water_depth {water_depth!r} is not allowed (a depth > 0 m)")
        slope = _number(func, "bottom_slope", bottom_slope, -30.0, 30.0, "deg")
        if slope and self.D is None:
            raise ProfileError(f"{func}: bottom_slope {bottom_slope!r} needs a water_depth (the depth at the source)")
        self.tanb = math.tan(math.radians(slope))
        self.reach = float(reach)
        top = 12000.0 if self.D is None else self.D
        self.zs = _number(func, "source_depth", source_depth, 0.0, top)
        top_r = top if self.D is None else min(12000.0, self.D + max(self.tanb, 0.0) * self.reach)
        self.zr = _number(func, "receiver_depth", receiver_depth, 0.0, top_r) if receiver_depth is not None else None
        self.frequency = _number(func, "frequency", frequency, 1e-3, 1e7, "Hz")
        self.alpha = _number(func, "absorption", absorption, 0.0, 10.0, "dB/m")
        if callable(bottom) or isinstance(bottom, FluidBottom):
            self.bottom = bottom
        else:
            try:
                r = complex(bottom)
            except (TypeError, ValueError):
                raise ProfileError(f"{func}: bottom {bottom!r} is not a reflection coefficient (a number with "
                                   "|R| <= 1, a function of the grazing angle, or a FluidBottom)") from None
            if not (math.isfinite(r.real) and math.isfinite(r.imag) and abs(r) <= 1.0):
                raise ProfileError(f"{func}: bottom {bottom!r} is not allowed (a reflection coefficient, |R| <= 1)")
            self.bottom = r
        self.profile = profile
        self._build(self.zr)

    def _build(self, zr):
        p = self.profile
        # with a sloping bottom its deepest point within reach is the last sample (the bottom
        # itself is not a sample: rays are cut where they meet it, `_slope_hit`)
        deepest = None if self.D is None else self.D + max(self.tanb, 0.0) * self.reach
        extra = [0.0, self.zs] + ([] if zr is None else [zr]) + ([] if deepest is None else [deepest])
        d = np.union1d(p.depths, extra)
        if deepest is not None:
            d = d[d <= deepest]
        self.aug = type(p)(d, p.speed(d), source=p.source)
        self.zr = zr

    def reflect_bottom(self, grazing, water_speed=None):
        if self.D is None:
            return np.ones_like(grazing, dtype=complex)
        if isinstance(self.bottom, FluidBottom):
            c = self.profile.speed(self.D) if water_speed is None else water_speed
            return np.asarray(self.bottom.reflection(np.abs(grazing), c), complex) * np.ones_like(grazing)
        if callable(self.bottom):
            return np.asarray(self.bottom(np.abs(grazing)), dtype=complex) * np.ones_like(grazing)
        return np.full(np.shape(grazing), self.bottom, dtype=complex)

    def _slope_hit(self, j, z, s, a, x, dt, samples=16, iterations=60):
        """Where the traversals from ``(z, s)`` (signed sine) at range ``x`` in layers ``j`` lasting
        ``dt`` first go below the sloping bottom ``z = D + x tan(beta)``: ``(hit, tau)``. The
        traversal (a circular arc, `SoundSpeedProfile._inside`) is sampled at ``samples`` times
        and the first crossing bisected."""
        aug = self.aug
        cap = np.where(np.isfinite(dt), dt, 2.0 * self.reach / np.interp(z, aug.depths, aug.speeds))
        frac = np.arange(1, samples + 1) / samples
        tau = cap[:, None] * frac[None, :]
        dx, z2, _, _ = aug._inside(j[:, None], z[:, None], s[:, None], a[:, None], tau)
        below = z2 > self.D + (x[:, None] + dx) * self.tanb
        hit = below.any(axis=1)
        first = np.argmax(below, axis=1)
        hi = np.where(hit, tau[np.arange(z.size), first], 0.0)
        lo = np.where(hit & (first > 0), tau[np.arange(z.size), np.maximum(first - 1, 0)], 0.0)
        for _ in range(iterations):
            mid = 0.5 * (lo + hi)
            dxm, zm, _, _ = aug._inside(j, z, s, a, mid)
            under = zm > self.D + (x + dxm) * self.tanb
            hi = np.where(under, mid, hi)
            lo = np.where(under, lo, mid)
        return hit, hi

    def fan(self, theta, r_max, max_bounces, steps=None):
        """Trace rays launched at ``theta`` (rad) until they pass ``r_max`` or ``max_bounces``
        boundary reflections: every crossing of the receiver depth as arrays ``ray, x, t, s (signed
        sine there), ns, nb, length, refl (complex product of the reflection coefficients), m``
        (``m``: the crossing's rank among the ray's crossings with the same bounces and heading),
        ``step`` (the index of the layer traversal it ends). With ``steps`` a list, every
        traversal's end is appended to it as ``(x, s, ns + nb)`` arrays over all rays (NaN for a
        ray no longer traced)."""
        aug, zr, D = self.aug, self.zr, self.D
        theta = np.asarray(theta, dtype=float)
        z, s, a = aug._start("eigenrays", np.full(theta.shape, self.zs), theta)
        z, s, a = (np.array(np.broadcast_to(v, theta.shape), dtype=float) for v in (z, s, a))
        n = theta.size
        down = s >= 0
        x, t, L = np.zeros(n), np.zeros(n), np.zeros(n)
        ns, nb = np.zeros(n, int), np.zeros(n, int)
        refl = np.ones(n, complex)
        idle = np.zeros(n, int)
        ev = {k: [] for k in ("ray", "x", "t", "s", "ns", "nb", "L", "refl", "step", "a")}
        n_step = 0
        # a source on a boundary: a ray launched into it is its reflected twin (launched away from
        # it), which is traced; tracing both would count the one ray twice
        into = ((z == 0.0) & (s < 0)) | ((D is not None) & (z == (D if D is not None else -1.0)) & (s > 0))
        todo = np.arange(n)[~into]

        def boundaries(k):
            up_s = (z[k] == 0.0) & ~down[k]
            if up_s.any():
                i = k[up_s]
                down[i], s[i], ns[i] = True, np.abs(s[i]), ns[i] + 1
                refl[i] *= -1.0
            if D is not None and not self.tanb:
                at_b = (z[k] == D) & down[k]
                if at_b.any():
                    i = k[at_b]
                    c = aug.speed(D)
                    refl[i] *= self.reflect_bottom(np.arctan2(np.abs(s[i]), a[i] * c))
                    down[i], s[i], nb[i] = False, -np.abs(s[i]), nb[i] + 1

        for _ in range(100000):
            if not todo.size:
                break
            k = todo
            j, z_e, s_e, d_e, dt, dx = aug._step(z[k], s[k], a[k], down[k])
            ok = np.isfinite(dt) & np.isfinite(dx)
            c0 = np.interp(z[k], aug.depths, aug.speeds)
            c1 = np.interp(z_e, aug.depths, aug.speeds)
            th0 = np.arctan2(np.where(down[k], np.abs(s[k]), -np.abs(s[k])), a[k] * c0)
            th1 = np.arctan2(s_e, a[k] * c1)
            g = aug._g[j]
            dth = th0 - th1
            with np.errstate(divide="ignore", invalid="ignore"):
                arc = dth / (a[k] * g)
            ds = np.where((np.abs(dth) > 1e-4) & (a[k] * g != 0), arc, 0.5 * (c0 + c1) * dt)
            if self.tanb:
                # a sloping bottom z = D + x tan(beta) met inside this traversal: cut it there
                sb, tau_b = self._slope_hit(j, z[k], np.where(down[k], np.abs(s[k]), -np.abs(s[k])), a[k], x[k], dt)
                ok |= sb
                dt = np.where(sb, tau_b, dt)
                dxb, zb_, s2b, _ = aug._inside(j, z[k], np.where(down[k], np.abs(s[k]), -np.abs(s[k])), a[k],
                                               np.where(sb, tau_b, 0.0))
                dx = np.where(sb, dxb, dx)
                z_e = np.where(sb, zb_, z_e)
                s_e = np.where(sb, s2b, s_e)
                c1 = np.interp(z_e, aug.depths, aug.speeds)
                th1 = np.arctan2(s_e, a[k] * c1)
                dth = th0 - th1
                with np.errstate(divide="ignore", invalid="ignore"):
                    arc = dth / (a[k] * g)
                ds = np.where((np.abs(dth) > 1e-4) & (a[k] * g != 0), arc, 0.5 * (c0 + c1) * dt)
            x[k] += np.where(ok, dx, 0.0)
            t[k] += np.where(ok, dt, 0.0)
            L[k] += np.where(ok, ds, 0.0)
            z[k], s[k], down[k] = np.where(ok, z_e, z[k]), np.where(ok, s_e, s[k]), np.where(ok, d_e, down[k])
            if self.tanb and sb.any():
                # reflect off the slope: theta' = 2 beta - theta, the grazing angle theta - beta
                i = k[sb]
                c = np.interp(z[i], aug.depths, aug.speeds)
                th = np.arctan2(s[i], a[i] * c)
                beta = math.atan(self.tanb)
                refl[i] *= self.reflect_bottom(np.clip(th - beta, 0.0, np.pi / 2), c)
                th2 = 2.0 * beta - th
                back = np.cos(th2) <= 0                      # reflected backwards: not followed
                s[i], a[i] = np.sin(th2), np.maximum(np.cos(th2), 0.0) / c
                down[i], nb[i] = s[i] > 0, nb[i] + 1
                ok[sb] &= ~back
            idle[k] = np.where(dt == 0, idle[k] + 1, 0)
            hit = ok & (dt > 0) & (z[k] == zr) & (x[k] <= r_max)
            if hit.any():
                i = k[hit]
                for key, v in (("ray", i), ("x", x[i]), ("t", t[i]), ("s", s[i]), ("ns", ns[i]), ("nb", nb[i]),
                               ("L", L[i]), ("refl", refl[i]), ("step", np.full(i.size, n_step)), ("a", a[i])):
                    ev[key].append(np.array(v))
            if steps is not None:
                row = np.full((3, n), np.nan)
                row[0, k], row[1, k], row[2, k] = x[k], s[k], ns[k] + nb[k]
                steps.append(row)
            n_step += 1
            boundaries(k)
            alive = ok & (x[k] <= r_max) & (ns[k] + nb[k] <= max_bounces) & (idle[k] < 3)
            todo = k[alive]
        out = {key: (np.concatenate(v) if v else np.zeros(0, complex if key == "refl" else float))
               for key, v in ev.items()}
        out["ray"] = out["ray"].astype(int)
        out["step"] = out["step"].astype(int)
        out["ns"] = out["ns"].astype(int)
        out["nb"] = out["nb"].astype(int)
        out["dir"] = (out["s"] > 0).astype(int)
        # rank among the ray's crossings with the same bounces and heading (events are in time order)
        order = np.lexsort((out["t"], out["dir"], out["nb"], out["ns"], out["ray"]))
        m = np.zeros(out["ray"].size, int)
        if order.size:
            grp = np.stack([out[q][order] for q in ("ray", "ns", "nb", "dir")], axis=1)
            new = np.ones(order.size, bool)
            new[1:] = np.any(grp[1:] != grp[:-1], axis=1)
            start = np.maximum.accumulate(np.where(new, np.arange(order.size), 0))
            m[order] = np.arange(order.size) - start
        out["m"] = m
        return out

    def ranges_of(self, theta, keys, r_max, max_bounces):
        """The range of the crossing of family ``keys`` (rows ``ns, nb, dir, m``) for rays launched
        at ``theta``: NaN where the ray has no such crossing within ``r_max``; also its event."""
        ev = self.fan(theta, r_max, max_bounces)
        n = np.size(theta)
        x = np.full(n, np.nan)
        idx = np.full(n, -1)
        if ev["ray"].size:
            match = ((ev["ns"] == keys[ev["ray"], 0]) & (ev["nb"] == keys[ev["ray"], 1])
                     & (ev["dir"] == keys[ev["ray"], 2]) & (ev["m"] == keys[ev["ray"], 3]))
            i = np.nonzero(match)[0]
            x[ev["ray"][i]] = ev["x"][i]
            idx[ev["ray"][i]] = i
        return x, idx, ev


def _launch_fan(func, angles, rays):
    lo, hi = (_number(func, "angles", v, -90.0, 90.0, "deg") for v in angles)
    if not lo < hi:
        raise ProfileError(f"{func}: angles {angles!r} is not allowed (min < max, deg from the horizontal)")
    if not (isinstance(rays, (int, np.integer)) and 2 <= rays <= 1_000_000):
        raise ProfileError(f"{func}: rays {rays!r} is not allowed (a count, 2 to 1000000)")
    return np.radians(np.linspace(lo, hi, int(rays)))


def _caustics(ocean, theta, keys, r_max, max_bounces):
    """How many caustics each eigenray (launch ``theta``, family ``keys``) has passed before the
    receiver: the sign changes of its signed ray-tube width ``q = -(dx/d theta0)_z sin(theta)``
    (the neighbours' separation across the ray at each layer boundary it crosses, by central
    differences of ``_H``), counted in the frame that a boundary reflection mirrors (the sign of
    ``q`` flips with it there, without a caustic). ``q`` starts positive at the source. A pair of
    caustics inside one layer traversal is not seen."""
    n = theta.size
    if not n:
        return np.zeros(0, int)
    steps = []
    ev = ocean.fan(np.concatenate([theta, theta + _H, theta - _H]), r_max, max_bounces, steps=steps)
    out = np.zeros(n, int)
    if not steps:
        return out
    S = np.stack(steps)                          # (step, 3, 3 n)
    x, s, bounces = S[:, 0], S[:, 1], S[:, 2]
    match = ((ev["ns"] == keys[ev["ray"] % n, 0]) & (ev["nb"] == keys[ev["ray"] % n, 1])
             & (ev["dir"] == keys[ev["ray"] % n, 2]) & (ev["m"] == keys[ev["ray"] % n, 3]) & (ev["ray"] < n))
    last = np.full(n, -1)
    last[ev["ray"][match]] = ev["step"][match]
    for r in range(n):
        k = last[r]
        if k < 0:
            continue
        xp, xm = x[:k + 1, n + r], x[:k + 1, 2 * n + r]
        same = bounces[:k + 1, r] == bounces[:k + 1, n + r]
        same &= bounces[:k + 1, r] == bounces[:k + 1, 2 * n + r]
        q = -(xp - xm) / (2 * _H) * s[:k + 1, r] * np.where(bounces[:k + 1, r] % 2 == 1, -1.0, 1.0)
        q = q[same & np.isfinite(q) & (np.abs(s[:k + 1, r]) > 1e-9)]
        sign = np.sign(q[q != 0])
        out[r] = int(np.sum(sign[1:] != sign[:-1]) + (sign.size > 0 and sign[0] < 0))
    return out


def _codes(ev):
    return ((ev["ns"] * 1001 + ev["nb"]) * 2 + ev["dir"]) * 100000 + ev["m"]


def _refined_fan(ocean, theta, r_max, max_bounces, R, passes=2, split=16, most=4096):
    """The fan's crossings, with ``split - 1`` more rays between two neighbours whose families
    differ at a crossing within 10 % of ``R`` of it (a shadow edge or a turning depth there: an
    eigenray may lie between them with no neighbour of its family), ``passes`` times; returns
    the merged launch angles (sorted) and their crossings."""
    ev = ocean.fan(theta, r_max, max_bounces)
    for _ in range(passes):
        code = _codes(ev)
        near = np.abs(ev["x"] - R) <= 0.1 * R
        sets = [set() for _ in range(theta.size)]
        for r, c in zip(ev["ray"][near], code[near]):
            sets[r].add(c)
        edges = [i for i in range(theta.size - 1) if sets[i] != sets[i + 1]]
        if not edges:
            break
        edges = np.array(edges[:max(1, most // (split - 1))])
        frac = np.arange(1, split) / split
        new = (theta[edges, None] + frac[None, :] * (theta[edges + 1] - theta[edges])[:, None]).ravel()
        ev_new = ocean.fan(new, r_max, max_bounces)
        merged = np.concatenate([theta, new])
        order = np.argsort(merged, kind="stable")
        rank = np.empty(order.size, int)
        rank[order] = np.arange(order.size)
        ev_new["ray"] = ev_new["ray"] + theta.size
        ev = {k: np.concatenate([ev[k], ev_new[k]]) for k in ev}
        ev["ray"] = rank[ev["ray"]]
        theta = merged[order]
    return theta, ev


def eigenrays(profile, source_depth, receiver_depth, range, *, water_depth=None, bottom=1.0, frequency=1000.0,
              absorption=0.0, max_bounces=4, angles=(-89.0, 89.0), rays=2001, bottom_slope=0.0):
    """Every ray joining a source at ``source_depth`` and a receiver at ``receiver_depth`` (m) at
    horizontal ``range`` (m), with at most ``max_bounces`` surface and bottom reflections together:
    a structured array of `ARRIVAL_DTYPE`, one row per eigenray, sorted by arrival time.

    Parameters
    ----------
    profile : SoundSpeedProfile
        The water's sound speed against depth.
    water_depth : float, optional
        Depth of the bottom at the source (m); None: no bottom (rays that go down are lost).
    bottom_slope : float
        The bottom's slope, degrees, positive where it deepens with range (-30 to 30; 0: flat): the
        bottom is ``z = water_depth + x tan(slope)`` at horizontal distance ``x`` from the source
        in every direction (the cylindrical symmetry of a 2-D model such as Bellhop's). A ray the
        slope reflects back towards the source is not followed.
    bottom : complex, callable or FluidBottom
        The bottom's plane-wave reflection coefficient: a number (default 1, rigid), a function of
        the grazing angle (rad) or a `FluidBottom`.
    frequency : float
        Hz: the wavelength of the caustic cap (module docstring).
    absorption : float
        dB/m along the path (e.g. ``mitsonar.acoustics.absorption(f, T, S, z)``).
    angles : (float, float)
        The fan of launch angles searched, degrees from the horizontal, positive downward.
    rays : int
        Rays in the fan: eigenrays whose neighbours in the fan belong to other families (near a
        shadow edge) are missed; raise it to find them.

    The module docstring gives the equations (ray-tube spreading, losses) and what is left out.
    """
    func = "eigenrays"
    R = _number(func, "range", range, 0.0, 1.0e6)
    if not R > 0:
        raise ProfileError(f"{func}: range {range!r} is not allowed (a horizontal distance > 0 m)")
    ocean = _Ocean(func, profile, source_depth, receiver_depth, water_depth, bottom, frequency, absorption,
                   bottom_slope, 1.5 * R)
    if ocean.D is not None and ocean.zr > ocean.D + R * ocean.tanb:
        raise ProfileError(f"{func}: receiver_depth {receiver_depth!r} is not allowed (below the bottom, "
                           f"{ocean.D + R * ocean.tanb:g} m at range {R:g} m)")
    if not (isinstance(max_bounces, (int, np.integer)) and 0 <= max_bounces <= 1000):
        raise ProfileError(f"{func}: max_bounces {max_bounces!r} is not allowed (a count, 0 to 1000)")
    theta = _launch_fan(func, angles, rays)
    r_max = R * (1.0 + 1e-9) + 1e-9
    theta, ev = _refined_fan(ocean, theta, r_max * 1.5, max_bounces, R)
    # brackets: neighbouring rays of the fan with a crossing of the same family on either side of r
    key = np.stack([ev["ns"], ev["nb"], ev["dir"], ev["m"]], axis=1)
    order = np.lexsort((ev["ray"], ev["m"], ev["dir"], ev["nb"], ev["ns"]))
    lo_t, hi_t, keys = [], [], []
    for p, q in zip(order[:-1], order[1:]):
        if (ev["ray"][q] == ev["ray"][p] + 1 and np.array_equal(key[p], key[q])
                and (ev["x"][p] - R) * (ev["x"][q] - R) <= 0):
            lo_t.append(theta[ev["ray"][p]])
            hi_t.append(theta[ev["ray"][q]])
            keys.append(key[p])
    if not keys:
        return np.zeros(0, ARRIVAL_DTYPE)
    lo, hi, keys = np.array(lo_t), np.array(hi_t), np.array(keys)
    f_lo = ocean.ranges_of(lo, keys, r_max * 1.5, max_bounces)[0] - R
    while np.max(hi - lo) > _TOL:
        mid = 0.5 * (lo + hi)
        f_mid = ocean.ranges_of(mid, keys, r_max * 1.5, max_bounces)[0] - R
        f_mid = np.where(np.isnan(f_mid), np.inf, f_mid)
        same = np.sign(f_mid) == np.sign(f_lo)
        lo, f_lo = np.where(same, mid, lo), np.where(same, f_mid, f_lo)
        hi = np.where(same, hi, mid)
        if np.all(mid == lo) and np.all(mid == hi):
            break
    th = 0.5 * (lo + hi)
    # a fan ray landing exactly on r brackets its eigenray from both sides: keep one
    _, first = np.unique(np.column_stack([keys, np.round(th, 9)]), axis=0, return_index=True)
    first = np.sort(first)
    th, keys = th[first], keys[first]
    x0, i0, ev0 = ocean.ranges_of(th, keys, r_max * 1.5, max_bounces)
    found = np.isfinite(x0) & (np.abs(x0 - R) <= 1e-6 * max(R, 1.0))
    xp = ocean.ranges_of(th + _H, keys, r_max * 1.5, max_bounces)[0]
    xm = ocean.ranges_of(th - _H, keys, r_max * 1.5, max_bounces)[0]
    dxdth = np.where(np.isfinite(xp) & np.isfinite(xm), (xp - xm) / (2 * _H),
                     np.where(np.isfinite(xp), (xp - x0) / _H, (x0 - xm) / _H))
    caustics = _caustics(ocean, th, keys, r_max * 1.5, max_bounces)
    i = i0[found]
    th, dxdth, caustics = th[found], dxdth[found], caustics[found]
    out = np.zeros(i.size, ARRIVAL_DTYPE)
    if not i.size:
        return out
    a = ev0["a"][i]
    c_r = float(profile.speed(ocean.zr))
    c_s = float(profile.speed(ocean.zs))
    s_r = ev0["s"][i]
    theta_r = np.arctan2(s_r, a * c_r)
    L = ev0["L"][i]
    refl = ev0["refl"][i]
    q = np.abs(dxdth * np.sin(theta_r))
    q_floor = np.sqrt(c_s / ocean.frequency * L)
    q = np.maximum(np.where(np.isfinite(q), q, 0.0), q_floor)
    p2 = c_r * np.cos(th) / (c_s * R * q)
    with np.errstate(divide="ignore"):
        spreading = -10.0 * np.log10(p2)
        boundary = -20.0 * np.log10(np.abs(refl))
    absorb = ocean.alpha * L
    out["time"] = ev0["t"][i]
    out["launch"] = th
    out["arrival"] = theta_r
    out["surface_bounces"] = ev0["ns"][i]
    out["bottom_bounces"] = ev0["nb"][i]
    out["spreading_loss"] = spreading
    out["absorption_loss"] = absorb
    out["boundary_loss"] = boundary
    out["transmission_loss"] = spreading + absorb + boundary
    out["caustics"] = caustics
    out["phase"] = (np.angle(refl) - 0.5 * np.pi * caustics) % (2 * np.pi)
    out["amplitude"] = 10.0 ** (-out["transmission_loss"] / 20.0)
    out["length"] = L
    return np.sort(out, order="time")


def arrivals(profile, source_depth, receiver_depth, range, **kwargs):
    """The arrivals at the receiver: `eigenrays` as a list of dicts (one per ray, in time order),
    the columns of Bellhop's arrivals file in mitsonar's units (angles in rad)."""
    table = eigenrays(profile, source_depth, receiver_depth, range, **kwargs)
    return [{name: row[name].item() for name in ARRIVAL_DTYPE.names} for row in table]


def _incoherent(table):
    with np.errstate(divide="ignore"):
        return float(-10.0 * np.log10(np.sum(10.0 ** (-table["transmission_loss"] / 10.0))))


def transmission_loss(profile, source_depth, receiver_depth, range, **kwargs):
    """One-way transmission loss (dB re 1 m) from ``source_depth`` to ``receiver_depth`` at horizontal
    ``range``: the incoherent sum of the `eigenrays` (keywords as there),
    ``-10 log10 sum_i |p_i|^2``; ``inf`` in a shadow zone (no eigenray). For the two-way loss of the
    sonar equation in straight water see `mitsonar.sonar_equation.two_way_transmission_loss`."""
    return _incoherent(eigenrays(profile, source_depth, receiver_depth, range, **kwargs))


def transmission_loss_field(profile, source_depth, depths, ranges, *, water_depth=None, bottom=1.0, frequency=1000.0,
                            absorption=0.0, max_bounces=4, angles=(-89.0, 89.0), rays=2001, bottom_slope=0.0):
    """Incoherent one-way TL (dB re 1 m) over ``depths`` x ``ranges`` (m): an array of shape
    ``(len(depths), len(ranges))`` for a plot (``inf`` in shadow).

    For each receiver depth the fan of ``rays`` launch angles is traced once; between two
    neighbouring rays of one family (same bounces, heading and rank of crossing) the receiver
    ranges they straddle get the ray-tube level of `eigenrays` with ``dx/d theta0`` the pair's
    secant slope and the other quantities interpolated linearly in range: Bellhop's geometric
    (hat-shaped) beams summed incoherently (Porter & Bucker 1987). Keywords as in `eigenrays`.
    """
    func = "transmission_loss_field"
    d = np.atleast_1d(np.asarray(depths, dtype=float))
    r = np.atleast_1d(np.asarray(ranges, dtype=float))
    if d.ndim != 1 or r.ndim != 1 or not (np.isfinite(d).all() and np.isfinite(r).all()) or (r <= 0).any():
        raise ProfileError(f"{func}: depths and ranges must be 1-D arrays of finite numbers (ranges > 0 m)")
    if not (isinstance(max_bounces, (int, np.integer)) and 0 <= max_bounces <= 1000):
        raise ProfileError(f"{func}: max_bounces {max_bounces!r} is not allowed (a count, 0 to 1000)")
    theta = _launch_fan(func, angles, rays)
    r_sorted = np.sort(r)
    r_max = float(r_sorted[-1])
    out = np.full((d.size, r.size), 0.0)
    ocean = _Ocean(func, profile, source_depth, None, water_depth, bottom, frequency, absorption, bottom_slope,
                   1.5 * r_max)
    c_s = float(profile.speed(ocean.zs))
    for row, zr in enumerate(d):
        deepest = 12000.0 if ocean.D is None else ocean.D + max(ocean.tanb, 0.0) * ocean.reach
        ocean.zr = _number(func, "depths", zr, 0.0, deepest)
        ocean._build(ocean.zr)
        c_r = float(profile.speed(zr))
        ev = ocean.fan(theta, r_max * 1.5, max_bounces)
        if ev["ray"].size < 2:
            continue
        key = np.stack([ev["ns"], ev["nb"], ev["dir"], ev["m"]], axis=1)
        order = np.lexsort((ev["ray"], ev["m"], ev["dir"], ev["nb"], ev["ns"]))
        p, q = order[:-1], order[1:]
        pair = (ev["ray"][q] == ev["ray"][p] + 1) & np.all(key[p] == key[q], axis=1)
        p, q = p[pair], q[pair]
        x1, x2 = ev["x"][p], ev["x"][q]
        dth = theta[ev["ray"][q]] - theta[ev["ray"][p]]
        slope = (x2 - x1) / dth
        th_r1, th_r2 = (np.arctan2(ev["s"][v], ev["a"][v] * c_r) for v in (p, q))
        xa, xb = np.minimum(x1, x2), np.maximum(x1, x2)
        ia = np.searchsorted(r_sorted, xa, side="left")
        ib = np.searchsorted(r_sorted, xb, side="left")      # grid ranges in [xa, xb)
        count = ib - ia
        has = count > 0
        seg = np.repeat(np.nonzero(has)[0], count[has])
        gi = np.concatenate([np.arange(u, w) for u, w in zip(ia[has], ib[has])]) if has.any() else np.zeros(0, int)
        if not seg.size:
            continue
        rr = r_sorted[gi]
        with np.errstate(divide="ignore", invalid="ignore"):
            w = np.where(x2[seg] != x1[seg], (rr - x1[seg]) / (x2[seg] - x1[seg]), 0.5)
        th0 = theta[ev["ray"][p[seg]]] + w * dth[seg]
        th_r = th_r1[seg] + w * (th_r2[seg] - th_r1[seg])
        L = ev["L"][p[seg]] + w * (ev["L"][q[seg]] - ev["L"][p[seg]])
        refl2 = np.abs(ev["refl"][p[seg]]) ** 2 + w * (np.abs(ev["refl"][q[seg]]) ** 2 - np.abs(ev["refl"][p[seg]]) ** 2)
        qq = np.maximum(np.abs(slope[seg] * np.sin(th_r)), np.sqrt(c_s / ocean.frequency * L))
        p2 = c_r * np.cos(th0) / (c_s * rr * qq) * refl2 * 10.0 ** (-ocean.alpha * L / 10.0)
        acc = np.zeros(r.size)
        np.add.at(acc, gi, p2)
        out[row] = acc
    # back to the caller's range order
    inv = np.argsort(np.argsort(r, kind="stable"), kind="stable")
    with np.errstate(divide="ignore"):
        return -10.0 * np.log10(out[:, inv])
