"""Bidirectional echo paths: two subpaths from the transducer joined at every pair of vertices.

The sonar's two ends are points with beam patterns: a path of ``k`` surface bounces
``v_0 v_1 ... v_k v_{k+1}`` starts at the transducer ``v_0`` (beam ``B_A``, the row's beam, that
`common.SonarIntegrator.sample` emits from) and ends at the transducer ``v_{k+1}`` (beam ``B_B``:
the same beam for a mechanical head, the transmit fan ``setup.connect`` for a multibeam one).
Its energy, in the units of `common` (on-axis source intensity 1 W/sr, on-axis receive aperture
1 m^2), is the integral over the surface points of

    B_A(v_0 -> v_1) G0(v_0, v_1) prod_i f(v_i) prod_i G(v_i, v_{i+1}) G0(v_k, v_{k+1}) B_B(v_{k+1} -> v_k)
    * 10^(-absorption L / 10)

with ``G(x, y) = V cos_x cos_y / |x - y|^2`` between surfaces and ``G0 = V cos / r^2`` to the
transducer (a point: no cosine there); ``L`` is the total path length, the echo's range ``L / 2``.

Strategy ``(s, t)``, ``s + t = k``, takes ``v_1 .. v_s`` from subpath A (beam-sampled, then
BSDF-sampled) and ``v_k .. v_{s+1}`` from subpath B, and joins ``v_s`` to ``v_{s+1}`` (Veach 1997,
ch. 10). ``s = k`` is `SonarIntegrator.sample`'s next-event estimator, ``s = 0`` the same from the
other end; the strategy that would hit the point transducer by chance has probability zero and
is not used. Each strategy's estimate is ``alpha_A(s) c(s, t) alpha_B(t)`` with ``alpha`` the
subpath throughputs (beam weight ``B / pdf`` times BSDF weights) and ``c`` the connection
``f_s f_t / d^2`` (``f`` = BSDF value times cosine, or ``B`` at a transducer end), visibility tested.

Multiple importance sampling: with ``p_j`` the area density of the path under strategy ``j``,
strategy ``s`` gets ``w_s = p_s^b / sum_j p_j^b`` (``b = 1`` balance, ``b = 2`` power heuristic).
The ratios are accumulated along each subpath (the recursive form of van Antwerpen 2011 and
Georgiev et al. 2012, "Light transport simulation with vertex connection and merging"): with
``a_i`` the density of ``v_i`` sampled from its own end and ``E_1 = 0``,

    E_{i+1} = (g_i / a_i)^b (1 + rev(v_i)^b E_i),   g_i = cos(v_i, v_{i+1}) / |v_i - v_{i+1}|^2

(``rev(v_i)`` the BSDF's solid-angle density at ``v_i`` of sampling the way back, given the way
forward), so that at a connection ``sum_{j<s} p_j / p_s = (b_s / a_s)^b (1 + rev(v_s)^b E_s)``,
``b_s`` the density of ``v_s`` sampled from the other subpath's end vertex; the same from B's
side gives ``sum_{j>s}``.

Subpath B is traced first and its vertices kept (`_Store`, ``D = max_depth`` slots per lane);
then A's transducer is joined to each of them, and subpath A is traced, each of its vertices
joined to B's transducer and to each of B's vertices (three loops, so that a surface-to-surface
join holds no beam pattern and a transducer join no BSDF): a lane costs ``2 D`` intersections and
``(D + 1)(D + 2) / 2 - 1`` shadow rays, against ``D`` and ``D`` for `SonarIntegrator.sample`.

Limits: a BSDF with a delta lobe (a smooth Mitsuba ``conductor``, say) is not special-cased: a
join at such a vertex evaluates to 0 while the weights still count it, so paths through it would
lose energy (the ``acoustic`` BSDF's Phong lobe is never a delta). The joins use the BSDF's
``f cos`` at both ends and geometric cosines in the densities, without Veach's (1997, 5.3)
correction for shading normals, which differ from geometric ones only on smooth-shaded meshes.
"""
from __future__ import annotations

import drjit as dr
import mitsuba as mi

from .emission import DB_TO_LOG2
from .samples import DIMS_EMIT, DIMS_PER_BOUNCE

HEURISTICS = {"balance": 1, "power": 2}


def beam_pdf(beam, d):
    """Solid-angle density with which ``beam.sample`` draws the beam-frame unit direction ``d``.

    Mirrors `beam.BeamPattern.sample` (a bilinear table over azimuth and elevation, divided by the
    angular spans and ``cos(el)``); 0 outside the table's support. It reads the pattern's table,
    which `BeamPattern` keeps private: a public ``BeamPattern.pdf_dir`` would own this.
    """
    az = dr.atan2(d.x, d.z)
    el = dr.safe_asin(d.y)
    x = (az - beam._p_az) / beam._p_saz
    y = (el - beam._p_el) / beam._p_sel
    cos_el = dr.cos(el)
    inside = (x >= 0) & (x <= 1) & (y >= 0) & (y <= 1) & (cos_el > 0)
    pdf = beam._distr.eval(mi.Point2f(x, y), active=inside)
    return dr.select(inside, pdf / (beam._p_saz * beam._p_sel * dr.select(inside, cos_el, 1.0)), 0.0)


def _local(frame, v):
    x, y, z = frame
    return mi.Vector3f(dr.dot(v, x), dr.dot(v, y), dr.dot(v, z))


def _with_wi(si, wi):
    """A copy of ``si`` whose incident direction (local) is ``wi``."""
    out = mi.SurfaceInteraction3f(si)
    out.wi = wi
    return out


def _mis(x, power):
    return x if power == 1 else dr.power(x, power)


class _End:
    """One end of the path: the transducer's origin, beam frame (x, y, z axes) and beam."""

    def __init__(self, frame, origin, beam):
        self.frame, self.origin, self.beam = frame, origin, beam

    def emit(self, u, active):
        """A world direction drawn from the beam: (direction, B / pdf, solid-angle pdf)."""
        d, weight = self.beam.sample(u, active)
        x, y, z = self.frame
        return x * d.x + y * d.y + z * d.z, weight, beam_pdf(self.beam, d)

    def gain_pdf(self, w):
        """(B, solid-angle pdf) of the world direction ``w`` leaving the transducer."""
        d = _local(self.frame, w)
        return self.beam.eval_dir(d), beam_pdf(self.beam, d)


def _step(scene, ctx, emitted, si, at_end, p_cur, a_cur, e_cur, samples, n_surf, power, active):
    """Extend a subpath from its current vertex (the transducer where ``at_end``, else ``si``).

    ``emitted`` is the subpath's first direction (`_End.emit`, drawn once outside the loops),
    ``n_surf`` the number of surface vertices so far (the BSDF dims of bounce ``n_surf - 1`` are
    used). Returns (next interaction, its area density ``a``, its MIS carry ``E``, the sample
    weight, the segment length, lanes still alive).
    """
    bsdf = si.bsdf()
    base = DIMS_EMIT + DIMS_PER_BOUNCE * (dr.maximum(n_surf, 1) - 1)
    on_surf = active & ~at_end
    bs, bsdf_w = bsdf.sample(ctx, si, samples.get(base), samples.get2(base + 1), on_surf)
    wo = si.to_world(bs.wo)
    # The way back is only weighed from the second surface vertex on (E_1 = 0).
    rev = bsdf.pdf(ctx, _with_wi(si, bs.wo), si.wi, on_surf & (e_cur > 0))
    e_dir, e_weight, e_pdf = emitted
    direction = dr.select(at_end, e_dir, wo)
    pdf_w = dr.select(at_end, e_pdf, bs.pdf)
    weight = dr.select(at_end, e_weight, bsdf_w.x)
    spawn = si.spawn_ray(wo)
    ray = mi.Ray3f(dr.select(at_end, p_cur, spawn.o), direction)
    active = active & (weight > 0) & (pdf_w > 0)
    nxt = scene.ray_intersect(ray, active)
    active &= nxt.is_valid()
    seg = dr.norm(nxt.p - p_cur)
    inv_d2 = dr.rcp(dr.square(seg))
    a_new = pdf_w * dr.abs(dr.dot(nxt.n, direction)) * inv_d2
    cos_out = dr.abs(dr.dot(si.n, wo))
    g_ratio = dr.select(a_cur > 0, cos_out * inv_d2 / a_cur, 0.0)
    e_new = dr.select(at_end, 0.0, _mis(g_ratio, power) * (1 + _mis(rev, power) * e_cur))
    return nxt, a_new, e_new, weight, seg, active


def _connect(scene, ctx, y_end, z_end, end_a, end_b, y, bsdf_y, p_y, a_y, e_y, z, bsdf_z, p_z, a_z, e_z, power,
             active):
    """Join vertex ``y`` of subpath A to vertex ``z`` of subpath B; ``y_end``/``z_end`` (Python
    bools: the kernel holds only what the case needs) say that one is its transducer instead.

    Returns (unweighted contribution ``c`` without the subpath throughputs, MIS weight, length of
    the joining segment, lanes whose connection exists and is unoccluded).
    """
    to_z = p_z - p_y
    dist = dr.norm(to_z)
    w = to_z / dist
    inv_d2 = dr.rcp(dr.square(dist))
    # Each end's value (f cos, or B at a transducer) and its density of sampling the other end.
    if y_end:
        f_a, fwd_a = end_a.gain_pdf(w)
    else:
        wo_y = y.to_local(w)
        f_y, fwd_a = bsdf_y.eval_pdf(ctx, y, wo_y, active)
        f_a = f_y.x
        rev_y = bsdf_y.pdf(ctx, _with_wi(y, wo_y), y.wi, active & (e_y > 0))
    if z_end:
        f_b, fwd_b = end_b.gain_pdf(-w)
    else:
        wo_z = z.to_local(-w)
        f_z, fwd_b = bsdf_z.eval_pdf(ctx, z, wo_z, active)
        f_b = f_z.x
        rev_z = bsdf_z.pdf(ctx, _with_wi(z, wo_z), z.wi, active & (e_z > 0))
    s_a = s_b = 0.0
    if not y_end:  # density of y sampled from z's side (area measure), against its own
        b_of_y = fwd_b * dr.abs(dr.dot(y.n, w)) * inv_d2
        s_a = dr.select(a_y > 0, _mis(b_of_y / a_y, power) * (1 + _mis(rev_y, power) * e_y), 0.0)
    if not z_end:
        a_of_z = fwd_a * dr.abs(dr.dot(z.n, w)) * inv_d2
        s_b = dr.select(a_z > 0, _mis(a_of_z / a_z, power) * (1 + _mis(rev_z, power) * e_z), 0.0)
    weight = dr.rcp(1 + s_a + s_b)
    weight = dr.select(dr.isfinite(weight), weight, 0.0)
    c = f_a * f_b * inv_d2
    valid = active & (c > 0) & dr.isfinite(c)
    origin = p_y if y_end else y.spawn_ray_to(p_z).o
    target = p_z if z_end else z.spawn_ray(-w).o
    shadow = mi.Ray3f(origin, target - origin)
    shadow.maxt = dr.opaque(mi.Float, 1 - mi.math.ShadowEpsilon)
    valid &= ~scene.ray_test(shadow, valid)
    return c, weight, dist, valid


class _Store:
    """Subpath B's surface vertices, ``depth`` slots per lane (slot ``lane * depth + t - 1``):
    what a connection needs of each (point, normals, incident direction, uv, BSDF) and its
    throughput, length, density and MIS carry. A slot never written has throughput 0."""

    _FIELDS = (("p", mi.Point3f), ("n", mi.Vector3f), ("sh_n", mi.Vector3f), ("wi", mi.Vector3f), ("uv", mi.Point2f),
               ("thr", mi.Float), ("length", mi.Float), ("a", mi.Float), ("e", mi.Float))

    def __init__(self, size):
        self.data = {name: dr.zeros(mi.Float, size * dr.size_v(array_type) if dr.size_v(array_type) > 0 else size)
                     for name, array_type in self._FIELDS}
        self.bsdf = dr.zeros(mi.BSDFPtr, size)

    def put(self, index, si, bsdf, thr, length, a, e, active):
        values = {"p": si.p, "n": si.n, "sh_n": si.sh_frame.n, "wi": si.to_world(si.wi), "uv": si.uv,
                  "thr": thr, "length": length, "a": a, "e": e}
        for name, _ in self._FIELDS:
            dr.scatter(self.data[name], values[name], index, active)
        dr.scatter(self.bsdf, bsdf, index, active)

    def get(self, index, active):
        """(interaction, BSDF, throughput, length, a, E) of slot ``index``."""
        v = {name: dr.gather(array_type, self.data[name], index, active) for name, array_type in self._FIELDS}
        si = dr.zeros(mi.SurfaceInteraction3f, dr.width(index))
        si.p, si.n, si.uv = v["p"], v["n"], v["uv"]
        si.sh_frame = mi.Frame3f(v["sh_n"])
        si.wi = si.sh_frame.to_local(v["wi"])
        return si, dr.gather(mi.BSDFPtr, self.bsdf, index, active), v["thr"], v["length"], v["a"], v["e"]

    def eval(self):
        dr.eval(self.data, self.bsdf)


@dr.syntax
def _trace_receive(scene, ctx, emitted, origin, samples, depth, slots, power, alive):
    """Trace subpath B once (up to ``depth`` surface vertices) into a `_Store`."""
    n = dr.width(alive)
    store = _Store(n * slots)
    base = dr.arange(mi.UInt32, n) * dr.opaque(mi.UInt32, slots)
    z = dr.zeros(mi.SurfaceInteraction3f, n)
    t = dr.zeros(mi.UInt32, n)
    thr = dr.full(mi.Float, 1.0, n)
    length = dr.zeros(mi.Float, n)
    a = dr.zeros(mi.Float, n)
    e = dr.zeros(mi.Float, n)
    p = mi.Point3f(origin)
    more = mi.Bool(alive)
    while dr.hint(more, label="bdpt_receive_subpath"):
        z, a, e, weight, seg, more = _step(scene, ctx, emitted, z, t == 0, p, a, e, samples, t, power, more)
        thr *= weight
        length += seg
        p = mi.Point3f(z.p)
        t += 1
        more &= thr > 0
        store.put(base + t - 1, z, z.bsdf(), thr, length, a, e, more)
        more &= t < depth
    store.eval()
    return store


@dr.syntax
def trace_bidirectional(setup, ping, samples_a, samples_b, record, power=1, only_s=None, active=True):
    """All connection strategies of the paths of one lane per ``ping``; ``record`` gets each.

    ``samples_a``/``samples_b`` are the primary samples of subpaths A and B (layout of
    `samples`). ``record(s, t, range, energy, valid)`` is called for every strategy with ``s``
    A-side and ``t`` B-side surface vertices (``1 <= s + t <= max_depth``), energy already MIS
    weighted (heuristic exponent ``power``). With ``only_s`` (an int) only strategies with that
    ``s`` are recorded, unweighted: each alone is an unbiased estimator of the paths of at least
    ``max(only_s, 1)`` bounces. Subpath B is traced first and kept (``max_depth`` vertices per
    lane), then subpath A, each of whose vertices is joined to each of B's.
    """
    scene, depth = setup.scene, setup.depth_o
    x_ax, y_ax, z_ax, origin = setup.frames.gather(ping)
    end_a = _End((x_ax, y_ax, z_ax), origin, setup.sensor.beam)
    if setup.connect is None:
        end_b = end_a
    else:
        cx, cy, cz, c_origin = setup.connect[0].gather(ping)
        end_b = _End((cx, cy, cz), c_origin, setup.connect[1])
    n = dr.width(ping)
    ctx = mi.BSDFContext(mi.TransportMode.Importance)
    atten = setup.absorption * DB_TO_LOG2
    alive = dr.full(mi.Bool, True, n) & active
    store = _trace_receive(scene, ctx, end_b.emit(samples_b.get2(0), alive), end_b.origin, samples_b, depth,
                           setup.depth, power, alive)
    base = dr.arange(mi.UInt32, n) * dr.opaque(mi.UInt32, setup.depth)

    emitted_a = end_a.emit(samples_a.get2(0), alive)
    # Strategy filter as opaque values: one kernel serves every choice.
    unweighted = dr.opaque(mi.Bool, only_s is not None)
    chosen = dr.opaque(mi.UInt32, 0 if only_s is None else int(only_s))
    none = dr.zeros(mi.SurfaceInteraction3f, n)

    # s = 0: A's transducer joined to B's vertices t = 1 .. max_depth.
    t = dr.ones(mi.UInt32, n)
    alive_b = mi.Bool(alive) & (~unweighted | (chosen == 0))
    while dr.hint(alive_b, label="bdpt_join_transmitter"):
        z, bsdf_z, thr_b, len_b, a_z, e_z = store.get(base + t - 1, alive_b)
        exists = alive_b & (thr_b > 0)
        c, w, dist, ok = _connect(scene, ctx, True, False, end_a, end_b, none, None, end_a.origin, None, None,
                                  z, bsdf_z, z.p, a_z, e_z, power, exists)
        w = dr.select(unweighted, 1.0, w)
        total = dist + len_b
        energy = c * thr_b * w * dr.exp2(-atten * total)
        record(dr.zeros(mi.UInt32, n), t, 0.5 * total, energy, ok & (energy > 0))
        t += 1
        alive_b = exists & (t <= depth)

    # A's first vertex, then its vertices s = 1 .. max_depth, each joined to B's transducer (t = 0)
    # and to B's vertices t = 1 .. max_depth - s.
    p_y = mi.Point3f(end_a.origin)
    y, a_y, e_y, thr_a, len_a, alive = _step(scene, ctx, emitted_a, none, dr.full(mi.Bool, True, n), p_y,
                                             dr.zeros(mi.Float, n), dr.zeros(mi.Float, n), samples_a,
                                             dr.zeros(mi.UInt32, n), power, alive)
    alive &= thr_a > 0
    p_y = mi.Point3f(y.p)
    s = dr.ones(mi.UInt32, n)
    while dr.hint(alive, label="bdpt_transmit"):
        bsdf_y = y.bsdf()
        picked = ~unweighted | (s == chosen)
        c, w, dist, ok = _connect(scene, ctx, False, True, end_a, end_b, y, bsdf_y, p_y, a_y, e_y,
                                  none, None, end_b.origin, None, None, power, alive & picked)
        w = dr.select(unweighted, 1.0, w)
        total = len_a + dist
        energy = thr_a * c * w * dr.exp2(-atten * total)
        record(s, dr.zeros(mi.UInt32, n), 0.5 * total, energy, ok & (energy > 0))

        t = dr.ones(mi.UInt32, n)
        alive_b = alive & picked & ((s + t) <= depth)
        while dr.hint(alive_b, label="bdpt_join"):
            z, bsdf_z, thr_b, len_b, a_z, e_z = store.get(base + t - 1, alive_b)
            exists = alive_b & (thr_b > 0)
            c, w, dist, ok = _connect(scene, ctx, False, False, end_a, end_b, y, bsdf_y, p_y, a_y, e_y,
                                      z, bsdf_z, z.p, a_z, e_z, power, exists)
            w = dr.select(unweighted, 1.0, w)
            total = len_a + dist + len_b
            energy = thr_a * c * thr_b * w * dr.exp2(-atten * total)
            record(s, t, 0.5 * total, energy, ok & (energy > 0))
            t += 1
            alive_b = exists & ((s + t) <= depth)

        more = alive & (s < depth)
        y, a_y, e_y, weight, seg, more = _step(scene, ctx, emitted_a, y, dr.zeros(mi.Bool, n), p_y, a_y, e_y,
                                               samples_a, s, power, more)
        thr_a *= weight
        len_a += seg
        p_y = mi.Point3f(y.p)
        s += 1
        alive = more & (thr_a > 0)
