#!/usr/bin/env python
"""Rerun the thesis mapping experiments (Soares 2017, 4.4.2: Figs. 4.1-4.4, 5.1, 5.2) on the box.

Scans of ``scenes_xml/box.xml`` rendered with the renderer's defaults from 7 positions x 3
orthogonal orientations (scan axis along z, x, y), mapped with ``HilbertMap()`` defaults using
10 %, 30 % and 100 % of the beams, and from 1 position x 3 orientations. Prints one JSON document:
per experiment the metrics of :func:`hilbertmap.metrics.evaluate` (with the hyper-parameters),
fit timings, plus query and epoch speeds, the scikit-learn Nystroem + SGDClassifier comparison on
the same samples, and the OctoMap anchor on the same pings (if ``octomap-python`` is installed).
Figures go to ``--out`` (default ``out/thesis_mapping``).

    python benchmarks/thesis_mapping.py [--out DIR] [--quick] [--no-sklearn] [--no-octomap] [--seed N]
        [--only 1x3,...] [--box LxWxD --origin x,y,z --speckle-seed N] [--multi-echo]

``--box 9x7x2.5 --origin 0.6,-0.4,0`` maps a held-out box (other walls, the sonar off-centre);
with ``--only 1x3`` only the thesis setting's three scans are rendered.
"""
from __future__ import annotations

import argparse
import json
import math
import os
import sys
import time

import numpy as np

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
sys.path.insert(0, ROOT)

POSITIONS = [(0.0, 0.0, 0.0), (2.5, 0.0, 0.0), (-2.5, 0.0, 0.0), (0.0, 2.0, 0.0), (0.0, -2.0, 0.0),
             (2.0, 1.5, -1.0), (-2.0, -1.5, -1.0)]


def box_xml(size: str, out_dir: str) -> str:
    """``scenes_xml/box.xml`` with other dimensions: ``size`` is ``LxWxD`` (length along x, width
    along y, floor depth below the origin, metres); the file is written to ``out_dir``."""
    try:
        L, W, D = (float(v) for v in size.lower().split("x"))
        assert L > 0 and W > 0 and D > 0
    except (ValueError, AssertionError):
        raise SystemExit(f"thesis_mapping: --box must be LxWxD in metres (e.g. 9x7x2.5), not {size!r}") from None
    X, Y, Z0 = L / 2, W / 2, -D
    hz, cz = (30 - Z0) / 2, (30 + Z0) / 2
    text = open(os.path.join(ROOT, "scenes_xml", "box.xml")).read()
    head = text[:text.index("    <!-- floor")]
    walls = [("floor", f'<scale x="{X}" y="{Y}"/><translate z="{Z0}"/>'),
             ("wall_xpos", f'<scale x="{hz}" y="{Y}"/><rotate y="1" angle="-90"/><translate x="{X}" z="{cz}"/>'),
             ("wall_xneg", f'<scale x="{hz}" y="{Y}"/><rotate y="1" angle="90"/><translate x="{-X}" z="{cz}"/>'),
             ("wall_ypos", f'<scale x="{X}" y="{hz}"/><rotate x="1" angle="90"/><translate y="{Y}" z="{cz}"/>'),
             ("wall_yneg", f'<scale x="{X}" y="{hz}"/><rotate x="1" angle="-90"/><translate y="{-Y}" z="{cz}"/>')]
    body = "".join(f'    <shape type="rectangle" id="{n}"><transform name="to_world">{t}</transform>'
                   f'<ref id="concrete"/></shape>\n' for n, t in walls)
    path = os.path.join(out_dir, f"box_{size}.xml")
    with open(path + ".tmp", "w") as f:
        f.write(head + body + "</scene>\n")
    os.replace(path + ".tmp", path)
    return path


def render_sets(seed: int = 0, scene_path: str | None = None, positions=POSITIONS, speckle_seed=None):
    import mitsonar
    from hilbertmap.testing import orthogonal_frames

    scene = mitsonar.load_scene(scene_path or os.path.join(ROOT, "scenes_xml", "box.xml"))
    scans = []
    t0 = time.perf_counter()
    for i, p in enumerate(positions):
        for j, T in enumerate(orthogonal_frames(p)):
            scans.append(mitsonar.render_scan(scene, seed=seed + 3 * i + j, pose=T, speckle_seed=speckle_seed))
    t_render = time.perf_counter() - t0
    V, F = mitsonar.scene_mesh(scene)
    return scans, (np.asarray(V, dtype=np.float64), np.asarray(F, dtype=np.int64)), t_render


def _clean(d):
    """JSON-ready copy: drop private entries, turn numpy scalars and non-finite floats into JSON."""
    out = {}
    for k, v in d.items():
        if k.startswith("_"):
            continue
        if isinstance(v, dict):
            out[k] = _clean(v)
        elif isinstance(v, (np.floating, float)):
            out[k] = float(v) if math.isfinite(float(v)) else None
        elif isinstance(v, (np.integer,)):
            out[k] = int(v)
        elif isinstance(v, (list, tuple)):
            out[k] = [x.item() if hasattr(x, "item") else x for x in v]
        else:
            out[k] = v
    return out


def headline(r: dict) -> dict:
    keys = ["auc", "auc_band_0.1_0.3", "auc_band_0.3_1", "all_auc", "all_auc_band_0.1_0.3", "free_seen_share",
            "surface_p_mean", "surface_p_gt_half",
            "ridge_fscore@0.1", "ridge_fscore@0.2", "level_fscore@0.1", "level_fscore@0.2",
            "ridge_acc_mean", "ridge_acc_p95", "ridge_acc_max", "ridge_comp_mean", "ridge_comp_p95",
            "level_acc_mean", "level_acc_p95", "level_acc_max",
            "slice_truth_p_mean", "slice_level_max", "slice_level_mean", "slice_level_comp_max",
            "slice_water_max", "slice_water_mean", "slice_water_comp_max", "slice_unobserved_depth",
            "slice_ridge_max", "slice_ridge_mean", "slice_ridge_comp_max",
            "ridge_slice_max", "ridge_slice_comp_max", "ridge_slice_hausdorff",
            "level_slice_max", "level_slice_comp_max", "level_slice_hausdorff"]
    return {k: (round(float(r[k]), 4) if r.get(k) is not None and math.isfinite(float(r[k])) else None)
            for k in keys if k in r}


# ----------------------------------------------------------------------------- baselines
def sklearn_comparison(samples, hm, points, bands, passes: int, seed: int):
    """scikit-learn Nystroem + SGDClassifier(log_loss, elasticnet) on the same samples.

    Occupied bins enter as the mean of their points' Nystroem features (eq. 4.6), with the same
    class weights as the Hilbert map. Timed: Nystroem fit, transform, and the SGD passes.
    """
    from sklearn.kernel_approximation import Nystroem
    from sklearn.linear_model import SGDClassifier

    from hilbertmap.metrics import point_metrics

    F, G = len(samples.free), len(samples.occupied)
    m = samples.occupied.shape[1]
    lanes = np.concatenate([samples.free, samples.occupied.reshape(-1, 3)])
    t0 = time.perf_counter()
    nys = Nystroem(kernel="rbf", gamma=hm.gamma_, n_components=hm.n_inducing, random_state=seed).fit(lanes)
    t_fit = time.perf_counter() - t0
    t0 = time.perf_counter()
    X_free = nys.transform(samples.free).astype(np.float32)
    X_occ = nys.transform(samples.occupied.reshape(-1, 3)).astype(np.float32).reshape(G, m, -1).mean(axis=1)
    t_transform = time.perf_counter() - t0
    X = np.concatenate([X_free, X_occ])
    y = np.r_[np.zeros(F), np.ones(G)]
    w = np.r_[np.ones(F), np.full(G, hm.occupied_weight_)]
    clf = SGDClassifier(loss="log_loss", penalty="elasticnet", alpha=hm.alpha, l1_ratio=hm.l1_ratio,
                        max_iter=passes, tol=None, random_state=seed)
    t0 = time.perf_counter()
    clf.fit(X, y, sample_weight=w)
    t_sgd = time.perf_counter() - t0
    del X, X_free, X_occ

    def prob(pts):
        out = []
        for a in range(0, len(pts), 20000):
            out.append(clf.predict_proba(nys.transform(pts[a:a + 20000]))[:, 1])
        return np.concatenate(out) if out else np.zeros(0)

    t0 = time.perf_counter()
    p_surf = prob(points["surface"])
    p_free = prob(points["free"])
    n_q = len(points["surface"]) + len(points["free"])
    t_query = time.perf_counter() - t0
    res = point_metrics(p_surf, p_free, points["d_free"], bands)
    res.update(n_lanes=int(len(lanes)), n_items=int(F + G), nystroem_fit_s=t_fit, transform_s=t_transform,
               transform_us_per_lane=1e6 * t_transform / max(len(lanes), 1), sgd_s=t_sgd,
               total_s=t_fit + t_transform + t_sgd, query_points_per_s=n_q / max(t_query, 1e-9), passes=passes)
    return res


def octomap_anchor(samples, points, truth, resolution: float, true_surface_points, bands, return_tree=False):
    """OctoMap on the same pings: rays from each transducer to its first echo's points (occupied at
    the end, free along), pings without echo as free rays to the end of their range window.
    ``return_tree``: return ``(metrics, tree)``, the ``octomap.OcTree`` too."""
    import octomap

    from hilbertmap.metrics import point_metrics, point_set_surface_metrics

    tree = octomap.OcTree(resolution)
    t0 = time.perf_counter()
    frames, spans, beams = samples.frames, samples.spans, samples.beams
    occ_by_ping = {}
    for g, k in enumerate(samples.occupied_ping):
        occ_by_ping.setdefault(int(k), []).append(g)
    rng = np.random.default_rng(0)
    for k in range(len(frames)):
        o = frames[k, :3, 3].astype(np.float64)
        if k in occ_by_ping:
            pts = samples.occupied[occ_by_ping[k]].reshape(-1, 3)
            tree.insertPointCloud(np.ascontiguousarray(pts, dtype=np.float64), o)
        else:
            # free rays to the end of the window, inside the nominal beam
            n = 32
            az = np.radians(rng.uniform(-0.5, 0.5, n) * beams[k, 0])
            el = np.radians(rng.uniform(-0.5, 0.5, n) * beams[k, 1])
            d = np.stack([np.cos(el) * np.sin(az), np.sin(el), np.cos(el) * np.cos(az)], axis=1)
            rmax = float(beams[k, 2])
            ends = o + (d @ frames[k, :3, :3].T) * rmax
            tree.insertPointCloud(np.ascontiguousarray(ends), o, maxrange=rmax * 0.999)
    t_build = time.perf_counter() - t0

    def prob(pts):
        out = np.full(len(pts), 0.5)
        for i, p in enumerate(pts):
            try:
                out[i] = tree.search(np.asarray(p, dtype=np.float64)).getOccupancy()
            except Exception:  # unknown space
                out[i] = 0.5
        return out

    p_surf = prob(points["surface"])
    res = point_metrics(p_surf, prob(points["free"]), points["d_free"], bands)
    if "free_all" in points:  # also where our map drew no sample (see hilbertmap.metrics)
        res.update({f"all_{k}": v for k, v in point_metrics(p_surf, prob(points["free_all"]),
                                                            points["d_free_all"], bands).items()})
    occ, _ = tree.extractPointCloud()
    V, F = truth
    res.update(point_set_surface_metrics(occ, true_surface_points, V, F, prefix="voxels"))
    res.update(resolution=resolution, build_s=t_build, n_occupied_voxels=int(len(occ)))
    return (res, tree) if return_tree else res


# ----------------------------------------------------------------------------- main
def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--out", default=os.path.join(ROOT, "out", "thesis_mapping"))
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--quick", action="store_true", help="only the 1 x 3 and 21 x 10 %% experiments")
    ap.add_argument("--no-sklearn", action="store_true")
    ap.add_argument("--no-octomap", action="store_true")
    ap.add_argument("--octomap-resolution", type=float, default=0.1)
    ap.add_argument("--sklearn-set", default="21x10", help="experiment whose samples scikit-learn also fits")
    ap.add_argument("--only", default=None, help="comma-separated experiments to run (1x3, 1x3_30, 21x10, 21x30, "
                    "21x100); 1x3 alone renders only its 3 scans")
    ap.add_argument("--box", default=None, help="a box of other dimensions, LxWxD metres (held-out geometry; "
                    "default scenes_xml/box.xml, 10x8x3)")
    ap.add_argument("--origin", default=None, help="x,y,z of the first position (the 1 x 3 experiments' sonar)")
    ap.add_argument("--speckle-seed", type=int, default=None, help="the scene's speckle (default the sensor's)")
    ap.add_argument("--multi-echo", action="store_true", help="HilbertMap(multi_echo=True): water between echoes "
                    "labelled free where a first map shows it reached")
    args = ap.parse_args(argv)
    os.makedirs(args.out, exist_ok=True)
    positions = list(POSITIONS)
    if args.origin is not None:
        try:
            positions[0] = tuple(float(v) for v in args.origin.split(","))
            assert len(positions[0]) == 3
        except (ValueError, AssertionError):
            raise SystemExit(f"thesis_mapping: --origin must be x,y,z in metres, not {args.origin!r}") from None
    only = None if args.only is None else set(args.only.split(","))
    if only is not None and not only <= {"1x3", "1x3_30", "21x10", "21x30", "21x100"}:
        raise SystemExit(f"thesis_mapping: --only takes 1x3, 1x3_30, 21x10, 21x30, 21x100, not {args.only!r}")
    if only is not None and only <= {"1x3", "1x3_30"}:
        positions = positions[:1]
    scene_path = box_xml(args.box, args.out) if args.box else None

    from hilbertmap import HilbertMap, write_mesh
    from hilbertmap import metrics as M
    from hilbertmap.plots import plot_half_region, plot_slices

    scans, truth, t_render = render_sets(args.seed, scene_path, positions, args.speckle_seed)
    V, F = truth
    report = {"scene": f"box {args.box}" if args.box else "scenes_xml/box.xml", "seed": args.seed,
              "multi_echo": args.multi_echo,
              "speckle_seed": args.speckle_seed, "positions": positions, "n_scans": len(scans),
              "render_s": t_render, "cpu_count": os.cpu_count(), "experiments": {}}
    experiments = [("1x3", scans[:3], 1.0, "Fig. 5.1 / 5.2: 1 position x 3 orientations, 100 % beams"),
                   ("1x3_30", scans[:3], 10.0 / 3.0, "Fig. 4.4: 1 position x 3 orientations, 30 % beams"),
                   ("21x10", scans, 10.0, "Fig. 4.1: 21 scans, 10 % beams"),
                   ("21x30", scans, 10.0 / 3.0, "Fig. 4.2: 21 scans, 30 % beams"),
                   ("21x100", scans, 1.0, "Fig. 4.3: 21 scans, 100 % beams")]
    if args.quick:
        experiments = [e for e in experiments if e[0] in ("1x3", "21x10")]
    if only is not None:
        experiments = [e for e in experiments if e[0] in only]
    bands = ((0.1, 0.3), (0.3, 1.0), (1.0, math.inf))
    slices = (("z", 0.0), ("y", 0.0), ("x", 0.0))
    extents = [((-6, 6), (-5, 5)), ((-6, 6), (-3.5, 6)), ((-5, 5), (-3.5, 6))]
    kept = {}
    for name, subset, stride, what in experiments:
        hm = HilbertMap(beam_stride=stride, random_state=args.seed, multi_echo=args.multi_echo)
        t0 = time.perf_counter()
        samples = hm.embed_all(subset, np.random.default_rng(args.seed))
        t_embed = time.perf_counter() - t0
        hm.fit(subset, samples=samples)
        hm.timings_["embed_s"] = t_embed
        hm.timings_["total_s"] += t_embed
        t0 = time.perf_counter()
        r = M.evaluate(hm, V, F, bands=bands, random_state=args.seed)
        t_eval = time.perf_counter() - t0
        plot_slices(hm, slices, truth=truth, extents=extents, path=os.path.join(args.out, f"slices_{name}.png"),
                    title=f"{what} (n_inducing={hm.n_inducing})")
        if name.startswith("1x3"):
            plot_half_region(hm, "z", 0.0, truth=truth, extent=((-6, 6), (-5, 5)),
                             path=os.path.join(args.out, f"half_{name}.png"))
        mv, mf = r.meshes["ridge"]
        write_mesh(os.path.join(args.out, f"ridge_{name}.ply"), mv, mf)
        thin = hm._thin(samples)
        entry = {"what": what, "beam_stride": stride, "n_pings": int(samples.info["n_pings"]),
                 "n_free": int(len(samples.free)), "n_groups": int(len(samples.occupied)),
                 "n_free_used": int(len(thin.free)), "n_groups_used": int(len(thin.occupied)),
                 "lanes": int(len(samples.free) + samples.occupied.shape[0] * samples.occupied.shape[1]),
                 "fit": {k: round(v, 3) for k, v in hm.timings_.items()}, "eval_s": round(t_eval, 1),
                 "eta0_": hm.eta0_, "headline": headline(r), "metrics": _clean(r)}
        report["experiments"][name] = entry
        kept[name] = (hm, samples, r)
        print(f"[{name}] fit {hm.timings_['total_s']:.1f} s  " + json.dumps(entry["headline"]), file=sys.stderr)

    # --- speeds --------------------------------------------------------------------------
    big = "21x100" if "21x100" in kept else list(kept)[-1]
    hm, samples, _ = kept[big]
    rng = np.random.default_rng(1)
    q = rng.uniform([-5, -4, -3], [5, 4, 3], (2_000_000, 3))
    hm.predict_proba(q[:1000])
    t0 = time.perf_counter()
    hm.predict_proba(q)
    t_q = time.perf_counter() - t0
    lanes = len(samples.free) + samples.occupied.shape[0] * samples.occupied.shape[1]
    t0 = time.perf_counter()
    hm._sgd_pass(samples)
    t_epoch = time.perf_counter() - t0
    report["speed"] = {"experiment": big, "query_points_per_s": len(q) / t_q,
                       "epoch_s": t_epoch, "epoch_lanes": int(lanes),
                       "epoch_items": int(len(samples.free) + len(samples.occupied)),
                       "epoch_s_per_million_lanes": t_epoch * 1e6 / lanes}

    # --- scikit-learn -----------------------------------------------------------------------
    if not args.no_sklearn and args.sklearn_set in kept:
        hm, samples, r = kept[args.sklearn_set]
        try:
            # the samples our fit learnt from (after its per-voxel thinning)
            sk = sklearn_comparison(hm._thin(samples), hm, r.points, bands, int(hm.n_passes), args.seed)
            ours = report["experiments"][args.sklearn_set]
            sk["speed_ratio_fit"] = sk["total_s"] / max(hm.timings_["features_s"] + hm.timings_["sgd_s"], 1e-9)
            sk["ours_auc"] = ours["metrics"]["auc"]
            sk["ours_auc_band_0.1_0.3"] = ours["metrics"]["auc_band_0.1_0.3"]
            report["sklearn"] = dict(experiment=args.sklearn_set, **_clean(sk))
        except ImportError as exc:
            report["sklearn"] = {"skipped": f"scikit-learn not installed ({exc})"}

    # --- OctoMap ----------------------------------------------------------------------------
    if not args.no_octomap:
        try:
            import octomap  # noqa: F401
        except ImportError as exc:
            report["octomap"] = {"skipped": f"octomap-python not installed ({exc})"}
        else:
            report["octomap"] = {}
            for name, (hm, samples, r) in kept.items():
                if name not in ("1x3", "21x100", "21x10"):
                    continue
                true_pts = r.points["surface"]
                oc = octomap_anchor(samples, r.points, truth, args.octomap_resolution, true_pts, bands)
                report["octomap"][name] = _clean(oc)
    print(json.dumps(_clean(report), indent=1))
    return 0


if __name__ == "__main__":
    sys.exit(main())
