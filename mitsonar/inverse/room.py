"""Analysis by synthesis for closed walls seen from inside by a mechanical head.

The room is a polygon of ``N`` corners ``c_i = (x_i, y_i)`` (counter-clockwise seen from above,
the sonar inside) extruded vertically from a floor at ``z_f`` up to a fixed ``top`` beyond the
head's range, with the floor itself as a fan of triangles: every wall is one planar quad whose
normal points into the water (the acoustic BSDF is one-sided). The unknowns are the corners and
the floor height. The room is rendered with the recorded scans' poses by the differentiable
renderer (``mi.render(scene, params)`` with ``<mesh>.vertex_positions``, ``plugins/integrators/paths/path_replay.py``)
and compared with the recorded intensities, as :func:`mitsonar.inverse.height_field.refine_height_field`
does for a height field:

    L(c, z_f) = sum_scans  sum (B s_k(c, z_f) - B t_k)^2 / sum (B t_k)^2

with ``B`` a Gaussian blur along range of ``blur`` bins (narrowed stage by stage); ``c`` and
``z_f`` move by Adam (Kingma and Ba 2015, Algorithm 1: ``m <- b1 m + (1 - b1) g``,
``v <- b2 v + (1 - b2) g^2``, ``theta <- theta - lr m_hat / (sqrt(v_hat) + eps)``), one step after
the gradients of all scans are summed.

Seen from inside a convex room the walls face the head, so the derivative the renderer gives
(ranges and incidence angles of single-bounce echoes, no silhouette or edge terms) is the one
that matters: a corner's position is the meeting of two walls that are each seen face-on. A
concave corner is where the map alone fails (Soares 2017, ch. 4: the map's surface rounds it,
its last decimetres never seen empty); the polygon has a sharp corner by construction, and
:func:`wall_points` turns the refined walls into occupied evidence for a second map
(:func:`hilbertmap.evidence.surface_samples`).

The starting polygon comes from a first map's surface: :func:`polygon_from_points` fits straight
walls to the points of its horizontal cut through the sonar and intersects neighbouring walls.

Limits: the walls are vertical and planar (an extruded polygon); the echoes are single-bounce
(the recorded scans' multipath is left in the residual); the material is known (the model's BSDF
is the scene's).

Seeds: scan ``k`` renders with ``seed + k`` in every iteration (common random numbers), on one
Dr.Jit thread (``deterministic``), so a fit is the same for the same seed.
"""
from __future__ import annotations

import math

import numpy as np

from mitsonar.inverse.driver import staged_refine

__all__ = ["polygon_from_points", "refine_room", "room_feedback", "room_mesh", "room_xml", "wall_points"]


def _corners(corners, what):
    C = np.asarray(corners, dtype=np.float64)
    if C.ndim != 2 or C.shape[1] != 2 or len(C) < 3 or not np.isfinite(C).all():
        raise ValueError(f"{what}: corners must be a finite (N, 2) array with N >= 3, not shape {C.shape}")
    area = 0.5 * np.sum(C[:, 0] * np.roll(C[:, 1], -1) - np.roll(C[:, 0], -1) * C[:, 1])
    if not area > 0:
        raise ValueError(f"{what}: corners must run counter-clockwise seen from above (signed area {area:.3g} m^2)")
    return C


def room_mesh(corners, floor, top):
    """(vertices (6N, 3) float32, faces (3N - 2, 3) uint32) of the polygon ``corners`` (N, 2,
    counter-clockwise) extruded from ``z = floor`` to ``z = top``: wall ``i`` (from corner ``i`` to
    ``i + 1``) is vertices ``4i .. 4i + 3`` (bottom i, bottom i+1, top i+1, top i), two triangles
    whose normal points into the room; the floor's fan (normal up) uses vertices ``4N .. 5N - 1``."""
    C = _corners(corners, "room_mesh")
    if not (math.isfinite(floor) and math.isfinite(top) and top > floor):
        raise ValueError(f"room_mesh: top must be above floor, both finite (got floor {floor!r}, top {top!r})")
    n = len(C)
    V, F = [], []
    for i in range(n):
        a, b = C[i], C[(i + 1) % n]
        V += [[a[0], a[1], floor], [b[0], b[1], floor], [b[0], b[1], top], [a[0], a[1], top]]
        k = 4 * i
        # (a, b_top, b) and (a, a_top, b_top): normal = left of a -> b, the inside of a CCW polygon
        F += [[k, k + 2, k + 1], [k, k + 3, k + 2]]
    base = 4 * n
    V += [[c[0], c[1], floor] for c in C]
    F += [[base, base + k, base + k + 1] for k in range(1, n - 1)]
    return np.asarray(V, np.float32), np.asarray(F, np.uint32)


def _vertex_sources(n):
    """Per vertex coordinate of `room_mesh`: (index into the flat corners, uses corner, uses floor)."""
    src, use_c, use_f = [], [], []
    for i in range(n):
        j = (i + 1) % n
        for c, z_floor in ((i, True), (j, True), (j, False), (i, False)):
            src += [2 * c, 2 * c + 1, 0]
            use_c += [1, 1, 0]
            use_f += [0, 0, 1 if z_floor else 0]
    for c in range(n):
        src += [2 * c, 2 * c + 1, 0]
        use_c += [1, 1, 0]
        use_f += [0, 0, 1]
    return np.asarray(src, np.uint32), np.asarray(use_c, np.float32), np.asarray(use_f, np.float32)


def room_xml(ply, *, range_max=12.0, n_bins=500, n_pings=200, bearing_step=1.8, beamwidth_h=3.0,
             beamwidth_v=35.0, beam_pattern="gaussian", bsdf='<string name="preset" value="concrete_good"/>'):
    """A scene of a mechanical head (``id="head"``) inside the room mesh ``ply`` (``id="room"``,
    face normals), single-bounce echoes; the head's defaults are those of ``scenes_xml/box.xml``."""
    from mitsonar.kinds import MECHANICAL

    return ('<scene version="3.0.0"><integrator type="sonar_tof"><integer name="max_depth" value="1"/></integrator>'
            f'<sensor type="sonar" id="head"><string name="kind" value="{MECHANICAL.name}"/>'
            f'<float name="range_min" value="0"/><float name="range_max" value="{range_max}"/>'
            f'<integer name="n_bins" value="{n_bins}"/><float name="bearing_start" value="0"/>'
            f'<float name="bearing_step" value="{bearing_step}"/><integer name="n_pings" value="{n_pings}"/>'
            f'<string name="beam_pattern" value="{beam_pattern}"/><float name="beamwidth_h" value="{beamwidth_h}"/>'
            f'<float name="beamwidth_v" value="{beamwidth_v}"/></sensor>'
            f'<bsdf type="acoustic" id="wall">{bsdf}</bsdf>'
            f'<shape type="ply" id="room"><string name="filename" value="{ply}"/>'
            '<boolean name="face_normals" value="true"/><ref id="wall"/></shape></scene>')


def _dp(P, tol):
    """Indices kept by Douglas-Peucker on the open polyline ``P`` (M, 2)."""
    keep = np.zeros(len(P), bool)
    keep[[0, -1]] = True
    stack = [(0, len(P) - 1)]
    while stack:
        a, b = stack.pop()
        if b <= a + 1:
            continue
        d = P[b] - P[a]
        L = np.hypot(*d)
        rel = P[a + 1:b] - P[a]
        dist = np.abs(rel[:, 0] * d[1] - rel[:, 1] * d[0]) / L if L > 0 else np.hypot(rel[:, 0], rel[:, 1])
        k = int(np.argmax(dist))
        if dist[k] > tol:
            m = a + 1 + k
            keep[m] = True
            stack += [(a, m), (m, b)]
    return np.nonzero(keep)[0]


def polygon_from_points(points, center, *, tol=0.15, min_wall=0.8, trim=0.4, bin_deg=0.5, merge_deg=5.0):
    """Corners (N, 2, counter-clockwise) of the straight walls through ``points`` (M, 2 or 3: x, y
    used), a room's cut seen from ``center`` (x, y).

    The points are ordered by bearing around ``center`` (one point, the median range, per
    ``bin_deg``), the closed polyline simplified by Douglas-Peucker to ``tol`` metres, a line
    fitted (total least squares) to each piece's points farther than ``trim`` metres from its
    ends (a rounded corner's points are left out), pieces shorter than ``min_wall`` dropped,
    neighbouring lines within ``merge_deg`` degrees and ``tol`` metres merged (one wall), and
    neighbouring lines intersected: the corners are where the walls meet, not where a smooth
    surface rounds them.
    """
    P = np.asarray(points, dtype=np.float64)
    if P.ndim != 2 or P.shape[1] not in (2, 3) or len(P) < 3 or not np.isfinite(P).all():
        raise ValueError(f"polygon_from_points: points must be a finite (M, 2) or (M, 3) array with M >= 3, "
                         f"not shape {P.shape}")
    o = np.asarray(center, dtype=np.float64)
    if o.shape not in ((2,), (3,)) or not np.isfinite(o).all():
        raise ValueError(f"polygon_from_points: center must be a finite (x, y) or (x, y, z), not {center!r}")
    o = o[:2]
    q = P[:, :2] - o
    ang = np.arctan2(q[:, 1], q[:, 0])
    rad = np.hypot(q[:, 0], q[:, 1])
    b = np.floor((ang + np.pi) / math.radians(bin_deg)).astype(np.int64)
    pts = []
    for k in np.unique(b):
        sel = b == k
        a, r = np.median(ang[sel]), np.median(rad[sel])
        pts.append([r * math.cos(a), r * math.sin(a)])
    Q = np.asarray(pts)
    if len(Q) < 8:
        raise ValueError(f"polygon_from_points: the points cover {len(Q)} bearings of {bin_deg} deg, too few "
                         "to fit walls")
    # closed Douglas-Peucker: split at the point farthest from the first
    far = int(np.argmax(np.hypot(*(Q - Q[0]).T)))
    loop = np.vstack([Q, Q[:1]])
    idx = np.unique(np.r_[_dp(loop[:far + 1], tol), far + _dp(loop[far:], tol)]) % len(Q)
    idx = np.unique(idx)
    lines = []
    for a, c in zip(idx, np.r_[idx[1:], idx[0] + len(Q)]):
        seg = Q[np.arange(a, c + 1) % len(Q)]
        A, B = seg[0], seg[-1]
        L = np.hypot(*(B - A))
        if L < min_wall:
            continue
        u = (B - A) / L
        s = (seg - A) @ u
        inner = seg[(s > trim) & (s < L - trim)]
        if len(inner) < 3:
            continue
        m = inner.mean(0)
        _, _, vt = np.linalg.svd(inner - m)
        d = vt[0] if vt[0] @ u > 0 else -vt[0]
        lines.append((m, d))
    # one wall cut in two by the simplification (a dent in the cut): neighbouring lines within
    # ``merge_deg`` of each other and ``tol`` of each other's line are one wall
    merged = True
    while merged and len(lines) > 3:
        merged = False
        for i in range(len(lines)):
            (m1, d1), (m2, d2) = lines[i], lines[(i + 1) % len(lines)]
            off = abs((m2 - m1)[0] * d1[1] - (m2 - m1)[1] * d1[0])
            if abs(d1 @ d2) > math.cos(math.radians(merge_deg)) and off < tol:
                d = d1 + d2
                lines[i] = ((m1 + m2) / 2, d / np.hypot(*d))
                del lines[(i + 1) % len(lines)]
                merged = True
                break
    if len(lines) < 3:
        raise ValueError(f"polygon_from_points: found {len(lines)} straight walls (need 3); lower min_wall "
                         f"({min_wall} m) or raise tol ({tol} m)")
    corners = []
    for (m1, d1), (m2, d2) in zip(lines, lines[1:] + lines[:1]):
        M = np.array([d1, -d2]).T
        if abs(np.linalg.det(M)) < 1e-6:
            raise ValueError("polygon_from_points: two neighbouring walls are parallel; raise tol or min_wall")
        t = np.linalg.solve(M, m2 - m1)
        corners.append(m1 + t[0] * d1)
    return _corners(np.asarray(corners) + o, "polygon_from_points")


def wall_points(corners, z_lo, z_hi, step=0.05, normals=False):
    """Points every ``step`` metres (along each wall and in height) on the walls of the polygon
    ``corners`` between ``z_lo`` and ``z_hi``: a refined room as occupied evidence for a map.
    With ``normals``: ``(points, unit normals into the room)``."""
    C = _corners(corners, "wall_points")
    if not (step > 0 and z_hi >= z_lo):
        raise ValueError(f"wall_points: need step > 0 and z_hi >= z_lo (got step {step!r}, z {z_lo!r}..{z_hi!r})")
    zs = np.linspace(z_lo, z_hi, max(int(round((z_hi - z_lo) / step)) + 1, 1))
    out, nrm = [], []
    for a, b in zip(C, np.roll(C, -1, axis=0)):
        L = np.hypot(*(b - a))
        n = max(int(math.ceil(L / step)), 1)
        t = np.arange(n) / n  # the corner at t = 0, the next wall's first point is the next corner
        xy = a + t[:, None] * (b - a)
        out.append(np.column_stack([np.repeat(xy, len(zs), 0), np.tile(zs, len(xy))]))
        nrm.append(np.tile([-(b - a)[1] / L, (b - a)[0] / L, 0.0], (len(out[-1]), 1)))  # left of a -> b
    return (np.concatenate(out), np.concatenate(nrm)) if normals else np.concatenate(out)


def refine_room(scene, corners, floor, poses, targets, *, top, stages=((4.0, 15), (1.5, 15)), spp=64, seed=0,
                lr=0.03, lr_decay=0.1, head="head", mesh="room", deterministic=True, callback=None):
    """Refine the corners and floor height of the room mesh ``mesh`` of ``scene`` (`room_mesh`,
    e.g. loaded from `room_xml`) so that its renders match ``targets``.

    Parameters
    ----------
    scene : mitsuba.Scene
        A scene with a mechanical sonar ``head`` and the room mesh ``mesh``.
    corners : array_like (N, 2)
        The polygon to start from, counter-clockwise seen from above (m).
    floor : float
        The floor height to start from (m).
    poses : sequence of (4, 4) arrays
        The head's bearing-0 ``to_world`` of each recorded scan.
    targets : sequence of arrays
        The recorded intensities of each scan, ``(n_pings, n_bins)`` like the renders.
    top : float
        The walls' top (m), fixed: above what the head's range reaches.
    stages : sequence of (blur_bins, iterations)
        Each stage compares the scans blurred by ``blur_bins`` along range.
    spp, seed : int
        Samples per ping; scan ``k`` renders with ``seed + k`` in every iteration.
    lr : float
        Adam's step (m per iteration, about).
    lr_decay : float
        Each stage's step falls geometrically from ``lr`` to ``lr * lr_decay`` over its iterations
        (Adam's momentum otherwise carries the walls past the minimum and back).
    deterministic : bool
        Run Dr.Jit on one thread during the fit (restored after): the vertex gradients are sums by
        atomic adds whose order varies between threads; on one the same seed gives the same room.
    callback : callable, optional
        ``callback(iteration, loss, corners, floor)`` after each iteration.

    Returns
    -------
    dict
        ``corners`` (N, 2) and ``floor`` refined, ``loss`` per iteration, ``loss_start`` and
        ``loss_final`` (at the last stage's blur), ``seconds``.
    """
    C = _corners(corners, "refine_room")
    if not math.isfinite(floor) or not (math.isfinite(top) and top > floor):
        raise ValueError(f"refine_room: floor must be finite and below top (got floor {floor!r}, top {top!r})")
    floor, top = float(floor), float(top)
    n = len(C)
    V0, _ = room_mesh(C, floor, top)
    key = f"{mesh}.vertex_positions"

    def build(params, opt):
        import drjit as dr
        import mitsuba as mi

        if dr.width(params[key]) != V0.size:
            raise ValueError(f"refine_room: the scene's {mesh!r} has {dr.width(params[key]) // 3} vertices, a room "
                             f"of {n} corners has {len(V0)} (make it with room_mesh)")
        src, use_c, use_f = _vertex_sources(n)
        src, use_c, use_f = mi.UInt32(src), mi.Float(use_c), mi.Float(use_f)
        top_part = mi.Float(np.tile([0.0, 0.0, top], len(V0)).astype(np.float32) * (1 - np.asarray(use_f))
                            * (1 - np.asarray(use_c)))
        opt["c"] = mi.Float(C.ravel().astype(np.float32))
        opt["zf"] = mi.Float([floor])

        def vertices():
            return (dr.gather(mi.Float, opt["c"], src) * use_c + dr.gather(mi.Float, opt["zf"], src * 0) * use_f
                    + top_part)

        def step_done(it, loss):
            if callback is not None:
                callback(it, loss, np.asarray(opt["c"], np.float64).reshape(n, 2), float(opt["zf"][0]))

        def finish():
            out = {"corners": np.asarray(opt["c"], np.float64).reshape(n, 2), "floor": float(opt["zf"][0])}
            params[key] = mi.Float(V0.ravel())
            return out

        return vertices, step_done, finish

    return staged_refine("refine_room", scene, poses, targets, build, head=head, key=key, stages=stages, spp=spp,
                         seed=seed, lr=lr, lr_decay=lr_decay, deterministic=deterministic)


def _head_of(scans, what):
    """(bearing-0 ``to_world`` of each scan, the shared head settings for `room_xml`)."""
    frames, head = [], None
    for k, s in enumerate(scans):
        b = np.asarray(s.bearings, np.float64)
        P = np.asarray(s.poses, np.float64)
        if len(b) < 2 or np.ptp(np.diff(b)) > 1e-6 or np.ptp(P[:, :3, 3], axis=0).max() > 1e-6:
            raise ValueError(f"{what}: scans[{k}] must be a mechanical scan from one fixed position with evenly "
                             "stepped bearings")
        c, s_ = math.cos(-b[0]), math.sin(-b[0])
        Ry = np.array([[c, 0, s_, 0], [0, 1, 0, 0], [-s_, 0, c, 0], [0, 0, 0, 1]])
        frames.append(P[0] @ Ry)
        h = dict(range_max=float(s.range_max), n_bins=int(s.n_bins), n_pings=len(b),
                 bearing_step=math.degrees(b[1] - b[0]), beamwidth_h=float(s.beamwidth_h),
                 beamwidth_v=float(s.beamwidth_v), beam_pattern=str(s.beam_pattern))
        if float(s.range_min) != 0.0 or abs(b[0]) > 1e-9:
            raise ValueError(f"{what}: scans[{k}] must start at range 0 and bearing 0 (the model head's)")
        if head is not None and any(abs(h[key] - head[key]) > 1e-6 if isinstance(h[key], float) else h[key] != head[key]
                                    for key in h):
            raise ValueError(f"{what}: scans[{k}] has other head settings than scans[0] ({h} vs {head})")
        head = h
    return frames, head


def room_feedback(scans, first_map, *, seed=0, spp=128, stages=((4.0, 30), (1.5, 30)), lr=0.03,
                  bsdf='<string name="preset" value="concrete_good"/>', z_half=1.0, step=0.05, free_per_point=32,
                  margin=0.05, slab=0.5, **map_params):
    """A second map of ``scans`` whose walls are the refined room's (analysis by synthesis fed back).

    The first map's ridge (``first_map.surface('ridge')`` in a slab of +-``slab`` m around the
    sonar) is cut through the sonar, the straight walls of the cut give the starting polygon
    (`polygon_from_points`), the floor starts where the map's probability first exceeds 0.5 below
    the sonar; `refine_room` moves them until the renders match the scans' intensities; the
    refined walls between ``z_half`` m below and above the sonar, every ``step`` m
    (`wall_points`), enter a new ``HilbertMap(random_state=seed, **map_params)`` as occupied
    evidence with ``free_per_point`` free samples each up to ``margin`` m before them
    (:func:`hilbertmap.evidence.surface_samples`, origin the sonar), beside the scans' own samples.

    Returns
    -------
    dict
        ``map`` (the second, fitted map), ``corners_start``, ``floor_start``, ``corners``,
        ``floor``, ``refine`` (`refine_room`'s result), ``n_points``.
    """
    import os
    import tempfile

    import mitsonar
    from hilbertmap import HilbertMap
    from hilbertmap import geometry as geo
    from hilbertmap.embedding import Samples
    from hilbertmap.evidence import surface_samples
    from mitsonar.inverse.driver import write_ply

    if not len(scans):
        raise ValueError("room_feedback: needs at least one scan")
    frames, head = _head_of(scans, "room_feedback")
    origins = np.array([T[:3, 3] for T in frames])
    if np.ptp(origins, axis=0).max() > 1e-6:
        raise ValueError("room_feedback: the scans must share one sonar position (the room is seen from inside)")
    o = origins[0]
    lo, hi = first_map.coverage_.bounds()
    mv, mf = first_map.surface("ridge", bounds=([lo[0], lo[1], o[2] - slab], [hi[0], hi[1], o[2] + slab]))
    cut = geo.plane_section(mv, mf, 2, float(o[2])) if len(mf) else np.zeros((0, 2, 3))
    if len(cut) == 0:
        raise ValueError("room_feedback: the first map has no ridge in the plane through the sonar")
    corners0 = polygon_from_points(cut.mean(axis=1), o[:2])
    zs = np.linspace(o[2], lo[2], max(int((o[2] - lo[2]) / 0.02), 2))
    p = first_map.predict_proba(np.column_stack([np.full(len(zs), o[0]), np.full(len(zs), o[1]), zs]))
    floor0 = float(zs[np.argmax(p > 0.5)]) if (p > 0.5).any() else float(lo[2])
    top = float(o[2] + head["range_max"] + 1.0)
    with tempfile.TemporaryDirectory() as tmp:
        ply = os.path.join(tmp, "room.ply")
        write_ply(ply, *room_mesh(corners0, floor0, top))
        scene = mitsonar.load_scene(room_xml(ply, bsdf=bsdf, **head))
    res = refine_room(scene, corners0, floor0, frames, [np.asarray(s.intensity) for s in scans], top=top,
                      stages=stages, spp=spp, seed=seed, lr=lr)
    P = wall_points(res["corners"], o[2] - z_half, o[2] + z_half, step)
    hm = HilbertMap(random_state=seed, **map_params)
    rng = np.random.default_rng(seed)
    parts = [hm.embed_all(scans), surface_samples(P, o, free_per_point=free_per_point, margin=margin, rng=rng)]
    samples = Samples.concatenate(parts)
    hm.fit(scans, samples=samples)
    return {"map": hm, "corners_start": corners0, "floor_start": floor0, "corners": res["corners"],
            "floor": res["floor"], "refine": res, "n_points": int(len(P))}
