#!/usr/bin/env python
"""sonar_bdpt against sonar_tof at equal wall time on the scenes of scenes_xml/ (issue 29).

Per scene (its first sensor and its integrator's ``max_depth``): each integrator's paths per second
are measured on a warm kernel, and the spp that fills ``--budget`` seconds is rendered
``--repeats`` times (seeds 1..R); the reference is a sonar_tof render of ``--reference-factor``
times sonar_tof's spp (seed 1000). Scores, over the whole scan (and over a scene's region of
interest where it has one, e.g. the hidden boulder's echo):

* ``rel_l2``: ``||I - I_ref|| / ||I_ref||``, averaged over the repeats. The reference's own noise
  is in it (about ``1 / sqrt(factor)`` of sonar_tof's error);
* ``rel_noise``: ``sqrt(sum over bins of the variance across the repeats) / ||I_ref||``: the
  error of an unbiased estimator without the reference's noise (both integrators are unbiased);
* ``error_ratio``: sonar_tof's ``rel_noise`` over sonar_bdpt's, each scaled to exactly
  ``--budget`` seconds by ``sqrt(seconds taken / budget)`` (> 1: bdpt wins at equal time);
* ``cost_ratio``: sonar_bdpt's seconds per lane over sonar_tof's seconds per path.

Prints one JSON object per scene, then a summary line.

    python benchmarks/bdpt.py [--scenes box,hidden_target] [--budget 2] [--repeats 3] [--reference-factor 16]
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
REGIONS = {"hidden_target": ("boulder", 6.4, 10.0), "slot_chamber": ("chamber", 3.6, 12.0)}


def paths_per_second(integ, scene, depth, n_pings, budget):
    """Paths (lanes) per ping per second of a warm render."""
    spp = 16
    integ.render_histogram(scene, 0, seed=0, spp=spp, max_depth=depth)  # compile
    while True:
        t0 = time.perf_counter()
        integ.render_histogram(scene, 0, seed=0, spp=spp, max_depth=depth)
        dt = time.perf_counter() - t0
        if dt > 0.3 * budget or spp >= 1 << 20:
            return spp / dt
        spp *= 4


def score(runs, ref, cols=slice(None)):
    runs, ref = runs[..., cols], ref[..., cols]
    norm = float(np.linalg.norm(ref))
    if norm == 0:
        return {"rel_l2": None, "rel_noise": None}
    rel = [float(np.linalg.norm(r - ref)) / norm for r in runs]
    noise = math.sqrt(float(runs.var(0, ddof=1).sum())) / norm if len(runs) > 1 else None
    return {"rel_l2": float(np.mean(rel)), "rel_noise": noise}


def bench(name, budget, repeats, factor):
    import mitsuba as mi

    import mitsonar

    scene = mitsonar.load_scene(os.path.join(SCENES, f"{name}.xml"))
    sensor = scene.sensors()[0]
    depth = int(getattr(scene.integrator(), "max_depth", 5))
    out = {"scene": name, "max_depth": depth, "n_pings": sensor.n_pings, "n_bins": sensor.n_bins,
           "budget_s": budget, "repeats": repeats}
    integs = {"sonar_tof": mi.load_dict({"type": "sonar_tof"}), "sonar_bdpt": mi.load_dict({"type": "sonar_bdpt"})}
    runs, info = {}, {}
    for key, integ in integs.items():
        pps = paths_per_second(integ, scene, depth, sensor.n_pings, budget)
        spp = max(1, int(pps * budget))
        t0 = time.perf_counter()
        runs[key] = np.stack([integ.render_histogram(scene, 0, seed=s + 1, spp=spp, max_depth=depth)
                              for s in range(repeats)])
        info[key] = {"spp": spp, "paths_per_ping_per_s": pps, "seconds": (time.perf_counter() - t0) / repeats}
    ref_spp = info["sonar_tof"]["spp"] * factor
    t0 = time.perf_counter()
    ref = integs["sonar_tof"].render_histogram(scene, 0, seed=1000, spp=ref_spp, max_depth=depth)
    out["reference"] = {"integrator": "sonar_tof", "spp": ref_spp, "seconds": time.perf_counter() - t0}
    region = REGIONS.get(name)
    for key in integs:
        info[key]["scan"] = score(runs[key], ref)
        if region:
            edges = sensor.range_min + sensor.bin_width * np.arange(sensor.n_bins)
            cols = (edges >= region[1]) & (edges < region[2])
            info[key][region[0]] = score(runs[key], ref, cols)
    out.update(info)
    out["cost_ratio"] = info["sonar_tof"]["paths_per_ping_per_s"] / info["sonar_bdpt"]["paths_per_ping_per_s"]
    for part in ["scan"] + ([region[0]] if region else []):
        t, b = (info[k][part]["rel_noise"] and info[k][part]["rel_noise"] * math.sqrt(info[k]["seconds"] / budget)
                for k in ("sonar_tof", "sonar_bdpt"))
        out[f"error_ratio_{part}"] = (t / b) if t and b else None
    return out


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    names = sorted(os.path.splitext(os.path.basename(p))[0] for p in glob.glob(os.path.join(SCENES, "*.xml")))
    ap.add_argument("--scenes", default=",".join(names))
    ap.add_argument("--budget", type=float, default=2.0, help="seconds per render (default 2)")
    ap.add_argument("--repeats", type=int, default=3)
    ap.add_argument("--reference-factor", type=int, default=16)
    args = ap.parse_args(argv)
    wins = {}
    for name in args.scenes.split(","):
        res = bench(name, args.budget, args.repeats, args.reference_factor)
        print(json.dumps(res), flush=True)
        ratio = res["error_ratio_scan"]
        wins[name] = None if ratio is None else round(ratio, 3)
    print(json.dumps({"summary": "sonar_tof rel_noise / sonar_bdpt rel_noise at equal time (> 1: bdpt wins)",
                      "error_ratio_scan": wins}))


if __name__ == "__main__":
    main()
