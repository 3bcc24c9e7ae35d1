"""Frame overhead: where the time of one `render_scan` frame goes, stage by stage (issue "Frame overhead").

Prints one JSON object. Per case (the 512-beam quay-wall frame, the 200-ping box scan, a
side-scan ping pair, a one-ping mechanical "Ping360-like" head) and per chain (``fast``: the
vectorised receiver chain (`mitsonar.receiver.fastchain`) and the speckle field cache, the default; ``reference``: the
straightforward chain, ``electronics.FAST = False`` and ``speckle.CACHE_SIZE = 0``), frames are
rendered interleaved (reference, fast, reference, ...; the machine is shared) and each stage is
timed by wrapping the function that does it:

  python_setup    everything not below: argument checks, the integrator's `setup`, the shared
                  frame (`shared_beams.SharedFrame`), metadata
  freeze_key      `frozen_pass.Context`: the walk that builds the recording's key
  emit            `frozen_pass.emitted`: the kernel drawing the emitted directions
  replay          `frozen_pass.run` up to the launch: the frozen recording's replay (Python side)
  kernels         waiting for the launched kernels: ray casting + histogram scatter + the exact
                  sums' conversion (`dr.sync_thread` after `run`); split with Dr.Jit's kernel
                  history (``kernel_ms``) and, for the quay frame, the bare ray-casting loop of
                  benchmarks/render.py over the same number of segments (``ray_cast_estimate``)
  copy_out        the histogram's ``.numpy()`` after the kernels finished
  speckle         `Electronics.scene_speckle`;  electronics: `Electronics.apply`
  scan            the `Scan` construction;  save: ``Scan.save`` to a temporary .npz

and the process's user and system CPU time, minor/major page faults and voluntary/involuntary
context switches per frame (``resource.getrusage``). ``system_time`` explains the system time
with measurements: the same frames with glibc keeping freed memory (``MALLOC_MMAP_THRESHOLD_``,
``MALLOC_TRIM_THRESHOLD_`` in a child process: page faults and system time fall if they came
from NumPy's large temporaries being mapped afresh), with Dr.Jit's allocation cache flushed after
every frame (``dr.flush_malloc_cache``), and with one Dr.Jit thread instead of the default.

``live_ping`` (also alone, with ``quay_frame_spp1``, by ``--fixed-only``): the fixed cost of
the live heads' one-row ping (harbour.xml's mechanical head, 16 paths, a new bearing each ping)
and of the quay frame at spp 1, stage by stage, for the reference chain, the fast chain and the
fast chain without its noise prefetch (`mitsonar.receiver.fastchain.PREFETCH`), interleaved.

Usage: python benchmarks/frame_profile.py [--frames 12] [--spp 64] [--ref-factor 16] [--quick] [--fixed-only]
"""
from __future__ import annotations

import argparse
import contextlib
import itertools
import json
import math
import os
import resource
import statistics
import subprocess
import sys
import tempfile
import time

import numpy as np

import mitsonar  # noqa: F401  (selects the variant and registers the plugins)
import drjit as dr  # noqa: E402
import mitsuba as mi  # noqa: E402

from mitsonar.plugins import module  # noqa: E402
from mitsonar.receiver import electronics as electronics_mod  # noqa: E402
from mitsonar.receiver import speckle as speckle_mod  # noqa: E402
from mitsonar.sim import render as render_mod  # noqa: E402
from mitsonar.sim.scene import load_scene  # noqa: E402

HERE = os.path.dirname(os.path.abspath(__file__))
SCENES = os.path.join(HERE, "..", "scenes_xml")
# name -> (scene file, {XML element text: replacement}, spp, max_depth or None)
CASES = {
    "quay_wall_512_beams": ("quay_wall.xml", {}, None, None),
    "box_scan": ("box.xml", {}, 256, None),
    "sidescan_ping_pair": ("wreck_sidescan.xml", {'name="n_pings" value="250"': 'name="n_pings" value="1"'}, 256, None),
    "ping360_like_ping": ("box.xml", {'name="n_pings" value="200"': 'name="n_pings" value="1"'}, 256, None),
}
STAGES = ("python_setup", "freeze_key", "emit", "replay", "kernels", "copy_out", "speckle", "electronics",
          "scan", "save")


class Stages:
    """Seconds per stage of the frame being timed (wrappers installed by `instrument`)."""

    def __init__(self):
        self.t = dict.fromkeys(STAGES, 0.0)

    def wrap(self, owner, name, stage):
        orig = getattr(owner, name)

        def timed(*a, **k):
            t = time.perf_counter()
            try:
                return orig(*a, **k)
            finally:
                self.t[stage] += time.perf_counter() - t

        setattr(owner, name, timed)
        return orig


@contextlib.contextmanager
def instrument(stages):
    """Time each stage of `render_scan` into ``stages`` (functions wrapped, restored after)."""
    fp = module("frozen_pass")
    E = electronics_mod.Electronics
    saved = []
    saved.append((fp, "emitted", stages.wrap(fp, "emitted", "emit")))
    saved.append((E, "apply", stages.wrap(E, "apply", "electronics")))
    saved.append((E, "scene_speckle", stages.wrap(E, "scene_speckle", "speckle")))
    saved.append((render_mod, "Scan", stages.wrap(render_mod, "Scan", "scan")))
    orig_ctx_init = fp.Context.__init__

    def ctx_init(self, *a, **k):
        t = time.perf_counter()
        orig_ctx_init(self, *a, **k)
        stages.t["freeze_key"] += time.perf_counter() - t

    orig_run = fp.run

    class Out:
        def __init__(self, value):
            self.value = value

        def numpy(self):
            t = time.perf_counter()
            try:
                return self.value.numpy()
            finally:
                stages.t["copy_out"] += time.perf_counter() - t

    def run(*a, **k):
        t0 = time.perf_counter()
        k0 = stages.t["freeze_key"]
        out = orig_run(*a, **k)
        t1 = time.perf_counter()
        dr.eval(out)
        dr.sync_thread()
        t2 = time.perf_counter()
        stages.t["replay"] += (t1 - t0) - (stages.t["freeze_key"] - k0)
        stages.t["kernels"] += t2 - t1
        return Out(out)

    fp.Context.__init__ = ctx_init
    fp.run = run
    try:
        yield
    finally:
        fp.Context.__init__ = orig_ctx_init
        fp.run = orig_run
        for owner, name, orig in saved:
            setattr(owner, name, orig)


def set_chain(fast):
    electronics_mod.FAST = fast
    speckle_mod.CACHE_SIZE = 4 if fast else 0   # the reference neither reads nor fills the cache


def load_case(name):
    path, edits, _, _ = CASES[name]
    full = os.path.join(SCENES, path)
    if not edits:
        return load_scene(full)
    text = open(full).read()
    for a, b in edits.items():
        assert a in text, (path, a)
        text = text.replace(a, b)
    with tempfile.NamedTemporaryFile("w", suffix=".xml", dir=SCENES, delete=False) as f:
        f.write(text)
    try:
        return load_scene(f.name)
    finally:
        os.unlink(f.name)


def frame(scene, spp, seed, save_dir, stages=None, after=None):
    """One frame: render_scan + save; wall seconds (and stages filled when given)."""
    t = time.perf_counter()
    scan = render_mod.render_scan(scene, spp=spp, seed=seed)
    t_save = time.perf_counter()
    scan.save(os.path.join(save_dir, "frame.npz"))
    end = time.perf_counter()
    if stages is not None:
        stages.t["save"] += end - t_save
    if after is not None:
        after()
    return end - t, scan


def usage():
    r = resource.getrusage(resource.RUSAGE_SELF)
    return np.array([r.ru_utime, r.ru_stime, r.ru_minflt, r.ru_majflt, r.ru_nvcsw, r.ru_nivcsw])


USAGE_KEYS = ("user_ms", "system_ms", "minflt", "majflt", "nvcsw", "nivcsw")


def per_frame(u, n):
    u = u / n
    return {k: round(float(v * (1e3 if k.endswith("_ms") else 1)), 3) for k, v in zip(USAGE_KEYS, u)}


def profile_case(name, frames, spp_quay, save_dir):
    scene = load_case(name)
    spp = CASES[name][2] or spp_quay
    sensor = scene.sensors()[0]
    out = {"rows": int(sensor.n_pings), "bins": int(sensor.n_bins), "spp": spp}
    scans = {}
    for fast in (False, True):       # compile and record both before timing
        set_chain(fast)
        scans[fast] = frame(scene, spp, 7, save_dir)[1]
    out["identical_bytes"] = bool(np.array_equal(scans[False].data, scans[True].data)
                                  and np.array_equal(scans[False].intensity, scans[True].intensity))
    acc = {f: {"wall": [], "stages": dict.fromkeys(STAGES, 0.0), "usage": np.zeros(6)} for f in (False, True)}
    for i in range(frames):
        for fast in (False, True):
            set_chain(fast)
            st = Stages()
            with instrument(st):
                u0 = usage()
                wall, _ = frame(scene, spp, 100 + i, save_dir, st)
                acc[fast]["usage"] += usage() - u0
            accounted = sum(v for k, v in st.t.items() if k != "python_setup")
            st.t["python_setup"] = wall - accounted
            acc[fast]["wall"].append(wall)
            for k in STAGES:
                acc[fast]["stages"][k] += st.t[k]
    for fast in (False, True):
        a = acc[fast]
        out["fast" if fast else "reference"] = {
            "frame_ms_median": round(1e3 * statistics.median(a["wall"]), 2),
            "frame_ms_min": round(1e3 * min(a["wall"]), 2),
            "stages_ms_mean": {k: round(1e3 * v / frames, 3) for k, v in a["stages"].items()},
            "cpu_per_frame": per_frame(a["usage"], frames),
        }
    r, f = out["reference"], out["fast"]
    out["reference_over_fast"] = {
        "wall_median": round(r["frame_ms_median"] / f["frame_ms_median"], 3),
        "cpu_user_plus_system": round((r["cpu_per_frame"]["user_ms"] + r["cpu_per_frame"]["system_ms"])
                                      / max(f["cpu_per_frame"]["user_ms"] + f["cpu_per_frame"]["system_ms"], 1e-9), 3),
    }
    out["fast"]["frames_per_s_median"] = round(1e3 / f["frame_ms_median"], 2)
    out["fast"]["frames_per_s_cpu"] = round(
        1e3 * (os.cpu_count() or 1) / max(f["cpu_per_frame"]["user_ms"] + f["cpu_per_frame"]["system_ms"], 1e-9), 2)
    return scene, out


def kernel_split(scene, spp):
    """Dr.Jit's own execution time per kernel of one frame (kernel history), by kind."""
    dr.set_flag(dr.JitFlag.KernelHistory, True)
    try:
        dr.kernel_history()
        render_mod.render_scan(scene, spp=spp, seed=3)
        hist = [k for k in dr.kernel_history() if k["type"] == dr.KernelType.JIT]
    finally:
        dr.set_flag(dr.JitFlag.KernelHistory, False)
    return [{"ms": round(h.get("execution_time", 0.0), 3), "size": int(h.get("size", 0)),
             "operations": int(h.get("operation_count", 0)), "compiled": not h.get("cache_hit")} for h in hist]


def ray_cast_estimate(scene, spp):
    """The frame's segments (per-row paths; the shared frame traces as many paths) at the bare
    ray-casting loop's rate (benchmarks/render.py `ceiling`): the part of the kernels that is ray casting."""
    sys.path.insert(0, HERE)
    import render as bench_render  # benchmarks/render.py

    segs, shadows, per_lane = bench_render.count_segments(scene, spp, per_lane=True)
    rate, _, _ = bench_render.ceiling(scene, spp, per_lane, 3)
    return {"segments": segs + shadows, "bare_segments_per_s": round(rate, 0),
            "ray_cast_ms": round(1e3 * (segs + shadows) / rate, 3)}


def relative_error(scene, spp, ref_factor):
    ref = render_mod.render_scan(scene, spp=spp * ref_factor, seed=999).intensity.astype(np.float64)
    errs = []
    for s in range(3):
        x = render_mod.render_scan(scene, spp=spp, seed=s).intensity.astype(np.float64)
        errs.append(float(np.linalg.norm(x - ref) / np.linalg.norm(ref)))
    return round(statistics.median(errs), 4)


def fixed_cost(scene, frames):
    """The cost of a frame as spp -> 0: render_scan and the integrator's render_histogram alone at
    spp 1 (medians, ms; the fast chain), and CPU ms per render_scan frame."""
    integ, sensor = scene.integrator(), scene.sensors()[0]
    out = {}
    for name, fn in (("render_scan_spp1", lambda s: render_mod.render_scan(scene, spp=1, seed=s)),
                     ("render_histogram_spp1", lambda s: integ.render_histogram(scene, sensor, seed=s, spp=1))):
        fn(0)
        t, u0 = [], usage()
        for i in range(frames):
            t0 = time.perf_counter()
            fn(1 + i)
            t.append(time.perf_counter() - t0)
        u = per_frame(usage() - u0, frames)
        out[name] = {"ms_median": round(1e3 * statistics.median(t), 3), "ms_min": round(1e3 * min(t), 3),
                     "cpu_ms": round(u["user_ms"] + u["system_ms"], 3)}
    return out


def set_mode(mode):
    """``reference``, ``fast`` or ``fast_no_prefetch`` (the fast chain drawing its receiver noise
    after the render instead of during it, `fastchain.PREFETCH`)."""
    from mitsonar.receiver import fastchain

    set_chain(mode != "reference")
    if hasattr(fastchain, "PREFETCH"):
        fastchain.PREFETCH = mode == "fast"


def staged(go, frames, modes=("reference", "fast", "fast_no_prefetch")):
    """``go(seed)`` timed ``frames`` times per mode (`set_mode`), the modes interleaved, each
    stage as in `profile_case` (no saving): medians of the wall time and mean ms per stage."""
    for mode in modes:               # compile and fill the caches before timing
        set_mode(mode)
        go(1)
    acc = {m: {"wall": [], "stages": {k: [] for k in STAGES}, "usage": np.zeros(6)} for m in modes}
    for i in range(frames):
        for mode in modes:
            set_mode(mode)
            st = Stages()
            with instrument(st):
                u0 = usage()
                t = time.perf_counter()
                go(100 + i)
                wall = time.perf_counter() - t
                acc[mode]["usage"] += usage() - u0
            st.t["python_setup"] = wall - sum(v for k, v in st.t.items() if k != "python_setup")
            acc[mode]["wall"].append(wall)
            for k in STAGES:
                acc[mode]["stages"][k].append(st.t[k])
    set_mode("fast")
    out = {}
    for mode in modes:
        a = acc[mode]
        w = sorted(a["wall"])
        out[mode] = {
            "ms_median": round(1e3 * statistics.median(w), 3), "ms_min": round(1e3 * w[0], 3),
            "ms_quartiles": [round(1e3 * w[len(w) // 4], 3), round(1e3 * w[(3 * len(w)) // 4], 3)],
            "stages_ms_mean": {k: round(1e3 * sum(v) / frames, 3) for k, v in a["stages"].items() if k != "save"},
            "stages_ms_median": {k: round(1e3 * statistics.median(v), 3) for k, v in a["stages"].items()
                                 if k != "save"},
            "cpu_per_frame": per_frame(a["usage"], frames)}
    return out


def live_ping_fixed_cost(frames, spp=16):
    """The live heads' ping (issue "live"): one row of scenes_xml/harbour.xml's mechanical head
    (`mitsonar.devices.live.live_scene`), ``spp`` paths, from the mount turned to a new bearing
    every ping (1.8 deg steps, as `PingRenderer.render` does): the pose changes every ping, so
    the speckle field of each ping is new. Stages per chain, interleaved."""
    from mitsonar.devices.live import live_scene
    from mitsonar.geometry.frames import bearing_rotation

    scene = live_scene(os.path.join(SCENES, "harbour.xml"))
    sonar = scene.sensors()[0]
    mount = np.array(sonar.to_world_np, dtype=np.float64)

    turns = itertools.count()

    def go(i):   # every call a new bearing (no mode finds another's field in the cache)
        pose = mount @ bearing_rotation(math.radians(1.8 * (next(turns) % 200)))
        return render_mod.render_scan(scene, spp=spp, seed=i, pose=pose, sensor=sonar)

    return {"rows": 1, "bins": int(sonar.n_bins), "spp": spp, **staged(go, frames)}


def quay_fixed_cost_stages(frames):
    """The 512-beam quay frame at spp 1 (the fixed cost of a frame, spp -> 0), stage by stage."""
    scene = load_case("quay_wall_512_beams")
    return {"rows": int(scene.sensors()[0].n_pings), "spp": 1,
            **staged(lambda i: render_mod.render_scan(scene, spp=1, seed=i), frames)}


CHILD = "MITSONAR_FRAME_PROFILE_CHILD"


def child_usage(frames, spp, extra_env, flush=False, threads=None):
    """getrusage per frame of ``frames`` quay-wall frames in a fresh process (after 2 warm-up frames)."""
    env = {**os.environ, **extra_env, CHILD: json.dumps({"frames": frames, "spp": spp, "flush": flush,
                                                         "threads": threads})}
    res = subprocess.run([sys.executable, os.path.abspath(__file__)], env=env, capture_output=True, text=True,
                         check=True)
    return json.loads(res.stdout.strip().splitlines()[-1])


def child_main(opts):
    if opts["threads"]:
        dr.set_thread_count(opts["threads"])
    scene = load_case("quay_wall_512_beams")
    with tempfile.TemporaryDirectory() as d:
        after = dr.flush_malloc_cache if opts["flush"] else None
        for s in range(2):
            frame(scene, opts["spp"], s, d)
        u0 = usage()
        t = time.perf_counter()
        for i in range(opts["frames"]):
            frame(scene, opts["spp"], 10 + i, d, after=after)
        wall = (time.perf_counter() - t) / opts["frames"]
        u = per_frame(usage() - u0, opts["frames"])
    print(json.dumps({**u, "wall_ms": round(1e3 * wall, 2), "threads": dr.thread_count()}))


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--frames", type=int, default=12)
    ap.add_argument("--spp", type=int, default=320,
                    help="quay-wall frame's paths per beam (320: about 5 %% relative error, shared beams, max_depth 3)")
    ap.add_argument("--ref-factor", type=int, default=16)
    ap.add_argument("--quick", action="store_true", help="skip the error, ray-casting and child-process parts")
    ap.add_argument("--fixed-only", action="store_true",
                    help="only the fixed costs: the live one-row harbour ping (spp 16) and the quay frame at spp 1")
    args = ap.parse_args(argv)
    if args.fixed_only:
        print(json.dumps({"cores": os.cpu_count(), "load_avg_start": os.getloadavg(),
                          "live_ping": live_ping_fixed_cost(args.frames),
                          "quay_frame_spp1": quay_fixed_cost_stages(args.frames),
                          "load_avg_end": os.getloadavg()}, indent=1))
        return
    out = {"cores": os.cpu_count(), "dr_threads": dr.thread_count(), "load_avg_start": os.getloadavg(),
           "cases": {}}
    with tempfile.TemporaryDirectory() as d:
        for name in CASES:
            scene, res = profile_case(name, args.frames, args.spp, d)
            res["kernels"] = kernel_split(scene, res["spp"])
            if name == "quay_wall_512_beams" and not args.quick:
                set_chain(True)
                res["relative_error"] = relative_error(scene, res["spp"], args.ref_factor)
                for depth in (1,):
                    t = []
                    for i in range(args.frames):
                        t0 = time.perf_counter()
                        render_mod.render_scan(scene, spp=res["spp"], seed=50 + i, max_depth=depth)
                        t.append(time.perf_counter() - t0)
                    res[f"max_depth_{depth}_frame_ms_median"] = round(1e3 * statistics.median(t), 2)
                res["ray_cast_estimate"] = ray_cast_estimate(scene, res["spp"])
                res["fixed_cost"] = fixed_cost(scene, args.frames)
            out["cases"][name] = res
    out["live_ping"] = live_ping_fixed_cost(args.frames)
    set_chain(True)
    if not args.quick:
        n = max(4, args.frames)
        big = {"MALLOC_MMAP_THRESHOLD_": str(1 << 30), "MALLOC_TRIM_THRESHOLD_": str(1 << 31)}
        st = {}
        for label, env, flush, threads in (("default", {}, False, None), ("glibc_keeps_freed_memory", big, False, None),
                                           ("dr_flush_malloc_cache_each_frame", {}, True, None),
                                           ("one_dr_thread", {}, False, 1)):
            for chain in ("reference", "fast"):
                e = dict(env)
                if chain == "reference":
                    e["MITSONAR_FRAME_PROFILE_REFERENCE"] = "1"
                st[f"{label}/{chain}"] = child_usage(n, args.spp, e, flush, threads)
        out["system_time"] = st
    out["load_avg_end"] = os.getloadavg()
    print(json.dumps(out, indent=1))


if __name__ == "__main__":
    if CHILD in os.environ:
        if os.environ.get("MITSONAR_FRAME_PROFILE_REFERENCE"):
            set_chain(False)
        child_main(json.loads(os.environ[CHILD]))
    else:
        main()
