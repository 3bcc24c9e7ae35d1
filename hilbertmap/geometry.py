"""Geometry on triangle meshes (numpy): distances, area sampling, visibility, plane sections."""
from __future__ import annotations

import numpy as np


def _tris(vertices, faces):
    V = np.asarray(vertices, dtype=np.float64).reshape(-1, 3)
    F = np.asarray(faces, dtype=np.int64).reshape(-1, 3)
    return V[F]  # (T, 3, 3)


def triangle_areas(vertices, faces) -> np.ndarray:
    t = _tris(vertices, faces)
    return 0.5 * np.linalg.norm(np.cross(t[:, 1] - t[:, 0], t[:, 2] - t[:, 0]), axis=1)


def sample_triangles(vertices, faces, n: int, rng: np.random.Generator) -> np.ndarray:
    """n points uniform in area on the mesh."""
    t = _tris(vertices, faces)
    if len(t) == 0 or n <= 0:
        return np.zeros((0, 3))
    a = triangle_areas(vertices, faces)
    if a.sum() <= 0:
        return np.zeros((0, 3))
    k = rng.choice(len(t), size=n, p=a / a.sum())
    u, v = rng.random(n), rng.random(n)
    flip = u + v > 1
    u[flip], v[flip] = 1 - u[flip], 1 - v[flip]
    tk = t[k]
    return tk[:, 0] + u[:, None] * (tk[:, 1] - tk[:, 0]) + v[:, None] * (tk[:, 2] - tk[:, 0])


def _closest_on_triangles(p, a, b, c):
    """Closest points on triangles (a, b, c) to points p, all (N, 3) (Ericson, RTCD 5.1.5)."""
    ab, ac, ap = b - a, c - a, p - a
    d1 = np.einsum("ij,ij->i", ab, ap)
    d2 = np.einsum("ij,ij->i", ac, ap)
    bp = p - b
    d3 = np.einsum("ij,ij->i", ab, bp)
    d4 = np.einsum("ij,ij->i", ac, bp)
    cp = p - c
    d5 = np.einsum("ij,ij->i", ab, cp)
    d6 = np.einsum("ij,ij->i", ac, cp)
    va = d3 * d6 - d5 * d4
    vb = d5 * d2 - d1 * d6
    vc = d1 * d4 - d3 * d2
    denom = va + vb + vc
    with np.errstate(divide="ignore", invalid="ignore"):
        v = vb / denom
        w = vc / denom
        res = a + ab * v[:, None] + ac * w[:, None]
        # edge ab
        m = (vc <= 0) & (d1 >= 0) & (d3 <= 0)
        t = d1 / (d1 - d3)
        res = np.where(m[:, None], a + t[:, None] * ab, res)
        # edge ac
        m2 = (vb <= 0) & (d2 >= 0) & (d6 <= 0)
        t = d2 / (d2 - d6)
        res = np.where(m2[:, None], a + t[:, None] * ac, res)
        # edge bc
        m3 = (va <= 0) & ((d4 - d3) >= 0) & ((d5 - d6) >= 0)
        t = (d4 - d3) / ((d4 - d3) + (d5 - d6))
        res = np.where(m3[:, None], b + t[:, None] * (c - b), res)
    # vertex regions
    res = np.where(((d1 <= 0) & (d2 <= 0))[:, None], a, res)
    res = np.where(((d3 >= 0) & (d4 <= d3))[:, None], b, res)
    res = np.where(((d6 >= 0) & (d5 <= d6))[:, None], c, res)
    return res


def point_mesh_distance(points, vertices, faces, chunk: int = 1 << 20) -> np.ndarray:
    """Exact unsigned distance from each point to the nearest triangle.

    Small meshes (64 triangles or fewer) by brute force. Larger ones: the largest triangles (radius
    over four times the median, at most 64: a seabed of two triangles beside piles of hundreds) by
    brute force, the rest by their nearest centres, the search widened (k x 4) for every point
    whose k-th centre is nearer than its best distance plus the largest radius of the rest, until
    no triangle left out can be nearer.
    """
    P = np.asarray(points, dtype=np.float64).reshape(-1, 3)
    t = _tris(vertices, faces)
    if len(t) == 0:
        return np.full(len(P), np.inf)
    if len(t) <= 64:
        return _brute_distance(P, t)
    from scipy.spatial import cKDTree

    cen = t.mean(axis=1)
    rads = np.max(np.linalg.norm(t - cen[:, None], axis=2), axis=1)
    order = np.argsort(rads)[::-1]
    n_big = int(min(64, np.count_nonzero(rads > 4.0 * np.median(rads))))
    big, small = order[:n_big], np.sort(order[n_big:])
    ts, cs = t[small], cen[small]
    rad = float(rads[small].max())
    tree = cKDTree(cs)
    out = np.empty(len(P))
    k0 = min(16, len(ts))
    for s in range(0, len(P), max(chunk // k0, 1)):
        p = P[s:s + chunk // k0]
        best = _brute_distance(p, t[big]) if n_big else np.full(len(p), np.inf)
        rest, k = np.arange(len(p)), k0
        while len(rest):
            dc, idx = tree.query(p[rest], k=k, workers=-1)
            dc, idx = dc.reshape(len(rest), k), idx.reshape(len(rest), k)
            b = best[rest]
            for j in range(k):
                tj = ts[idx[:, j]]
                q = _closest_on_triangles(p[rest], tj[:, 0], tj[:, 1], tj[:, 2])
                b = np.minimum(b, np.linalg.norm(p[rest] - q, axis=1))
            best[rest] = b
            if k == len(ts):
                break
            # a triangle whose centre lies beyond the k-th can be nearer only if the k-th centre is
            # nearer than best + the largest radius: those points search again, wider
            rest = rest[dc[:, -1] < b + rad]
            k = min(4 * k, len(ts))
        out[s:s + len(p)] = best
    return out


def _brute_distance(P, t) -> np.ndarray:
    """Distance from each point ``P`` (N, 3) to the nearest of the triangles ``t`` (T, 3, 3)."""
    best = np.full(len(P), np.inf)
    for a, b, c in t:
        A = np.broadcast_to(a, P.shape)
        q = _closest_on_triangles(P, A, np.broadcast_to(b, P.shape), np.broadcast_to(c, P.shape))
        best = np.minimum(best, np.linalg.norm(P - q, axis=1))
    return best


def segments_blocked(origins, points, vertices, faces, eps: float = 1e-6) -> np.ndarray:
    """Whether the segment origin_i -> point_i crosses any triangle (Moller-Trumbore)."""
    O = np.asarray(origins, dtype=np.float64).reshape(-1, 3)
    P = np.asarray(points, dtype=np.float64).reshape(-1, 3)
    D = P - O
    t = _tris(vertices, faces)
    blocked = np.zeros(len(P), dtype=bool)
    lo, hi = np.minimum(O, P), np.maximum(O, P)
    for a, b, c in t:
        tmin, tmax = np.minimum(np.minimum(a, b), c), np.maximum(np.maximum(a, b), c)
        cand = ~blocked & np.all(hi >= tmin - eps, axis=1) & np.all(lo <= tmax + eps, axis=1)
        if not cand.any():
            continue
        o, d = O[cand], D[cand]
        e1, e2 = b - a, c - a
        pv = np.cross(d, e2)
        det = pv @ e1
        ok = np.abs(det) > 1e-12
        inv = np.where(ok, 1.0 / np.where(ok, det, 1.0), 0.0)
        tv = o - a
        u = np.einsum("ij,ij->i", tv, pv) * inv
        qv = np.cross(tv, e1)
        v = np.einsum("ij,ij->i", d, qv) * inv
        s = (qv @ e2) * inv
        hit = ok & (u >= 0) & (v >= 0) & (u + v <= 1) & (s > eps) & (s < 1 - eps)
        idx = np.nonzero(cand)[0]
        blocked[idx[hit]] = True
    return blocked


def visible_from(points, sensors, vertices, faces) -> np.ndarray:
    """Whether each point is in line of sight of at least one sensor position."""
    P = np.asarray(points, dtype=np.float64).reshape(-1, 3)
    vis = np.zeros(len(P), dtype=bool)
    for s in np.asarray(sensors, dtype=np.float64).reshape(-1, 3):
        rest = ~vis
        if not rest.any():
            break
        blocked = segments_blocked(np.broadcast_to(s, (int(rest.sum()), 3)), P[rest], vertices, faces)
        idx = np.nonzero(rest)[0]
        vis[idx[~blocked]] = True
    return vis


def plane_section(vertices, faces, axis: int, value: float) -> np.ndarray:
    """Segments (S, 2, 3) where the mesh crosses the plane ``x[axis] = value``."""
    t = _tris(vertices, faces)
    d = t[:, :, axis] - value
    segs = []
    for tri, dv in zip(t, d):
        pts = []
        for i, j in ((0, 1), (1, 2), (2, 0)):
            if dv[i] == 0:
                pts.append(tri[i])
            if (dv[i] < 0 < dv[j]) or (dv[j] < 0 < dv[i]):
                s = dv[i] / (dv[i] - dv[j])
                pts.append(tri[i] + s * (tri[j] - tri[i]))
        if len(pts) >= 2:
            pts = np.unique(np.round(np.array(pts), 12), axis=0)
            if len(pts) >= 2:
                segs.append(pts[:2])
    return np.array(segs).reshape(-1, 2, 3)


def sample_segments(segs: np.ndarray, step: float) -> np.ndarray:
    out = []
    for a, b in segs:
        n = max(int(np.ceil(np.linalg.norm(b - a) / step)), 1)
        s = (np.arange(n) + 0.5) / n
        out.append(a + s[:, None] * (b - a))
    return np.concatenate(out) if out else np.zeros((0, 3))
