"""Frame targets (issue "Frame overhead"): the issue's four targets as ratios, in one run.

Prints one JSON object:

  * ``quay_frame``: the 512-beam quay-wall frame (scenes_xml/quay_wall.xml) at 5 % relative L2
    error, ``max_depth`` 3 and 1, with each ``emission`` of the shared paths (``transmit``: the
    fan's density, ``receive``: the receive-weighted density, plugins/integrators/paths/receive_emission.py). Per
    depth one reference (``--ref-spp`` paths per beam, half with each emission, seeds apart from
    the runs'); per emission a sweep of spp (error and seconds of ``render_histogram``,
    benchmarks/render.py `sweep`), the spp fitted to 5 % and renders there (`render.time_to`:
    raised while the median error is above 5 %), then full frames (`render_scan`: the receiver
    chain included, no saving) at that spp, the two emissions interleaved: ``frames_per_s`` and
    its ratio to 85, and ``frames_per_s_by_cpu`` (cores / CPU seconds per frame: about the rate
    of an idle machine when a loaded one stretches the wall time).
    ``reference_error``: the reference's own relative error (half the distance between its two
    halves over its norm), which the measured errors include.
    ``equal_error``: transmit's spp, frame wall and CPU time at 5 % over receive's (> 1: receive wins).
  * ``box_scan``: the 200-ping box scan (per-row paths) to 5 %: milliseconds, ratio 10 ms / it.
  * ``segments``: the box scan at ``--big-spp`` (>= 1 M paths): segments per second of the
    integrator over the bare ray-casting loop of benchmarks/render.py (`ceiling`, interleaved
    with the renders), target >= 0.85.
  * per quay-frame row, ``segments_at_5pct`` (intersections and visibility rays of the frame's
    shared paths at its 5 % spp, `shared_segments`) and ``ray_casting_bound_frames_per_s``: the
    frame rate if the frame cost nothing but those rays at the bare loop's rate of ``segments``
    (no physics, no histogram, no receiver chain): a ceiling for the frame rate on these cores.
  * ``fixed_cost``: the quay frame at spp 1 (`render_scan` and `render_histogram`, medians) and
    the intercept of the seconds-per-spp line of the sweep; target < 2 ms.

Issue 55's ratios (``targets``): the quay frame's rate at 5 % over the rate its rays alone allow
(``ray_casting_bound_frames_per_s``; target 0.6 at ``max_depth`` 3, 0.45 at 1), and the fixed
cost, the frame at spp 1 over the frame at 5 % (target at most 0.1).

Usage: python benchmarks/frame_targets.py [--repeats 5] [--ref-spp 8192] [--big-spp 8192] [--quick]
"""
from __future__ import annotations

import argparse
import json
import os
import statistics
import sys
import time

import numpy as np

HERE = os.path.dirname(os.path.abspath(__file__))
sys.path.insert(0, HERE)

import render as bench  # noqa: E402  (benchmarks/render.py)

import mitsonar  # noqa: E402,F401
import mitsuba as mi  # noqa: E402

from mitsonar.sim import render as render_mod  # noqa: E402

SCENES = os.path.join(HERE, "..", "scenes_xml")
TARGET_FPS, TARGET_BOX_MS, TARGET_SEGMENTS, TARGET_FIXED_MS = 85.0, 10.0, 0.85, 2.0
EMISSIONS = ("transmit", "receive")


def reference(scene, sensor, depth, spp):
    """The mean of a transmit and a receive render at ``spp`` each, and its own relative error."""
    halves = [mi.load_dict({"type": "sonar_tof", "max_depth": depth, "emission": e}).render_histogram(
        scene, sensor, seed=70001 + k, spp=spp) for k, e in enumerate(EMISSIONS)]
    ref = 0.5 * (halves[0] + halves[1])
    return ref, float(0.5 * np.linalg.norm(halves[0] - halves[1]) / np.linalg.norm(ref))


def frames_interleaved(scene, spps, depth, repeats):
    """``render_scan`` frames (receiver chain included, no saving) of each emission at its own spp,
    interleaved (the machine's load hits both alike): median and fastest wall seconds and median
    CPU seconds of this process per frame (``time.process_time``: every thread)."""
    integs = {e: mi.load_dict({"type": "sonar_tof", "max_depth": depth, "emission": e}) for e in spps}
    for e, integ in integs.items():
        render_mod.render_scan(scene, spp=spps[e], seed=1, integrator=integ)
    wall, cpu = {e: [] for e in spps}, {e: [] for e in spps}
    for r in range(repeats):
        for e, integ in integs.items():
            t0, c0 = time.perf_counter(), time.process_time()
            render_mod.render_scan(scene, spp=spps[e], seed=2000 + r, integrator=integ)
            wall[e].append(time.perf_counter() - t0)
            cpu[e].append(time.process_time() - c0)
    return {e: (statistics.median(wall[e]), min(wall[e]), statistics.median(cpu[e])) for e in spps}


def quay_frame(spps, repeats, ref_spp):
    scene = mitsonar.load_scene(os.path.join(SCENES, "quay_wall.xml"))
    sensor = scene.sensors()[0]
    out = {"rows": sensor.n_pings, "bins": sensor.n_bins}
    for depth in (3, 1):
        ref, ref_err = reference(scene, sensor, depth, ref_spp // 2)
        per = {"reference_spp": ref_spp, "reference_error": round(ref_err, 4)}
        for emission in EMISSIONS:
            integ = mi.load_dict({"type": "sonar_tof", "max_depth": depth, "emission": emission})
            results = bench.sweep(scene, integ, sensor, ref, spps, repeats, segments=False)
            to = bench.time_to(scene, integ, sensor, ref, results, repeats)
            m = to["measured"]
            per[emission] = {
                "sweep": [{k: (round(v, 5) if isinstance(v, float) else v) for k, v in r.items()} for r in results],
                "spp_to_5pct": m["spp"], "rel_l2_error": round(m["rel_l2_error"], 4),
                "rel_l2_error_less_reference": round(float(np.sqrt(max(m["rel_l2_error"] ** 2 - ref_err ** 2, 0.0))), 4),
                "fit": {k: to["fit"][k] for k in ("alpha", "c", "overhead_s", "seconds_per_spp")},
            }
        timed = frames_interleaved(scene, {e: per[e]["spp_to_5pct"] for e in EMISSIONS}, depth, max(repeats, 7))
        for emission, (med, fastest, cpu) in timed.items():
            per[emission].update({
                "frame_ms_median": round(1e3 * med, 2), "frame_ms_min": round(1e3 * fastest, 2),
                "frame_cpu_ms": round(1e3 * cpu, 2),
                "frames_per_s": round(1.0 / med, 2), "frames_per_s_over_target": round(1.0 / med / TARGET_FPS, 4),
                "frames_per_s_by_cpu": round((os.cpu_count() or 1) / cpu, 2)})
        t, r = per["transmit"], per["receive"]
        per["equal_error"] = {"spp_transmit_over_receive": round(t["spp_to_5pct"] / r["spp_to_5pct"], 3),
                              "frame_wall_transmit_over_receive": round(t["frame_ms_median"] / r["frame_ms_median"], 3),
                              "frame_cpu_transmit_over_receive": round(t["frame_cpu_ms"] / r["frame_cpu_ms"], 3)}
        out[f"max_depth_{depth}"] = per
    return scene, out


def shared_segments(scene, integ, spp, seed=1):
    """(intersections, visibility rays) of one shared-path quay frame of ``spp`` paths per beam,
    as ``integ`` traces it (its emission; a visibility ray per echo that some beam hears: the
    path function's own rule), counted by a `record` that adds nothing to a histogram."""
    import drjit as dr

    from mitsonar.plugins.integrators import sonar_tof
    from mitsonar.plugins.integrators.paths import samples, shared_beams

    sensor = scene.sensors()[0]
    setup = integ.setup(scene, sensor, None, None)
    shared = shared_beams.SharedFrame(setup)
    seed_o, first_o = samples.opaque_u32(seed), samples.opaque_u32(0)
    zero, _, samples = integ._shared_lanes(shared.n_rows * spp, seed_o, first_o)
    d, w = integ.shared_emitted(shared, samples)
    counts = dr.zeros(mi.UInt32, 2)

    def record(depth, rng, energy, valid, hit):
        dr.scatter_add(counts, mi.UInt32(1), mi.UInt32(0))
        dr.scatter_add(counts, mi.UInt32(1), mi.UInt32(1), energy > 0)

    with dr.suspend_grad():
        integ.sample(sonar_tof._emitting(shared.path_setup, d, w), zero, samples, record)
        c = counts.numpy()
    return int(c[0]), int(c[1])


def box_scan(spps, repeats, ref_factor, big_spp):
    scene = mitsonar.load_scene(os.path.join(SCENES, "box.xml"))
    integ, sensor = scene.integrator(), scene.sensors()[0]
    ref = integ.render_histogram(scene, sensor, seed=12345, spp=ref_factor * max(spps))
    results = bench.sweep(scene, integ, sensor, ref, spps, repeats, segments=False)
    m = bench.time_to(scene, integ, sensor, ref, results, repeats)["measured"]
    out = {"pings": sensor.n_pings, "spp_to_5pct": m["spp"], "rel_l2_error": round(m["rel_l2_error"], 4),
           "ms": round(1e3 * m["seconds"], 2), "ms_min": round(1e3 * m["seconds_min"], 2),
           "target_ms": TARGET_BOX_MS, "target_over_ms": round(TARGET_BOX_MS / (1e3 * m["seconds"]), 4)}
    # segments per second at >= 1 M paths against the bare ray-casting loop, interleaved
    _, _, per_lane = bench.count_segments(scene, big_spp, seed=1, per_lane=True)
    own = []

    def render_big(r):
        t = time.perf_counter()
        integ.render_histogram(scene, sensor, seed=100 + r, spp=big_spp)
        own.append(time.perf_counter() - t)

    integ.render_histogram(scene, sensor, seed=99, spp=big_spp)
    rate, _, ceil_s = bench.ceiling(scene, big_spp, per_lane, repeats, between=render_big)
    n_int, n_vis = bench.count_segments(scene, big_spp)
    ours = (n_int + n_vis) / statistics.median(own)
    seg = {"paths": sensor.n_pings * big_spp, "segments": n_int + n_vis, "integrator_segments_per_s": round(ours),
           "bare_loop_segments_per_s": round(rate), "ratio": round(ours / rate, 4), "target": TARGET_SEGMENTS,
           "ratio_over_target": round(ours / rate / TARGET_SEGMENTS, 4)}
    return out, seg


def fixed_cost(scene, repeats, fits):
    integ, sensor = scene.integrator(), scene.sensors()[0]
    out = {}
    for name, fn in (("render_scan_spp1", lambda s: render_mod.render_scan(scene, spp=1, seed=s)),
                     ("render_histogram_spp1", lambda s: integ.render_histogram(scene, sensor, seed=s, spp=1))):
        fn(0)
        t = []
        for i in range(max(repeats, 9)):
            t0 = time.perf_counter()
            fn(1 + i)
            t.append(time.perf_counter() - t0)
        out[name] = {"ms_median": round(1e3 * statistics.median(t), 3), "ms_min": round(1e3 * min(t), 3)}
    out["sweep_intercept_ms"] = {k: round(1e3 * v, 3) for k, v in fits.items()}
    med = out["render_scan_spp1"]["ms_median"]
    out["target_ms"] = TARGET_FIXED_MS
    out["target_over_ms"] = round(TARGET_FIXED_MS / med, 4)
    return out


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--repeats", type=int, default=5)
    ap.add_argument("--ref-spp", type=int, default=8192, help="quay reference paths per beam (both emissions)")
    ap.add_argument("--big-spp", type=int, default=8192, help="box scan paths per ping for the segment ratio")
    ap.add_argument("--quick", action="store_true", help="fewer sweep points and repeats (a smoke run)")
    args = ap.parse_args(argv)
    import drjit as dr

    quay_spps = [64, 256] if args.quick else [64, 128, 256, 512]
    box_spps = [256, 1024] if args.quick else [128, 256, 512, 1024, 2048]
    repeats = 3 if args.quick else args.repeats
    out = {"cores": os.cpu_count(), "dr_threads": dr.thread_count(), "load_avg_start": os.getloadavg(),
           "variant": mi.variant(), "receiver_chain": "dr.jit"}
    scene, out["quay_frame"] = quay_frame(quay_spps, repeats, args.ref_spp)
    out["box_scan"], out["segments"] = box_scan(box_spps, repeats, 16, args.big_spp)
    fits = {f"max_depth_{d}_{e}": out["quay_frame"][f"max_depth_{d}"][e]["fit"]["overhead_s"]
            for d in (3, 1) for e in EMISSIONS}
    out["fixed_cost"] = fixed_cost(scene, repeats, fits)
    best = max((out["quay_frame"]["max_depth_3"][e] for e in EMISSIONS), key=lambda r: r["frames_per_s"])
    # What the frame at 5 % would cost if it were nothing but its rays: its segments at the bare
    # ray-casting loop's rate (measured above, box scan, same process).
    bare = out["segments"]["bare_loop_segments_per_s"]
    for depth in (3, 1):
        for e in EMISSIONS:
            row = out["quay_frame"][f"max_depth_{depth}"][e]
            integ = mi.load_dict({"type": "sonar_tof", "max_depth": depth, "emission": e})
            n_int, n_vis = shared_segments(scene, integ, row["spp_to_5pct"])
            row["segments_at_5pct"] = n_int + n_vis
            row["ray_casting_bound_frames_per_s"] = round(bare / (n_int + n_vis), 2)
    out["targets"] = {
        "quay_frames_per_s_over_85": best["frames_per_s_over_target"],
        "quay_frames_per_s_by_cpu_over_85": round(max(out["quay_frame"]["max_depth_3"][e]["frames_per_s_by_cpu"]
                                                      for e in EMISSIONS) / TARGET_FPS, 4),
        "quay_max_depth_1_frames_per_s_over_85": max(out["quay_frame"]["max_depth_1"][e]["frames_per_s_over_target"]
                                                     for e in EMISSIONS),
        "box_10ms_over_ms": out["box_scan"]["target_over_ms"],
        "segments_ratio_over_0.85": out["segments"]["ratio_over_target"],
        "fixed_2ms_over_ms": out["fixed_cost"]["target_over_ms"],
        # the bare ray casting alone at 5 % (max_depth 3, the faster emission), over 85 frames/s
        "quay_ray_casting_bound_over_85": round(best["ray_casting_bound_frames_per_s"] / TARGET_FPS, 4),
    }
    # issue 55: the frame at 5 % over the rate its rays alone allow, and the fixed cost's share
    for depth, want in ((3, 0.6), (1, 0.45)):
        rows = out["quay_frame"][f"max_depth_{depth}"]
        share = max(rows[e]["frames_per_s"] / rows[e]["ray_casting_bound_frames_per_s"] for e in EMISSIONS)
        out["targets"][f"max_depth_{depth}_frame_over_ray_bound"] = round(share, 4)
        out["targets"][f"max_depth_{depth}_frame_over_ray_bound_target"] = want
    spp1_ms = out["fixed_cost"]["render_scan_spp1"]["ms_median"]
    out["targets"]["fixed_cost_share_of_5pct_frame"] = round(spp1_ms * best["frames_per_s"] / 1e3, 4)
    out["targets"]["fixed_cost_share_target"] = 0.1
    out["load_avg_end"] = os.getloadavg()
    print(json.dumps(out, indent=1))


if __name__ == "__main__":
    main()
