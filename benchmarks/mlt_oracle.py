#!/usr/bin/env python
"""How much could any Metropolis sampler gain over path tracing on a scene? (issue 5, analysis)

Traces ``--paths`` uniform echo paths per ping (the path function both integrators share) and
compares, per path evaluation, the variance of the bins of

* path tracing: each path adds its echoes ``e_k`` to their bins;
* an ideal Metropolis sampler: independent paths drawn exactly in proportion to ``f = sum_k e_k``
  with the exact per-ping normalisation ``b``, each adding ``b e_k / f`` (no chain correlation,
  no cost for b) - the best ``sonar_mlt`` could ever do per path;
* the normalisation alone: ``b`` from uniform paths has the relative variance CV^2 of ``f``, and
  its error scales every bin of a ping, so ``PT variance / (CV^2 b^2)`` bounds the gain of any
  estimator whose per-ping total comes from uniform samples, however good its chains;
* the same two for one target over the whole scan (``sonar_mlt``'s ``normalisation="scan"``:
  the ping a primary coordinate, paths spread over the pings in proportion to their echoes, one
  ``B`` estimated from all uniform paths).

The ratios above compare with path tracing by *independent* uniform paths, the estimator whose
per-path variance the traced paths give directly. ``sonar_tof`` itself draws its paths from a
scrambled Sobol sequence (`samples.SobolSamples`), which lowers its error by 1.2-15x at the same
paths depending on the scene; with ``--baseline-spp`` the oracle also renders the default
``sonar_tof`` ``--baseline-repeats`` times at each of those spp (new seeds each), measures its
actual relative L2 error (the summed per-bin variance over the repeats over the summed squared
mean) and reports, per spp, ``sonar_tof_rel_error``, ``sobol_gain`` (independent over Sobol) and
``global_ideal_over_sonar_tof``: the error of ``sonar_tof`` over the ideal Metropolis sampler's at
equal paths. It bounds what any Metropolis sampler of this path function can gain over the
default path tracer: a real one also pays for chain correlation, the normalisation and a
costlier evaluation, so at equal time it gains less.

``--resample-draws N`` runs the ideal global sampler instead of computing it: N paths per ping
resampled in proportion to ``f`` from the traced ones, ``B e_k / f`` each; its measured error
matches the formula's (0.95-1.03 of it on box, glossy_corridor, hidden_target and intake with
16384 paths and 512 draws per ping).

Prints one JSON object per scene: ``ideal_variance_ratio`` (PT / ideal Metropolis; the square
root is the best equal-sample error ratio, ``ideal_error_ratio``), ``normalisation_bound_error_ratio``
(PT / b-only), ``global_ideal_error_ratio`` and ``global_normalisation_bound_error_ratio`` (one
target over the scan), the spread of the per-ping totals (``ping_total_cv2``), the median CV^2 of
f and the share of paths with f = 0.

    python benchmarks/mlt_oracle.py [--scenes box,slot_chamber,glossy_corridor,hidden_target] [--paths 4096]
                                    [--guide image|none] [--curved-guide] [--no-strip-guide]
                                    [--baseline-spp 4096,32768 --baseline-repeats 8]
                                    [--baseline-allocation auto|uniform|adaptive]

The ratios are estimates from the paths traced: on hidden_target, where 2 paths in 1000 carry nearly
all of the boulder's echo, 4096 paths per ping give an ideal ratio of 24 and 65536 give 18.
"""
from __future__ import annotations

import argparse
import json
import os

import numpy as np

HERE = os.path.dirname(os.path.abspath(__file__))


def analyse(name, paths, seed=7, guide="image", baseline_spp=(), baseline_repeats=8, baseline_sampling="sobol",
            resample_draws=0, resample_repeats=8, baseline_allocation="auto"):
    import drjit as dr
    import mitsuba as mi

    import mitsonar
    from mitsonar.plugins.integrators.paths.samples import HashSamples
    from mitsonar.plugins.integrators.sonar_mlt import _Context

    scene = mitsonar.load_scene(os.path.join(HERE, "..", "scenes_xml", f"{name}.xml"))
    integrator = mi.load_dict({"type": "sonar_tof", "guide": guide})
    depth = 5
    ctx = _Context(integrator, integrator.setup(scene, 0, max_depth=depth))
    P, B = ctx.sensor.n_pings, ctx.sensor.n_bins
    lane = dr.arange(mi.UInt32, P * paths)
    ping = lane // paths
    f, bins, vals = ctx.records(P * paths)
    ctx.trace(HashSamples(mi.UInt32(seed), ping, lane - ping * paths), ping, lane, f, bins, vals)
    f = f.numpy().astype(np.float64).reshape(P, paths)
    bins = bins.numpy().reshape(P, paths, depth)
    vals = vals.numpy().astype(np.float64).reshape(P, paths, depth)
    var_pt = var_ideal = var_b = norm2 = 0.0
    cv2, g2f, mean2 = [], [], []
    B_all = f.mean()
    for p in range(P):
        per_bin = np.zeros((paths, B))
        for k in range(depth):
            np.add.at(per_bin, (np.arange(paths), bins[p, :, k]), vals[p, :, k])
        mean = per_bin.mean(0)
        norm2 += (mean ** 2).sum()
        var_pt += ((per_bin ** 2).mean(0) - mean ** 2).sum()
        b = f[p].mean()
        if b <= 0:
            continue
        share = np.divide(per_bin, f[p][:, None], out=np.zeros_like(per_bin), where=f[p][:, None] > 0)
        w = f[p] / f[p].sum()
        var_ideal += b ** 2 * ((w[:, None] * share ** 2).sum(0) - (w[:, None] * share).sum(0) ** 2).sum()
        # one target over all pings: E_p[g^2 / f] summed over the ping's bins, and its norm
        g2f.append((np.divide(per_bin ** 2, f[p][:, None], out=np.zeros_like(per_bin),
                              where=f[p][:, None] > 0)).sum(1).mean())
        mean2.append((mean ** 2).sum())
        c = (f[p] ** 2).mean() / b ** 2 - 1.0
        cv2.append(c)
        var_b += c * (mean ** 2).sum()
    # Global target (the ping a primary coordinate, one normalisation B over all pings): an ideal
    # sampler spends P * paths samples in proportion to f over (ping, U); bin (p, j) gets variance
    # (B E_p[g^2/f] - I^2 / P) / paths, and B from all P * paths uniform paths scales every bin.
    var_glob = float(np.sum(B_all * np.asarray(g2f) - np.asarray(mean2) / P))
    cv2_all = (f ** 2).mean() / B_all ** 2 - 1.0
    var_B = cv2_all / P * norm2
    out = {"scene": name, "paths_per_ping": paths,
            "global_ideal_error_ratio": float(np.sqrt(var_pt / var_glob)),
            "global_normalisation_bound_error_ratio": float(np.sqrt(var_pt / var_B)),
            "ping_total_cv2": float(np.var(f.mean(1)) / np.mean(f.mean(1)) ** 2),
            "pt_rel_error_per_path": float(np.sqrt(var_pt / norm2)),
            "ideal_variance_ratio": float(var_pt / var_ideal),
            "ideal_error_ratio": float(np.sqrt(var_pt / var_ideal)),
            "normalisation_bound_error_ratio": float(np.sqrt(var_pt / var_b)),
            "median_cv2_of_f": float(np.median(cv2)),
            "zero_f_share": float(np.mean(f == 0))}
    if resample_draws:
        out["resampled_ideal"] = resampled_ideal(f, bins, vals, resample_draws, resample_repeats, seed)
    if baseline_spp:
        tof = mi.load_dict({"type": "sonar_tof", "guide": guide, "sampling": baseline_sampling,
                            "allocation": baseline_allocation})
        out["baseline"] = baseline(tof, scene, out, baseline_spp, baseline_repeats, depth)
    return out


def resampled_ideal(f, bins, vals, draws, repeats, seed):
    """The ideal global sampler run, not computed: ``draws`` paths per ping drawn in proportion to
    ``f`` from the traced pool (all pings at once, with replacement), each adding ``B e_k / f``
    to its ping's bins (``B`` the pool's mean ``f``), ``repeats`` times. Its relative error around
    the pool's own mean (what it is unbiased for) checks ``global_ideal_error_ratio``'s formula:
    the pool must hold many more paths than are drawn."""
    P, paths, depth = bins.shape
    n_bins = int(bins.max()) + 1
    F = f.ravel()
    cdf = np.cumsum(F) / F.sum()
    B_all = F.mean()
    exact = np.zeros((P, n_bins))
    np.add.at(exact, (np.repeat(np.arange(P), paths * depth), bins.ravel()), vals.ravel() / paths)
    rng = np.random.default_rng([seed, 0x0AC1E])
    errs = []
    for _ in range(repeats):
        idx = np.minimum(np.searchsorted(cdf, rng.random(P * draws), side="right"), len(F) - 1)
        p, i = idx // paths, idx % paths
        w = (B_all / draws) / F[idx]
        est = np.zeros((P, n_bins))
        for k in range(depth):
            np.add.at(est, (p, bins[p, i, k]), vals[p, i, k] * w)
        errs.append(((est - exact) ** 2).sum())
    return {"draws_per_ping": draws, "repeats": repeats,
            "rel_error": float(np.sqrt(np.mean(errs) / (exact ** 2).sum()))}


def baseline(integrator, scene, oracle, spps, repeats, depth):
    """``sonar_tof`` (by default its Sobol emission, the oracle's guide) measured against the oracle:
    per spp, its relative L2 error over ``repeats`` renders (seeds 1000, 1001, ...), the error the
    independent-path estimator would have there, and the ideal Metropolis sampler's, all at the
    paths the render traced (its allocation's pilot included: ``paths_per_ping``)."""
    if repeats < 2:
        raise ValueError(f"--baseline-repeats {repeats}: at least 2 renders are needed for a variance")
    rows = {}
    for spp in spps:
        integrator.last_plan = {}
        H = np.stack([integrator.render_histogram(scene, seed=1000 + r, spp=spp, max_depth=depth)
                      for r in range(repeats)])
        rel = float(np.sqrt(H.var(axis=0, ddof=1).sum() / (H.mean(axis=0) ** 2).sum()))
        plan = integrator.last_plan
        paths = spp + plan.get("extra_paths_per_row", 0)
        indep = oracle["pt_rel_error_per_path"] / np.sqrt(paths)
        ideal = indep / oracle["global_ideal_error_ratio"]
        bound = indep / oracle["global_normalisation_bound_error_ratio"]
        rows[str(spp)] = {"paths_per_ping": paths, "allocation": plan.get("allocation", "uniform"),
                          "moved": plan.get("paths_per_row_min") != plan.get("paths_per_row_max"),
                          "sonar_tof_rel_error": rel, "independent_rel_error": float(indep),
                          "sobol_gain": float(indep / rel), "global_ideal_over_sonar_tof": float(rel / ideal),
                          "global_normalisation_bound_over_sonar_tof": float(rel / bound)}
    return rows


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--scenes", default="box,slot_chamber,glossy_corridor,hidden_target")
    ap.add_argument("--paths", type=int, default=4096)
    ap.add_argument("--guide", default="image", choices=("image", "none"),
                    help="the path function's guide (sonar_tof's default image, or none: BSDF sampling)")
    ap.add_argument("--curved-guide", action="store_true",
                    help="turn on the image guide through curved mirrors (plugins/integrators/paths/image_guide.py CURVED_GUIDE) for "
                         "the path function and the baseline")
    ap.add_argument("--no-strip-guide", action="store_true",
                    help="turn off the strip guide to curved mirrors (plugins/integrators/paths/image_guide.py STRIP_GUIDE, on by "
                         "default) for the path function and the baseline: the bound as measured before it")
    ap.add_argument("--baseline-spp", default="",
                    help="also render the default sonar_tof at these spp (comma separated) and compare the ideal "
                         "sampler with its measured error (see the module's docstring)")
    ap.add_argument("--baseline-repeats", type=int, default=8, help="renders per baseline spp (default 8)")
    ap.add_argument("--baseline-allocation", default="auto", choices=("auto", "uniform", "adaptive"),
                    help="the baseline sonar_tof's allocation (default auto, its own default; uniform: the "
                         "baseline before 2026-11-27)")
    ap.add_argument("--resample-draws", type=int, default=0,
                    help="also run the ideal sampler by resampling this many paths per ping from the traced ones "
                         "(checks the ideal ratio's formula; keep it well under --paths)")
    args = ap.parse_args(argv)
    try:
        spps = [int(v) for v in args.baseline_spp.split(",") if v.strip()]
    except ValueError:
        ap.error(f"--baseline-spp {args.baseline_spp!r}: give whole numbers of paths per ping, comma separated")
    if any(v < 1 for v in spps) or (spps and args.baseline_repeats < 2):
        ap.error("--baseline-spp takes positive numbers and --baseline-repeats at least 2")
    if args.resample_draws < 0:
        ap.error("--resample-draws takes a number of paths per ping (0: off)")
    if args.curved_guide:
        import mitsonar  # noqa: F401  (registers the plugins)
        from mitsonar.plugins.integrators.paths import image_guide

        image_guide.CURVED_GUIDE = True
    if args.no_strip_guide:
        import mitsonar  # noqa: F401  (registers the plugins)
        from mitsonar.plugins.integrators.paths import image_guide

        image_guide.STRIP_GUIDE = False
    print(json.dumps([analyse(s, args.paths, guide=args.guide, baseline_spp=spps, baseline_repeats=args.baseline_repeats,
                              resample_draws=args.resample_draws, baseline_allocation=args.baseline_allocation)
                      for s in args.scenes.split(",")], indent=1))


if __name__ == "__main__":
    main()
