r"""Derivatives of a scan by path replay: the AD modes of `SonarIntegrator.sample`.

The primal scan is the exact histogram ``I[row, b] = 1/N sum_paths sum_k E_k 1[r_k in bin b]``
(``E_k``, ``r_k``: energy and range of bounce ``k``'s echo, ``plugins/integrators/common.py``). A hard bin has
no derivative with respect to range, so the derivative is that of

    I~[row, b] = 1/N sum E_k  K_b(r_k),   K_b = (bin b's indicator) convolved with a one-bin box,

taken as: the change of an echo's energy counted in its own bin (``dE_k 1[r_k in b]``: exact for
everything that does not move an echo) plus the change of its range smoothed by the box
(``E_k dK_b/dr dr_k``). ``dK_b/dr`` is ``+1/w`` at bin b's lower edge and ``-1/w`` at its upper one
(``w`` the bin width), so a range change moves energy across the bin edge nearest to the echo,
at ``E_k dr_k / w``: the derivative of the scan binned by linear interpolation between bin centres.
Sums over bins, and anything smooth over a few bins (a range centroid, a loss on a blurred scan),
get the derivative of the exact histogram's expectation; a single bin's range derivative is that
of the scan seen through a one-bin box.

Estimator (path replay backpropagation, Vicini et al. 2021, as Mitsuba's ``prb.py``): sampling
is detached (emitted directions and BSDF lobes are drawn with the current values and kept fixed),
so the emission weight ``B / pdf`` differentiates as ``dB / pdf`` and a BSDF sample weight as
``d(f cos) / pdf``. The echo energy is a product ``E_k = w_beam * beta_1 ... beta_k-1 * e_k``; the
reverse pass runs each path twice: a primal replay sums ``S = sum_k a_k E_k`` (``a_k`` the adjoint of
echo k's bin), then the adjoint replay walks the path again and back-propagates, at every bounce,
the echo's own term and ``rest * d(beta)/beta`` where ``rest`` is what later echoes still carry
(``S`` minus the echoes passed). Nothing of a path is stored: memory does not grow with paths.
The forward pass carries ``d(throughput)/throughput`` along the path.

Geometry (the sensor's ``to_world``): an emitted direction is fixed in the beam frame, so moving
the head moves its rays. Hit points move on their surfaces' tangent planes (exact on planar
facets, first order on curved ones; texture lookups do not follow the moving point):
``dp_k = A_k dp_k-1`` with ``A = I - w n^T / (n . w)`` for a segment of direction ``w`` onto a
surface of normal ``n``, and the first segment also turns with the emitted direction. Each path
carries the Jacobians of its hit point and path length with respect to the head's origin and
emitted direction (``Jo``, ``Jw``; 3 x 3 each) and rebuilds, at every bounce, an attached copy of
the echo from them; the head's axes enter the receive beam directly. Visibility and the path's
discontinuities (edges, occlusion boundaries) are not differentiated (as in ``prb``).

Mesh vertices (``<shape id>.vertex_positions``, issue "Inverse problems"): the ray, fixed in the
beam frame, is intersected again with derivatives, so an echo's point slides along its ray when
its facet moves (``dp = w (n . dx) / (n . w)``: the range changes) and its facet's normal turns
(the incidence angle changes, in the BSDF); the shading frame turns with the facet normal
(meshes need ``face_normals``). Not differentiated: silhouettes and facet edges (a facet's normal
jumps at its edges, and moving vertices moves those jumps; on a coarse height map this is the
bias measured by ``benchmarks/inverse.py``), and the motion of an earlier bounce's point seen by
later bounces (exact for single-bounce echoes).
"""
from __future__ import annotations

import drjit as dr
import mitsuba as mi

from .emission import DB_TO_LOG2, emit as emit_ray
from .samples import DIMS_EMIT, DIMS_PER_BOUNCE

_NO_GRAD_OK = dr.ADFlag.Default | dr.ADFlag.AllowNoGrad
_KEEP_TANGENTS = dr.ADFlag.ClearNone | dr.ADFlag.AllowNoGrad


class Adjoint:
    """The adjoint of one scan image (``grad_in`` of ``render_backward``, already divided by the
    paths per row), and the per-echo weights the reverse pass needs."""

    def __init__(self, bins, grad):
        self.bins, self.grad = bins, grad

    def own_bin(self, ping, rng, valid):
        """The adjoint of the bin an echo of range ``rng`` lands in (0 outside the window)."""
        b, inside = self.bins.index(rng, valid)
        return dr.gather(mi.Float, self.grad, self.bins.flat(ping, b), inside)

    def weights(self, ping, rng, valid):
        """``(a, a_r)``: ``a`` the adjoint of the echo's own bin (0 outside the window), ``a_r`` the
        rate at which moving the echo by dr changes the adjoint-weighted scan (box kernel: the
        adjoints on either side of the nearest bin edge, divided by the bin width)."""
        bins = self.bins
        b, inside = bins.index(rng, valid)
        a = dr.gather(mi.Float, self.grad, bins.flat(ping, b), inside)
        up, lo, e = edge_bins(bins, rng, valid)
        g_up = dr.gather(mi.Float, self.grad, bins.flat(ping, e), up)
        g_lo = dr.gather(mi.Float, self.grad, bins.flat(ping, e - 1), lo)
        return a, (g_up - g_lo) * bins.inv_width


def edge_bins(bins, rng, valid):
    """The bins on either side of the bin edge nearest to ``rng``: ``(upper exists, lower exists,
    e)`` with the upper bin ``e`` and the lower ``e - 1`` (an edge of the window has one)."""
    t = (rng - bins.r_min) * bins.inv_width
    n = mi.Float(bins.n_bins_o)
    valid = valid & (t >= -0.5) & (t < n + 0.5)
    e = mi.UInt32(dr.maximum(dr.round(t), 0.0))
    return valid & (e < bins.n_bins_o), valid & (e >= 1), e


def _relative(value):
    """1 with the derivative ``d(value) / value`` (0 where ``value`` is 0)."""
    ok = dr.detach(value) > 0
    return dr.select(ok, value / dr.select(ok, dr.detach(value), 1.0), 0.0)


def differentiable_keys(params) -> list:
    """The keys of ``params`` (``mi.SceneParameters``) whose derivatives the sonar integrators
    compute: the sonar sensor's and the acoustic BSDF's differentiable parameters, and the
    ``data``/``value`` of a texture that is an acoustic BSDF's ``diffuse``, and a mesh's
    ``vertex_positions`` (`_attached_hit`)."""
    import re

    from mitsonar.plugins.bsdfs.acoustic import AcousticBSDF
    from mitsonar.plugins.sensors.sonar import SonarSensor

    owner = {k: params.properties[k][2] for k in params.keys()}
    bsdfs = [k.rsplit(".", 1)[0] for k, node in owner.items() if isinstance(node, AcousticBSDF)]
    return [k for k, node in owner.items()
            if not params.flags(k) & mi.ParamFlags.NonDifferentiable
            and (isinstance(node, (SonarSensor, AcousticBSDF))
                 or any(re.fullmatch(re.escape(b) + r"\.diffuse\.(data|value)", k) for b in bsdfs)
                 or (isinstance(node, mi.Mesh) and k.endswith(".vertex_positions")))]


def moving_meshes(scene) -> bool:
    """Whether a mesh of ``scene`` has gradients enabled on its vertex positions."""
    return any(isinstance(s, mi.Mesh) and dr.grad_enabled(s.vertex_positions_buffer())
               for s in scene.shapes())


def check_attached(params, source):
    """Refuse, in one line, parameters with gradients enabled that the sonar integrators do not
    differentiate (a shape's ``to_world``, a film's size): their derivative would silently be 0."""
    if params is None or not hasattr(params, "properties"):
        return
    allowed = set(differentiable_keys(params))
    for k in params.keys():
        if k.endswith(".vertex_normals") and isinstance(params.properties[k][2], mi.Mesh) and dr.grad_enabled(params[k]):
            raise ValueError(f"{source}: mesh {k[:-len('.vertex_normals')]!r} has vertex normals; its vertex positions "
                             f"are differentiated with face normals only: give it <boolean name=\"face_normals\" "
                             f"value=\"true\"/>")
        if k not in allowed and dr.grad_enabled(params[k]):
            raise ValueError(f"{source}: parameter {k!r} has gradients enabled but is not differentiated by the "
                             f"sonar integrators; allowed: {', '.join(sorted(allowed))}")


def acoustic_bsdfs(scene):
    """``([(bsdf, instance id)], others)``: the scene's ``acoustic`` BSDFs attached directly to
    shapes, and whether any shape has another BSDF."""
    out, others = {}, False
    for shape in scene.shapes():
        b = shape.bsdf()
        if b is not None and type(b).__name__ == "AcousticBSDF":
            if id(b) not in out:
                out[id(b)] = (b, dr.reinterpret_array(mi.UInt32, mi.BSDFPtr(b))[0])
        else:
            others = True
    return list(out.values()), others


def _eval_attached(ad, bsdf, ctx, si, wo, active, forward):
    """``f cos(theta_o)`` with derivatives: the scene's ``acoustic`` BSDFs are evaluated by direct
    calls, masked by instance (a Python BSDF's parameters are read inside a virtual call's scope,
    which forward-mode AD cannot enter afterwards: Dr.Jit issue #295); other BSDFs (``twosided``
    wrappers, Mitsuba's own) go through the virtual call, differentiated in reverse mode only."""
    ids = dr.reinterpret_array(mi.UInt32, bsdf)
    value, known = mi.Float(0.0), mi.Bool(False)
    for b, instance in ad.bsdfs:
        m = active & (ids == instance)
        value = dr.select(m, b.eval(ctx, si, wo, m).x, value)
        known |= m
    if not ad.other_bsdfs:
        return value
    others = active & ~known
    if forward:
        with dr.suspend_grad():
            other = bsdf.eval(ctx, si, wo, others).x
    else:
        other = bsdf.eval(ctx, si, wo, others).x
    return dr.select(others, other, value)


def _attached_hit(scene, ray, si, active):
    """``(dp, frame)``: the displacement of ``si``'s hit point (0, attached to the scene's mesh
    vertices) and its shading frame attached to them, with ``si``'s exact values.

    The ray is intersected again with derivatives (Mitsuba's default ray flags, not
    ``mi.RayFlags.FollowShape``): the emitted direction is fixed in the beam frame, so when a
    facet moves the echo's point moves along the ray, ``dp = w (n . dx) / (n . w)`` (``dx`` the
    facet's displacement there), and the facet's normal turns (`_attached_hit` turns the shading
    normal with it). Only the point's own facet is
    followed: a later bounce does not see an earlier point move (exact for single-bounce echoes),
    and silhouettes (a ray leaving one facet for another) are not differentiated."""
    si_s = scene.ray_intersect(mi.Ray3f(ray), mi.RayFlags.All, False, active)
    dp = si_s.p - dr.detach(si_s.p)
    # Mitsuba attaches the facet's geometric normal (not the shading frame): the shading frame
    # turns as its facet does, by the smallest rotation taking n to n + dn (exact for face
    # normals; for interpolated vertex normals, the turn of the facet under the point).
    dn = si_s.n - dr.detach(si_s.n)
    f = si.sh_frame
    frame = mi.Frame3f(f.s - f.n * dr.dot(f.s, dn), f.t - f.n * dr.dot(f.t, dn), f.n + dn)
    return dr.select(active, dp, 0.0), frame


def _project(v, w, n, ndw):
    """``(I - w n^T / (n . w)) v``: a displacement ``v`` of a ray's start carried along ``w`` to the
    plane of normal ``n`` (a hit point moving on its tangent plane)."""
    return v - w * (dr.dot(n, v) / ndw)


@dr.syntax
def replay(setup, mode, ping, samples, adjoint=None, state_in=None, record=None, active=True):
    """One AD pass over one path per lane (see the module docstring).

    ``mode`` ``dr.ADMode.Primal``: returns ``S = sum_k a_k E_k`` per lane (``adjoint`` weights;
    `SonarIntegrator.sample` runs the primal path function for this instead, which also returns
    which bounces' echoes were seen). ``dr.ADMode.Backward``: back-propagates ``state_in`` (``S``,
    or ``(S, seen)`` from `SonarIntegrator.sample`: then bit k of ``seen`` replaces bounce k's
    visibility ray, for k < 32) and the echoes' adjoints into the parameters with gradients
    enabled; returns None.
    ``dr.ADMode.Forward``: calls ``record(k, range, energy, valid, hit, d_energy, d_range)`` with
    each echo's derivatives along the parameters' tangents; returns None.
    """
    primal = mode == dr.ADMode.Primal
    seen = None
    if isinstance(state_in, tuple):
        state_in, seen = state_in
    known = seen is not None and setup.depth <= 32
    backward = mode == dr.ADMode.Backward
    forward = mode == dr.ADMode.Forward
    scene = setup.scene
    ad = setup.ad
    x_ax, y_ax, z_ax, origin, d_local, weight, ray = emit_ray(setup, ping, samples, active)
    # The emitted direction's angles: the emission weight B / pdf differentiates as dB / B there.
    az0, el0 = dr.atan2(d_local.x, d_local.z), dr.safe_asin(d_local.y)
    rel = mi.Float(0.0)
    throughput = mi.Float(weight)
    path_length = mi.Float(0.0)
    previous = mi.Point3f(origin)
    depth = mi.UInt32(0)
    active = mi.Bool(active) & (weight > 0)
    total_s = mi.Float(0.0)
    rest = mi.Float(state_in if backward else 0.0)
    # Jacobians of the current point and of the path length to it, with respect to the head's
    # origin (jo*) and emitted direction (jw*): columns, and rows as vectors.
    jo0, jo1, jo2 = mi.Vector3f(1, 0, 0), mi.Vector3f(0, 1, 0), mi.Vector3f(0, 0, 1)
    jw0, jw1, jw2 = mi.Vector3f(0), mi.Vector3f(0), mi.Vector3f(0)
    jlo, jlw = mi.Vector3f(0), mi.Vector3f(0)
    max_depth = setup.depth_o
    ctx = mi.BSDFContext(mi.TransportMode.Importance)

    while dr.hint(active, label=f"sonar_path_replay_{mode.name}"):
        si = scene.ray_intersect(ray, active)
        active &= si.is_valid()
        w = ray.d
        seg = dr.norm(si.p - previous)
        path_length += seg
        n = si.n
        ndw = dr.dot(n, w)
        ndw = dr.select(dr.abs(ndw) > 1e-6, ndw, 1e-6)
        first = depth == 0
        t0 = dr.select(first, seg, 0.0)
        n_jo0, n_jo1, n_jo2 = _project(jo0, w, n, ndw), _project(jo1, w, n, ndw), _project(jo2, w, n, ndw)
        n_jw0 = _project(jw0 + mi.Vector3f(t0, 0, 0), w, n, ndw)
        n_jw1 = _project(jw1 + mi.Vector3f(0, t0, 0), w, n, ndw)
        n_jw2 = _project(jw2 + mi.Vector3f(0, 0, t0), w, n, ndw)
        jlo += mi.Vector3f(dr.dot(w, n_jo0 - jo0), dr.dot(w, n_jo1 - jo1), dr.dot(w, n_jo2 - jo2))
        jlw += mi.Vector3f(dr.dot(w, n_jw0 - jw0), dr.dot(w, n_jw1 - jw1), dr.dot(w, n_jw2 - jw2))
        jo0, jo1, jo2, jw0, jw1, jw2 = n_jo0, n_jo1, n_jo2, n_jw0, n_jw1, n_jw2

        bsdf = si.bsdf(ray)
        to_tx = origin - si.p
        dist = dr.norm(to_tx)
        r_det = 0.5 * (path_length + dist)
        echo = active & (dist > 0)
        if dr.hint(known, mode="scalar"):
            echo &= ((seen >> depth) & 1) != 0
        else:
            echo &= ~scene.ray_test(si.spawn_ray_to(origin), echo)
        a, a_r = mi.Float(0.0), mi.Float(0.0)
        if dr.hint(not forward, mode="scalar"):
            a, a_r = adjoint.weights(ping, r_det, echo)

        base = DIMS_EMIT + DIMS_PER_BOUNCE * depth
        bs, bsdf_weight = bsdf.sample(ctx, si, samples.get(base), samples.get2(base + 1), active)

        with dr.resume_grad(when=not primal):
            # The emission weight's derivative, taken at the first bounce (inside the loop, so that
            # nothing of a pass outlives it in the AD graph).
            emit = dr.select(first, _relative(ad.beam.eval(az0, el0)), 0.0)
            if dr.hint(forward, mode="scalar"):
                rel += dr.forward_to(emit, flags=_KEEP_TANGENTS)
            # The echo, attached to the parameters and (through the Jacobians) to the head's pose.
            ax, ay, az, ao = ad.frames.gather(ping)
            w0 = ax * d_local.x + ay * d_local.y + az * d_local.z
            dq_o, dq_w = ao - dr.detach(ao), w0 - dr.detach(w0)
            p = (si.p + jo0 * dq_o.x + jo1 * dq_o.y + jo2 * dq_o.z
                 + jw0 * dq_w.x + jw1 * dq_w.y + jw2 * dq_w.z)
            length = path_length + dr.dot(jlo, dq_o) + dr.dot(jlw, dq_w)
            si_a = mi.SurfaceInteraction3f(si)
            si_a.wi = dr.select(first, si.to_local(-w0), si.wi)
            if dr.hint(ad.geometry, mode="scalar"):
                # Mesh vertices with gradients: the hit point slides along the (fixed) ray and the
                # normal turns with the facet; the echo sees both (range, incidence angle).
                p_s, frame = _attached_hit(scene, ray, si, active)
                p = p + p_s
                length = length + dr.dot(w, p_s)
                si_a.sh_frame = frame
                si_a.n = frame.n
                si_a.wi = si_a.to_local(dr.select(first, -w0, -w))
            if dr.hint(ad.connect is None, mode="scalar"):
                cx, cy, cz, c_beam = ax, ay, az, ad.beam
            else:
                cx, cy, cz, _ = ad.connect[0].gather(ping)
                c_beam = ad.connect[1]
            back_v = ao - p
            dist_a = dr.norm(back_v)
            back = back_v / dist_a
            f = _eval_attached(ad, bsdf, ctx, si_a, si_a.to_local(back), echo, forward)
            rx = -back
            gain = c_beam.eval_dir(mi.Vector3f(dr.dot(rx, cx), dr.dot(rx, cy), dr.dot(rx, cz)))
            total = length + dist_a
            energy = throughput * f * gain / dr.square(dist_a) * dr.exp2(-ad.absorption * DB_TO_LOG2 * total)
            rng = 0.5 * total
            echo &= dr.detach(energy) > 0
            e_det = dr.detach(energy)

            beta = _relative(_eval_attached(ad, bsdf, ctx, si_a, bs.wo, active, forward))
            go_on = active & (depth + 1 < max_depth) & (dr.detach(bsdf_weight.x) > 0)

            if dr.hint(primal, mode="scalar"):
                total_s += dr.select(echo, a * e_det, 0.0)
            elif dr.hint(backward, mode="scalar"):
                rest -= dr.select(echo, a * e_det, 0.0)
                objective = (dr.select(echo, a * energy + e_det * a_r * rng, 0.0)
                             + dr.select(go_on, rest * beta, 0.0) + dr.select(active, state_in * emit, 0.0))
                dr.backward_from(objective, flags=_NO_GRAD_OK)
            else:
                d_energy, d_range, d_beta = dr.forward_to(energy, rng, beta, flags=_KEEP_TANGENTS)
                record(depth, dr.detach(rng), e_det, echo, si, e_det * rel + d_energy, d_range)
                rel += dr.select(go_on, d_beta, 0.0)

        throughput *= dr.detach(bsdf_weight.x)
        ray = si.spawn_ray(si.to_world(bs.wo))
        previous = mi.Point3f(si.p)
        depth += 1
        active &= (depth < max_depth) & (throughput > 0)

    return total_s if primal else None
