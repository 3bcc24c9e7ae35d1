"""Cost of the order-independent histogram sums (``plugins/integrators/paths/exact_sum.py``) against float64 atomics.

Prints one JSON object. In this one run (shared machines are noisy), renders are interleaved with
three sums: ``exact`` (the default: `exact_sum.ExactBins` in a window of its words, 0-4 unless a
pass reaches above, `exact_sum.run_pass`), ``exact_nine`` (all nine words and the non-finite count, 80
bytes per bin: the sums before windows, `sonar_tof` with its windows ended) and ``float64`` (a
stand-in that adds float64 atomics, as the integrators did before exact sums); for each case: the
median and fastest seconds per render of each, exact / float64, exact / exact_nine, and the bytes
per bin of each kind's last pass. The float64 renders are not the same bytes with another thread
count (tests/test_determinism.py), the exact ones are, and ``exact`` and ``exact_nine`` are the
same bits (``same_bits``).

Cases: ``box`` (the 200-ping mechanical box, per-row paths), ``box_fls`` (a 256-beam multibeam
frame, shared beams), ``box_bdpt`` (sonar_bdpt on the box, which keeps nine words),
``quay_frame`` (the 512-beam x 500-bin quay frame of `frame_targets.py` with its own integrator);
``--threads`` sets Dr.Jit's pool.

``sum_stage``: the sums alone for the quay frame's 256 000 bins, interleaved, median
milliseconds: zero the words, add 472 000 float32 echoes (the frame's segments at 5 %, energies
spread over 1e-20..1e2) and convert the words to float64 (``.numpy()``), with nine words and with
`exact_sum.DEFAULT`, the window `exact_sum.run_pass` sums in.

Measured on 2 shared cores (load about 4), 2 threads, 9 interleaved repeats, --spp-scale 4,
median seconds exact / float64: box spp 4096 0.325 / 0.312 (1.04), box_fls spp 1024 0.097 / 0.079
(1.24: a shared echo is scored into many beams, mostly two integer atomics each), box_bdpt spp
1024 0.091 / 0.085 (1.06); at the default spp 1.39 (noisy: fastest 0.049 / 0.046), 1.18, 1.09.

Usage: python benchmarks/exact_sum.py [--repeats 7] [--threads N] [--spp-scale 1] [--only NAME]
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

CASES = {   # name: (scene, integrator properties (None: the scene's own), spp)
    "box": ("box.xml", {"type": "sonar_tof"}, 1024),
    "box_fls": ("box_fls.xml", {"type": "sonar_tof", "share_beams": True}, 256),
    "box_bdpt": ("box.xml", {"type": "sonar_bdpt", "max_depth": 3}, 256),
    "quay_frame": ("quay_wall.xml", None, 250),
}
KINDS = ("exact", "exact_nine", "float64")


class Float64Bins:
    """`exact_sum.ExactBins`' interface over a float64 histogram with atomic adds (the old sums)."""

    def __init__(self, n, mode=None, window=None):
        import drjit as dr
        import mitsuba as mi

        self.hist = dr.zeros(mi.Float64, int(n))
        self.words = self.hist
        self.window = None   # `exact_sum.run_pass` learns nothing from it
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

    def bytes_per_bin(self):
        return 8.0


def _recording(cls):
    """``cls`` that keeps the bytes per bin of the last sums made (`ExactBins.bytes_per_bin`)."""
    class Recording(cls):
        last = None

        def __init__(self, n, *args, **kwargs):
            super().__init__(n, *args, **kwargs)
            type(self).last = self.bytes_per_bin()
    return Recording


def sum_stage(repeats):
    """Median milliseconds of zero + add + convert for the quay frame's bins, nine words and window."""
    import drjit as dr
    import mitsuba as mi
    import numpy as np

    from mitsonar.plugins.integrators.paths import exact_sum

    n, m = 512 * 500, 472_000
    rng = np.random.default_rng(0)
    values = mi.Float(10.0 ** rng.uniform(-20, 2, m).astype(np.float32))
    index = mi.UInt32(rng.integers(0, n, m).astype(np.uint32))
    window = exact_sum.DEFAULT   # the window `exact_sum.run_pass` sums in
    probe = exact_sum.ExactBins(n, window=window)
    probe.add(values, index)
    assert probe.missed() == 0, "the echoes reach above the default window"
    times = {"nine": [], "window": []}
    for i in range(repeats + 1):
        for kind, w in (("nine", None), ("window", window)):
            t0 = time.perf_counter()
            h = exact_sum.ExactBins(n, window=w)
            h.add(values, index)
            h.total().numpy()
            if i:
                times[kind].append(1e3 * (time.perf_counter() - t0))
            bpb = h.bytes_per_bin()
            times.setdefault("bytes_per_bin", {})[kind] = bpb
    return {"bins": n, "adds": m, "window": list(window), "bytes_per_bin": times.pop("bytes_per_bin"),
            "median_ms": {k: round(statistics.median(v), 3) for k, v in times.items()},
            "fastest_ms": {k: round(min(v), 3) for k, v in times.items()}}


def main(argv=None):
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--repeats", type=int, default=7)
    p.add_argument("--threads", type=int, default=None)
    p.add_argument("--spp-scale", type=float, default=1.0, help="multiplies every case's spp")
    p.add_argument("--only", default="", help="the cases whose name holds this (sum_stage always runs)")
    args = p.parse_args(argv)

    import drjit as dr
    import mitsuba as mi

    import mitsonar

    mitsonar.ensure_variant()   # the variant is chosen on first use: before the plugin modules
    from mitsonar.plugins.integrators import sonar_bdpt, sonar_tof
    from mitsonar.plugins.integrators.paths import exact_sum

    if args.threads:
        dr.set_thread_count(args.threads)
    homes = [sonar_tof, sonar_bdpt]
    out = {"threads": dr.thread_count(), "repeats": args.repeats, "cases": {}}
    classes = {"exact": _recording(exact_sum.ExactBins), "exact_nine": _recording(exact_sum.ExactBins),
               "float64": _recording(Float64Bins)}
    for name, (xml, props, spp) in CASES.items():
        if args.only not in name:
            continue
        spp = max(1, int(spp * args.spp_scale))
        scene = mitsonar.load_scene(os.path.join(ROOT, "scenes_xml", xml))
        integs = {}
        for kind in KINDS:
            # a setting of its own per kind: frozen passes (plugins/integrators/paths/frozen_pass.py) are recorded
            # per integrator setting, so each kind replays its own recording
            integs[kind] = scene.integrator() if props is None else mi.load_dict(props)
            if props is None:   # the scene's own settings, one integrator per kind
                scene = mitsonar.load_scene(os.path.join(ROOT, "scenes_xml", xml))
            integs[kind].bench_sums = kind
        integs["exact_nine"]._exact_lo = integs["exact_nine"]._exact_hi = -1   # windows ended
        times = {k: [] for k in KINDS}
        hists = {}
        for r in range(args.repeats + 1):          # the first round compiles the kernels
            for kind in KINDS:
                for m in homes:
                    m.ExactBins = classes[kind]
                t0 = time.perf_counter()
                hists[kind] = integs[kind].render_histogram(scene, 0, seed=r, spp=spp)
                if r:
                    times[kind].append(time.perf_counter() - t0)
        for m in homes:
            m.ExactBins = exact_sum.ExactBins
        med = {k: statistics.median(v) for k, v in times.items()}
        out["cases"][name] = {"spp": spp, "median_s": med, "fastest_s": {k: min(v) for k, v in times.items()},
                              "exact_over_float64": med["exact"] / med["float64"],
                              "exact_over_exact_nine": med["exact"] / med["exact_nine"],
                              "same_bits": hists["exact"].tobytes() == hists["exact_nine"].tobytes(),
                              "bytes_per_bin": {k: classes[k].last for k in KINDS},
                              # the window its passes summed in (None: nine words, as sonar_bdpt's)
                              "window": exact_sum.window_of(integs["exact"]) if classes["exact"].last < 80 else None}
    out["sum_stage"] = sum_stage(args.repeats)
    print(json.dumps(out, indent=1))


if __name__ == "__main__":
    main()
