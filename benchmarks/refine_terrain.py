#!/usr/bin/env python
"""Analysis by synthesis on the rocky slope (issue 45, item 2): a side-scan survey's heights refined
from a flat start until rendering them gives back the recorded pings.

The truth: ``scenes_xml/rocky_slope.ply`` (a 14 deg slope rising towards +y, 0.08 m rms roughness,
rocks), surveyed by a two-channel side-scan head (2 x 50 deg beams, depressed 30 deg, 0-10 m in
200 bins) running along x at ``y = 0``, ``--altitude`` above the slope's mean, pinging every
``--spacing`` metres over ``x in [-L/2, L/2]``; the recorded pings are the renders of the true
mesh (noise-free expected intensities, the seeds the fit uses: common random numbers). The model:
a height field on a ``--cell`` grid over ``x in [-L/2, L/2]``, ``y in [-8, 8]``, started flat at
the true mean depth of the vertices the pings see (``1.5 <= |y| <= 7.5`` m: outside the nadir gap,
inside the swath), refined by :func:`mitsonar.inverse.height_field.refine_height_field`.

Prints one JSON object: the RMS height error over the seen vertices before and after (and their
ratio), the render-and-compare loss at the last stage's blur before and after (and their ratio),
the seconds, and whether a second run with the same seed gives the same heights (``--check-determinism``).
With ``--feedback``: the survey mapped by ``hilbertmap.HilbertMap`` (pings every 0.1 m), without and
with the refined surface fed back as occupied evidence (``hilbertmap.evidence``), with the flat
start's instead (a control), and by OctoMap (0.1 m, ``thesis_mapping.octomap_anchor``: the same
scans' samples) unless ``--no-octomap`` or octomap-python is missing; each scored against the true
mesh: its seabed height field (the column peak; OctoMap's most probable voxel of each column)
by vertical RMS, bias and coverage over the seen vertices and, as triangles, by accuracy,
completeness and F-scores at 0.1 and 0.2 m against true points in the seen strip; AUC and
near-wall AUC (free points 0.1-0.3 m from the seabed) of every map on the same test points (those
``hilbertmap.metrics.evaluate`` draws for the scans-only map, ``all_*`` without its ``seen``
filter); for the Hilbert maps the ridge surface's metrics (``ridge_*``, the slice in the
cross-track plane ``x = 0``), for OctoMap its occupied voxel centres' (``voxels_*``).

    python benchmarks/refine_terrain.py [--length 3] [--cell 0.25] [--spp 64] [--iterations 25] [--seed 0] [--check-determinism] [--feedback [--no-octomap]]
"""
from __future__ import annotations

import argparse
import json
import math
import os
import sys
import tempfile

import numpy as np

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
sys.path.insert(0, ROOT)


def true_heights(x, y):
    """The rocky slope's heights at the grid points (bilinear in its 99 x 99 vertex grid)."""
    from scipy.interpolate import RegularGridInterpolator

    from mitsonar.scenes.terrain import read_ply

    V, _ = read_ply(os.path.join(ROOT, "scenes_xml", "rocky_slope.ply"))
    xs, ys = np.unique(np.round(V[:, 0], 5)), np.unique(np.round(V[:, 1], 5))
    Z = np.full((len(xs), len(ys)), np.nan)
    Z[np.searchsorted(xs, np.round(V[:, 0], 5)), np.searchsorted(ys, np.round(V[:, 1], 5))] = V[:, 2]
    f = RegularGridInterpolator((xs, ys), Z)
    X, Y = np.meshgrid(x, y, indexing="ij")
    return f(np.stack([X.ravel(), Y.ravel()], 1)).reshape(len(x), len(y))


def run(length=3.0, cell=0.5, spacing=0.5, altitude=3.0, spp=128, seed=0, stages=((2.5, 6.0, 15), (1.0, 2.0, 15)),
        lr=0.08, smooth=0.05, lr_decay=1.0, verbose=True):
    import mitsuba as mi

    import mitsonar
    from mitsonar.inverse.driver import write_ply
    from mitsonar.inverse.height_field import grid_mesh, refine_height_field, sidescan_xml

    from mitsonar.sim.variant import ensure_variant

    ensure_variant()
    half = length / 2
    x = np.arange(-half, half + 1e-9, cell)
    y = np.arange(-8.0, 8.0 + 1e-9, cell)
    z_true = true_heights(x, y)
    seen = (np.abs(y)[None, :] >= 1.5) & (np.abs(y)[None, :] <= 7.5) & np.ones((len(x), 1), bool)
    depth = float(z_true[seen].mean())
    pings = np.arange(-half + spacing / 2, half, spacing)
    poses = []
    for xp in pings:
        m = np.eye(4)
        m[:3, 3] = (xp, 0.0, -10.0 + altitude)
        poses.append(m)
    truth = mitsonar.load_scene(sidescan_xml(os.path.join(ROOT, "scenes_xml", "rocky_slope.ply")))
    targets = []
    p = mi.traverse(truth)
    for k, P in enumerate(poses):
        p["head.to_world"] = mi.Transform4f(mi.Matrix4f(P))
        p.update()
        targets.append(np.asarray(mi.render(truth, spp=spp, seed=seed + k))[..., 0])
    with tempfile.TemporaryDirectory() as tmp:
        ply = os.path.join(tmp, "model.ply")
        write_ply(ply, *grid_mesh(x, y, np.full_like(z_true, depth)))
        model = mitsonar.load_scene(sidescan_xml(ply))

    def rms(z):
        return float(np.sqrt(np.mean((z - z_true)[seen] ** 2)))

    def show(it, loss, z):
        if verbose:
            print(f"iter {it:3d} loss {loss:.4f} rms {rms(z):.3f} m", file=sys.stderr, flush=True)

    res = refine_height_field(model, x, y, np.full_like(z_true, depth), poses, targets, stages=stages, spp=spp,
                              seed=seed, lr=lr, lr_decay=lr_decay, smooth=smooth, callback=show)
    return res, rms(np.full_like(z_true, depth)), rms(res["z"]), dict(nx=len(x), ny=len(y), pings=len(poses),
                                                                       depth=depth)


def map_heights(hm, x, y, cell):
    """The map's seabed height at the grid's vertices (``hilbertmap.elevation``'s column peak;
    NaN where the column never reaches p = 0.5 in the region seen)."""
    from hilbertmap.elevation import elevation_grid

    lo = (x[0] - cell / 2, y[0] - cell / 2, -13.0)
    hi = (x[-1] + cell / 2, y[-1] + cell / 2, -6.5)
    g = elevation_grid(hm, resolution=cell, z_step=0.02, bounds=(lo, hi))
    return g.elevation[::-1].T[:len(x), :len(y)]


def height_mesh(x, y, z):
    """Triangles of a height field over the cells whose four corners are finite (NaN: no surface)."""
    from mitsonar.inverse.height_field import grid_mesh

    V, F = grid_mesh(x, y, np.nan_to_num(z))
    ok = np.isfinite(z).ravel()
    F = F[ok[F].all(1)]
    return V.astype(np.float64), F.astype(np.int64)


def surface_scores(x, y, z, z_true, seen, V, F, true_pts, rng):
    """A map's seabed height field ``z`` (NaN where it has none) against the truth: vertical RMS
    and bias and coverage over the seen vertices; the height field as a surface (its triangles over
    the seen strip): accuracy (distance from it to the true mesh), completeness (from ``true_pts``,
    true-surface points in the seen strip, to it) and F-scores (``hilbertmap.metrics``' definitions)."""
    from hilbertmap import metrics as M

    ok = seen & np.isfinite(z)
    out = {"rms_m": float(np.sqrt(np.mean((z - z_true)[ok] ** 2))) if ok.any() else None,
           "bias_m": float(np.mean((z - z_true)[ok])) if ok.any() else None,
           "coverage": float(ok.sum() / seen.sum())}
    mv, mf = height_mesh(x, y, np.where(seen, z, np.nan))
    d_acc, d_comp = M.surface_distances(mv, mf, V, F, true_pts, rng)
    for k, d in (("acc", d_acc), ("comp", d_comp)):
        out[f"surface_{k}_mean_m"] = float(np.mean(d)) if len(d) else None
        out[f"surface_{k}_p95_m"] = float(np.percentile(d, 95)) if len(d) else None
    for tau in (0.1, 0.2):
        out[f"surface_fscore@{tau:g}"] = M.fscore(d_acc, d_comp, tau)
    return out


def octomap_heights(tree, x, y, cell):
    """OctoMap's seabed height at the grid's vertices, the same rule as the Hilbert map's column
    peak: among the occupied voxels whose centre lies within half a cell of the vertex (in x, y),
    the mean height of the most probable ones; NaN where none."""
    occ, _ = tree.extractPointCloud()
    occ = np.asarray(occ, dtype=np.float64).reshape(-1, 3)
    z = np.full((len(x), len(y)), np.nan)
    if not len(occ):
        return z
    p = np.array([tree.search(np.ascontiguousarray(c)).getOccupancy() for c in occ])
    i = np.rint((occ[:, 0] - x[0]) / cell).astype(np.int64)
    j = np.rint((occ[:, 1] - y[0]) / cell).astype(np.int64)
    inside = (i >= 0) & (i < len(x)) & (j >= 0) & (j < len(y))
    i, j, p, zc = i[inside], j[inside], p[inside], occ[inside, 2]
    best = np.full(z.shape, -np.inf)
    np.maximum.at(best, (i, j), p)
    top = p >= best[i, j] - 1e-9
    s, n = np.zeros(z.shape), np.zeros(z.shape)
    np.add.at(s, (i[top], j[top]), zc[top])
    np.add.at(n, (i[top], j[top]), 1.0)
    z[n > 0] = s[n > 0] / n[n > 0]
    return z


POINT_KEYS = ("auc", "auc_band_0.1_0.3", "surface_p_mean", "all_auc", "all_auc_band_0.1_0.3")
RIDGE_KEYS = ("ridge_acc_mean", "ridge_acc_p95", "ridge_acc_max", "ridge_comp_mean", "ridge_comp_p95",
              "ridge_comp_max", "ridge_fscore@0.1", "ridge_fscore@0.2", "ridge_slice_hausdorff")


def feedback(x, y, z_true, z_refined, seen, cell, spp=256, seed=0, spacing=0.1, altitude=3.0, octomap=True,
             octomap_resolution=0.1):
    """The Hilbert map of the side-scan survey (pings every ``spacing`` m), then the same map with
    the refined surface's seen vertices as occupied evidence (:mod:`hilbertmap.evidence`), as a
    control with the flat start's, and OctoMap from the same scans' samples; each scored against
    the true mesh (see :func:`report_metrics`)."""
    import mitsonar
    from hilbertmap import HilbertMap
    from hilbertmap import geometry as geo
    from hilbertmap import metrics as M
    from hilbertmap.embedding import Samples
    from hilbertmap.evidence import surface_samples
    from mitsonar.inverse.height_field import sidescan_xml
    from mitsonar.scenes.terrain import read_ply

    ply = os.path.join(ROOT, "scenes_xml", "rocky_slope.ply")
    V, F = read_ply(ply)
    F = np.asarray(F, dtype=np.int64)
    # the truth cropped to the triangles near the survey (the 10 m range and 1.5 m along-track
    # margin), so that the test points drawn on it land where the pings can see
    c = V[F].mean(1)
    F = F[(np.abs(c[:, 0]) <= x[-1] + 1.5) & (np.abs(c[:, 1]) <= 10.5)]
    truth = mitsonar.load_scene(sidescan_xml(ply))
    xs = np.arange(x[0], x[-1] + 1e-9, spacing)
    scans = []
    for k, xp in enumerate(xs):
        T = np.eye(4)
        T[:3, 3] = (xp, 0.0, -10.0 + altitude)
        scans.append(mitsonar.render_scan(truth, pose=T, spp=spp, seed=seed + k))
    X, Y = np.meshgrid(x, y, indexing="ij")
    rng = np.random.default_rng(seed)
    tp = geo.sample_triangles(V, F, 200000, rng)
    strip = (tp[:, 0] >= x[0]) & (tp[:, 0] <= x[-1]) & (np.abs(tp[:, 1]) >= 1.5) & (np.abs(tp[:, 1]) <= 7.5)
    true_pts = tp[strip][:20000]

    out, common, base_samples = {}, None, None
    for name, z_ev in (("scans_only", None), ("with_refined_surface", z_refined), ("with_flat_start", "flat")):
        hm = HilbertMap(random_state=seed)
        samples = hm.embed_all(scans)
        if z_ev is None:
            base_samples = samples
        else:
            z_ev = np.full_like(z_true, float(z_true[seen].mean())) if isinstance(z_ev, str) else z_ev
            P = np.stack([X[seen], Y[seen], z_ev[seen]], 1)
            O = np.stack([xs[np.abs(xs[None, :] - P[:, :1]).argmin(1)], np.zeros(len(P)),
                          np.full(len(P), -10.0 + altitude)], 1)
            samples = Samples.concatenate([samples, surface_samples(P, O, rng=np.random.default_rng(seed))])
        hm.fit(scans, samples=samples)
        res = surface_scores(x, y, map_heights(hm, x, y, cell), z_true, seen, V, F, true_pts,
                             np.random.default_rng(seed))
        r = M.evaluate(hm, V, F, surfaces=("ridge",), n_surface=10000, n_free=60000, resolution=0.1,
                       slice_axis="x", slice_resolution=0.05, random_state=seed, contours=False)
        if common is None:  # every map's probabilities on the scans-only map's test points
            common = r.points
        p_surf = hm.predict_proba(common["surface"])
        pm = M.point_metrics(p_surf, hm.predict_proba(common["free"]), common["d_free"])
        pm.update({f"all_{k}": v for k, v in M.point_metrics(p_surf, hm.predict_proba(common["free_all"]),
                                                             common["d_free_all"]).items()})
        res.update({k: pm[k] for k in POINT_KEYS})
        res.update({k: r[k] for k in RIDGE_KEYS if k in r})
        res["ridge_hausdorff"] = max(r["ridge_acc_max"], r["ridge_comp_max"])
        out[name] = res
    if octomap:
        try:
            import octomap  # noqa: F401
        except ImportError as exc:
            out["octomap"] = {"skipped": f"octomap-python not installed ({exc})"}
        else:
            from thesis_mapping import octomap_anchor

            bands = ((0.1, 0.3), (0.3, 1.0), (1.0, math.inf))
            oc, tree = octomap_anchor(base_samples, common, (V, F), octomap_resolution, common["surface"], bands,
                                      return_tree=True)
            res = surface_scores(x, y, octomap_heights(tree, x, y, cell), z_true, seen, V, F, true_pts,
                                 np.random.default_rng(seed))
            res.update({k: oc[k] for k in POINT_KEYS if k in oc})
            res.update({k: oc[k] for k in oc if k.startswith("voxels_")})
            res["voxels_hausdorff"] = max(oc["voxels_acc_max"], oc["voxels_comp_max"])
            res.update(resolution_m=octomap_resolution, n_occupied_voxels=oc["n_occupied_voxels"])
            out["octomap"] = res
    out["pings"] = len(scans)
    out["n_test_points"] = dict(surface=int(len(common["surface"])), free=int(len(common["free"])),
                                free_all=int(len(common["free_all"])), surface_strip=int(len(true_pts)))
    return out


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--length", type=float, default=3.0, help="survey length along x (m)")
    ap.add_argument("--cell", type=float, default=0.25, help="model grid spacing (m); the truth's is 0.245")
    ap.add_argument("--spp", type=int, default=64)
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--iterations", type=int, default=25, help="per stage (two stages)")
    ap.add_argument("--stages", default=None, help="sigma:blur:iterations,... (vertices, bins, steps; default "
                    "2.5:6:N,1:2:N with N = --iterations)")
    ap.add_argument("--lr", type=float, default=0.08)
    ap.add_argument("--smooth", type=float, default=0.05)
    ap.add_argument("--lr-decay", type=float, default=1.0, help="each stage's step falls to lr * this")
    ap.add_argument("--check-determinism", action="store_true")
    ap.add_argument("--feedback", action="store_true", help="also map the survey with hilbertmap, without and with "
                    "the refined surface as occupied evidence, and score the map's own seabed heights")
    ap.add_argument("--no-octomap", action="store_true", help="with --feedback: leave out the OctoMap baseline")
    a = ap.parse_args(argv)
    if not (a.length > 0 and a.cell > 0 and a.spp >= 1 and a.iterations >= 1):
        raise SystemExit("refine_terrain: --length, --cell must be > 0 m, --spp and --iterations >= 1")
    stages = ((2.5, 6.0, a.iterations), (1.0, 2.0, a.iterations))
    if a.stages:
        try:
            stages = tuple((float(s), float(b), int(n)) for s, b, n in (t.split(":") for t in a.stages.split(",")))
            assert all(s > 0 and b >= 0 and n >= 1 for s, b, n in stages)
        except (ValueError, AssertionError):
            raise SystemExit(f"refine_terrain: --stages must be sigma:blur:iterations,... (sigma > 0, blur >= 0, "
                             f"iterations >= 1), not {a.stages!r}") from None
    kw = dict(spp=a.spp, seed=a.seed, stages=stages, lr=a.lr, smooth=a.smooth, lr_decay=a.lr_decay)
    res, before, after, info = run(a.length, a.cell, **kw)
    out = {"scene": "scenes_xml/rocky_slope.ply, side-scan along x at y = 0", **info, "spp": a.spp, "seed": a.seed,
           "lr": a.lr, "lr_decay": a.lr_decay, "smooth": a.smooth,
           "stages": stages, "rms_before_m": before, "rms_after_m": after, "rms_ratio": before / max(after, 1e-12),
           "loss_before": res["loss_start"], "loss_after": res["loss_final"],
           "loss_ratio": res["loss_start"] / max(res["loss_final"], 1e-30),
           "loss_by_blur_bins": {str(b): {"before": v[0], "after": v[1], "ratio": v[0] / max(v[1], 1e-30)}
                                 for b, v in res["loss_by_blur"].items()},
           "seconds": round(res["seconds"], 1)}
    if a.feedback:
        x = np.arange(-a.length / 2, a.length / 2 + 1e-9, a.cell)
        y = np.arange(-8.0, 8.0 + 1e-9, a.cell)
        z_true = true_heights(x, y)
        seen = (np.abs(y)[None, :] >= 1.5) & (np.abs(y)[None, :] <= 7.5) & np.ones((len(x), 1), bool)
        out["hilbert_map"] = feedback(x, y, z_true, res["z"], seen, a.cell, seed=a.seed, octomap=not a.no_octomap)
    if a.check_determinism:
        res2, _, after2, _ = run(a.length, a.cell, verbose=False, **kw)
        out["deterministic"] = bool(np.array_equal(res2["z"], res["z"]))
    print(json.dumps(out, indent=1))
    return 0


if __name__ == "__main__":
    sys.exit(main())
