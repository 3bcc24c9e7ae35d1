"""Ray-tube amplitudes in the refracted renderer (issue 58): their cost and what they change.

One 256-beam echo-sounder ping over a flat seabed (and, with ``max_depth`` 2, its second bounces
through eigenrays) through the 20-sample thermocline of ``benchmarks/svp.py``, rendered with the
way back weighed by its ray tube (`refraction.RAY_TUBE` True, the default) and by ``1 / L^2``
(False, before), interleaved in one run. Prints one JSON object: per setting the best seconds of
``--repeats`` warm renders, ``time_ratio`` (tube / 1 / L^2; the target is under 1.3) and the echo
level change it makes (median and max over beams of the peak's dB difference, same seed).

Usage: python benchmarks/ray_tube.py [--spp 1024] [--repeats 3] [--depth 40] [--max-depth 2]
"""
from __future__ import annotations

import argparse
import json
import math
import os
import platform
import sys
import time

import numpy as np

import mitsonar
from mitsonar.plugins.integrators.paths import refraction
from mitsonar.scenes import echosounders

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
from svp import HEAD, profile20  # noqa: E402


def scene_for(head, depth, max_depth):
    floor = np.diag([2000.0, 2000.0, 1.0, 1.0])
    floor[2, 3] = -depth
    m = " ".join(f"{v:.17g}" for v in floor.ravel())
    xml = (f'<scene version="3.0.0"><integrator type="sonar_tof"><integer name="max_depth" value="{max_depth}"/>'
           f'</integrator>{echosounders.sonar_xml(head)}'
           f'<shape type="rectangle"><transform name="to_world"><matrix value="{m}"/></transform>'
           '<bsdf type="acoustic"><float name="diffuse" value="0.5"/><float name="specular" value="0.2"/></bsdf>'
           '</shape></scene>')
    return mitsonar.load_scene(xml)


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--spp", type=int, default=1024)
    ap.add_argument("--repeats", type=int, default=3)
    ap.add_argument("--depth", type=float, default=40.0)
    ap.add_argument("--max-depth", type=int, default=2)
    args = ap.parse_args(argv)
    head = echosounders.configure("r2sonic_2024", n_beams=256, range_max=100.0, bin_width=0.1)
    pose = np.array(head.mount, float)
    pose[2, 3] = -HEAD
    svp = profile20()
    scene = scene_for(head, args.depth, args.max_depth)
    settings = {"tube": True, "one_over_l2": False}
    best, scans = {k: math.inf for k in settings}, {}
    try:
        for k, on in settings.items():                      # compile both
            refraction.RAY_TUBE = on
            mitsonar.render_scan(scene, spp=args.spp, seed=0, pose=pose, sound_speed_profile=svp)
        for r in range(args.repeats):
            for k, on in settings.items():
                refraction.RAY_TUBE = on
                t0 = time.perf_counter()
                scans[k] = mitsonar.render_scan(scene, spp=args.spp, seed=1, pose=pose, sound_speed_profile=svp)
                best[k] = min(best[k], time.perf_counter() - t0)
    finally:
        refraction.RAY_TUBE = True
    peak = {k: scans[k].intensity.astype(float).max(axis=1) for k in settings}
    ok = (peak["tube"] > 0) & (peak["one_over_l2"] > 0)
    diff = 10.0 * np.log10(peak["tube"][ok] / peak["one_over_l2"][ok])
    print(json.dumps(dict(spp=args.spp, beams=256, depth=args.depth, max_depth=args.max_depth, head_depth=HEAD,
                          machine=platform.machine(), python=sys.version.split()[0], cpus=os.cpu_count(),
                          seconds=best, time_ratio=best["tube"] / best["one_over_l2"],
                          peak_change_db=dict(median=float(np.median(diff)), max=float(np.max(np.abs(diff))))),
                     indent=1))


if __name__ == "__main__":
    main()
