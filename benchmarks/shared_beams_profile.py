"""Where a multibeam frame's time goes (issue "Survey speed"): ``scenes_xml/quay_wall.xml``'s
512-beam x 500-bin frame with ``sonar_tof`` (per-row paths, and ``share_beams``).

Prints one JSON object, all measured in this one run (medians of ``--repeats`` warm renders):
  * ``render_s``: a whole frame (``render_histogram``) at ``--spp``;
  * ``paths_only_s``: the same paths with the echo scoring replaced by one counter add per
    bounce (ray casts, BSDF sampling and evaluation, gains; no histogram scatter), so
    ``render_s - paths_only_s`` is the scoring (one float64 scatter per echo; ``share_beams``:
    one per beam in the echo's window);
  * ``bare_rays_s``: the ray-cast ceiling of benchmarks/render.py (same lanes, bounces and
    visibility rays, nothing else) for the per-row paths;
  * ``kernels``: Dr.Jit's kernel history of one warm render (codegen, backend compile or cache
    load, execution, in ms) and ``first_render_s``, the first render in this process (tracing +
    compiling or loading from the kernel cache);
  * ``paired``: per-row paths at ``2 spp`` against shared paths at ``spp``, renders interleaved
    (the machine's load hits both alike), median seconds and their ratio; on quay_wall and box_fls
    the shared frame at half the spp has the lower error (benchmarks/render.py).

Usage: python benchmarks/shared_beams_profile.py [--spp 256] [--repeats 5]
"""
from __future__ import annotations

import argparse
import json
import os
import statistics
import sys
import time

import mitsonar  # noqa: F401
import drjit as dr  # noqa: E402
import mitsuba as mi  # noqa: E402

HERE = os.path.dirname(os.path.abspath(__file__))
sys.path.insert(0, HERE)
import render as bench  # noqa: E402


def median_time(fn, repeats):
    fn(0)
    times = []
    for r in range(repeats):
        t = time.perf_counter()
        fn(1 + r)
        times.append(time.perf_counter() - t)
    return statistics.median(times)


def kernel_times(fn):
    dr.set_flag(dr.JitFlag.KernelHistory, True)
    try:
        dr.kernel_history()
        fn(99)
        hist = [k for k in dr.kernel_history() if k["type"] == dr.KernelType.JIT]
    finally:
        dr.set_flag(dr.JitFlag.KernelHistory, False)
    keys = ("codegen_time", "backend_time", "execution_time")
    return {"n": len(hist), **{k: round(sum(h.get(k, 0.0) for h in hist), 2) for k in keys},
            "cache_hits": sum(bool(h.get("cache_hit")) for h in hist)}


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--spp", type=int, default=256)
    ap.add_argument("--repeats", type=int, default=5)
    args = ap.parse_args(argv)
    from mitsonar.plugins.integrators.paths import shared_beams
    from mitsonar.plugins.integrators.paths.samples import SobolSamples

    scene = mitsonar.load_scene(os.path.join(HERE, "..", "scenes_xml", "quay_wall.xml"))
    sensor = scene.sensors()[0]
    depth = scene.integrator().max_depth
    out = {"scene": "scenes_xml/quay_wall.xml", "rows": sensor.n_pings, "bins": sensor.n_bins, "spp": args.spp,
           "max_depth": depth, "cores": os.cpu_count()}
    for share in (False, True):
        integ = mi.load_dict({"type": "sonar_tof", "max_depth": depth, "share_beams": share})
        t = time.perf_counter()
        integ.render_histogram(scene, sensor, seed=0, spp=args.spp)
        first = time.perf_counter() - t
        full = lambda s: integ.render_histogram(scene, sensor, seed=s, spp=args.spp)  # noqa: E731

        def paths_only(s):
            setup = integ.setup(scene, sensor)
            tally = dr.zeros(mi.UInt32, 1)

            def record(k, rng, energy, valid, hit):
                dr.scatter_add(tally, mi.UInt32(1), mi.UInt32(0), valid & (energy > 0))

            if share:
                shared = shared_beams.SharedFrame(setup)
                n = sensor.n_pings * args.spp
                zero = dr.zeros(mi.UInt32, n)
                samples = SobolSamples(dr.opaque(mi.UInt32, s), zero, dr.arange(mi.UInt32, n))
                integ.sample(shared.path_setup, zero, samples, record)
            else:
                ping, samples = integ.lanes(sensor.n_pings, s, 0, args.spp)
                integ.sample(setup, ping, samples, record)
            return tally.numpy()

        with dr.suspend_grad():
            row = {"first_render_s": first, "render_s": median_time(full, args.repeats),
                   "paths_only_s": median_time(paths_only, args.repeats), "kernels": kernel_times(full)}
        row["scoring_s"] = row["render_s"] - row["paths_only_s"]
        out["share_beams" if share else "per_row"] = row
    its = {sh: mi.load_dict({"type": "sonar_tof", "max_depth": depth, "share_beams": sh}) for sh in (False, True)}
    runs = ((False, 2 * args.spp), (True, args.spp))
    times = {False: [], True: []}
    for sh, spp in runs:
        its[sh].render_histogram(scene, sensor, seed=0, spp=spp)
    for r in range(args.repeats):
        for sh, spp in runs:
            t = time.perf_counter()
            its[sh].render_histogram(scene, sensor, seed=1 + r, spp=spp)
            times[sh].append(time.perf_counter() - t)
    a, b = statistics.median(times[False]), statistics.median(times[True])
    out["paired"] = {"per_row_spp": 2 * args.spp, "per_row_s": a, "shared_spp": args.spp, "shared_s": b,
                     "per_row_over_shared": a / b}
    old = os.getcwd()
    _, _, per_lane = bench.count_segments(scene, args.spp, seed=1, per_lane=True)
    _, segs, secs = bench.ceiling(scene, args.spp, per_lane, args.repeats)
    os.chdir(old)
    out["per_row"]["bare_rays_s"] = secs
    out["per_row"]["segments"] = segs
    json.dump(out, sys.stdout, indent=2)
    print()


if __name__ == "__main__":
    main()
