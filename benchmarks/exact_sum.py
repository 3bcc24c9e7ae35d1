"""Cost of the order-independent histogram sums (``plugins/integrators/paths/exact_sum.py``) against float64 atomics.

Prints one JSON object. In this one run (shared machines are noisy), renders with the integer
words of `exact_sum.ExactBins` (the default) and with a stand-in that adds float64 atomics, as the
integrators did before, are interleaved; for each case: the median and fastest seconds per render
of each, and exact / float64. The float64 renders are not the same bytes with another thread count
(tests/test_determinism.py), the exact ones are.

Cases: ``box`` (the 200-ping mechanical box, per-row paths), ``box_fls`` (a 256-beam multibeam
frame, shared beams), ``box_bdpt`` (sonar_bdpt on the box); ``--threads`` sets Dr.Jit's pool.

Measured on 2 shared cores (load about 4), 2 threads, 9 interleaved repeats, --spp-scale 4,
median seconds exact / float64: box spp 4096 0.325 / 0.312 (1.04), box_fls spp 1024 0.097 / 0.079
(1.24: a shared echo is scored into many beams, mostly two integer atomics each), box_bdpt spp
1024 0.091 / 0.085 (1.06); at the default spp 1.39 (noisy: fastest 0.049 / 0.046), 1.18, 1.09.

Usage: python benchmarks/exact_sum.py [--repeats 7] [--threads N] [--spp-scale 1]
"""
from __future__ import annotations

import argparse
import json
import os
import statistics
import sys
import time

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
sys.path.insert(0, ROOT)

CASES = {   # name: (scene, integrator properties, spp)
    "box": ("box.xml", {"type": "sonar_tof"}, 1024),
    "box_fls": ("box_fls.xml", {"type": "sonar_tof", "share_beams": True}, 256),
    "box_bdpt": ("box.xml", {"type": "sonar_bdpt", "max_depth": 3}, 256),
}


class Float64Bins:
    """`exact_sum.ExactBins`' interface over a float64 histogram with atomic adds (the old sums)."""

    def __init__(self, n, mode=None):
        import drjit as dr
        import mitsuba as mi

        self.hist = dr.zeros(mi.Float64, int(n))
        self.words = self.hist
        self.mode = dr.ReduceMode.Direct if mode is None else mode

    def reserve(self, adds):
        pass

    def add(self, values, index, active=True, mode=None):
        import drjit as dr
        import mitsuba as mi

        dr.scatter_add(self.hist, mi.Float64(values), index, active, mode=self.mode if mode is None else mode)

    def total(self):
        return self.hist

    def numpy(self):
        return self.hist.numpy()


def main(argv=None):
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--repeats", type=int, default=7)
    p.add_argument("--threads", type=int, default=None)
    p.add_argument("--spp-scale", type=float, default=1.0, help="multiplies every case's spp")
    args = p.parse_args(argv)

    import drjit as dr
    import mitsuba as mi

    import mitsonar

    mitsonar.ensure_variant()
    from mitsonar.plugins.integrators import sonar_bdpt, sonar_tof
    from mitsonar.plugins.integrators.paths import exact_sum

    if args.threads:
        dr.set_thread_count(args.threads)
    homes = [sonar_tof, sonar_bdpt]
    out = {"threads": dr.thread_count(), "repeats": args.repeats, "cases": {}}
    for name, (xml, props, spp) in CASES.items():
        spp = max(1, int(spp * args.spp_scale))
        scene = mitsonar.load_scene(os.path.join(ROOT, "scenes_xml", xml))
        integs = {}
        for kind in ("exact", "float64"):
            # a setting of its own per kind: frozen passes (plugins/integrators/paths/frozen_pass.py) are recorded
            # per integrator setting, so each kind replays its own recording
            integs[kind] = mi.load_dict(props)
            integs[kind].bench_sums = kind
        times = {"exact": [], "float64": []}
        for r in range(args.repeats + 1):          # the first round compiles the kernels
            for kind, cls in (("exact", exact_sum.ExactBins), ("float64", Float64Bins)):
                for m in homes:
                    m.ExactBins = cls
                t0 = time.perf_counter()
                integs[kind].render_histogram(scene, 0, seed=r, spp=spp)
                if r:
                    times[kind].append(time.perf_counter() - t0)
        for m in homes:
            m.ExactBins = exact_sum.ExactBins
        med = {k: statistics.median(v) for k, v in times.items()}
        out["cases"][name] = {"spp": spp, "median_s": med, "fastest_s": {k: min(v) for k, v in times.items()},
                              "exact_over_float64": med["exact"] / med["float64"]}
    print(json.dumps(out, indent=1))


if __name__ == "__main__":
    main()
