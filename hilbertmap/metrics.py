"""Compare a Hilbert map with known geometry given as triangles (vertices, faces).

Everything is measured inside the region the sonar saw (``HilbertMap.insonified``), ping by ping
in its nominal beam (-3 dB widths): true-surface points count where they lie within 0.1 m of the
ranges of a ping's first echo (the surfaces that answered); free test points where they lie before
a ping's first echo and in its line of sight (so the inside of walls, acoustic shadows and surfaces
that never returned an echo do not count).

Comparing maps: ``evaluate`` returns the test points it drew (``report.points``), and another map (the
OctoMap anchor of ``benchmarks/thesis_mapping.py``) is scored on exactly those points, its unknown
cells counting as p = 0.5. The insonified tests depend only on the pings, the same for both maps,
but the free points are also kept only inside ``hm.seen`` (0.25 m voxels holding one of this map's
training samples after thinning): water that a ping crossed without leaving a sample there is not
scored. That could lean our way (OctoMap's rays do cover it), so every point metric is also
reported on all insonified free points (``all_*``), with ``free_seen_share``, the share of them
the filter keeps; the surface points are not filtered by it. The extracted surfaces are scored on
the same true-surface points for both.

:func:`evaluate` returns an :class:`EvaluationReport`: a dict of numbers (JSON-ready, and short
to print) whose ``meshes`` and ``points`` attributes hold the surfaces and test points it used:

``auc``                AUC of p: points on the true surfaces against free points >= 0.1 m away
``auc_band_<a>_<b>``   the same against free points a..b metres from a surface (0.1-0.3 is the band
                       that tells good maps from poor ones)
``surface_p_mean``     mean probability on the true surfaces (``surface_p_median``, ``surface_p_gt_half``)
``all_<metric>``       the point metrics above with every insonified free point, seen or not
                       (``free_seen_share``: the share inside ``hm.seen``)
``<method>_*``         for each extracted surface (``ridge`` and ``level``, the 0.5 isosurface):
                       ``_acc_mean/_p95/_max`` distance from it to the truth, ``_comp_mean/_p95/_max``
                       from the truth to it (completeness), ``_fscore@0.1`` and ``_fscore@0.2``;
                       ``_slice_max``, ``_slice_comp_max``, ``_slice_hausdorff``: the same two ways
                       in the plane through the sonar, between the surface's cut and the insonified
                       true lines (:func:`mesh_slice_metrics`; issue #31's measure for the ridge)
``slice_*``            in the plane through the sonar (``slice_axis``, default z): distance from the
                       0.5 contour to the truth (``slice_level_max``, ``_mean``) and back
                       (``slice_level_comp_max``), the same for the ridge climbed from the contour
                       (the contour's shadow side left out, as the ridge surface's), mean p on the
                       truth lines;
                       ``slice_water_*``: the part of the 0.5 contour that bounds the water the
                       sonar is in (the thesis's half-probability region, Fig. 5.2), leaving out
                       the contour that closes the p > 0.5 band behind the walls, in their shadow;
                       ``slice_unobserved_depth``: how far from the truth the water next to the walls
                       goes without any ping seeing it empty (see :func:`unobserved_depth`), the
                       error a 0.5 level has when it follows the data and no further
``params``             the map's hyper-parameters and learnt sizes that produced the result
"""
from __future__ import annotations

import math
import textwrap

import numpy as np

from . import geometry as geo
from .surfaces import in_front, plateau_step, sample_grid


class EvaluationReport(dict):
    """The metrics of :func:`evaluate`: a dict of numbers (and ``params``, a dict), JSON-ready.

    The arrays it was computed from are attributes, not entries, so printing the report shows
    numbers only:

    ``meshes``  ``{method: (vertices, faces)}`` of the extracted surfaces
    ``points``  the test points: ``surface`` (on the true surfaces), ``free`` and ``d_free`` (free
                points inside ``hm.seen`` and their distance to the truth), ``free_all`` and
                ``d_free_all`` (every insonified free point)

    ``report["_meshes"]`` and ``report["_points"]`` (the spelling of the plain dict this used to
    be) still give them.
    """

    def __init__(self, metrics: dict, meshes: dict, points: dict):
        super().__init__(metrics)
        self.meshes = meshes
        self.points = points

    def __missing__(self, key):
        if key in ("_meshes", "_points"):
            import warnings

            warnings.warn(f"report[{key!r}] is deprecated: use report.{key[1:]}", DeprecationWarning, stacklevel=2)
            return self.meshes if key == "_meshes" else self.points
        raise KeyError(key)

    def __repr__(self) -> str:
        def fmt(v):
            return f"{v:.4g}" if isinstance(v, float) else repr(v)

        items = [f"{k}={fmt(v)}" for k, v in self.items() if not isinstance(v, dict)]
        items += [f"{k}=<dict of {len(v)}>" for k, v in self.items() if isinstance(v, dict)]
        items.append("meshes=<" + ", ".join(f"{k}: {len(f)} faces" for k, (_, f) in self.meshes.items()) + ">")
        items.append("points=<" + ", ".join(f"{k}: {len(p)}" for k, p in self.points.items()) + ">")
        text = "EvaluationReport(" + ", ".join(items) + ")"
        return textwrap.fill(text, width=100, subsequent_indent="    ", break_long_words=False,
                             break_on_hyphens=False)

    __str__ = __repr__


def auc(pos: np.ndarray, neg: np.ndarray) -> float:
    """Area under the ROC curve (Mann-Whitney U, ties counted half)."""
    pos = np.asarray(pos, dtype=np.float64).ravel()
    neg = np.asarray(neg, dtype=np.float64).ravel()
    if len(pos) == 0 or len(neg) == 0:
        return float("nan")
    allv = np.concatenate([pos, neg])
    order = np.argsort(allv, kind="mergesort")
    ranks = np.empty(len(allv))
    sv = allv[order]
    # average ranks of ties
    first = np.r_[True, sv[1:] != sv[:-1]]
    grp = np.cumsum(first) - 1
    starts = np.nonzero(first)[0]
    ends = np.r_[starts[1:], len(sv)]
    avg = 0.5 * (starts + ends - 1) + 1.0
    ranks[order] = avg[grp]
    r_pos = ranks[: len(pos)].sum()
    return float((r_pos - len(pos) * (len(pos) + 1) / 2.0) / (len(pos) * len(neg)))


def fscore(d_pred_to_true: np.ndarray, d_true_to_pred: np.ndarray, tau: float) -> float:
    if len(d_pred_to_true) == 0 or len(d_true_to_pred) == 0:
        return 0.0
    p = float(np.mean(d_pred_to_true < tau))
    r = float(np.mean(d_true_to_pred < tau))
    return 0.0 if p + r == 0 else 2 * p * r / (p + r)


def _stats(prefix: str, d: np.ndarray) -> dict:
    if len(d) == 0:
        return {f"{prefix}_mean": float("nan"), f"{prefix}_p95": float("nan"), f"{prefix}_max": float("nan")}
    return {f"{prefix}_mean": float(np.mean(d)), f"{prefix}_p95": float(np.percentile(d, 95)),
            f"{prefix}_max": float(np.max(d))}


def surface_distances(pred_v, pred_f, true_v, true_f, true_points, rng, n: int = 20000):
    """(distances from points on the predicted mesh to the truth, from ``true_points`` to it)."""
    if len(pred_f) == 0:
        return np.zeros(0), np.full(len(true_points), np.inf)
    pp = geo.sample_triangles(pred_v, pred_f, n, rng)
    d_acc = geo.point_mesh_distance(pp, true_v, true_f)
    d_comp = geo.point_mesh_distance(true_points, pred_v, pred_f)
    return d_acc, d_comp


def evaluate(hm, vertices, faces, *, surfaces=("ridge", "level"), n_surface: int = 20000, n_free: int = 200000,
             bands=((0.1, 0.3), (0.3, 1.0), (1.0, math.inf)), taus=(0.1, 0.2), slice_axis="z",
             slice_value=None, slice_resolution: float = 0.02, resolution=None, random_state=0,
             surface_bounds=None, contours: bool = True) -> EvaluationReport:
    """Metrics of a fitted :class:`~hilbertmap.HilbertMap` against the true mesh (see module doc).

    ``contours=False`` leaves out the 0.5 contour's and the climbed ridge's ``slice_*`` metrics
    (the slowest part); the extracted surfaces' cuts (``<method>_slice_*``) are always reported.
    """
    rng = np.random.default_rng(random_state)
    V = np.asarray(vertices, dtype=np.float64)
    F = np.asarray(faces, dtype=np.int64)
    out: dict = {}

    # --- probabilities on the true surfaces and in free space --------------------------------
    surf = geo.sample_triangles(V, F, n_surface * 4, rng)
    surf = surf[hm.insonified(surf, part="echo")][:n_surface]
    lo, hi = hm.coverage_.bounds()
    free_all = rng.uniform(lo, hi, (n_free, 3))
    free_all = free_all[hm.insonified(free_all, V, F, part="free")]
    seen = hm.seen(free_all, dilate=0)
    d_free_all = geo.point_mesh_distance(free_all, V, F)
    free, d_free = free_all[seen], d_free_all[seen]
    p_surf = hm.predict_proba(surf)
    p_free_all = hm.predict_proba(free_all)
    out.update(point_metrics(p_surf, p_free_all[seen], d_free, bands))
    # the same on every insonified free point, also where this map drew no training sample
    out.update({f"all_{k}": v for k, v in point_metrics(p_surf, p_free_all, d_free_all, bands).items()})
    out["free_seen_share"] = float(seen.mean()) if len(seen) else float("nan")

    # --- extracted surfaces: from one grid of probabilities ------------------------------------
    meshes = {}
    grid = sample_grid(hm, resolution, surface_bounds) if len(surfaces) else None
    for method in surfaces:
        mv, mf = hm.surface("ridge" if method == "ridge" else "level", grid=grid)
        meshes[method] = (mv, mf)
        d_acc, d_comp = surface_distances(mv, mf, V, F, surf, rng)
        out.update(_stats(f"{method}_acc", d_acc))
        out.update(_stats(f"{method}_comp", d_comp))
        for tau in taus:
            out[f"{method}_fscore@{tau:g}"] = fscore(d_acc, d_comp, tau)
        out[f"{method}_n_faces"] = int(len(mf))
        out.update(mesh_slice_metrics(hm, mv, mf, V, F, axis=slice_axis, value=slice_value,
                                      step=slice_resolution / 2, prefix=f"{method}_slice"))

    # --- the cross-section through the sonar -------------------------------------------------
    if contours:
        out.update(slice_metrics(hm, V, F, axis=slice_axis, value=slice_value, resolution=slice_resolution))
    out["params"] = dict(hm.get_params(), lengthscale_=float(hm.lengthscale_),
                         n_components_=int(getattr(hm, "n_components_", -1)),
                         n_samples_seen_=int(hm.n_samples_seen_))
    points = dict(surface=surf, free=free, d_free=d_free, free_all=free_all, d_free_all=d_free_all)
    return EvaluationReport(out, meshes, points)


def point_metrics(p_surf, p_free, d_free, bands=((0.1, 0.3), (0.3, 1.0), (1.0, math.inf))) -> dict:
    """AUCs and mean probabilities from probabilities on true-surface and free test points."""
    p_surf, p_free, d_free = (np.asarray(a, dtype=np.float64) for a in (p_surf, p_free, d_free))
    out = {"n_surface_points": int(len(p_surf)), "n_free_points": int(len(p_free))}
    out["surface_p_mean"] = float(np.mean(p_surf)) if len(p_surf) else float("nan")
    out["surface_p_median"] = float(np.median(p_surf)) if len(p_surf) else float("nan")
    out["surface_p_gt_half"] = float(np.mean(p_surf > 0.5)) if len(p_surf) else float("nan")
    out["auc"] = auc(p_surf, p_free[d_free >= bands[0][0]])
    for a, b in bands:
        m = (d_free >= a) & (d_free < b)
        key = f"auc_band_{a:g}_{b:g}" if math.isfinite(b) else f"auc_band_{a:g}_inf"
        out[key] = auc(p_surf, p_free[m])
        out[key.replace("auc_", "free_p_mean_")] = float(np.mean(p_free[m])) if m.any() else float("nan")
    return out


def point_set_surface_metrics(pred_points, true_points, vertices, faces, taus=(0.1, 0.2), prefix="points") -> dict:
    """Accuracy / completeness / F-score of a surface given as points (e.g. occupied voxel centres)."""
    from scipy.spatial import cKDTree

    pred = np.asarray(pred_points, dtype=np.float64).reshape(-1, 3)
    d_acc = geo.point_mesh_distance(pred, vertices, faces) if len(pred) else np.zeros(0)
    d_comp = cKDTree(pred).query(true_points)[0] if len(pred) else np.full(len(true_points), np.inf)
    out = {}
    out.update(_stats(f"{prefix}_acc", d_acc))
    out.update(_stats(f"{prefix}_comp", d_comp))
    for tau in taus:
        out[f"{prefix}_fscore@{tau:g}"] = fscore(d_acc, d_comp, tau)
    return out


def slice_truth(hm, vertices, faces, axis=2, value=None, step: float = 0.01):
    """Points every ``step`` metres on the true surfaces' cut by the plane ``x[axis] = value``
    (default: through the sonar, the median of the sensor positions), kept where a ping's first
    echo came from them (``hm.insonified(part='echo')``); returns ``(points, axis, value)``."""
    a = "xyz".index(axis) if isinstance(axis, str) else int(axis)
    if value is None:
        value = float(np.median(hm.sensor_positions_[:, a])) if len(hm.sensor_positions_) else 0.0
    truth = geo.sample_segments(geo.plane_section(vertices, faces, a, value), step)
    return truth[hm.insonified(truth, part="echo")], a, float(value)


def mesh_slice_metrics(hm, mesh_v, mesh_f, vertices, faces, axis="z", value=None, step: float = 0.01,
                       prefix: str = "ridge_slice") -> dict:
    """Two-sided distances between an extracted surface and the truth in one plane (thesis Fig. 5.2).

    The surface mesh ``(mesh_v, mesh_f)`` and the true mesh are both cut by the plane (through the
    sonar by default) and sampled every ``step`` metres; the true line is kept where it was
    insonified (:func:`slice_truth`). ``<prefix>_max``: the farthest point of the surface's line
    from the true surfaces (accuracy); ``<prefix>_comp_max``: the farthest point of the insonified
    true line from the surface's line (completeness: inf where the surface has no line in the
    plane); ``<prefix>_hausdorff``: the larger of the two.
    """
    from scipy.spatial import cKDTree

    truth, a, value = slice_truth(hm, vertices, faces, axis, value, step)
    pts = geo.sample_segments(geo.plane_section(mesh_v, mesh_f, a, value), step) if len(mesh_f) else np.zeros((0, 3))
    d_acc = geo.point_mesh_distance(pts, vertices, faces) if len(pts) else np.zeros(0)
    out = {f"{prefix}_max": float(d_acc.max()) if len(d_acc) else float("nan")}
    if len(truth) == 0:
        d_comp = np.zeros(0)
    else:
        d_comp = cKDTree(pts).query(truth)[0] if len(pts) else np.full(len(truth), np.inf)
    out[f"{prefix}_comp_max"] = float(d_comp.max()) if len(d_comp) else float("nan")
    both = [v for v in (out[f"{prefix}_max"], out[f"{prefix}_comp_max"]) if not math.isnan(v)]
    out[f"{prefix}_hausdorff"] = max(both) if both else float("nan")
    return out


def slice_metrics(hm, vertices, faces, axis="z", value=None, resolution: float = 0.02) -> dict:
    """Errors of the 0.5 contour and of the ridge in one plane (thesis Fig. 5.2)."""
    import matplotlib

    matplotlib.use("Agg")
    from matplotlib import contour as _contour  # noqa: F401  (ensures the backend is loaded)
    import matplotlib.pyplot as plt

    truth, a, value = slice_truth(hm, vertices, faces, axis, value, resolution / 2)
    res = {"slice_axis": "xyz"[a], "slice_value": value}
    if len(truth) == 0:
        return res
    others = [i for i in range(3) if i != a]
    lo, hi = truth.min(axis=0) - 0.5, truth.max(axis=0) + 0.5
    sl = hm.slice(a, value, extent=((lo[others[0]], hi[others[0]]), (lo[others[1]], hi[others[1]])),
                  resolution=resolution)
    fig = plt.figure()
    P2 = _contour_points(plt.contour(sl.u, sl.v, sl.prob, levels=[0.5]))
    plt.close(fig)
    P = np.zeros((len(P2), 3))
    P[:, others[0]], P[:, others[1]] = P2[:, 0], P2[:, 1]
    P[:, a] = value
    keep = hm.seen(P, dilate=0)
    # The thesis's half-probability region (Fig. 5.2): the water the sonar is in, bounded by the
    # 0.5 contour. Its boundary is the part of the contour the pings looked at; the rest of the
    # contour closes the p > 0.5 band behind the walls, in their acoustic shadow.
    water = _water_boundary(sl, P2, hm.sensor_positions_[:, others])[keep]
    P = P[keep]
    d_lvl = geo.point_mesh_distance(P, vertices, faces) if len(P) else np.zeros(0)
    res.update(_stats("slice_level", d_lvl))
    from scipy.spatial import cKDTree

    res["slice_level_comp_max"] = float(cKDTree(P).query(truth)[0].max()) if len(P) else float("inf")
    d_w = d_lvl[water] if len(P) else np.zeros(0)
    res.update(_stats("slice_water", d_w))
    res["slice_water_comp_max"] = float(cKDTree(P[water]).query(truth)[0].max()) if water.any() else float("inf")
    res["slice_truth_p_mean"] = float(np.mean(hm.predict_proba(truth)))
    res["slice_unobserved_depth"] = unobserved_depth(hm, vertices, faces, sl, a, value, truth, step=resolution)
    # ridge in the plane: from the contour, climb along the in-plane gradient to the maximum
    if len(P):
        R = _climb(hm, P, a)
        d_r = geo.point_mesh_distance(R, vertices, faces)
        res.update(_stats("slice_ridge", d_r))
        res["slice_ridge_comp_max"] = float(cKDTree(R).query(truth)[0].max())
    else:  # no 0.5 contour in the plane at all
        res.update(_stats("slice_ridge", np.zeros(0)))
        res["slice_ridge_comp_max"] = float("inf")
    return res


def unobserved_depth(hm, vertices, faces, sl, axis, value, truth, step: float = 0.02) -> float:
    """How far from the true surfaces the slice's water goes unobserved: the data's limit on a 0.5 level.

    Water (in line of sight of a sensor, inside the map's seen voxels) that no ping's nominal free
    frustum covers, in the pockets that touch the true lines (``truth``): where an echo came from the
    beam's skirt (concave corners, oblique walls), no ping saw the last stretch before the wall as
    empty. A 0.5 level that calls exactly the observed-free water free lies up to this far from the
    truth; the map can only do better there by guessing, and worse by smoothing over free evidence.
    Sampled on a grid of ``step`` metres; 0 when every pocket is shallower than one step.
    """
    from scipy import ndimage

    others = [i for i in range(3) if i != axis]
    u = np.arange(sl.u[0], sl.u[-1] + 1e-9, step)
    v = np.arange(sl.v[0], sl.v[-1] + 1e-9, step)
    U, W = np.meshgrid(u, v)
    P = np.zeros((U.size, 3))
    P[:, others[0]], P[:, others[1]], P[:, axis] = U.ravel(), W.ravel(), value
    cand = hm.seen(P, dilate=0)
    idx = np.nonzero(cand)[0]
    idx = idx[geo.visible_from(P[idx], hm.sensor_positions_, vertices, faces)]
    idx = idx[~hm.insonified(P[idx], part="free")]
    if len(idx) == 0:
        return 0.0
    hole = np.zeros(U.size, dtype=bool)
    hole[idx] = True
    labels, _ = ndimage.label(hole.reshape(U.shape))
    # pockets that reach the walls: a pixel within one step of a true line
    iu = np.clip(np.rint((truth[:, others[0]] - u[0]) / step).astype(np.int64), 0, len(u) - 1)
    iv = np.clip(np.rint((truth[:, others[1]] - v[0]) / step).astype(np.int64), 0, len(v) - 1)
    near = np.zeros(U.shape, dtype=bool)
    near[iv, iu] = True
    near = ndimage.binary_dilation(near)
    touching = np.unique(labels[near & (labels > 0)])
    pocket = np.isin(labels.ravel(), touching) & hole
    if not pocket.any():
        return 0.0
    return float(geo.point_mesh_distance(P[pocket], vertices, faces).max())


def _contour_points(cs) -> np.ndarray:
    """(n, 2): the points of the first level's lines of the matplotlib contour set ``cs``, lines
    of a single point left out.

    Read from the level's path (one per level since matplotlib 3.8), split into its lines where a
    line starts (``MOVETO``), not from ``cs.allsegs``: matplotlib 3.8.0, the floor, gives there
    the level's points as one array instead of its lines, and later releases deprecate it."""
    from matplotlib.path import Path

    paths = cs.get_paths()
    if not paths or len(paths[0].vertices) == 0:
        return np.zeros((0, 2))
    path = paths[0]
    starts = [] if path.codes is None else np.flatnonzero(path.codes == Path.MOVETO)[1:]
    lines = [p for p in np.split(path.vertices, starts) if len(p) > 1]
    return np.concatenate(lines) if lines else np.zeros((0, 2))


def _water_boundary(sl, contour, sensors) -> np.ndarray:
    """Which ``contour`` points (plane coordinates) border the p < 0.5 region holding a sensor.

    The p < 0.5 pixels of the slice are split into connected regions; the regions under the
    sensors (projected on the plane) are the water; a contour point borders it when one of the
    four pixels around it belongs to it.
    """
    from scipy import ndimage

    if len(contour) == 0:
        return np.zeros(0, dtype=bool)
    labels, _ = ndimage.label(sl.prob < 0.5)
    u0, v0 = sl.u[0], sl.v[0]
    du = sl.u[1] - sl.u[0] if len(sl.u) > 1 else 1.0
    dv = sl.v[1] - sl.v[0] if len(sl.v) > 1 else 1.0
    nv, nu = labels.shape

    def pixel(points, fu, fv):
        iu = np.clip(fu((points[:, 0] - u0) / du).astype(np.int64), 0, nu - 1)
        iv = np.clip(fv((points[:, 1] - v0) / dv).astype(np.int64), 0, nv - 1)
        return labels[iv, iu]

    water = np.unique(pixel(np.asarray(sensors, dtype=np.float64).reshape(-1, 2), np.rint, np.rint))
    water = water[water > 0]
    near = np.zeros(len(contour), dtype=bool)
    for fu in (np.floor, np.ceil):
        for fv in (np.floor, np.ceil):
            near |= np.isin(pixel(contour, fu, fv), water)
    return near


def _climb(hm, P, fixed_axis, max_shift=None, n=31):
    h = 0.25 * min(hm.lengthscale_, 0.2)
    grad = np.zeros_like(P)
    for i in range(3):
        if i == fixed_axis:
            continue
        o = np.zeros(3)
        o[i] = h
        grad[:, i] = (hm.decision_function(P + o) - hm.decision_function(P - o)) / (2 * h)
    nrm = grad / np.maximum(np.linalg.norm(grad, axis=1, keepdims=True), 1e-12)
    # the same front rule as the ridge surface: contour points whose low side was never seen empty
    # close the p > 0.5 band in a wall's shadow and are not the wall's face
    front = in_front(hm, P, nrm)
    if front.any():
        P, nrm = P[front], nrm[front]
    step = max_shift if max_shift is not None else 1.5 * hm.lengthscale_
    ts = np.linspace(0, step, n)
    pts = P[:, None, :] + ts[None, :, None] * nrm[:, None, :]
    f = hm.decision_function(pts.reshape(-1, 3)).reshape(len(P), n)
    # the same rule as HilbertMap.ridge_surface: the wall's face, not the maximum in its shadow
    return P + plateau_step(f, ts, 0.1)[:, None] * nrm
