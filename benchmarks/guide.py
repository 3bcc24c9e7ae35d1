#!/usr/bin/env python
"""Image guiding (``guide="image"``) against BSDF sampling alone, per scene of scenes_xml/.

Per scene (its first sensor, its integrator's ``max_depth``, ``sonar_tof``): ``--repeats`` renders
of each setting at ``--spp`` (seeds 1..R, the two settings interleaved so that load on a shared
machine hits both alike) and a guided reference of ``--reference-factor`` times the spp (seed
1000). Scores:

* ``rel_noise``: ``sqrt(sum over bins of the variance across the repeats) / ||I_ref||``, the
  error of each unbiased estimator without the reference's noise; in a region of interest too
  (the echoes seen only through the plates: hidden_target's and periscope's boulder);
* ``seconds``: median wall time of a render;
* ``noise_ratio``: unguided over guided ``rel_noise`` at equal paths; ``error_ratio``: the same at
  equal time (each scaled by ``sqrt(seconds)``): > 1 means the guide wins;
* ``time_ratio``: guided over unguided seconds.

Prints one JSON object per scene, then a summary line.

    python benchmarks/guide.py [--scenes box,hidden_target] [--spp 4096] [--repeats 5] [--reference-factor 16]
"""
from __future__ import annotations

import argparse
import glob
import json
import math
import os
import time

import numpy as np

HERE = os.path.dirname(os.path.abspath(__file__))
SCENES = os.path.join(HERE, "..", "scenes_xml")
# Range windows (m) of the echoes a scene is about, scored on their own.
REGIONS = {"hidden_target": (6.4, 10.0), "periscope": (10.4, 14.0)}


def main():
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    names = sorted(os.path.basename(p)[:-4] for p in glob.glob(os.path.join(SCENES, "*.xml")))
    ap.add_argument("--scenes", default=",".join(names))
    ap.add_argument("--spp", type=int, default=4096)
    ap.add_argument("--repeats", type=int, default=5)
    ap.add_argument("--reference-factor", type=int, default=16)
    args = ap.parse_args()

    import mitsuba as mi

    import mitsonar

    ratios = {}
    for name in args.scenes.split(","):
        scene = mitsonar.load_scene(os.path.join(SCENES, f"{name}.xml"))
        depth = getattr(scene.integrator(), "max_depth", 5)
        sensor = scene.sensors()[0]
        integs = {g: mi.load_dict({"type": "sonar_tof", "max_depth": depth, "guide": g}) for g in ("none", "image")}
        ref = integs["image"].render_histogram(scene, 0, seed=1000, spp=args.spp * args.reference_factor)
        runs = {g: [] for g in integs}
        secs = {g: [] for g in integs}
        for g, integ in integs.items():
            integ.render_histogram(scene, 0, seed=0, spp=min(args.spp, 64))  # compile
        for r in range(args.repeats):
            for g, integ in integs.items():
                t0 = time.perf_counter()
                runs[g].append(integ.render_histogram(scene, 0, seed=r + 1, spp=args.spp))
                secs[g].append(time.perf_counter() - t0)
        norm = float(np.linalg.norm(ref))
        out = {"scene": name, "spp": args.spp, "rows": int(sensor.n_pings), "bins": int(sensor.n_bins)}
        region = REGIONS.get(name)
        cols = slice(None)
        if region is not None:
            lo, hi = region
            edges = np.linspace(sensor.range_min, sensor.range_max, sensor.n_bins + 1)
            cols = (edges[:-1] >= lo) & (edges[:-1] < hi)
        for g in integs:
            a = np.stack(runs[g])
            out[g] = {"seconds": float(np.median(secs[g])),
                      "rel_noise": math.sqrt(float(a.var(0, ddof=1).sum())) / norm,
                      "total_over_ref": float(a.mean(0).sum() / ref.sum())}
            if region is not None:
                rn = float(np.linalg.norm(ref[:, cols]))
                out[g]["region_rel_noise"] = math.sqrt(float(a[..., cols].var(0, ddof=1).sum())) / rn
        key = "region_rel_noise" if region is not None else "rel_noise"
        n0, n1 = out["none"][key], out["image"][key]
        t0, t1 = out["none"]["seconds"], out["image"]["seconds"]
        out["noise_ratio"] = n0 / n1 if n1 > 0 else None
        out["time_ratio"] = t1 / t0
        out["error_ratio"] = (n0 * math.sqrt(t0)) / (n1 * math.sqrt(t1)) if n1 > 0 else None
        ratios[name] = out["error_ratio"]
        print(json.dumps(out), flush=True)
    print(json.dumps({"summary": "error_ratio (> 1: guide wins at equal time)", **ratios}))


if __name__ == "__main__":
    main()
