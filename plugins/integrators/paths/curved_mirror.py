"""The image guide through a curved mirror: the reflection point on a sphere or a cylinder.

`image_guide` aims the bounce after a chain of mirrors at the transducer's image in the tangent
plane of the last mirror, the plane where the path met it on the way out. On a plane that is the
way home from anywhere; on a curved mirror (a tank, a pile, a ship's bow) the way home from the
target ``x`` meets the mirror at another point ``S``, the *specular point* of ``x`` and the image
``I`` before that mirror (the transducer itself after one mirror): the point of the surface whose
normal bisects the directions to ``x`` and to ``I``. For a sphere or a cylinder it lies in a plane
(the plane of the sphere's centre, ``x`` and ``I``; for a cylinder, the cross-section, the axial
coordinate following by unfolding), where it solves Alhazen's problem, the reflection point on a
circle (Alhazen, *Optics* book V; a quartic in the point's coordinates, Neumann 1998,
*Amer. Math. Monthly* 105, 523-528): here by Newton's method on the angle ``phi`` of the point on
the circle, ``g(phi) = n x u_x + n x u_I = 0`` (``n`` the circle's normal at ``phi``, ``u`` the unit
vectors to ``x`` and ``I``, ``x`` the 2D cross product), from the angle of the bisector of the
directions from the centre to ``x`` and to ``I`` (exact when both are far), `NEWTON_STEPS` steps
(with the analytic derivative of `_g`).

The mirror's shape is read where the path met it (`local_mirror`): the normal curvatures along the
surface's parameter directions, ``k_u = (dn/du . dp/du) / |dp/du|^2`` and ``k_v`` likewise (the
second fundamental form over the first, do Carmo 1976, sec. 3-2; for Mitsuba's sphere and
cylinder the parameter directions are the principal ones). Equal curvatures make a sphere, one of
them under `FLAT_RATIO` of the other a cylinder along that direction, of radius ``1 / k``, centred
``1 / k`` behind the surface. A concave or flat mirror (curvature under `MIN_CURVATURE`) keeps the
tangent-plane image.

The guide's width: a turn ``delta`` at ``x`` moves the point on the mirror by ``delta a / cos
theta`` (``a = |x - S|``, ``theta`` the angle of incidence) in the plane of the curvature, whose
normal then turns by that over ``R``, so the reflected ray turns by ``delta (D / b + 2 a / (R cos
theta))`` with ``D = a + b``, ``b = |S - I|`` (the plane's ``D / b`` of `image_guide`, plus the
curvature's part); across (a sphere's second direction) by ``delta (D / b + 2 a cos theta / R)``,
along a cylinder's axis by ``delta D / b``. The guide is an isotropic Phong lobe: its exponent is
the mirror's times the square of the smaller factor (the wider direction: narrower, it left part of
the echo to BSDF sampling alone, which raised the error behind a tank by 1.3x; the product of the
two factors was best on the bow, the smaller one is within 1.3x of it there). Whatever the width and aim, the mixture's density is evaluated for
the same deterministic axis, so the estimate stays unbiased (`image_guide`).
"""
from __future__ import annotations

import drjit as dr
import mitsuba as mi

#: Newton steps of the reflection point's angle.
NEWTON_STEPS = 2
#: Least curvature (1/m) that makes a mirror curved: under it (a radius over 1 km) the tangent
#: plane is the mirror.
MIN_CURVATURE = 1e-3
#: A principal curvature under this fraction of the other is flat: a cylinder along it.
FLAT_RATIO = 0.1
#: Ray flags of the path kernel's intersections when guiding: the normal's derivatives too.
RAY_FLAGS = mi.RayFlags.All | mi.RayFlags.dNSdUV


def local_mirror(si, incoming):
    """The sphere or cylinder that fits the surface at ``si`` (met by a ray of direction
    ``incoming``): ``(centre, axis, radius)``; ``axis`` is zero for a sphere, ``radius`` 0 where the
    surface is flat or concave seen from the ray's side (the tangent plane is the guide's mirror)."""
    n = mi.Vector3f(si.sh_frame.n)
    side = dr.select(dr.dot(n, incoming) < 0, 1.0, -1.0)       # +1: the normal faces the ray
    ku = dr.dot(si.dn_du, si.dp_du) / dr.maximum(dr.squared_norm(si.dp_du), 1e-20) * side
    kv = dr.dot(si.dn_dv, si.dp_dv) / dr.maximum(dr.squared_norm(si.dp_dv), 1e-20) * side
    k_hi = dr.maximum(ku, kv)
    k_lo = dr.minimum(ku, kv)
    convex = (k_hi > MIN_CURVATURE) & (k_lo > -FLAT_RATIO * k_hi) & dr.isfinite(k_hi)
    cylinder = k_lo < FLAT_RATIO * k_hi
    k = dr.select(cylinder, k_hi, 0.5 * (ku + kv))
    radius = dr.select(convex, 1.0 / dr.maximum(k, MIN_CURVATURE), 0.0)
    # a cylinder's axis: the parameter direction of the smaller curvature
    along = dr.select(ku < kv, si.dp_du, si.dp_dv)
    axis = dr.select(convex & cylinder, dr.normalize(along), mi.Vector3f(0.0))
    centre = si.p - radius * side * n
    return mi.Point3f(centre), axis, radius


def _cross2(ax, ay, bx, by):
    return ax * by - ay * bx


def _g(phi, radius, xx, yx, yy):
    """Alhazen's condition at angle ``phi`` for the 2D points ``(xx, 0)`` and ``(yx, yy)``, and its
    derivative in ``phi``: per point, ``h = n x u`` with ``u = (X - S) / L`` has
    ``h' = t x u - (R / L) (1 - (u . t) h)`` (``t = dn/dphi``, ``n x t = 1``)."""
    s, c = dr.sincos(phi)
    g, dg = mi.Float(0.0), mi.Float(0.0)
    for px, py in ((xx, mi.Float(0.0)), (yx, yy)):
        ax, ay = px - radius * c, py - radius * s
        length = dr.maximum(dr.sqrt(ax * ax + ay * ay), 1e-20)
        ux, uy = ax / length, ay / length
        h = _cross2(c, s, ux, uy)
        g += h
        dg += _cross2(-s, c, ux, uy) - radius / length * (1.0 - (-s * ux + c * uy) * h)
    return g, dg


def specular_point(x, image, centre, axis, radius, start=None):
    """The point ``S`` of the mirror ``(centre, axis, radius)`` (`local_mirror`) that reflects
    ``x`` into ``image``: ``(S, ok, cos_theta)``. ``ok`` where Newton's method converged to a
    point seen from both sides' points (else the caller keeps the tangent-plane image). ``start``:
    a point near the answer (the path's own hit on the mirror, where the way out reflected), else
    the bisector's guess."""
    sphere = dr.squared_norm(axis) < 0.5
    rx, ri = x - centre, image - centre
    plane_n = dr.cross(rx, ri)
    a = dr.select(sphere, plane_n / dr.maximum(dr.norm(plane_n), 1e-20), axis)
    zx, zi = dr.dot(rx, a), dr.dot(ri, a)
    px = rx - zx * a
    e1 = px / dr.maximum(dr.norm(px), 1e-20)
    e2 = dr.cross(a, e1)
    xx = dr.norm(px)
    yx, yy = dr.dot(ri, e1), dr.dot(ri, e2)
    # start: the bisector of the directions from the centre to x and to the image
    ly = dr.maximum(dr.sqrt(yx * yx + yy * yy), 1e-20)
    phi = dr.atan2(yy / ly, 1.0 + yx / ly)
    if start is not None:
        rs = start - centre
        phi = dr.atan2(dr.dot(rs, e2), dr.dot(rs, e1))
    for _ in range(NEWTON_STEPS):
        g0, slope = _g(phi, radius, xx, yx, yy)
        step = dr.select(dr.abs(slope) > 1e-12, g0 / slope, 0.0)
        phi = phi - dr.clip(step, -0.5, 0.5)
    s, c = dr.sincos(phi)
    sx, sy = radius * c, radius * s
    l1 = dr.norm(mi.Vector2f(xx - sx, -sy))
    l2 = dr.norm(mi.Vector2f(yx - sx, yy - sy))
    z = zx + (zi - zx) * l1 / dr.maximum(l1 + l2, 1e-20)
    S = centre + sx * e1 + sy * e2 + z * a
    n = c * e1 + s * e2
    to_x, to_i = dr.normalize(x - S), dr.normalize(image - S)
    cos_x, cos_i = dr.dot(n, to_x), dr.dot(n, to_i)
    # converged: the normal bisects the two directions in the plane (|n x u_x + n x u_I| small)
    resid = _cross2(c, s, (xx - sx) / dr.maximum(l1, 1e-20), -sy / dr.maximum(l1, 1e-20)) + \
        _cross2(c, s, (yx - sx) / dr.maximum(l2, 1e-20), (yy - sy) / dr.maximum(l2, 1e-20))
    ok = ((radius > 0) & (xx > radius) & (ly > radius) & (cos_x > 0) & (cos_i > 0)
          & (dr.abs(resid) < 1e-3) & dr.isfinite(phi))
    return mi.Point3f(S), ok, cos_x


def turn_rates(x, S, image, cos_t, radius, sphere):
    """How fast the echo's ray turns when the ray from ``x`` turns (the module docstring), for the
    specular point ``S`` on a mirror of ``radius`` between ``x`` and ``image``, ``cos_t`` its
    angle of incidence: ``(S - x, a, D, D / b, k1, k2)`` with ``a = |S - x|``, ``b = |image - S|``,
    ``D = a + b``; ``k1 = D / b + 2 a / (R cos theta)`` across the curvature, ``k2`` along it
    (``D / b`` along a cylinder's axis, ``D / b + 2 a cos theta / R`` across a sphere's plane of
    incidence; ``sphere`` a mask or a Python bool). Shared by `aim` and `strip_lobe`."""
    to_s = S - x
    a_len = dr.norm(to_s)
    b_len = dr.norm(image - S)
    d_len = a_len + b_len
    plane = d_len / dr.maximum(b_len, 1e-3 * d_len)
    cos_t = dr.maximum(cos_t, 1e-2)
    k1 = plane + 2.0 * a_len / (radius * cos_t)
    k2 = plane + dr.select(sphere, 2.0 * a_len * cos_t / radius, 0.0)
    return to_s, a_len, d_len, plane, k1, k2


def aim(x, image, n_chain, centre, axis, radius, start=None):
    """The guide's target after a curved mirror, in the terms of `image_guide.sample_bounce`:
    ``(virtual image, segment, n_chain, ok)``. The virtual image lies on the ray from ``x``
    through the specular point ``S`` at the unfolded length ``D = |x - S| + |S - image|``, and the
    segment is ``|x - S|``, so that `sample_bounce`'s plane rule gives ``(D / b)^2``; ``n_chain``
    carries the curvature's extra narrowing (the module docstring)."""
    S, ok, cos_t = specular_point(x, image, centre, axis, radius, start)
    to_s, a_len, d_len, plane, k1, k2 = turn_rates(x, S, image, cos_t, dr.maximum(radius, 1e-6),
                                                   dr.squared_norm(axis) < 0.5)
    virtual = x + to_s / dr.maximum(a_len, 1e-12) * d_len
    # the wider of the two directions sets the (isotropic) guide's width: a guide narrower than the
    # integrand leaves part of it to the BSDF's own sampling (heavy tails), a wider one only wastes
    return mi.Point3f(virtual), a_len, n_chain * dr.square(dr.minimum(k1, k2) / plane), ok


# ---------------------------------------------------------------------------------------------
# The way out to a curved mirror's specular strip (`image_guide.STRIP_GUIDE`).

#: Widening of the strip lobe over the integrand's width (the mixture's other components cover
#: what a narrower lobe misses, but a lobe narrower than the echo leaves it to them: heavy tails).
STRIP_WIDEN = 1.0


def scene_mirrors(scene, min_exponent, lobe_exponent):
    """The convex curved mirrors of ``scene`` known in closed form: a tuple of
    ``(centre, axis, radius, exponent)`` (Python floats; ``axis`` (0, 0, 0) for a sphere) for every
    Mitsuba sphere and cylinder whose BSDF's lobe counts as a mirror (``exponent`` at least
    ``min_exponent``, read by ``lobe_exponent(bsdf)``: `image_guide.lobe_exponent`) and whose ``to_world`` keeps it round (a
    uniform scale across the axis). Mitsuba's unit sphere is centred at the origin, its unit
    cylinder runs along z from 0 to 1 with radius 1 (``p0``/``p1``/``radius`` go to ``to_world``).

    A curved mirror counts only where another shape is mirror-like too: the strip is aimed at from
    a mirror-like vertex on another shape (from the mirror itself there is no strip to aim at), so
    a scene whose only mirror is the curved one keeps its kernel and cost."""
    import numpy as np

    out = []
    shapes = list(scene.shapes())
    exps = [lobe_exponent(shape.bsdf()) for shape in shapes]
    for i, shape in enumerate(shapes):
        shape_class = shape.class_name()
        if not any(e >= min_exponent for j, e in enumerate(exps) if j != i):
            continue
        if shape_class not in ("Sphere", "Cylinder"):
            continue
        n = exps[i]
        if not n >= min_exponent or not np.isfinite(n):
            continue
        m = np.array(mi.traverse(shape)["to_world"].matrix, dtype=np.float64).reshape(4, 4)
        centre, ex, ey, ez = m[:3, 3], m[:3, 0], m[:3, 1], m[:3, 2]
        radius = float(np.linalg.norm(ex))
        if not np.isclose(radius, np.linalg.norm(ey), rtol=1e-4) or radius <= 0:
            continue        # an ellipse or ellipsoid: no closed-form specular point here
        if shape_class == "Sphere":
            if not np.isclose(radius, np.linalg.norm(ez), rtol=1e-4):
                continue
            axis = (0.0, 0.0, 0.0)
        else:
            axis = tuple(float(v) for v in ez / np.linalg.norm(ez))
        out.append((tuple(float(v) for v in centre), axis, radius, float(n)))
    return tuple(out)


def strip_lobe(x, image, mirror):
    """The guide from a mirror-like vertex ``x`` to the specular point of the convex ``mirror``
    (`scene_mirrors`) between ``x`` and ``image`` (the transducer's image after ``x``): the
    point ``S`` whose normal bisects the directions to ``x`` and to ``image`` (Alhazen's problem,
    `specular_point`), ``(axis, e1, e2, sigma1, sigma2, ok)``: a Gaussian in the plane
    tangent to the direction ``axis = (S - x) / a`` (`strip_pdf`). Its widths are the echo's: a
    turn ``delta`` at ``x`` moves the point on the mirror by ``delta a / cos theta`` across the
    curvature, which turns the ray reflected at it by ``delta k1`` with ``k1 = D / b + 2 a /
    (R cos theta)`` (``b = |image - S|``, ``D = a + b``; along a cylinder's axis ``k2 = D / b``,
    across a sphere's plane of incidence ``D / b + 2 a cos theta / R``, the module docstring); the
    mirror's Phong lobe of exponent ``n`` keeps ``cos^n`` of the turn, a Gaussian of standard
    deviation ``1 / sqrt(n)``, so ``sigma_i = STRIP_WIDEN / (k_i sqrt(n))``. ``ok`` where
    Newton's method converged to a point that faces both ``x`` and ``image`` (`specular_point`)."""
    (cx, cy, cz), (ax, ay, az), radius, n = mirror
    centre, c_axis = mi.Point3f(cx, cy, cz), mi.Vector3f(ax, ay, az)
    sphere = (ax, ay, az) == (0.0, 0.0, 0.0)
    S, ok, cos_t = specular_point(x, image, centre, c_axis, mi.Float(radius))
    to_s, a_len, _, _, k1, k2 = turn_rates(x, S, image, cos_t, radius, sphere)
    d = to_s / dr.maximum(a_len, 1e-12)
    # e1: across the curvature (a cylinder: perpendicular to its axis; a sphere: in the plane of
    # incidence, that of x, S and the centre), e2 = d x e1
    if sphere:
        side = dr.cross(S - centre, d)
    else:
        side = dr.cross(d, c_axis)
    fallback = mi.Frame3f(d).s
    side_n = dr.norm(side)
    across = dr.select(side_n > 1e-6, side / dr.maximum(side_n, 1e-12), fallback)
    e1 = dr.normalize(dr.cross(across, d)) if sphere else across
    e1 = dr.select(side_n > 1e-6, e1, fallback)
    e2 = dr.cross(d, e1)
    root_n = dr.sqrt(mi.Float(n))
    # x on (or inside) the mirror itself: no strip to aim at
    rel = x - centre
    off_axis = dr.norm(rel if sphere else rel - dr.dot(rel, c_axis) * c_axis)
    ok &= (off_axis > radius * (1.0 + 1e-3)) & (a_len > 1e-3 * radius) & dr.isfinite(a_len)
    return d, e1, e2, STRIP_WIDEN / (k1 * root_n), STRIP_WIDEN / (k2 * root_n), ok


def strip_sample(lobe, u):
    """A direction from the strip lobe (`strip_lobe`) for the uniform point ``u`` (Box-Muller in
    the tangent plane of the axis: ``w = normalize(axis + s1 g1 e1 + s2 g2 e2)``)."""
    d, e1, e2, s1, s2, _ = lobe
    r = dr.sqrt(-2.0 * dr.log(dr.maximum(1.0 - u.x, 1e-30)))
    sn, cs = dr.sincos(2.0 * dr.pi * u.y)
    return dr.normalize(d + (s1 * r * cs) * e1 + (s2 * r * sn) * e2)


def strip_pdf(lobe, w):
    """Solid-angle density of `strip_sample` at the unit direction ``w``: the plane's Gaussian
    times the Jacobian of the gnomonic map, ``p(w) = N(u / s1) N(v / s2) / (s1 s2 t^3)`` with
    ``t = w . axis``, ``u = w . e1 / t``, ``v = w . e2 / t`` (``du dv = dw / t^3``)."""
    d, e1, e2, s1, s2, _ = lobe
    t = dr.dot(w, d)
    ts = dr.maximum(t, 1e-6)
    u, v = dr.dot(w, e1) / ts / s1, dr.dot(w, e2) / ts / s2
    g = dr.exp(-0.5 * (u * u + v * v)) * (0.5 * dr.inv_pi) / (s1 * s2 * ts * ts * ts)
    return dr.select(t > 1e-6, g, 0.0)
