"""Gradient benchmark: cost of a forward+backward pass against a forward render, and memory against spp.

Prints one JSON object. Everything is measured in this one run (shared machines are noisy):
  * ``time``: on the box scene (``scenes_xml/box.xml``, 200 pings x 500 bins, max_depth 5), the
    seconds of ``mi.render`` without gradients (the forward render) and of ``mi.render`` with
    gradients enabled on the walls' ``diffuse``/``specular`` and the head's ``to_world`` followed by
    ``dr.backward`` of a loss on the scan (forward+backward: the primal render, then the path
    replay's two passes), median of repeats with the kernels compiled; ``ratio`` = the second / the
    first. Target (issue "Differentiable scans"): <= 3.
  * ``memory``: for each spp, the peak memory (MiB) of a fresh process that loads the box and runs
    one forward+backward pass, and of one that runs the forward render only: Dr.Jit's allocation
    watermark and the resident set. The path replay stores nothing per path (a path's state lives
    in the loop's registers) and gradient passes hold at most 2^20 lanes, so the peak must not
    grow with spp once a pass is full; ``memory_growth`` = largest / smallest Dr.Jit peak of the
    forward+backward passes among the spp that fill a pass (``spp_per_full_pass`` and up).
    Target: flat.

Usage: python benchmarks/gradients.py [--spp 2048] [--repeats 3] [--memory-spp 1024,8192,32768]
"""
from __future__ import annotations

import argparse
import json
import os
import platform
import resource
import statistics
import subprocess
import sys
import time

HERE = os.path.dirname(os.path.abspath(__file__))
BOX = os.path.join(HERE, "..", "scenes_xml", "box.xml")


def _scene_and_params(pings=200):
    import drjit as dr
    import mitsuba as mi

    import mitsonar
    from mitsonar.sim.render import scan_parameters

    scene = mitsonar.load_scene(BOX)
    keys = [k for k in scan_parameters(scene).keys() if k.endswith((".diffuse", ".specular"))] + ["sonar.to_world"]
    params = scan_parameters(scene, keys)
    return scene, params, keys, dr, mi


def one_pass(pings, spp, grad, seed=0):
    """Seconds of one forward render (``grad`` False) or one forward+backward pass."""
    scene, params, keys, dr, mi = _scene_and_params(pings)
    if grad:
        for k in keys:
            dr.enable_grad(params[k])
        params.update()
    t0 = time.perf_counter()
    if grad:
        img = mi.render(scene, params, spp=spp, seed=seed)
        loss = dr.sum(dr.square(img.array))
        dr.backward(loss)
        dr.eval([dr.grad(params[k]) for k in keys])
    else:
        img = mi.render(scene, spp=spp, seed=seed)
        dr.eval(img)
    dr.sync_thread()
    return time.perf_counter() - t0


def timing(pings, spp, repeats):
    one_pass(pings, spp, False)  # compile
    one_pass(pings, spp, True)
    fwd = statistics.median(one_pass(pings, spp, False, seed=r) for r in range(repeats))
    both = statistics.median(one_pass(pings, spp, True, seed=r) for r in range(repeats))
    return {"spp": spp, "pings": pings, "forward_s": fwd, "forward_backward_s": both, "ratio": both / fwd,
            "target_ratio": 3.0}


def peak_mib(spp, grad):
    """Peak memory (MiB) of a fresh process doing one pass: Dr.Jit's own allocations (its
    watermark for the backend in use) and the resident set (which includes LLVM compiling)."""
    code = (f"import sys, resource; sys.path.insert(0, {HERE!r}); import gradients as g; "
            f"import drjit as dr, mitsuba as mi; g.one_pass(200, {spp}, {grad}); "
            f"b = dr.backend_v(mi.Float); "
            f"print(dr.detail.malloc_watermark(b), resource.getrusage(resource.RUSAGE_SELF).ru_maxrss)")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    jit, rss = out.stdout.strip().splitlines()[-1].split()
    return int(jit) / 2**20, int(rss) / 1024.0


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--spp", type=int, default=2048)
    ap.add_argument("--repeats", type=int, default=3)
    ap.add_argument("--memory-spp", default="1024,8192,32768")
    args = ap.parse_args(argv)
    t = timing(200, args.spp, args.repeats)
    mem = []
    for spp in [int(s) for s in args.memory_spp.split(",")]:
        (fb_jit, fb_rss), (f_jit, f_rss) = peak_mib(spp, True), peak_mib(spp, False)
        mem.append({"spp": spp, "paths": spp * 200, "forward_backward_jit_peak_mib": fb_jit,
                    "forward_backward_rss_peak_mib": fb_rss, "forward_jit_peak_mib": f_jit,
                    "forward_rss_peak_mib": f_rss})
    # Memory is flat once a gradient pass is full (GRADIENT_LANES_PER_PASS lanes): compare those.
    from mitsonar.plugins.integrators import common

    full = common.GRADIENT_LANES_PER_PASS // 200
    peaks = [m["forward_backward_jit_peak_mib"] for m in mem if m["spp"] >= full] or \
        [m["forward_backward_jit_peak_mib"] for m in mem]
    result = {"benchmark": "gradients", "scene": "scenes_xml/box.xml", "machine": platform.machine(),
              "cpus": os.cpu_count(), "time": t, "memory": mem,
              "spp_per_full_pass": full, "memory_growth": max(peaks) / min(peaks),
              "target_memory": "flat (growth ~1) once passes are full",
              "self_peak_mib": resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0}
    print(json.dumps(result, indent=1))


if __name__ == "__main__":
    main()
