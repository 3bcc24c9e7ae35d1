"""Analysis by synthesis for a survey past piles over a flat seabed: the vertical fan's arcs resolved.

A wide vertical fan (a multibeam's 20 deg, a mechanical head's 35 deg) puts each echo anywhere on
an arc of the beam at its range: the map spreads it over the arc (``hilbertmap``'s occupied groups),
in front of a pile by up to ``r (1 - cos(fan / 2))`` and below the seabed, where no later ping can
carve it away. Here the scene is modelled as a horizontal seabed ``z = z_s`` and vertical cylinders
``(c_x, c_y, rho)`` (piles, standing from below the seabed to above what the head reaches), started
from the first map's surface (:func:`piles_from_points`), refined until their renders with the
survey's poses give back the recorded intensities (:func:`refine_piles`; the loss and Adam as
:func:`mitsonar.inverse.room.refine_room`'s; the seabed given, e.g. by the vehicle's altimeter,
or searched by rendering, :func:`seabed_search`), and fed back (:func:`piles_feedback`):

* **echo attribution**: each occupied group of the scans (the arc of one full bin) keeps the
  points of its beam where the refined model's first surface lies at that bin's range (rays cast
  through the beam, first hits), and only where there are such points: an echo the model cannot
  explain keeps its arc;
* **surface evidence**: the model's first hits in every beam as occupied points with free water
  before them (:func:`hilbertmap.evidence.surface_samples`, origin the head).

Seen from the vehicle, a pile's echo moves with its distance ``|c - s| - rho`` and the seabed's with
``z_s``; the renderer's vertex derivative follows those ranges (single-bounce echoes, no silhouette
terms: a pile's bearing extent is not differentiated, its position across the line of sight comes
from the views' spread along the track).

Limits: the piles are vertical circular cylinders, the seabed flat and horizontal; the materials are
known (``pile_bsdf``, ``seabed_bsdf``); the echoes are single-bounce (the dihedral's double bounce
and the recorded multipath stay in the residual); the targets are the scans' noise-free
intensities.

Seeds: frame ``k`` renders with ``seed + k`` in every iteration (common random numbers), on one Dr.Jit
thread (``deterministic``); the attribution's and the evidence's rays and the maps take ``seed``.
"""
from __future__ import annotations

import math

import numpy as np

from mitsonar.acoustics.water import SOUND_SPEED
from mitsonar.inverse.driver import staged_refine

__all__ = ["attribute_groups", "model_hits", "piles_feedback", "piles_from_points", "piles_mesh", "piles_xml",
           "refine_piles", "seabed_search"]


def _piles(piles, what):
    P = np.asarray(piles, dtype=np.float64).reshape(-1, 3) if np.size(piles) else np.zeros((0, 3))
    if P.ndim != 2 or P.shape[1] != 3 or not np.isfinite(P).all() or not (P[:, 2] > 0).all():
        raise ValueError(f"{what}: piles must be a finite (N, 3) array of (x, y, radius > 0), not {np.shape(piles)}")
    return P


def piles_mesh(piles, seabed, bounds, top, *, sides=24):
    """Meshes of the model: ``(pile vertices (2 sides N, 3), pile faces (2 sides N, 3), seabed
    vertices (4, 3), seabed faces (2, 3))``, float32 / uint32.

    Pile ``i`` (``(x, y, radius)``) is a prism of ``sides`` faces from ``seabed - 1`` to ``top``:
    vertices ``2 sides i + 2 j`` (bottom) and ``+ 1`` (top) at angle ``2 pi j / sides`` on the
    circle, faces facing out. The seabed is the rectangle ``bounds`` ((x0, y0), (x1, y1)) at
    ``z = seabed``, facing up."""
    P = _piles(piles, "piles_mesh")
    (x0, y0), (x1, y1) = bounds
    if not (math.isfinite(seabed) and math.isfinite(top) and top > seabed and x1 > x0 and y1 > y0):
        raise ValueError(f"piles_mesh: need top above seabed and non-empty bounds (got seabed {seabed!r}, "
                         f"top {top!r}, bounds {bounds!r})")
    a = 2 * math.pi * np.arange(sides) / sides
    V, F = [], []
    for i, (x, y, r) in enumerate(P):
        for j in range(sides):
            V += [[x + r * math.cos(a[j]), y + r * math.sin(a[j]), seabed - 1.0],
                  [x + r * math.cos(a[j]), y + r * math.sin(a[j]), top]]
            b, t = 2 * sides * i + 2 * j, 2 * sides * i + 2 * j + 1
            b2, t2 = 2 * sides * i + 2 * ((j + 1) % sides), 2 * sides * i + 2 * ((j + 1) % sides) + 1
            F += [[b, b2, t2], [b, t2, t]]  # counter-clockwise seen from outside
    Vs = np.array([[x0, y0, seabed], [x1, y0, seabed], [x1, y1, seabed], [x0, y1, seabed]], np.float32)
    Fs = np.array([[0, 1, 2], [0, 2, 3]], np.uint32)
    return (np.asarray(V, np.float32).reshape(-1, 3), np.asarray(F, np.uint32).reshape(-1, 3), Vs, Fs)


def _vertex_arrays(piles, seabed, bounds, top, sides):
    """`piles_mesh`'s vertex positions as the two flat ``mi.Float`` the scene's ``piles`` and
    ``seabed`` take (``<id>.vertex_positions``)."""
    import mitsuba as mi

    Vp, _, Vs, _ = piles_mesh(piles, seabed, bounds, top, sides=sides)
    return mi.Float(Vp.ravel()), mi.Float(Vs.ravel())


def piles_xml(piles_ply, seabed_ply, head, *, pile_bsdf='<string name="preset" value="concrete_good"/>',
              seabed_bsdf='<string name="preset" value="seabed_mud"/>', max_depth=3):
    """A scene of one sonar (``id="head"``, the settings ``head`` of `_head_settings`: kind,
    bearings, beam, range) with the pile mesh (``id="piles"``) and the seabed (``id="seabed"``),
    face normals, echoes of up to ``max_depth`` bounces (3: a pile's corner with the seabed, a
    dihedral, gives its bright double-bounce echo; the vertex derivative follows the last bounce's
    point only, exact for single-bounce echoes)."""
    h = head
    return ('<scene version="3.0.0"><integrator type="sonar_tof">'
            f'<integer name="max_depth" value="{int(max_depth)}"/></integrator>'
            f'<sensor type="sonar" id="head"><string name="kind" value="{h["kind"]}"/>'
            f'<float name="range_min" value="{h["range_min"]}"/><float name="range_max" value="{h["range_max"]}"/>'
            f'<integer name="n_bins" value="{h["n_bins"]}"/><float name="bearing_start" value="{h["bearing_start"]}"/>'
            f'<float name="bearing_step" value="{h["bearing_step"]}"/><integer name="n_pings" value="{h["n_rows"]}"/>'
            f'<string name="beam_pattern" value="{h["beam_pattern"]}"/>'
            f'<float name="beamwidth_h" value="{h["beamwidth_h"]}"/>'
            f'<float name="beamwidth_v" value="{h["beamwidth_v"]}"/>'
            f'<float name="sound_speed" value="{h["sound_speed"]}"/></sensor>'
            f'<bsdf type="acoustic" id="pile_bsdf">{pile_bsdf}</bsdf>'
            f'<bsdf type="acoustic" id="seabed_bsdf">{seabed_bsdf}</bsdf>'
            f'<shape type="ply" id="piles"><string name="filename" value="{piles_ply}"/>'
            '<boolean name="face_normals" value="true"/><ref id="pile_bsdf"/></shape>'
            f'<shape type="ply" id="seabed"><string name="filename" value="{seabed_ply}"/>'
            '<boolean name="face_normals" value="true"/><ref id="seabed_bsdf"/></shape></scene>')


def _head_settings(scans, what):
    """(the head's ``to_world`` of each scan, the settings `piles_xml` needs), checked: every scan
    a frame of the same steered head (evenly stepped bearings, one position a frame)."""
    from mitsonar.geometry.frames import bearing_rotation
    from mitsonar.kinds import kind_of

    frames, head = [], None
    for k, s in enumerate(scans):
        kind = kind_of(s)
        b = np.asarray(s.bearings, np.float64)
        P = np.asarray(s.poses, np.float64)
        if kind is None or not kind.steered or len(b) < 2 or np.ptp(np.diff(b)) > 1e-6 or np.ptp(P[:, :3, 3], axis=0).max() > 1e-6:
            raise ValueError(f"{what}: scans[{k}] must be one frame of a steered head (one position, evenly stepped "
                             f"bearings); it is a {s.kind} scan")
        T = P[0] @ np.linalg.inv(bearing_rotation(b[0]))
        if not np.allclose(T[None] @ bearing_rotation(b), P, atol=1e-5):
            raise ValueError(f"{what}: scans[{k}]'s rows are not one head turned by its bearings")
        frames.append(T)
        h = dict(kind=kind.name, range_min=float(s.range_min), range_max=float(s.range_max), n_bins=int(s.n_bins),
                 bearing_start=math.degrees(b[0]), bearing_step=math.degrees(b[1] - b[0]), n_rows=len(b),
                 beam_pattern=str(s.beam_pattern), beamwidth_h=float(s.beamwidth_h),
                 beamwidth_v=float(s.beamwidth_v), sound_speed=float(getattr(s, "sound_speed", SOUND_SPEED)))
        if head is not None and any(abs(h[q] - head[q]) > 1e-6 if isinstance(h[q], float) else h[q] != head[q]
                                    for q in h):
            raise ValueError(f"{what}: scans[{k}] has other head settings than scans[0]")
        head = h
    return frames, head


def piles_from_points(points, sensors, *, cell=0.2, min_points=20, max_extent=3.0, radius=0.25, front=90.0):
    """Piles ``(N, 3)`` ``(x, y, radius)`` from surface points ``points`` (M, 3) of a first map.

    The points are binned in plan view on ``cell`` m cells, the occupied cells joined into
    8-connected clusters; a cluster of at least ``min_points`` points no wider than
    ``max_extent`` m is a pile. Its points are its front smeared towards the ``sensors`` (K, 3;
    the positions that saw it) by the fan (an echo at range ``r`` spread over the arc, horizontal
    distances ``r cos e``): the front is put at the ``front`` percentile of their distances along
    the direction from the sensors' mean, the axis ``radius`` m behind it. Wider clusters (walls)
    are left out.
    """
    from scipy import ndimage

    P = np.asarray(points, np.float64).reshape(-1, 3)
    S = np.asarray(sensors, np.float64).reshape(-1, 3)
    if not (np.isfinite(P).all() and np.isfinite(S).all() and len(S)):
        raise ValueError("piles_from_points: points and sensors must be finite (M, 3) and (K >= 1, 3) arrays")
    if len(P) < min_points:
        return np.zeros((0, 3))
    lo = P[:, :2].min(0)
    ij = np.floor((P[:, :2] - lo) / cell).astype(np.int64)
    grid = np.zeros(ij.max(0) + 1, bool)
    grid[ij[:, 0], ij[:, 1]] = True
    lab, n = ndimage.label(grid, structure=np.ones((3, 3)))
    pl = lab[ij[:, 0], ij[:, 1]]
    out = []
    s_mean = S[:, :2].mean(0)
    for c in range(1, n + 1):
        Q = P[pl == c, :2]
        if len(Q) < min_points or np.max(np.ptp(Q, axis=0)) > max_extent:
            continue
        u = Q.mean(0) - s_mean
        u = u / max(np.hypot(*u), 1e-12)
        along = (Q - s_mean) @ u
        k = np.argmin(np.abs(along - np.percentile(along, front)))
        m = s_mean + along[k] * u + ((Q - s_mean) @ np.array([-u[1], u[0]])).mean() * np.array([-u[1], u[0]])
        out.append([*(m + radius * u), radius])
    return np.asarray(out, np.float64).reshape(-1, 3)


def seabed_search(scene, piles, poses, targets, candidates, *, top, bounds, blur=4.0, spp=16, seed=0, sides=24,
                  head="head", floor_db=-40.0):
    """The seabed height among ``candidates`` whose renders (the piles fixed) best match
    ``targets``, and the loss of each: the start for `refine_piles` where the map shows no seabed
    (a weak echo, like mud's).

    The loss (`mitsonar.inverse.driver.render_loss`, no gradients) compares each frame's mean level
    against range, averaged over its beams, in dB above a floor ``floor_db`` below the peak of the
    recorded averages (`render_loss`'s ``across_beams`` and ``floor_db``): the seabed echoes in
    every beam, the piles in a few, so the seabed's onset range and level rule it. With
    ``floor_db=None`` the relative loss of `refine_piles` over every bin instead, ruled by the
    piles' bright faces: on the harbour survey it moved with the render's seed by more than the
    seabed's own part of it and chose -4.5 m for a seabed at -6 m with one seed in two
    (``benchmarks/harbour_feedback.py``)."""
    from mitsonar.inverse.driver import jit_poses_targets, render_loss
    from mitsonar.sim.render import scan_parameters

    keys = ("piles.vertex_positions", "seabed.vertex_positions")
    params = scan_parameters(scene, [f"{head}.to_world", *keys])
    tf, tg = jit_poses_targets(poses, targets)
    losses = []
    for z in candidates:
        arrays = _vertex_arrays(piles, float(z), bounds, top, sides)
        losses.append(render_loss(scene, params, head, keys, tf, tg, lambda: arrays, blur=blur, grad=False,
                                  spp=spp, seed=seed, floor_db=floor_db, across_beams=floor_db is not None))
    return float(np.asarray(candidates)[int(np.argmin(losses))]), np.asarray(losses)


def _parabola_vertex(z, losses):
    """The vertex of the least-squares parabola through ``(z, losses)``, kept within the
    candidates' span; the best candidate where the fit opens downwards."""
    z, losses = np.asarray(z, np.float64), np.asarray(losses, np.float64)
    a, b, _ = np.polyfit(z, losses, 2)
    if not a > 0:
        return float(z[np.argmin(losses)])
    return float(np.clip(-b / (2.0 * a), z.min(), z.max()))


def refine_piles(scene, piles, seabed, poses, targets, *, top, bounds, stages=((4.0, 20), (1.5, 20)), spp=32,
                 seed=0, lr=0.02, lr_decay=0.1, sides=24, head="head", refine_seabed=True, refine_radius=True,
                 deterministic=True, callback=None):
    """Refine the piles ``(x, y, radius)`` and the seabed height of `piles_xml`'s scene so that its
    renders with ``poses`` match ``targets`` (loss and Adam as `refine_room`'s: the intensities
    blurred along range, stage by stage).

    Parameters
    ----------
    scene : mitsuba.Scene
        `piles_xml`'s scene (meshes ``piles`` and ``seabed`` of `piles_mesh`).
    piles : array_like (N, 3)
        ``(x, y, radius)`` to start from (m).
    seabed : float
        The seabed height to start from (m).
    poses, targets : sequences
        The head's ``to_world`` and the recorded intensities ``(rows, bins)`` of each frame.
    top : float
        The piles' top (m), fixed.
    bounds : ((x0, y0), (x1, y1))
        The seabed rectangle (m), fixed.
    stages : sequence of (blur_bins, iterations)
    spp, seed : int
        Samples per beam; frame ``k`` renders with ``seed + k`` in every iteration.
    lr, lr_decay : float
        Adam's step (m) and its geometric fall over each stage.
    refine_seabed : bool
        Move the seabed too (False: kept where it is, e.g. from the vehicle's altimeter).
    refine_radius : bool
        Move the radii too (False: kept; seen from one side, a pile's front fixes ``|c - s| -
        radius``, and the radius only the views' spread around it).
    deterministic : bool
        One Dr.Jit thread during the fit (the vertex gradients are atomic sums).
    callback : callable, optional
        ``callback(iteration, loss, piles, seabed)``.

    Returns
    -------
    dict
        ``piles``, ``seabed``, ``loss`` per iteration, ``loss_start``, ``loss_final`` (last
        stage's blur), ``seconds``.
    """
    P = _piles(piles, "refine_piles")
    if not math.isfinite(seabed) or not (math.isfinite(top) and top > seabed):
        raise ValueError(f"refine_piles: seabed must be finite and below top (got {seabed!r}, top {top!r})")
    seabed, top = float(seabed), float(top)
    n = len(P)
    keys = ("piles.vertex_positions", "seabed.vertex_positions")

    def build(params, opt):
        import drjit as dr
        import mitsuba as mi

        Vp, _, Vs, _ = piles_mesh(P, seabed, bounds, top, sides=sides)
        if dr.width(params[keys[0]]) != Vp.size:
            raise ValueError(f"refine_piles: the scene's piles mesh has {dr.width(params[keys[0]]) // 3} vertices, "
                             f"{n} piles of {sides} sides have {len(Vp)} (make it with piles_mesh)")
        # pile vertex coordinates: x = c_x + rho cos a, y = c_y + rho sin a, z fixed (bottom: seabed - 1)
        a = 2 * math.pi * np.repeat(np.arange(sides), 2) / sides
        a = np.tile(a, n)
        pile = np.repeat(np.arange(n), 2 * sides)
        comp = np.tile([0, 1, 2], len(a))
        vtx = np.repeat(np.arange(len(a)), 3)
        idx_c = mi.UInt32((3 * pile[vtx] + np.minimum(comp, 1)).astype(np.uint32))
        idx_r = mi.UInt32((3 * pile[vtx] + 2).astype(np.uint32))
        trig = mi.Float(np.where(comp == 0, np.cos(a[vtx]), np.where(comp == 1, np.sin(a[vtx]), 0.0)).astype(np.float32))
        is_xy = mi.Float((comp < 2).astype(np.float32))
        is_bottom = mi.Float(((comp == 2) & (vtx % 2 == 0)).astype(np.float32))
        z_top = mi.Float(((comp == 2) & (vtx % 2 == 1)).astype(np.float32) * top)
        seabed_xy = mi.Float(np.where(np.arange(Vs.size) % 3 == 2, 0.0, Vs.ravel()).astype(np.float32))
        seabed_z = mi.Float((np.arange(Vs.size) % 3 == 2).astype(np.float32))
        opt["piles"] = mi.Float(P.ravel().astype(np.float32))
        if refine_seabed:
            opt["zs"] = mi.Float([seabed])

        def vertices():
            p, zs = opt["piles"], (opt["zs"] if refine_seabed else mi.Float([seabed]))
            zb = dr.gather(mi.Float, zs, dr.zeros(mi.UInt32, dr.width(is_bottom))) - 1.0
            pv = (dr.gather(mi.Float, p, idx_c) * is_xy + dr.gather(mi.Float, p, idx_r) * trig + zb * is_bottom + z_top)
            sv = seabed_xy + seabed_z * dr.gather(mi.Float, zs, dr.zeros(mi.UInt32, dr.width(seabed_z)))
            return pv, sv

        def step_done(it, loss):
            q = np.asarray(opt["piles"], np.float64).reshape(n, 3)
            if not refine_radius or (q[:, 2] < 0.02).any():  # a radius may not cross zero
                q[:, 2] = P[:, 2] if not refine_radius else np.maximum(q[:, 2], 0.02)
                opt["piles"] = mi.Float(q.ravel().astype(np.float32))
            if callback is not None:
                callback(it, loss, q, float(opt["zs"][0]) if refine_seabed else seabed)

        def finish():
            out = {"piles": np.asarray(opt["piles"], np.float64).reshape(n, 3),
                   "seabed": float(opt["zs"][0]) if refine_seabed else seabed}
            params[keys[0]], params[keys[1]] = _vertex_arrays(P, seabed, bounds, top, sides)
            return out

        return vertices, step_done, finish

    return staged_refine("refine_piles", scene, poses, targets, build, head=head, key=keys, stages=stages, spp=spp,
                         seed=seed, lr=lr, lr_decay=lr_decay, deterministic=deterministic)


def model_hits(scene, origins, directions):
    """First-hit distances (inf: none) of rays from ``origins`` along unit ``directions`` (N, 3)
    in ``scene``'s geometry (the model's surfaces)."""
    import drjit as dr
    import mitsuba as mi

    O = np.asarray(origins, np.float32)
    D = np.asarray(directions, np.float32)
    ray = mi.Ray3f(mi.Point3f(*(mi.Float(np.ascontiguousarray(O[:, i])) for i in range(3))),
                   mi.Vector3f(*(mi.Float(np.ascontiguousarray(D[:, i])) for i in range(3))))
    si = scene.ray_intersect(ray)
    return np.asarray(dr.select(si.is_valid(), si.t, dr.inf), np.float64)


def _beam_rays(scan, rows, n, rng):
    """(origins, unit world directions) of ``n`` rays per row ``rows`` of ``scan``, uniform over
    the beam's nominal (-3 dB) extent (the map's own `_beam_directions`)."""
    from hilbertmap.embedding import _beam_directions

    poses = np.asarray(scan.poses, np.float64)[np.repeat(rows, n)]
    d = _beam_directions(rng, len(poses), scan, "uniform", 1.0)
    return poses[:, :3, 3], np.einsum("nij,nj->ni", poses[:, :3, :3], d)


def attribute_groups(scene, scan, samples, rng, *, rays=256, tolerance=0.0, drop_unexplained=False):
    """``samples`` (the map's embedding of ``scan``, every ping kept) with each occupied group's
    points moved to where the model ``scene`` puts that bin's echo: ``rays`` rays through the
    group's beam, those whose first hit lies in the bin's range (+-``tolerance``), their hit points
    drawn with replacement; a group with none keeps its points (``drop_unexplained``: is left out).
    Returns (samples, share explained)."""
    occ = samples.occupied
    G, m, _ = occ.shape
    if G == 0:
        return samples, 1.0
    poses = np.asarray(scan.poses, np.float64)
    if len(samples.frames) != len(poses):
        raise ValueError("attribute_groups: the samples must keep every ping of the scan (ping_stride 1)")
    bw = (float(scan.range_max) - float(scan.range_min)) / int(scan.n_bins)
    o = poses[samples.occupied_ping, :3, 3]
    r = np.linalg.norm(occ - o[:, None, :], axis=2).mean(1)
    lo = float(scan.range_min) + np.floor((r - float(scan.range_min)) / bw) * bw
    O, D = _beam_rays(scan, samples.occupied_ping, rays, rng)
    t = model_hits(scene, O, D).reshape(G, rays)
    ok = (t >= lo[:, None] - tolerance) & (t < lo[:, None] + bw + tolerance)
    new = occ.copy()
    D = D.reshape(G, rays, 3)
    for g in np.nonzero(ok.any(1))[0]:
        k = np.nonzero(ok[g])[0]
        pick = k[rng.integers(0, len(k), m)]
        new[g] = o[g] + D[g, pick] * t[g, pick, None]
    if drop_unexplained:  # the model is trusted: an echo it cannot place is left out
        import dataclasses

        keep = ok.any(1)
        return (dataclasses.replace(samples, occupied=new[keep], occupied_ping=samples.occupied_ping[keep]),
                float(keep.mean()))
    import dataclasses

    return dataclasses.replace(samples, occupied=new), float(ok.any(1).mean())


def piles_feedback(scans, first_map, *, seabed=None, piles=None, seed=0, spp=32, stages=((4.0, 20), (1.5, 20)), lr=0.02, frame_stride=4,
                   radius=0.25, rays=256, evidence_rays=16, free_per_point=16, margin=0.02, sides=24, ridge_resolution=0.2,
                   pile_bsdf='<string name="preset" value="concrete_good"/>',
                   seabed_bsdf='<string name="preset" value="seabed_mud"/>', max_depth=3, corroborate=0.25, seabed_evidence=True,
                   drop_unexplained=False, refine_radius=True, **map_params):
    """A second map of the survey ``scans`` (frames of one steered head along a track) with the
    refined piles and seabed fed back (see the module docstring).

    The piles start from ``piles`` ((N, 3) ``(x, y, radius)``, e.g. a chart's) or else from the
    first map's ridge (`piles_from_points`, ``ridge_resolution`` m), the seabed from ``seabed``
    (e.g. the vehicle's altimeter; then kept fixed) or else from a search by rendering
    (`seabed_search`: every 0.25 m below the head, then every 5 cm around the best, after a first
    stage has refined the piles on a seabed as deep as the head reaches; the map itself may show
    none); the seabed is kept there while every ``frame_stride``-th frame refines the piles
    (`refine_piles`), then searched again every 5 cm beside the refined piles (the vertex of a
    parabola fitted to the losses); then each scan is embedded by a new
    ``hilbertmap.IncrementalHilbertMap(random_state=seed, **map_params)``, its groups attributed
    (`attribute_groups`, ``rays`` a group), the model's first hits of ``evidence_rays`` rays a
    beam added as surface evidence with ``free_per_point`` free samples each (up to ``margin`` m
    before them), and learnt (``partial_fit``), scan by scan.

    Returns
    -------
    dict
        ``map``, ``piles_start``, ``seabed_start`` (where the piles were refined), ``piles``,
        ``seabed`` (searched: the second search's), ``refine`` (`refine_piles`'s result; its
        ``loss_start`` that of the whole fit, its ``seabed`` the final one), ``explained`` (the
        share of the scans' occupied groups the model explained), ``evidence_share`` (of the model's
        hits, those the recording corroborates).
    """
    import os
    import tempfile

    from scipy.ndimage import maximum_filter1d

    import mitsonar
    from hilbertmap import IncrementalHilbertMap
    from hilbertmap.embedding import Samples
    from hilbertmap.evidence import surface_samples
    from mitsonar.inverse.driver import write_ply

    if not len(scans):
        raise ValueError("piles_feedback: needs at least one scan")
    if not (isinstance(frame_stride, (int, np.integer)) and frame_stride >= 1):
        raise ValueError(f"piles_feedback: frame_stride must be an integer >= 1, not {frame_stride!r}")
    frames, head = _head_settings(scans, "piles_feedback")
    lo, hi = first_map.coverage_.bounds()
    mv, _ = first_map.surface("ridge", resolution=ridge_resolution)
    if len(mv) == 0:
        raise ValueError("piles_feedback: the first map has no ridge surface")
    sensors = np.array([T[:3, 3] for T in frames])
    piles0 = piles_from_points(mv, sensors, radius=radius) if piles is None else _piles(piles, "piles_feedback")
    if len(piles0) == 0:
        raise ValueError("piles_feedback: no pile found on the first map's ridge (clusters of points in plan view)")
    pad = head["range_max"]
    bounds = ((min(lo[0], sensors[:, 0].min()) - pad, min(lo[1], sensors[:, 1].min()) - pad),
              (max(hi[0], sensors[:, 0].max()) + pad, max(hi[1], sensors[:, 1].max()) + pad))
    top = float(sensors[:, 2].max() + pad)
    z_start = float(sensors[:, 2].mean() - pad)
    with tempfile.TemporaryDirectory() as tmp:
        plies = os.path.join(tmp, "piles.ply"), os.path.join(tmp, "seabed.ply")
        Vp, Fp, Vs, Fs = piles_mesh(piles0, z_start, bounds, top, sides=sides)
        write_ply(plies[0], Vp, Fp)
        write_ply(plies[1], Vs, Fs)
        scene = mitsonar.load_scene(piles_xml(*plies, head, pile_bsdf=pile_bsdf, seabed_bsdf=seabed_bsdf,
                                              max_depth=max_depth))
    use = list(range(0, len(scans), int(frame_stride)))
    poses, targets = [frames[k] for k in use], [np.asarray(scans[k].intensity) for k in use]
    start = piles0

    def fine_search(P, around):  # every 5 cm within 0.25 m of ``around``, less blurred
        fine = around + np.arange(-0.25, 0.2501, 0.05)
        return fine, seabed_search(scene, P, poses, targets, fine, top=top, bounds=bounds, blur=1.5, seed=seed,
                                   sides=sides)[1]

    if seabed is None:
        # the piles first, standing on a seabed as deep as the head reaches (their echoes all
        # kept), then the seabed searched by rendering every 0.25 m with the piles in place (with
        # misplaced piles, cutting them short lowered the loss: a seabed far too high), then both
        z_head = float(sensors[:, 2].mean())
        cand = np.arange(z_head - 0.5, z_head - head["range_max"], -0.25)
        first = refine_piles(scene, piles0, float(cand[-1]), poses, targets, top=top, bounds=bounds,
                             stages=stages[:1], spp=spp, seed=seed, lr=lr, sides=sides, refine_seabed=False,
                             refine_radius=refine_radius)
        start = first["piles"]
        z0, _ = seabed_search(scene, start, poses, targets, cand, top=top, bounds=bounds, seed=seed, sides=sides)
        fine, losses = fine_search(start, z0)  # then every 5 cm around the best
        seabed0 = float(fine[int(np.argmin(losses))])
    else:
        first, seabed0 = None, float(seabed)
    res = refine_piles(scene, start, seabed0, poses, targets, top=top, bounds=bounds, stages=stages,
                       spp=spp, seed=seed, lr=lr, sides=sides, refine_seabed=False, refine_radius=refine_radius)
    if first is not None:
        res["loss_start"] = first["loss_start"]  # the whole fit's start (the first stage's blur)
        # the seabed searched again beside the refined piles (the first stage's piles, a few cm
        # fat, left it 3-5 cm deep on the harbour survey), at the vertex of the parabola fitted to
        # the losses every 5 cm around it: between candidates, and steadier than one of them
        res["seabed"] = _parabola_vertex(*fine_search(res["piles"], seabed0))
    # the refined model, for the rays
    from mitsonar.sim.render import scan_parameters

    params = scan_parameters(scene, ["head.to_world", "piles.vertex_positions", "seabed.vertex_positions"])
    params["piles.vertex_positions"], params["seabed.vertex_positions"] = _vertex_arrays(res["piles"], res["seabed"],
                                                                                      bounds, top, sides)
    params.update()
    import mitsuba as mi

    hm = IncrementalHilbertMap(random_state=seed, **map_params)
    rng = np.random.default_rng(seed)
    explained, kept = [], []
    bw = (head["range_max"] - head["range_min"]) / head["n_bins"]
    import drjit as dr

    for k, s in enumerate(scans):
        smp = hm.embed(s, rng)
        smp, share = attribute_groups(scene, s, smp, rng, rays=rays, drop_unexplained=drop_unexplained)
        explained.append(share)
        # the model's surface where the scan recorded its echo: hits in bins where the recording
        # holds at least ``corroborate`` of the model's own render (a seabed the model extends
        # beyond the real one, or a pile it misplaces, adds no evidence there)
        params["head.to_world"] = mi.Transform4f(mi.Matrix4f(frames[k]))
        params.update()
        with dr.suspend_grad():
            model = np.asarray(mi.render(scene, params, spp=spp, seed=seed + k), np.float64)[..., 0]
        # each bin with its neighbours (one bin of slack in range; np.roll wrapped the last bin's
        # echo round onto the first)
        rec = maximum_filter1d(np.asarray(s.intensity, np.float64), 3, axis=1, mode="nearest")
        rows = np.arange(len(rec))
        O, D = _beam_rays(s, rows, int(evidence_rays), rng)
        t = model_hits(scene, O, D)
        row = np.repeat(rows, int(evidence_rays))
        hit = (t > head["range_min"]) & (t < head["range_max"])
        b = np.clip(((np.where(hit, t, head["range_min"]) - head["range_min"]) / bw).astype(np.int64), 0,
                    head["n_bins"] - 1)
        hit &= (rec[row, b] > 0) & (rec[row, b] >= corroborate * model[row, b])
        if not seabed_evidence:  # the piles' surface only (the seabed's height is the least certain)
            hit &= O[:, 2] + D[:, 2] * np.where(hit, t, 0.0) > res["seabed"] + 0.05
        kept.append(float(hit.mean()))
        if hit.any():
            ev = surface_samples(O[hit] + D[hit] * t[hit, None], O[hit], free_per_point=int(free_per_point),
                                 margin=margin, rng=rng)
            smp = Samples.concatenate([smp, ev])
        hm.partial_fit(s, samples=smp)
    return {"map": hm, "piles_start": piles0, "seabed_start": seabed0, "piles": res["piles"],
            "seabed": res["seabed"], "refine": res, "explained": float(np.mean(explained)),
            "evidence_share": float(np.mean(kept))}
