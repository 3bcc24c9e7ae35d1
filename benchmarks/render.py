"""Render benchmark: time and error of a full box scan versus spp, against the ray-cast ceiling.

Prints one JSON object. Everything is measured in this one run (shared machines are noisy):
  * for each spp: seconds per full 200-ping scan (median of repeats, kernels compiled),
    paths/s, segments/s (ray casts: one intersection per bounce plus one visibility ray per
    echo connection) and the relative L2 error of the whole scan against a render with 32x the
    largest spp;
  * the ceiling: a bare loop of `scene.ray_intersect` bounces over the same lanes, the same
    emitted directions (sampled from each ping's beam) and, lane by lane, the same number of
    bounces and visibility rays at the same bounces as the sonar paths (so about the same
    segments and the same SIMD divergence), with cosine-weighted bounces, in segments/s;
    `ratio_to_ceiling` = our segments/s / the ceiling's.
Targets (issue 2): <= 5 % relative L2 error in under 1 s, at >= 0.5 of the ceiling.
  * ``sampling``: per scene (the box, the intake, the quay wall's 512-beam frame with a floor),
    the time to 5 % relative L2 error of ``sonar_tof`` with each sampling of the emitted
    directions (``independent``: uniform random, the sampler before issue "Survey speed";
    ``sobol``: Owen-scrambled Sobol per row, the default), against a reference rendered with
    ``ref_factor`` x the largest spp; ``time_to_5pct_ratio`` = independent's time / sobol's;
    ``sobol+share_beams`` (multibeam frames: quay_wall, box_fls): sobol with the frame's paths
    traced from the transmit fan and shared between the receive beams (``share_beams``);
    ``time_to_5pct_over_last``: each sampling's time over the last one's.
    Targets (issue "Survey speed"): the box under 0.05 s, the 512-beam frame at 10 Hz or more.
  * ``time_to_5pct`` (per scene and sampling): the spp where the error curve crosses 5 %
    (`fit_time_to`: ``c spp^-alpha`` through the two sweep points that bracket 5 %; a Sobol
    emission's error falls faster than 1/sqrt(spp), and in steps at powers of two), then renders
    at that spp (median and fastest of the repeats, error median), the spp raised by the fitted
    law while the median error is above 5 %; ``survey_speed_targets``: the fastest sampling per
    target scene against its bound;
  * ``frozen_vs_traced`` (``--freeze-ab``): each scene's fastest sampling at its time-to-5 % spp,
    renders with frozen passes (``plugins/integrators/paths/frozen_pass.py``, the default) and traced ones
    interleaved: medians, fastest, and traced / frozen.

Usage: python benchmarks/render.py [--spp 256,512,1024,2048,4096] [--repeats 3] [--ref-factor 32]
                                   [--sampling-scenes box,intake,quay_wall,box_fls]
                                   [--samplings independent,sobol,sobol+share_beams]
                                   [--freeze-ab] [--skip-box-sweep]
"""
from __future__ import annotations

import argparse
import json
import os
import platform
import statistics
import sys
import time

import numpy as np

import mitsonar  # noqa: F401  (selects the variant and registers the plugins)
import drjit as dr  # noqa: E402
import mitsuba as mi  # noqa: E402

HERE = os.path.dirname(os.path.abspath(__file__))
BOX = os.path.join(HERE, "..", "scenes_xml", "box.xml")


def count_segments(scene, spp, seed=0, per_lane=False):
    """Ray casts of one scan, traced by the scene's integrator's path function with the sensor's own
    absorption and (multibeam) transmit fan: intersections (one per bounce) + visibility rays (one per echo:
    the path skips the visibility ray of a bounce whose echo is zero, e.g. far outside the beam);
    with ``per_lane`` also, per path, its number of bounces and a bit mask of the bounces that
    cast a visibility ray (two UInt32 arrays)."""
    from mitsonar.plugins.integrators.paths import samples

    integrator = scene.integrator()
    setup = integrator.setup(scene, 0)
    sensor = setup.sensor
    n = sensor.n_pings * spp
    lane = dr.arange(mi.UInt32, n)
    ping = lane // spp
    counts = dr.zeros(mi.UInt32, 2)
    bounces = dr.zeros(mi.UInt32, n)
    shadows = dr.zeros(mi.UInt32, n)

    def record(depth, rng, energy, valid, hit):
        dr.scatter_add(counts, mi.UInt32(1), mi.UInt32(0))
        dr.scatter_add(counts, mi.UInt32(1), mi.UInt32(1), energy > 0)
        dr.scatter_add(bounces, mi.UInt32(1), lane)
        dr.scatter_add(shadows, mi.UInt32(1) << depth, lane, energy > 0)

    with dr.suspend_grad():
        integrator.sample(setup, ping, samples.HashSamples(mi.UInt32(seed), ping, lane - ping * spp), record)
        c = counts.numpy()
        dr.eval(bounces, shadows)
    if per_lane:
        return int(c[0]), int(c[1]), (bounces, shadows)
    return int(c[0]), int(c[1])


@dr.syntax
def _bare_bounces(scene, frames, beam, n_pings, spp, limit, shadow_bits, seed):
    """Same lanes, same emitted directions (drawn from the beam of each ping), and per lane the
    same number of bounces (``limit``) and visibility rays at the same bounces (``shadow_bits``)
    as the sonar paths; then only ray casts: a cosine-weighted bounce per hit."""
    n = n_pings * spp
    lane = dr.arange(mi.UInt32, n)
    ping = lane // dr.opaque(mi.UInt32, spp)
    rng = mi.PCG32(n, dr.arange(mi.UInt64, n) + seed)
    x_ax, y_ax, z_ax, origin = frames.gather(ping)
    d, _ = beam.sample(mi.Point2f(rng.next_float32(), rng.next_float32()))
    ray = mi.Ray3f(origin, x_ax * d.x + y_ax * d.y + z_ax * d.z)
    active = mi.Bool(True)
    depth = mi.UInt32(0)
    segs = mi.UInt32(0)
    while active:
        si = scene.ray_intersect(ray, active)
        active &= si.is_valid()
        segs += 1
        shadow = active & (((shadow_bits >> depth) & 1) == 1)
        scene.ray_test(si.spawn_ray_to(origin), shadow)
        segs += dr.select(shadow, 1, 0)
        wo = mi.warp.square_to_cosine_hemisphere(mi.Point2f(rng.next_float32(), rng.next_float32()))
        ray = si.spawn_ray(si.to_world(wo))
        depth += 1
        active &= depth < limit
    return dr.sum(segs)


def ceiling(scene, spp, per_lane, repeats, between=None):
    """Segments/s of the bare loop: ray_intersect + ray_test per bounce, no BSDF, no bins.
    ``between(r)``, if given, runs after each timed bare loop (the renders it is compared with,
    interleaved, so that the machine's load hits both alike)."""
    from mitsonar.plugins.sensors.sonar import PingFrames

    sensor = scene.sensors()[0]
    frames = PingFrames(sensor.ping_poses())
    times, segs = [], 0
    for r in range(repeats + 1):
        t = time.perf_counter()
        segs = int(_bare_bounces(scene, frames, sensor.beam, sensor.n_pings, spp, per_lane[0], per_lane[1],
                                 dr.opaque(mi.UInt64, r)).numpy()[0])
        dt = time.perf_counter() - t
        if r:
            times.append(dt)
            if between is not None:
                between(r)
    return segs / statistics.median(times), segs, statistics.median(times)


SCENE_SPP = {"box": "128,256,512,1024,2048,4096", "intake": "128,256,512,1024,2048,4096",
             "quay_wall": "64,128,256,512,1024,2048", "box_fls": "32,64,128,256,512,1024,2048"}
# A sampling name ``<sampling>+share_beams`` is that sampling with the multibeam frame's paths
# shared between receive beams (sonar_tof ``share_beams``; multibeam scenes only).
SHARE = "+share_beams"


def integrator_dict(depth, sampling):
    """The sonar_tof of a sampling name of the comparison (see `SHARE`)."""
    share = sampling.endswith(SHARE)
    return {"type": "sonar_tof", "max_depth": depth, "sampling": sampling[:-len(SHARE)] if share else sampling,
            "share_beams": share}


def sweep(scene, integ, sensor, ref, spps, repeats, segments=True):
    """Seconds (median of ``repeats``, warm), paths/s and relative L2 error per spp."""
    results = []
    for spp in spps:
        integ.render_histogram(scene, sensor, seed=0, spp=spp)  # compile / warm
        times, errs = [], []
        for r in range(repeats):
            t = time.perf_counter()
            h = integ.render_histogram(scene, sensor, seed=1 + r, spp=spp)
            times.append(time.perf_counter() - t)
            errs.append(float(np.linalg.norm(h - ref) / np.linalg.norm(ref)))
        secs = statistics.median(times)
        row = {"spp": spp, "seconds": secs, "paths_per_s": sensor.n_pings * spp / secs,
               "rel_l2_error": statistics.median(errs)}
        if segments:
            n_int, n_vis = count_segments(scene, spp)
            row.update(segments=n_int + n_vis, segments_per_s=(n_int + n_vis) / secs)
        results.append(row)
    return results


def fastest_within(results, error=0.05):
    within = [r for r in results if r["rel_l2_error"] <= error]
    return min(within, key=lambda r: r["seconds"]) if within else None


def fit_time_to(results, error=0.05):
    """The spp and seconds at which a sweep reaches ``error``, from the sweep's own points: the
    error follows ``c spp^-alpha`` (alpha = 1/2 for independent samples; more with the
    Sobol-stratified emission, whose error falls faster), fitted in log-log space between the
    two sweep points that bracket ``error`` (all points when none do), and a render costs
    ``a + b spp`` (least squares over the sweep: per-frame overhead plus per-path time).
    Returns the fit, the predicted spp (rounded up) and seconds; `measure_at` checks them."""
    spp = np.array([r["spp"] for r in results], dtype=np.float64)
    err = np.array([r["rel_l2_error"] for r in results], dtype=np.float64)
    secs = np.array([r["seconds"] for r in results], dtype=np.float64)
    order = np.argsort(spp)
    spp, err, secs = spp[order], err[order], secs[order]
    pick = np.arange(len(spp))
    for i in range(len(spp) - 1):
        if err[i] > error >= err[i + 1]:
            pick = np.array([i, i + 1])
    x, y = np.log(spp[pick]), np.log(err[pick])
    alpha = float(min(max(-np.polyfit(x, y, 1)[0], 0.25), 1.5)) if len(pick) > 1 else 0.5
    logc = float(np.mean(y + alpha * x))
    b, a = np.polyfit(spp, secs, 1) if len(spp) > 1 else (secs[0] / spp[0], 0.0)
    need = int(np.ceil(np.exp((logc - np.log(error)) / alpha)))
    return {"alpha": alpha, "c": float(np.exp(logc)), "bracketed": len(pick) == 2, "overhead_s": float(a),
            "seconds_per_spp": float(b), "spp": need, "predicted_seconds": float(a + b * need)}


def measure_at(scene, integ, sensor, ref, spp, repeats, seed0=1000):
    """Median seconds and relative L2 error of ``repeats`` warm renders at ``spp`` (seeds not used
    by the sweep)."""
    integ.render_histogram(scene, sensor, seed=seed0 - 1, spp=spp)
    times, cpu, errs = [], [], []
    for r in range(repeats):
        t, c = time.perf_counter(), time.process_time()
        h = integ.render_histogram(scene, sensor, seed=seed0 + r, spp=spp)
        times.append(time.perf_counter() - t)
        cpu.append(time.process_time() - c)
        errs.append(float(np.linalg.norm(h - ref) / np.linalg.norm(ref)))
    # CPU seconds of this process over the cores: about the wall time on an idle machine (the
    # kernels run on every core; other jobs on a shared machine lengthen the wall time, not this).
    return {"spp": spp, "seconds": statistics.median(times), "seconds_min": min(times),
            "cpu_seconds_per_core": statistics.median(cpu) / os.cpu_count(),
            "rel_l2_error": statistics.median(errs), "rel_l2_error_max": max(errs)}


def time_to(scene, integ, sensor, ref, results, repeats, error=0.05):
    """`fit_time_to` on the sweep, then renders at the fitted spp; while their median error is
    above ``error``, the spp grows by the fitted law (at most twice). The last measurement is the
    time to ``error``."""
    fit = fit_time_to(results, error)
    spp, tries = fit["spp"], []
    for _ in range(3):
        at = measure_at(scene, integ, sensor, ref, spp, repeats)
        tries.append(at)
        if at["rel_l2_error"] <= error:
            break
        spp = int(np.ceil(spp * (at["rel_l2_error"] / error) ** (1.0 / fit["alpha"]) * 1.02))
    return {"fit": fit, "tries": tries, "measured": tries[-1]}


def compare_sampling(name, samplings, repeats, ref_factor):
    """Time to 5 % per sampling strategy on one scene (the reference: sobol, ``ref_factor`` x
    the largest spp)."""
    scene = mitsonar.load_scene(os.path.join(HERE, "..", "scenes_xml", f"{name}.xml"))
    sensor = scene.sensors()[0]
    depth = scene.integrator().max_depth
    spps = [int(v) for v in SCENE_SPP.get(name, SCENE_SPP["box"]).split(",")]
    ref_spp = ref_factor * max(spps)
    ref = mi.load_dict({"type": "sonar_tof", "max_depth": depth}).render_histogram(scene, sensor, seed=12345,
                                                                                  spp=ref_spp)
    out = {"rows": sensor.n_pings, "bins": sensor.n_bins, "kind": sensor.kind, "max_depth": depth,
           "reference_spp": ref_spp, "by_sampling": {}}
    samplings = [k for k in samplings if sensor.kind == "multibeam" or not k.endswith(SHARE)]
    for sampling in samplings:
        integ = mi.load_dict(integrator_dict(depth, sampling))
        results = sweep(scene, integ, sensor, ref, spps, repeats, segments=False)
        best = fastest_within(results)
        out["by_sampling"][sampling] = {"results": results, "fastest_within_5pct": best,
                                        "rows_per_s_at_5pct": sensor.n_pings / best["seconds"] if best else None,
                                        "time_to_5pct": time_to(scene, integ, sensor, ref, results,
                                                                max(repeats, 5))}
    bests = [out["by_sampling"][k]["fastest_within_5pct"] for k in samplings]
    if len(bests) == 2 and all(bests):
        out["time_to_5pct_ratio"] = bests[0]["seconds"] / bests[1]["seconds"]
    # Each sampling's time to 5 % over the last one's (> 1: the last is faster).
    out["time_to_5pct_over_last"] = {k: (b["seconds"] / bests[-1]["seconds"] if b and bests[-1] else None)
                                     for k, b in zip(samplings, bests)}
    # The same from the fitted error curve, measured at the fitted spp (finer than the sweep's grid).
    fits = {k: out["by_sampling"][k]["time_to_5pct"]["measured"] for k in samplings}
    out["time_to_5pct_fitted"] = {k: {"spp": f["spp"], "seconds": f["seconds"], "seconds_min": f["seconds_min"],
                                      "cpu_seconds_per_core": f["cpu_seconds_per_core"],
                                      "rel_l2_error": f["rel_l2_error"], "frames_per_s": 1.0 / f["seconds"]}
                                  for k, f in fits.items()}
    return out


def frozen_vs_traced(name, sampling, spp, repeats):
    """Seconds of one render with the passes frozen (`frozen_pass`, the default) and traced every
    time, interleaved (the machine's load hits both alike): medians and traced / frozen."""
    from mitsonar.plugins.integrators.paths import frozen_pass as fp
    scene = mitsonar.load_scene(os.path.join(HERE, "..", "scenes_xml", f"{name}.xml"))
    sensor = scene.sensors()[0]
    integ = mi.load_dict(integrator_dict(scene.integrator().max_depth, sampling))
    times = {True: [], False: []}
    try:
        for f in (True, False):
            fp.FREEZE = f
            integ.render_histogram(scene, sensor, seed=0, spp=spp)
        for r in range(repeats):
            for f in (True, False):
                fp.FREEZE = f
                t = time.perf_counter()
                integ.render_histogram(scene, sensor, seed=1 + r, spp=spp)
                times[f].append(time.perf_counter() - t)
    finally:
        fp.FREEZE = True
    a, b = statistics.median(times[False]), statistics.median(times[True])
    return {"sampling": sampling, "spp": spp, "traced_s": a, "frozen_s": b, "traced_over_frozen": a / b,
            "traced_min_s": min(times[False]), "frozen_min_s": min(times[True])}


def box_sweep(spps, repeats, ref_factor):
    """The box scan's error and time per spp, and its segment throughput against the ray-cast ceiling."""
    scene = mitsonar.load_scene(BOX)
    integ = scene.integrator()
    sensor = scene.sensors()[0]
    t = time.perf_counter()
    ref_spp = ref_factor * max(spps)
    ref = integ.render_histogram(scene, sensor, seed=12345, spp=ref_spp)
    t_ref = time.perf_counter() - t
    results = sweep(scene, integ, sensor, ref, spps, repeats)
    big = max(spps)
    _, _, per_lane = count_segments(scene, big, seed=1, per_lane=True)
    own = []

    def render_big(r):
        t = time.perf_counter()
        integ.render_histogram(scene, sensor, seed=100 + r, spp=big)
        own.append(time.perf_counter() - t)

    ceil_rate, ceil_segs, ceil_secs = ceiling(scene, big, per_lane, repeats, between=render_big)
    n_int, n_vis = count_segments(scene, big)
    # The same ratio from renders interleaved with the bare loops (robust to the machine's load).
    interleaved = (n_int + n_vis) / statistics.median(own) / ceil_rate
    for r in results:
        r["ratio_to_ceiling"] = r["segments_per_s"] / ceil_rate
        if r["spp"] == big:
            r["lane_time_ratio_to_ceiling"] = ceil_secs / r["seconds"]
    best = fastest_within(results)
    return {
        "benchmark": "render_box_full_scan",
        "scene": "scenes_xml/box.xml",
        "n_pings": sensor.n_pings, "n_bins": sensor.n_bins, "max_depth": integ.max_depth,
        "reference_spp": ref_spp, "reference_seconds": t_ref,
        "results": results,
        "ceiling": {"lanes": sensor.n_pings * big, "segments": ceil_segs, "seconds": ceil_secs,
                    "segments_per_s": ceil_rate},
        "target": {"rel_l2_error": 0.05, "seconds": 1.0, "ratio_to_ceiling": 0.5},
        "fastest_within_5pct": best,
        "ratio_to_ceiling_interleaved": {"spp": big, "ratio": interleaved, "render_s": statistics.median(own)},
        "meets_target": bool(best and best["seconds"] < 1.0 and best["ratio_to_ceiling"] >= 0.5),
        "micron_seconds_per_scan": 13.0,
    }


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--spp", default="256,512,1024,2048,4096")
    ap.add_argument("--repeats", type=int, default=3)
    ap.add_argument("--ref-factor", type=int, default=32)
    ap.add_argument("--sampling-scenes", default="box,intake,quay_wall,box_fls",
                    help="scenes on which to time the samplers to 5 %% (empty: skip)")
    ap.add_argument("--samplings", default="independent,sobol,sobol+share_beams")
    ap.add_argument("--freeze-ab", action="store_true",
                    help="also time frozen against traced passes, interleaved, at each scene's time-to-5 %% spp")
    ap.add_argument("--skip-box-sweep", action="store_true",
                    help="skip the box sweep and the ray-cast ceiling (only the time-to-5 %% comparison)")
    args = ap.parse_args(argv)
    spps = [int(s) for s in args.spp.split(",")]

    out = {"variant": mitsonar.sim.variant(), "cores": os.cpu_count(), "python": platform.python_version()}
    if not args.skip_box_sweep:
        out.update(box_sweep(spps, args.repeats, args.ref_factor))
    samplings = args.samplings.split(",")
    out["sampling"] = {name: compare_sampling(name, samplings, args.repeats, args.ref_factor)
                       for name in filter(None, args.sampling_scenes.split(","))}
    # Issue "Survey speed": time to 5 % per scene and sampling (fitted spp, measured there) and
    # whether the targets are met: the box under 0.05 s, a 512-beam frame with a floor at 10 Hz.
    out["time_to_5pct"] = {name: v["time_to_5pct_fitted"] for name, v in out["sampling"].items()}
    targets = {"box": ("seconds", 0.05), "quay_wall": ("frames_per_s", 10.0), "box_fls": ("frames_per_s", 10.0)}
    out["survey_speed_targets"] = {}
    for name, (key, bound) in targets.items():
        if name in out["time_to_5pct"]:
            best = min(out["time_to_5pct"][name].values(), key=lambda f: f["seconds"])
            ok = (best[key] < bound if key == "seconds" else best[key] >= bound) and best["rel_l2_error"] <= 0.05
            # The same with the CPU seconds per core (about an idle machine's wall time).
            cpu = best["cpu_seconds_per_core"]
            ok_cpu = (cpu < bound if key == "seconds" else 1.0 / cpu >= bound) and best["rel_l2_error"] <= 0.05
            out["survey_speed_targets"][name] = {key: best[key], "bound": bound, "spp": best["spp"],
                                                 "rel_l2_error": best["rel_l2_error"], "met": bool(ok),
                                                 "cpu_seconds_per_core": cpu, "met_by_cpu_seconds": bool(ok_cpu)}
    if args.freeze_ab:
        out["frozen_vs_traced"] = {}
        for name in filter(None, args.sampling_scenes.split(",")):
            fits = out["time_to_5pct"][name]
            sampling = min(fits, key=lambda k: fits[k]["seconds"])
            out["frozen_vs_traced"][name] = frozen_vs_traced(name, sampling, fits[sampling]["spp"],
                                                             max(args.repeats, 5))
    json.dump(out, sys.stdout, indent=2)
    print()


if __name__ == "__main__":
    main()
