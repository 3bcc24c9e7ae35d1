"""Realism report: do the default scans' bytes look like a real Micron's?

For each scene in ``scenes_xml/`` and each sonar of the scene (its own kind: mechanical or
multibeam), the default scan (``--spp``, seeds ``--seeds``, the sensor's own electronics) is
rendered and the statistics of `mitsonar.receiver.realism` are computed from its bytes: the Weibull shape of
the non-zero bytes beyond 1.6 m, the fraction of zero bytes beyond 1.6 m, and the mean byte from
0.1 to 1.0 m (the transducer's ring-down). Printed as one JSON object beside the real head's
ranges (``real``), with ``inside`` per statistic (the mean over the seeds against the range).

The real ranges come from public recordings of a Tritech Micron (200 bins, 10-20 m, harbour and
tank scenes), the head whose electronics the defaults model; a multibeam scan is held to them too,
though a real multibeam's numbers differ (its receiver, beamformer and display are another head's).

``--figure PATH`` draws, per scene (mechanical heads), the histogram of the non-zero bytes beyond
1.6 m against the fitted Weibull density.

Usage: python benchmarks/realism.py [--spp 1024] [--seeds 11,12,13] [--scenes box,intake]
                                    [--figure realism.png]
"""
from __future__ import annotations

import argparse
import glob
import json
import os
import sys
import time

import numpy as np

HERE = os.path.dirname(os.path.abspath(__file__))
sys.path.insert(0, os.path.dirname(HERE))

import mitsonar  # noqa: E402
from mitsonar.receiver.realism import FAR_FROM, REAL_RANGES, byte_statistics, inside  # noqa: E402


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--spp", type=int, default=1024)
    ap.add_argument("--seeds", default="11,12,13")
    ap.add_argument("--scenes", default="", help="comma-separated scene names (default: all of scenes_xml/)")
    ap.add_argument("--figure", default="", help="PNG of the byte histograms against the fitted Weibull")
    args = ap.parse_args(argv)
    seeds = [int(s) for s in args.seeds.split(",") if s]
    root = os.path.join(os.path.dirname(HERE), "scenes_xml")
    names = ([n for n in args.scenes.split(",") if n] or
             sorted(os.path.splitext(os.path.basename(p))[0] for p in glob.glob(os.path.join(root, "*.xml"))))
    report = {"real": {k: list(v) for k, v in REAL_RANGES.items()}, "spp": args.spp, "seeds": seeds, "scenes": {}}
    pictures = []
    for name in names:
        scene = mitsonar.load_scene(os.path.join(root, f"{name}.xml"))
        for index, sensor in enumerate(scene.sensors()):
            t0 = time.perf_counter()
            rows, last = [], None
            for seed in seeds:
                last = mitsonar.render_scan(scene, spp=args.spp, seed=seed, sensor=index)
                rows.append(byte_statistics(last.data, last.ranges))
            mean = {k: float(np.nanmean([r[k] for r in rows])) for k in REAL_RANGES}
            key = f"{name}[{index}]" if len(scene.sensors()) > 1 else name
            report["scenes"][key] = {"kind": last.kind, "shape": list(last.data.shape),
                                     "range_max": last.range_max, "mean": mean,
                                     "per_seed": rows, "inside": inside(mean),
                                     "seconds": round(time.perf_counter() - t0, 2)}
            if last.kind == "mechanical":
                pictures.append((key, last))
    print(json.dumps(report, indent=1))
    if args.figure and pictures:
        _figure(pictures, args.figure)
    return 0


def _figure(pictures, path):
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    from scipy import stats

    cols = min(4, len(pictures))
    rows = -(-len(pictures) // cols)
    fig, axes = plt.subplots(rows, cols, figsize=(4.2 * cols, 3.4 * rows), squeeze=False)
    for ax in axes.ravel()[len(pictures):]:
        ax.axis("off")
    for ax, (name, scan) in zip(axes.ravel(), pictures):
        far = scan.data[:, scan.ranges > FAR_FROM].astype(np.float64).ravel()
        nz = far[far > 0]
        k, _, scale = stats.weibull_min.fit(nz, floc=0)
        ax.hist(nz, bins=np.arange(0.5, 256.5, 4), density=True, color="0.6", label="bytes > 0 beyond 1.6 m")
        x = np.linspace(1, 255, 400)
        ax.plot(x, stats.weibull_min.pdf(x, k, scale=scale), "C3", label=f"Weibull k = {k:.2f}")
        lo, hi = REAL_RANGES["weibull_shape"]
        ax.set_title(f"{name}: zeros {np.mean(far == 0):.0%} (real 14-51 %)\nreal Micron k {lo}-{hi}", fontsize=9)
        ax.set_xlabel("byte")
        ax.legend(fontsize=7)
    fig.tight_layout()
    tmp = path + ".tmp.png"
    fig.savefig(tmp, dpi=110)
    os.replace(tmp, path)
    print(f"wrote {path}", file=sys.stderr)


if __name__ == "__main__":
    sys.exit(main())
