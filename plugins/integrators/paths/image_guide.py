"""Image guiding: sample the next bounce towards the transducer's mirror image.

A sonar is monostatic (or nearly: a multibeam's fan and beams share one point), so an echo
that reached a target through a glossy or mirror-like surface goes home the same way: the path
``T - P1 - x - P2 - T`` with ``P1``, ``P2`` on one smooth plate (``scenes_xml/hidden_target.xml``).
After ``x`` (the boulder, diffuse) path tracing needs its BSDF sample to leave within the plate's
narrow lobe around the one direction that the plate turns back to ``T``: on that scene 2 in 1000
paths carried 99.9 % of the boulder's echo. That direction is known in closed form: by the
image-source method (Urick, *Principles of Underwater Sound*, 3rd ed., 1983, sec. 5.5; Allen and
Berkley 1979) the ray that leaves ``x``, reflects in the plane of ``P1`` and reaches ``T`` points
at the image ``T'`` of ``T`` in that plane. Reflecting ``T`` in the tangent plane of every
glossy vertex since the last diffuse one (``T' = R_k(...R_1(T))``) gives the unfolded target of a
chain of mirrors, e.g. the double bounce of a corner reflector.

The guided direction is one component of a one-sample mixture (Veach 1997, sec. 9.2.4): with
probability ``alpha`` a Phong lobe ``(n_g + 1) / (2 pi) cos^n_g`` about ``normalize(T' - x)``,
otherwise the BSDF's own sampling; the path weight is ``f cos / (alpha p_g + (1 - alpha) p_bsdf)``,
so the estimator stays unbiased whatever the guide's width (the BSDF component covers every
direction the BSDF reflects into). The width follows the mirror's lobe: a Phong lobe of
exponent ``n`` at the plate, seen from ``x`` through the unfolded line of length ``D`` of which
``d`` lies beyond the plate, is narrower by ``d / D`` (a turn ``delta`` at ``x`` moves the hit
point by ``delta |x - P|`` and turns the reflected ray by ``delta D / d``), so
``n_g = n (D / d)^2``. A vertex counts as a mirror when its BSDF has a narrow lobe, whichever
component the path sampled there (a path that left the plate diffusely and met the target
returns through the plate's lobe all the same; tying the chain to the sampled component left
those paths to chance and they were most of the remaining noise on hidden_target): the
exponent read from the BSDF's density at the mirror direction,
``n = 2 pi p(mirror) - 1`` (exact for a pure Phong lobe, an underestimate when the BSDF mixes in
diffuse scatter, which only widens the guide), at least `MIN_EXPONENT`.

The way back through two mirrors (a periscope, a corner reflector: ``T - A - B - x - B - A - T``)
is guided too (`advance_chain`): at ``x`` the bounce aims at ``R_B(R_A(T))``, and at ``B`` on the
way back at ``R_A(T)``, the image the chain held before ``B``; without it that bounce was ``B``'s
own sample and ``A``'s lobe was only met at the connection to ``T``, a heavy-tailed estimate. On
`scenes_xml/periscope.xml` (3 seeds of 1.4 M independent paths) guiding the way back lowers the
boulder window's variance per path 2.0-2.8x, and its largest path from 28 000 to 11 000-13 000
times the ping's mean, for 8 % more time per path.

*The way out to a curved mirror* (`STRIP_GUIDE`): a convex curved mirror (a steel pile, a
sphere) returns an echo only from the thin strip of its surface whose normal bisects the
directions to where the ray came from and to the transducer's image: on
``scenes_xml/pile_quay.xml`` (the pile seen only in a quay wall) the wall's BSDF sample met that
strip in 0.7 % of paths, and the top 0.1 % of the wall-pile-wall echoes held 96 % of their
second moment. So at the first mirror of a chain, for each mirror-like sphere or cylinder of the
scene (`curved_mirror.scene_mirrors`), the bounce may aim at its specular point towards the image
after the vertex (Alhazen's problem, `curved_mirror.strip_lobe`), with a Gaussian lobe as wide as
the echo across and along the mirror: a component of probability `STRIP_PROB` of the same
one-sample mixture. On pile_quay 12.5 % of the paths now meet the strip, the variance per path is
6.1x lower for 1.9x the time per path (the paths that reach the pile go on), and the error at
equal CPU time 1.3-2.5x lower (docs/benchmarks.rst). Scenes whose only mirror is the curved one
(a tank, a bow: there is no other mirror to aim from) or without curved mirrors keep their kernel,
byte for byte.

Where no mirror precedes a bounce, ``alpha`` is 0 and the bounce is the BSDF's sample. A scene
without any mirror-like BSDF (`has_mirrors`: concrete, sand, rock, the seabed presets) is traced by
the unguided kernel itself, so it costs nothing; where there are mirrors each bounce pays one
more BSDF density, to read the lobe (0-31 % more time per path on the scenes of scenes_xml/, `benchmarks/guide.py`).
The primary samples keep their layout (`samples`): dim ``2 + 3k`` picks the component (rescaled
for the BSDF's own lobe choice), dims ``3 + 3k``, ``4 + 3k`` draw the direction.
"""
from __future__ import annotations

import math

import drjit as dr
import mitsuba as mi

#: Probability of the guided component after a mirror-like vertex.
GUIDE_PROB = 0.5
#: Widest lobe that counts as a mirror (Phong exponent; 100: half power 6.7 deg off the mirror
#: direction). Concrete (exponent 30) is left out: guiding after it measured no gain on the box.
MIN_EXPONENT = 100.0
#: Cap of the guide's exponent (a lobe about 0.4 deg wide).
MAX_EXPONENT = 1.0e5
#: Guide the way back through a chain of two mirrors too (`advance_chain`); read when a path
#: kernel is traced (a frozen pass keeps what it recorded: `frozen_pass.clear` after a change).
RETURN_GUIDE = True
#: Aim the bounce after a curved mirror (a sphere or cylinder, read from the surface's curvature
#: where the path met it) at the mirror's specular point instead of the tangent plane's image
#: (`curved_mirror`); read when a path kernel is traced, as `RETURN_GUIDE`. Off by default: at equal
#: paths it lowers the error behind a ship's bow 1.3x and behind a tank 1.13x, but a scene with a
#: mirror-like sphere or cylinder pays about 25 % more CPU time per path, so at equal time it gains
#: 1.2x on ``hull_target``, nothing on ``tank_target`` and loses 1.12x on ``pile_quay`` (whose pile
#: is never the last mirror before a diffuse target; docs/benchmarks.rst).
CURVED_GUIDE = False
#: At a mirror-like vertex, aim the bounce at the specular strip of each convex curved mirror of
#: the scene (a mirror-like Mitsuba sphere or cylinder, `curved_mirror.scene_mirrors`): the point
#: whose normal bisects the directions to the vertex and to the transducer's image after it, so
#: that the mirror sends the echo home along the chain (`curved_mirror.strip_lobe`). Read when a
#: render sets up, as `CURVED_GUIDE`.
STRIP_GUIDE = True
#: Probability of the strips' components, shared among the scene's curved mirrors.
STRIP_PROB = 0.5


def lobe_exponent(bsdf) -> float:
    """The narrowest lobe ``bsdf`` can have, as the exponent `lobe_at` reads from its density (at
    normal incidence, where the acoustic BSDF's diffuse share of the density is largest, so its
    smallest reading is its largest here); infinity for a BSDF of unknown shape (it may be a
    mirror), 0 for one without a specular part."""
    from mitsonar.plugins.bsdfs.acoustic import AcousticBSDF, lobe_pdf

    if not isinstance(bsdf, AcousticBSDF):
        return math.inf
    d, s, n = (float(dr.detach(getattr(bsdf, k))[0]) for k in ("diffuse", "specular", "shininess"))
    if s <= 0:
        return 0.0
    return exponent_of_peak(lobe_pdf(s / (d + s), n, 1.0, 1.0))


def exponent_of_peak(peak):
    """The Phong exponent ``n`` whose normalised lobe has the density ``peak`` at its axis:
    ``(n + 1) / (2 pi) = peak``."""
    return 2.0 * math.pi * peak - 1.0


def has_mirrors(scene) -> bool:
    """Whether any shape of ``scene`` has a BSDF whose lobe counts as a mirror (`MIN_EXPONENT`):
    without one no chain can form, so the integrators trace their unguided kernel."""
    return any(lobe_exponent(shape.bsdf()) >= MIN_EXPONENT for shape in scene.shapes())


#: Mitsuba shapes whose curvature `curved_mirror.local_mirror` reads exactly (a sphere, a cylinder).
CURVED_SHAPES = ("Sphere", "Cylinder")


class Guide:
    """A guide that knows the scene's convex curved mirrors (`STRIP_GUIDE`): ``curved`` as
    `scene_guide`'s ``"curved"``, ``mirrors`` from `curved_mirror.scene_mirrors` (Python numbers:
    part of a frozen pass's key, `frozen_pass`)."""

    def __init__(self, curved, mirrors, planes=()):
        self.curved, self.mirrors, self.planes = bool(curved), tuple(mirrors), tuple(planes)

    def __eq__(self, other):
        return isinstance(other, Guide) and (self.curved, self.mirrors, self.planes) == \
            (other.curved, other.mirrors, other.planes)

    def __hash__(self):
        return hash((self.curved, self.mirrors, self.planes))

    def __repr__(self):
        return f"Guide(curved={self.curved}, mirrors={len(self.mirrors)}, planes={len(self.planes)})"


def is_curved(guide):
    """Whether the kernel of ``guide`` (`scene_guide`) reads the mirrors' curvature."""
    return guide == "curved" or (isinstance(guide, Guide) and guide.curved)


def scene_guide(scene):
    """The guide a scene needs: False (no mirror-like BSDF, `has_mirrors`), ``"curved"`` where a
    mirror-like sphere or cylinder is among its shapes and `CURVED_GUIDE` is on (the kernel then
    reads the normal's derivatives and solves for the reflection points, `curved_mirror`), a
    `Guide` where such a shape is known in closed form and `STRIP_GUIDE` is on (the bounces at
    mirror-like vertices may aim at its specular strip), else True (planar mirrors: the
    tangent-plane images alone, at no extra cost). A scene without mirrors but with glossy
    rectangles (`plane_guide.scene_planes`) gets a `Guide` holding them (``planes``)."""
    if not has_mirrors(scene):
        from . import plane_guide

        # no chain can form; glossy planes ahead may still turn echoes home (`plane_guide`)
        planes = plane_guide.scene_planes(scene, lobe_exponent) if plane_guide.PLANE_GUIDE else ()
        return Guide(False, (), planes) if planes else False
    curved = CURVED_GUIDE and any(shape.class_name() in CURVED_SHAPES and lobe_exponent(shape.bsdf()) >= MIN_EXPONENT
                                  for shape in scene.shapes())
    if STRIP_GUIDE:
        from .curved_mirror import scene_mirrors

        mirrors = scene_mirrors(scene, MIN_EXPONENT, lobe_exponent)
        if mirrors:
            return Guide(curved, mirrors)
    return "curved" if curved else True


def phong_pdf(n, cos_a):
    """Solid-angle density of the normalised Phong lobe ``(n + 1) / (2 pi) cos^n``."""
    return dr.select(cos_a > 0, (n + 1) * (0.5 * dr.inv_pi) * dr.power(dr.maximum(cos_a, 0.0), n), 0.0)


def sample_bounce(bsdf, ctx, si, image, n_chain, segment, u1, u2, active, strips=(), probs=None):
    """The next direction at ``si`` from the mixture of the guide and the BSDF.

    ``image`` is the transducer's image through the glossy vertices since the last diffuse one
    and ``n_chain`` the narrowest of their lobes' exponents (0: no mirror, the BSDF samples
    alone); ``segment`` is the length of the ray that reached ``si`` (from the previous vertex,
    the chain's last mirror when there is one). ``strips``: lobes towards curved mirrors'
    specular strips (`curved_mirror.strip_lobe`, `STRIP_GUIDE`), each a component of probability
    ``STRIP_PROB / len(strips)`` (or ``probs``, one per lobe: `plane_guide.lobes`) where its
    ``ok`` holds, the other components sharing the rest.
    Returns ``(wo_world, weight)``: the world direction and ``f cos / pdf`` of the mixture.
    """
    # A BSDF with a delta lobe (Mitsuba's conductor, smooth plastic) keeps its own sampling: the
    # mixture's eval / pdf would give its delta lobe a weight of zero.
    smooth = ~mi.has_flag(bsdf.flags(), mi.BSDFFlags.Delta)
    guided = (n_chain > 0) & smooth
    alpha = dr.select(guided, GUIDE_PROB, 0.0)
    if strips:
        from . import curved_mirror

        # the strips' components first: u1 below their summed probability picks one, the rest of
        # [0, 1) is rescaled for the planar guide and the BSDF as without them
        probs = probs or [STRIP_PROB / len(strips)] * len(strips)
        beta = [dr.select(lobe[-1] & smooth, p, 0.0) for lobe, p in zip(strips, probs)]
        beta_sum, use_s, wo_s, below = mi.Float(0.0), mi.Bool(False), mi.Vector3f(0.0), mi.Float(0.0)
        for lobe, b in zip(strips, beta):
            beta_sum += b
            pick = active & (u1 >= below) & (u1 < beta_sum)
            wo_s = dr.select(pick, curved_mirror.strip_sample(lobe, u2), wo_s)
            use_s |= pick
            below = mi.Float(beta_sum)
        u1 = dr.select(beta_sum > 0, dr.minimum((u1 - beta_sum) / (1.0 - beta_sum), dr.one_minus_epsilon(mi.Float)),
                       u1)
        mixed = guided | (beta_sum > 0)
    else:
        use_s, mixed = mi.Bool(False), guided
    use_g = active & guided & (u1 < alpha) & ~use_s
    u_b = dr.select(guided, dr.minimum((u1 - alpha) / (1.0 - alpha), dr.one_minus_epsilon(mi.Float)), u1)
    bs, bsdf_weight = bsdf.sample(ctx, si, u_b, u2, active & ~use_g & ~use_s)

    to_image = image - si.p
    total = dr.norm(to_image)
    axis = to_image / dr.maximum(total, 1e-12)
    beyond = dr.maximum(total - segment, 1e-3 * total)
    n_g = dr.minimum(n_chain * dr.square(total / beyond), MAX_EXPONENT)
    cos_a = dr.power(u2.x, 1.0 / (n_g + 1.0))
    sin_a = dr.safe_sqrt(1.0 - cos_a * cos_a)
    s, c = dr.sincos(2.0 * dr.pi * u2.y)
    wo_g = mi.Frame3f(axis).to_world(mi.Vector3f(sin_a * c, sin_a * s, cos_a))

    wo = dr.select(use_g, wo_g, si.to_world(bs.wo))
    if strips:
        wo = dr.select(use_s, wo_s, wo)
    # Outside a chain (and away from the strips) the bounce is the BSDF's own sample and weight:
    # only mixed lanes evaluate the mixture.
    value, p_bsdf = bsdf.eval_pdf(ctx, si, si.to_local(wo), active & mixed)
    pdf = alpha * phong_pdf(n_g, dr.dot(wo, axis)) + (1.0 - alpha) * p_bsdf
    if strips:
        pdf *= 1.0 - beta_sum
        for lobe, b in zip(strips, beta):
            pdf += dr.select(b > 0, b * curved_mirror.strip_pdf(lobe, wo), 0.0)
    ok = active & mixed & (pdf > 0)
    weight = dr.select(mixed, dr.select(ok, value.x / dr.select(ok, pdf, 1.0), 0.0), bsdf_weight.x)
    return wo, weight


def lobe_at(bsdf, si, active):
    """The exponent of ``bsdf``'s lobe at ``si``, read from its density at the mirror direction of
    the incoming ray (`exponent_of_peak`): a mirror when at least `MIN_EXPONENT`."""
    mirror_dir = mi.Vector3f(-si.wi.x, -si.wi.y, si.wi.z)
    return exponent_of_peak(bsdf.pdf(mi.BSDFContext(mi.TransportMode.Importance), si, mirror_dir, active))


def mirror_image(point, p, normal):
    """The image of ``point`` in the plane through ``p`` with unit ``normal``."""
    return point - 2.0 * dr.dot(point - p, normal) * normal


def advance_chain(si, origin, image, n_chain, prev_image, prev_n, n_here, active):
    """`advance` with the way back: ``(image, n_chain, prev_image, prev_n, ret_image, ret_n)``.

    ``prev_image``/``prev_n`` are the chain's image and exponent before its last mirror. A path
    that left a chain of two mirrors ``A, B`` for a diffuse target ``x`` (a periscope, a corner
    reflector) comes home through ``B`` and then ``A``: the bounce at ``x`` aims at ``R_B(R_A(T))``
    (the chain's image), and the bounce at ``B`` on the way back at ``R_A(T)``, the image before
    ``B``. That one is returned as ``ret_image``/``ret_n`` at a diffuse vertex after at least two
    mirrors (else ``ret_n`` is 0), for the next vertex to use if it is a mirror; a mirror uses it
    up. One level is kept: with ``max_depth`` 5 a round trip through more mirrors cannot close."""
    mirror = active & (n_here >= MIN_EXPONENT)
    nrm = si.sh_frame.n
    reflected = mirror_image(image, si.p, nrm)
    extended = dr.select(n_chain > 0, dr.minimum(n_chain, n_here), n_here)
    zero = mi.Float(0.0)
    return (dr.select(mirror, reflected, origin), dr.select(mirror, extended, zero),
            dr.select(mirror, image, origin), dr.select(mirror, n_chain, zero),
            dr.select(mirror, origin, prev_image), dr.select(mirror, zero, prev_n))


def start_chain(origin):
    """A path's guide state at the transducer ``origin``, no mirror met yet: the tuple
    ``(image, n_chain, prev_image, prev_n, ret_image, ret_n)`` of `advance_chain` and the last
    mirror's ``(centre, axis, radius, hit)`` of `curvature` (radius 0: none, or flat)."""
    return (mi.Point3f(origin), mi.Float(0.0), mi.Point3f(origin), mi.Float(0.0), mi.Point3f(origin), mi.Float(0.0),
            mi.Point3f(0.0), mi.Vector3f(0.0), mi.Float(0.0), mi.Point3f(0.0))


def ray_flags(guide):
    """The path kernel's intersection flags: with the curved guide (`scene_guide`) the normal's
    derivatives too, which give a curved mirror's shape (`curved_mirror.local_mirror`)."""
    if is_curved(guide):
        from .curved_mirror import RAY_FLAGS

        return RAY_FLAGS
    return mi.RayFlags.All


def chained(chain):
    """Whether a mirror-like vertex precedes the next bounce (the chain is not empty)."""
    return chain[1] > 0



def scatter(bsdf, ctx, si, samples, base, guide, chain, origin, segment, active):
    """The way on from a bounce, guided or not: ``(ray, weight, chain, chained)``.

    ``guide`` is a Python bool (the kernel's shape): with it, `bounce` (the guided mixture; ``chained``
    says which lanes were on a chain before it, for the hard-echo tag); without, the BSDF's own
    sample (``chained`` None). ``base`` is the bounce's first primary-sample dimension. The one
    bounce step of the straight and the refracted path functions."""
    if dr.hint(guide, mode="scalar"):
        was_chained = active & chained(chain)
        wo, weight, chain = bounce(bsdf, ctx, si, chain, origin, segment, samples.get(base),
                                   samples.get2(base + 1), active, curved=is_curved(guide),
                                   mirrors=getattr(guide, "mirrors", ()), planes=getattr(guide, "planes", ()))
        return si.spawn_ray(wo), weight, chain, was_chained
    bs, bsdf_weight = bsdf.sample(ctx, si, samples.get(base), samples.get2(base + 1), active)
    return si.spawn_ray(si.to_world(bs.wo)), bsdf_weight.x, chain, None


def bounce(bsdf, ctx, si, chain, origin, segment, u1, u2, active, curved=False, mirrors=(), planes=()):
    """One guided bounce at ``si``: ``(wo_world, weight, chain after si)``.

    The target is the chain's image (the guide's width narrowed by ``segment``, the ray that
    reached ``si``, `sample_bounce`), except on the way back from a target seen through two
    mirrors: at the nearer mirror the bounce aims at the image in the farther one (``ret_image``,
    `advance_chain`), unnarrowed, since that mirror lies ahead, not behind (`RETURN_GUIDE`). With
    ``curved`` (a Python bool, `scene_guide`) the bounce after a curved mirror aims at its specular
    point (`curved_mirror.aim`). ``mirrors``: the scene's convex curved mirrors
    (`curved_mirror.scene_mirrors`, `STRIP_GUIDE`): at a mirror-like ``si`` the bounce may aim at
    the specular strip of each, towards the transducer's image after ``si``
    (`curved_mirror.strip_lobe`). ``planes``: glossy rectangles of a scene without mirrors
    (`plane_guide`): every bounce may aim at their specular points towards the transducer; no
    chain forms there, so it is returned as it came."""
    image, n_chain, prev_image, prev_n, ret_image, ret_n, centre, axis, radius, hit = chain
    if planes:
        from . import plane_guide

        lobes, probs = plane_guide.lobes(si.p, origin, planes, active)
        wo, weight = sample_bounce(bsdf, ctx, si, image, n_chain, segment, u1, u2, active, lobes, probs)
        return wo, weight, chain
    n_here = lobe_at(bsdf, si, active)
    strips = ()
    if mirrors:
        from . import curved_mirror

        # the first mirror of a chain only: from a mirror met after others (the quay wall on the
        # way home from the pile) a strip leads to another round trip, whose echo is weak (on
        # pile_quay such echoes hold 0.5 % of the second moment; the longer paths cost time)
        here = active & (n_here >= MIN_EXPONENT) & (n_chain == 0)
        nrm = si.sh_frame.n
        after = mirror_image(image, si.p, nrm)    # the image after si (as `advance_chain` makes it)
        strips = []
        for m in mirrors:
            lobe = curved_mirror.strip_lobe(si.p, after, m)
            strips.append(lobe[:-1] + (lobe[-1] & here,))
    homeward = (ret_n > 0) & (n_here >= MIN_EXPONENT) & RETURN_GUIDE
    target, seg, n_aim = image, segment, n_chain
    if curved:
        # after a curved mirror: aim at its specular point between si and the image before it
        from . import curved_mirror

        virtual, s_len, n_c, ok = curved_mirror.aim(si.p, prev_image, n_chain, centre, axis, radius, hit)
        use = ok & (n_chain > 0) & ~homeward
        target, seg, n_aim = dr.select(use, virtual, image), dr.select(use, s_len, segment), dr.select(use, n_c, n_chain)
    wo, weight = sample_bounce(bsdf, ctx, si, dr.select(homeward, ret_image, target),
                               dr.select(homeward, ret_n, n_aim), dr.select(homeward, 0.0, seg),
                               u1, u2, active, strips)
    return wo, weight, advance_chain(si, origin, image, n_chain, prev_image, prev_n, n_here, active) + \
        curvature(si, n_here, active, curved)


def curvature(si, n_here, active, curved=True):
    """The last mirror's shape for the chain after ``si``: ``(centre, axis, radius)`` of
    `curved_mirror.local_mirror` at a mirror-like vertex (radius 0 where it is flat), radius 0 at a
    diffuse one (which restarts the chain), and the point ``si.p`` (where Newton's method starts:
    the way home meets the mirror near where the way out did)."""
    if not curved:
        return mi.Point3f(0.0), mi.Vector3f(0.0), mi.Float(0.0), mi.Point3f(0.0)
    from . import curved_mirror

    centre, axis, radius = curved_mirror.local_mirror(si, -si.to_world(si.wi))
    mirror = active & (n_here >= MIN_EXPONENT)
    return centre, axis, dr.select(mirror, radius, 0.0), mi.Point3f(si.p)


def advance(bsdf, si, origin, image, n_chain, active):
    """The chain after ``si``: ``(image, n_chain)`` extended by ``si`` when its BSDF's lobe is
    narrow (the image reflected in its tangent plane), else restarted at the transducer
    ``origin``."""
    o = mi.Point3f(origin)
    image, n_chain, *_ = advance_chain(si, o, image, n_chain, o, mi.Float(0.0), lobe_at(bsdf, si, active), active)
    return image, n_chain
