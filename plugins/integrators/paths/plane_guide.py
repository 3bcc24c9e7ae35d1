"""Plane guiding: aim a bounce at a glossy plane's specular point, the way home of a dihedral echo.

A quay wall standing on the seabed is a dihedral reflector: the echo that bounces seabed - wall -
transducer (or wall - seabed - transducer) is the strongest return of a real harbour image
(``scenes_xml/quay_wall.xml``). Path tracing with next-event estimation finds the seabed - wall
order badly: after the seabed (sand, mostly diffuse) the BSDF's sample must leave within the
narrow set of directions that the wall's glossy lobe (concrete: Phong exponent 30) turns back to
the transducer ``T``, and the echo's weight is that lobe evaluated at the connection, a heavy
tail (``benchmarks/dihedral.py``: 11 000 paths per beam for 5 % error in the corner bins).

That set of directions is known in closed form. By the image-source method (Allen and Berkley,
"Image method for efficiently simulating small-room acoustics", J. Acoust. Soc. Am. 65(4), 1979;
Urick, *Principles of Underwater Sound*, 3rd ed., 1983, sec. 5.5) the ray from ``x`` that
reflects specularly in a plane ``P`` and reaches ``T`` points at ``T'``, the image of ``T`` in
``P``; it meets ``P`` at the specular point ``q = x + t (T' - x)`` with ``t = h_x / (h_x + h_T)``
(``h`` the heights above the plane). How far a turn ``delta`` of the ray at ``x`` may go: it moves
the hit point by ``delta a`` (``a = |q - x|``), which turns the direction from there to ``T`` by
``delta a / b`` (``b = |T - q|``) one way while the mirror direction turns by ``delta`` the other,
so the echo leaves the lobe's axis by ``delta k`` with ``k = (a + b) / b``. A Phong lobe
``cos^n`` is about a Gaussian of standard deviation ``1 / sqrt(n)`` in that angle
(``cos^n e = exp(n ln cos e) ~ exp(-n e^2 / 2)``), so the guide is a Gaussian lobe about
``(q - x) / a`` of standard deviation ``sigma = 1 / (k sqrt(n))`` (the planar case of
`curved_mirror.strip_lobe`, whose sampling and density it shares: `curved_mirror.strip_sample`,
`curved_mirror.strip_pdf`).

The guide is one component of the one-sample mixture of `image_guide.sample_bounce` (Veach,
"Robust Monte Carlo methods for light transport simulation", PhD thesis, Stanford 1997, sec.
9.2.4): with probability `PLANE_PROB` (shared among the planes whose specular point lies on the
rectangle, seen from the front by both ``x`` and ``T``) the direction comes from a plane's lobe,
else from the BSDF; the weight is ``f cos / (mixture density)``, so every bounce keeps its
expectation whatever the guide's width (the BSDF's component covers every direction it reflects
into) and a render's expectation is unchanged.

Which planes: the scene's Mitsuba ``rectangle`` shapes whose BSDF has a lobe of exponent at least
`PLANE_EXPONENT` (`image_guide.lobe_exponent`: concrete 25.6; the sand and seabed presets
1.7 and 0), in scenes without mirror-like BSDFs (`image_guide.has_mirrors`): those keep their
chain guide (`image_guide`, whose image of a mirror behind the path aims the same way) and their
bytes, and so do scenes whose every shape is glossy (from a glossy vertex the BSDF's own lobe
finds the mirror direction). Meshes are not searched for planes: Mitsuba merges the box's
rectangles into one mesh, and on the harbour (a concrete quay mesh on a sand seabed) guiding
the mesh's planar faces (a prototype) left the error unchanged at spp 64 (the direct echoes' noise
rules there) for 1.1-1.3x the CPU time; so the box, the harbour and the wreck trace the unguided
kernel as before. Measured on the quay wall's 512-beam frame (docs/benchmarks.rst): the corner
bins' multipath error 1.6-1.7x lower at equal paths (3 900 paths per beam to 5 % instead of
11 400), the frame's error 3.8-4.2 % against 4.5-4.7 % at spp 256, for up to 19 % more CPU time
per path (the frame reaches 5 % at spp 247 instead of 270). Spheres and cylinders
(the piles' feet: another 8 % less error) are left out: finding their specular point
(`curved_mirror.specular_point`, Newton's method) took 30-50 % more time per path, which ate the
gain.
"""
from __future__ import annotations

import math

import drjit as dr
import mitsuba as mi

#: Plane guiding on (read when a render sets up, `image_guide.scene_guide`).
PLANE_GUIDE = True
#: A glossy plane: a lobe of at least this Phong exponent (concrete 25.6, sand 1.7).
PLANE_EXPONENT = 10.0
#: Probability of the planes' components of the mixture, shared among the planes.
PLANE_PROB = 0.25


def scene_planes(scene, lobe_exponent):
    """The glossy rectangles of ``scene``: a tuple of ``(centre, ex, ey, normal, exponent)``
    (Python floats: part of a frozen pass's key), for every Mitsuba ``rectangle`` (the square
    ``[-1, 1]^2`` at ``z = 0`` of its ``to_world``: ``ex``, ``ey`` its half-sides) whose BSDF's
    lobe (``lobe_exponent(bsdf)``, `image_guide.lobe_exponent`) is at least `PLANE_EXPONENT` and
    finite (a BSDF of unknown shape reads infinite). Empty when every shape is glossy: from a
    glossy vertex the BSDF's own lobe already sends the path on towards the mirror direction (a
    box of concrete rectangles gains nothing)."""
    import numpy as np

    shapes = list(scene.shapes())
    exps = [lobe_exponent(shape.bsdf()) for shape in shapes]
    if not any(e < PLANE_EXPONENT for e in exps):
        return ()
    out = []
    for shape, n in zip(shapes, exps):
        if shape.class_name() != "Rectangle" or not (PLANE_EXPONENT <= n < math.inf):
            continue
        m = np.array(mi.traverse(shape)["to_world"].matrix, dtype=np.float64).reshape(4, 4)
        c, ex, ey = m[:3, 3], m[:3, 0], m[:3, 1]
        normal = np.cross(ex, ey)
        if not np.linalg.norm(normal) > 0:
            continue
        normal /= np.linalg.norm(normal)
        out.append(tuple(tuple(float(v) for v in a) for a in (c, ex, ey, normal)) + (float(n),))
    return tuple(out)


def specular_point(x, target, plane):
    """``(q, ok)``: the point of ``plane`` (`scene_planes`) where the ray from ``x`` reflects
    towards ``target`` (through the image ``target'``, module docstring); ``ok`` where both
    points lie in front of the plane (at least 1 mm) and ``q`` on the rectangle."""
    c, ex, ey, normal, _ = plane
    c, ex, ey, nv = mi.Point3f(*c), mi.Vector3f(*ex), mi.Vector3f(*ey), mi.Vector3f(*normal)
    h_x = dr.dot(x - c, nv)
    h_t = dr.dot(target - c, nv)
    image = target - 2.0 * h_t * nv
    q = x + (h_x / dr.maximum(h_x + h_t, 1e-12)) * (image - x)
    u = dr.dot(q - c, ex) / dr.squared_norm(ex)
    v = dr.dot(q - c, ey) / dr.squared_norm(ey)
    ok = (h_x > 1e-3) & (h_t > 1e-3) & (dr.abs(u) <= 1.0) & (dr.abs(v) <= 1.0)
    return q, ok


def plane_lobe(x, target, plane):
    """The guide from ``x`` towards ``plane``'s specular point on the way to ``target``:
    ``(axis, e1, e2, sigma, sigma, ok)``, the lobe tuple of `curved_mirror.strip_lobe` (a
    Gaussian of standard deviation ``sigma = 1 / (k sqrt(n))`` in the plane tangent to the axis,
    ``k = (a + b) / b``: the module docstring)."""
    q, ok = specular_point(x, target, plane)
    a = dr.norm(q - x)
    b = dr.norm(target - q)
    axis = (q - x) / dr.maximum(a, 1e-12)
    frame = mi.Frame3f(axis)
    sigma = dr.maximum(b, 1e-6) / ((a + b) * math.sqrt(plane[-1]))
    return axis, frame.s, frame.t, sigma, sigma, ok & (a > 1e-3)


def lobes(x, target, planes, active):
    """The lobes of every plane of ``planes`` from ``x`` (`plane_lobe`, ``ok`` within ``active``)
    and their mixture probabilities (`PLANE_PROB` shared), for `image_guide.sample_bounce`."""
    out = []
    for plane in planes:
        lobe = plane_lobe(x, target, plane)
        out.append(lobe[:-1] + (lobe[-1] & active,))
    return out, [PLANE_PROB / len(planes)] * len(planes)
