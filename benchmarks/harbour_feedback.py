"""The harbour's multibeam survey mapped, then again with piles refined by the renderer fed back.

The survey of ``benchmarks/survey_mapping.py`` (``scenes_xml/harbour.xml``'s 128-beam multibeam
along ``harbour_survey.tum``, ``--frames`` frames at ``--spp``, seed 1) is mapped by
:class:`hilbertmap.IncrementalHilbertMap` with the multibeam's default budget (the first map); then
:func:`mitsonar.inverse.piles.piles_feedback` finds the piles on its ridge, refines them
(and the seabed, without ``--altitude``) against the recorded intensities, and maps the survey
again with each echo placed where the refined model puts it (those it cannot place left out) and
the model's surface as evidence (the second map, on a ``--node-spacing`` lattice: 0.1 m, finer
than the first map's 0.15 m, since the evidence now knows the surfaces to centimetres;
``--keep-unexplained``: also the one that keeps the echoes it cannot place on their arcs;
``--true-model``: the feedback of the true piles and seabed, unrefined, what this way of mapping
can reach). Both are scored against the scene by ``hilbertmap.metrics.evaluate`` (the
settings of ``survey_mapping.py``'s ``multibeam_quality``: ridge surface on a 0.2 m grid, 5000
true surface points, AUC and near-wall AUC), beside OctoMap (0.1 m, the first map's samples) when
octomap-python is installed.

``--altitude A``: the seabed is the vehicle's height minus ``A`` (its altimeter; the survey runs 4 m
above the seabed), kept fixed; without it the seabed is searched by rendering (the mud's echo is
25-30 dB under the piles' at the fan's grazing angles: `seabed_search` compares each frame's mean
level over its beams in dB; seeds 0-4 found -5.976 to -5.999 m).

Prints one JSON object: ``first`` and ``feedback`` (the scores), ``octomap``, ``piles`` (start,
refined, truth, errors), ``seabed``, ``loss`` (render-and-compare at the last blur, start, final,
ratio; with ``--true-model`` also the true model's loss, the floor the recorded frames' own noise
leaves, and ``excess_ratio``, the fall of the loss above that floor), ``explained`` (share of the
echoes the model placed), seconds, and ``targets`` (the issue's:
ridge F-score at 0.1 m >= 0.6, mean accuracy < 0.3 m).

    python benchmarks/harbour_feedback.py [--frames 100] [--spp 64] [--seed 0] [--altitude 4] [--node-spacing 0.1] [--keep-unexplained] [--true-model] [--no-octomap]
"""
from __future__ import annotations

import argparse
import json
import os
import sys
import time

import numpy as np

HERE = os.path.dirname(os.path.abspath(__file__))
sys.path.insert(0, HERE)

TRUE_PILES = np.array([[4.0, -8.0, 0.3], [8.0, -8.0, 0.3], [12.0, -8.0, 0.3], [16.0, -8.0, 0.3]])
TRUE_SEABED = -6.0


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--frames", type=int, default=100)
    ap.add_argument("--spp", type=int, default=64)
    ap.add_argument("--seed", type=int, default=0, help="the feedback's seed (refinement renders, rays, map)")
    ap.add_argument("--altitude", type=float, default=None, help="the vehicle's altimeter (m): the seabed, fixed")
    ap.add_argument("--resolution", type=float, default=0.2, help="the scores' surface grid (m)")
    ap.add_argument("--node-spacing", type=float, default=0.1,
                    help="the second map's lattice (m; the first map's: 0.15, the default)")
    ap.add_argument("--no-octomap", action="store_true")
    ap.add_argument("--true-model", action="store_true",
                    help="also the feedback of the true piles and seabed (no refinement): what the map can reach")
    ap.add_argument("--keep-unexplained", action="store_true",
                    help="also the feedback that keeps the echoes the model cannot place on their arcs")
    args = ap.parse_args(argv)
    if args.frames < 1 or args.spp < 1 or not args.node_spacing > 0:
        ap.error("--frames and --spp must be >= 1, --node-spacing > 0")

    import survey_mapping as sm

    from mitsonar.inverse.piles import piles_feedback
    from mitsonar.sim.groundtruth import scene_mesh

    report = {"command": "python benchmarks/harbour_feedback.py " + " ".join(argv if argv is not None else sys.argv[1:])}
    scene, scans, t_render, _ = sm.render("multibeam", args.spp, max_scans=args.frames)
    V, F = scene_mesh(scene)
    report["render_s"] = round(t_render, 2)
    t0 = time.perf_counter()
    first, samples, _ = sm.map_incrementally(scans, **sm.MULTIBEAM_LIGHT)
    report["first_map_s"] = round(time.perf_counter() - t0, 2)
    report["first"], full = sm.score(first, V, F, args.resolution)

    seabed = None
    if args.altitude is not None:
        seabed = float(np.mean([np.asarray(s.poses)[0, 2, 3] for s in scans])) - args.altitude
    t0 = time.perf_counter()
    second = dict(sm.MULTIBEAM_LIGHT, node_spacing=args.node_spacing)
    res = piles_feedback(scans, first, seabed=seabed, seed=args.seed, drop_unexplained=True, **second)
    report["feedback_s"] = round(time.perf_counter() - t0, 2)
    report["refine_s"] = round(res["refine"]["seconds"], 2)
    report["feedback"] = sm.score(res["map"], V, F, args.resolution)[0]
    if args.true_model:  # the ceiling: the true piles and seabed, not refined
        true = piles_feedback(scans, first, seabed=TRUE_SEABED, piles=TRUE_PILES, stages=((1.5, 0),), seed=args.seed,
                              drop_unexplained=True, **second)
        report["feedback_true_model"] = sm.score(true["map"], V, F, args.resolution)[0]
    if args.keep_unexplained:  # the echoes the model cannot place kept on their arcs (a control)
        kept = piles_feedback(scans, first, seabed=seabed, seed=args.seed, **second)
        report["feedback_keep_unexplained"] = sm.score(kept["map"], V, F, args.resolution)[0]

    def matched(P):
        out = []
        for p in P:
            k = int(np.argmin(np.hypot(*(TRUE_PILES[:, :2] - p[:2]).T)))
            out.append(dict(estimate=[round(float(v), 4) for v in p], truth=TRUE_PILES[k].tolist(),
                            centre_error=round(float(np.hypot(*(p[:2] - TRUE_PILES[k, :2]))), 4),
                            radius_error=round(float(p[2] - TRUE_PILES[k, 2]), 4)))
        return out

    report["piles"] = dict(start=matched(res["piles_start"]), refined=matched(res["piles"]))
    report["seabed"] = dict(start=res["seabed_start"], refined=res["seabed"], truth=TRUE_SEABED,
                            source="altimeter" if seabed is not None else "render search")
    r = res["refine"]
    report["loss"] = dict(start=r["loss_start"], final=r["loss_final"], ratio=r["loss_start"] / r["loss_final"])
    if args.true_model:
        # the recorded frames' own Monte Carlo noise (spp --spp) leaves the true model a loss too: the
        # floor; the fit's ratio over it says how much of the loss the model could explain it did
        floor = true["refine"]["loss_final"]
        report["loss"].update(true_model=floor, excess_ratio=(r["loss_start"] - floor) / (r["loss_final"] - floor)
                              if r["loss_final"] > floor else float("inf"))
    report["explained"] = res["explained"]
    report["evidence_share"] = res["evidence_share"]

    if not args.no_octomap:
        report["octomap"] = sm.octomap_report(first, samples, full, V, F)

    fb = report["feedback"]
    report["targets"] = {
        "ridge_fscore@0.1": dict(target=0.6, first=report["first"]["ridge_fscore@0.1"], feedback=fb["ridge_fscore@0.1"],
                                 met=fb["ridge_fscore@0.1"] >= 0.6),
        "ridge_acc_mean": dict(target=0.3, first=report["first"]["ridge_acc_mean"], feedback=fb["ridge_acc_mean"],
                               met=fb["ridge_acc_mean"] < 0.3)}
    print(json.dumps(sm._clean(report), indent=1))
    return 0


if __name__ == "__main__":
    sys.exit(main())
