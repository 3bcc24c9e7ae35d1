"""Path-weight audit: how much of a bin one path can carry, for every scene and sonar kind.

A Monte Carlo estimate of a bin converges once no single path holds a large share of it. For each
scene in ``scenes_xml/`` and each sonar kind (the scene's own sensor, and the same pose with the
other kind: ``mechanical``, 200 pings of 1.8 deg, or ``multibeam``, 512 receive beams of 0.5 deg
across 130 deg), ``sonar_tof`` paths are traced in passes over several seeds (default 10^8 paths
per scene and kind, 8 seeds), and per bin and per echo class (``single``: the first bounce's echo;
``multipath``: echoes after two or more bounces) the audit keeps the sum, the count and the largest
single-path contribution. It prints one JSON object with, per scene and kind and class:

``max_over_mean``     largest single-path contribution / the bin's estimate (its mean over all
                      the row's paths), over the bins that hold at least 1e-4 of the frame's
                      largest bin: at ``spp`` paths per row that path carries ``max_over_mean / spp``
                      of its bin. ``bin`` is (row, bin, range in m).
``spp_for_1pct``      the spp at which the heaviest path carries 1 % of its bin (``100 x
                      max_over_mean``): below it, renders of that bin are dominated by rare paths.
                      ``paths_in_bin`` says how many audited paths reached that bin (a handful:
                      the bin is reached rarely, and the figure is a rough one).
``peak_over_echo``    largest contribution / the mean contribution of the paths that reached the
                      bin: the spread of the integrand itself. A bounded, smooth integrand (a beam,
                      a Lambert-Phong surface, one bounce) keeps it small (tens); a firefly, or a
                      glossy corner reflector's echo found rarely by the second bounce, makes it large.

``verdict`` says, per scene and kind, whether the single-bounce echo is bounded (``peak_over_echo``
at most ``SINGLE_BOUND``), and whether multipath has a heavy tail (``peak_over_echo`` above
``HEAVY_TAIL``) and where. Before the fix of the beam sampler's tail pdf (issue "Fireflies"),
single-bounce ``peak_over_echo`` reached 1e6 on multibeam heads.

``--bar`` adds the issue's convergence bar on the multibeam scenes with ``max_depth`` >= 2: 8 seeds
of spp 2^15 (512 beams for the converted scenes), each render's relative L2 distance to the median
of the 8 (target < 5 %) and its largest bin against the median render's largest (target < 20x).

Usage: python benchmarks/weights.py [--paths 1e8] [--seeds 8] [--scenes box,quay_wall,...]
                                    [--kinds mechanical,multibeam] [--bar] [--bar-spp 32768] [-o audit.json]
"""
from __future__ import annotations

import argparse
import glob
import json
import math
import os
import re
import sys
import time
import xml.etree.ElementTree as ET

import numpy as np

HERE = os.path.dirname(os.path.abspath(__file__))
SCENES = os.path.join(HERE, "..", "scenes_xml")
KINDS = ("mechanical", "multibeam")
SINGLE_BOUND = 100.0   # peak / mean of a bin's single-bounce echoes on a bounded integrand
HEAVY_TAIL = 1000.0    # multipath peak / mean above which a bin's echo needs many paths
SIGNIFICANT = 1e-4     # bins below this fraction of the frame's largest bin are not audited

# The sensor of each kind when a scene is converted to it (pose, range window and vertical beam
# width stay the scene's).
CONVERT = {
    "mechanical": {"bearing_start": 0.0, "bearing_step": 1.8, "n_pings": 200, "beamwidth_h": 3.0},
    "multibeam": {"bearing_start": -65.0, "bearing_step": 130.0 / 511, "n_pings": 512, "beamwidth_h": 0.5},
}


def scene_names():
    return sorted(os.path.splitext(os.path.basename(p))[0] for p in glob.glob(os.path.join(SCENES, "*.xml")))


def scene_for_kind(name, kind):
    """The scene's XML text with its sonar as ``kind`` (unchanged when it already is), and
    whether it was converted."""
    with open(os.path.join(SCENES, f"{name}.xml"), encoding="utf-8") as fh:
        text = fh.read()
    # Mitsuba's parser takes "--" inside comments; ElementTree does not: drop the comments.
    root = ET.fromstring(re.sub(r"<!--.*?-->", "", text, flags=re.S))
    sensor = root.find("sensor[@type='sonar']")
    kind_el = sensor.find("string[@name='kind']")
    native = kind_el.get("value") if kind_el is not None else "mechanical"
    if native != kind:
        if kind_el is None:
            kind_el = ET.SubElement(sensor, "string", name="kind")
        kind_el.set("value", kind)
        for child in list(sensor):
            if child.get("name", "").startswith("tx_"):
                sensor.remove(child)
        for key, value in CONVERT[kind].items():
            el = sensor.find(f"*[@name='{key}']")
            if el is None:
                el = ET.SubElement(sensor, "integer" if isinstance(value, int) else "float", name=key)
            el.set("value", repr(value))
    return ET.tostring(root, encoding="unicode"), native != kind


def audit(scene, paths, seeds, max_depth):
    """Per class (single, multipath): per-bin sums, counts and largest contribution, numpy."""
    import drjit as dr
    import mitsuba as mi

    from mitsonar.plugins.integrators import sonar_tof

    # independent samples: the per-path weights audited are those of the beam and the BSDFs
    integrator = mi.load_dict({"type": "sonar_tof", "max_depth": max_depth, "sampling": "independent"})
    setup = integrator.setup(scene, 0)
    sensor = setup.sensor
    rows, n_bins = sensor.n_pings, sensor.n_bins
    spp = max(1, math.ceil(paths / seeds / rows))
    per_pass = max(1, min(spp, sonar_tof.MAX_LANES_PER_PASS // rows))
    size = 2 * rows * n_bins
    total = np.zeros(size)
    count = np.zeros(size)
    peak = np.zeros(size)
    with dr.suspend_grad():
        for seed in range(seeds):
            start = 0
            while start < spp:
                n = min(per_pass, spp - start)
                ping, samples = integrator.lanes(rows, seed, start, n)
                s = dr.zeros(mi.Float64, size)
                c = dr.zeros(mi.UInt32, size)
                m = dr.zeros(mi.Float, size)

                def record(k, rng, energy, valid, hit):
                    b, valid = setup.bins.index(rng, valid)
                    cls = dr.select(k == 0, mi.UInt32(0), mi.UInt32(rows * n_bins))
                    idx = cls + setup.bins.flat(ping, b)
                    dr.scatter_add(s, mi.Float64(energy), idx, valid)
                    dr.scatter_add(c, mi.UInt32(1), idx, valid)
                    dr.scatter_reduce(dr.ReduceOp.Max, m, energy, idx, valid)

                integrator.sample(setup, ping, samples, record)
                dr.eval(s, c, m)
                total += s.numpy()
                count += c.numpy()
                peak = np.maximum(peak, m.numpy())
                start += n
    n_row = spp * seeds
    shape = (2, rows, n_bins)
    return (total / n_row).reshape(shape), count.reshape(shape), peak.reshape(shape), n_row, sensor


def summarise(mean, count, peak, n_row, sensor):
    """The JSON entry of one audit: per class, the heaviest path against its bin's estimate and
    against the mean of the paths that reached the bin (see the module docstring)."""
    frame_max = mean.sum(axis=0).max()
    centres = sensor.bin_centres()
    out = {}
    for c, label in enumerate(("single", "multipath")):
        ok = mean[c] >= SIGNIFICANT * frame_max
        if not ok.any():
            out[label] = None
            continue
        safe = np.where(ok, mean[c], 1.0)
        ratio = np.where(ok, peak[c] / safe, 0.0)
        echo = np.where(ok, peak[c] * count[c] / (safe * n_row), 0.0)
        r, b = np.unravel_index(np.argmax(ratio), ratio.shape)
        er, eb = np.unravel_index(np.argmax(echo), echo.shape)
        out[label] = {"max_over_mean": float(ratio[r, b]), "bin": [int(r), int(b), round(float(centres[b]), 3)],
                      "spp_for_1pct": int(math.ceil(100 * ratio[r, b])), "paths_in_bin": int(count[c, r, b]),
                      "peak_over_echo": float(echo[er, eb]),
                      "peak_bin": [int(er), int(eb), round(float(centres[eb]), 3)],
                      "bins_audited": int(ok.sum())}
    return out


def verdict(name, kind, res):
    """One line: is the single-bounce echo bounded, is the multipath echo heavy-tailed."""
    words = []
    single, multi = res["single"], res["multipath"]
    if single is not None:
        words.append(("bounded" if single["peak_over_echo"] <= SINGLE_BOUND else "UNBOUNDED")
                     + f" single bounce (peak {single['peak_over_echo']:.3g}x the bin's mean echo)")
    if multi is not None:
        heavy = multi["peak_over_echo"] > HEAVY_TAIL
        words.append(("heavy-tailed" if heavy else "light") + f" multipath (peak {multi['peak_over_echo']:.3g}x "
                     f"at {multi['peak_bin'][2]} m, 1 % per path from spp {multi['spp_for_1pct']})")
    return f"{name}/{kind}: " + "; ".join(words)


def bar(scene, spp, seeds=8, max_depth=3):
    import mitsonar

    imgs = np.array([mitsonar.render_scan(scene, spp=spp, seed=s, max_depth=max_depth).intensity
                     for s in range(seeds)], dtype=np.float64)
    median = np.median(imgs, axis=0)
    dist = [float(np.linalg.norm(i - median) / np.linalg.norm(median)) for i in imgs]
    peaks = [float(i.max() / median.max()) for i in imgs]
    return {"spp": spp, "seeds": seeds, "max_depth": max_depth, "rel_l2_to_median": [round(d, 4) for d in dist],
            "max_bin_over_median_max": [round(p, 3) for p in peaks],
            "met": bool(max(dist) < 0.05 and max(peaks) < 20)}


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--paths", type=float, default=1e8, help="paths per scene and kind (default 1e8)")
    ap.add_argument("--seeds", type=int, default=8)
    ap.add_argument("--scenes", default=",".join(scene_names()))
    ap.add_argument("--kinds", default=",".join(KINDS))
    ap.add_argument("--max-depth", type=int, default=None, help="default: the scene's integrator's")
    ap.add_argument("--bar", action="store_true", help="also run the 8-seed convergence bar on multibeam scenes")
    ap.add_argument("--bar-spp", type=int, default=1 << 15)
    ap.add_argument("-o", "--output", help="also write the JSON here, rewritten after every scene and kind "
                                           "(a long run keeps what it measured)")
    args = ap.parse_args(argv)
    names, kinds = args.scenes.split(","), args.kinds.split(",")
    for n in names:
        if n not in scene_names():
            ap.error(f"--scenes: {n!r} is not a scene of scenes_xml/ (one of {', '.join(scene_names())})")
    for k in kinds:
        if k not in KINDS:
            ap.error(f"--kinds: {k!r} is not one of {', '.join(KINDS)}")
    if args.paths < 1 or args.seeds < 1:
        ap.error("--paths and --seeds must be >= 1")

    import mitsonar

    result = {"paths_per_scene_and_kind": int(args.paths), "seeds": args.seeds,
              "significant_bins": SIGNIFICANT, "single_bound": SINGLE_BOUND, "heavy_tail": HEAVY_TAIL,
              "scenes": {}, "verdict": []}
    for name in names:
        for kind in kinds:
            xml, converted = scene_for_kind(name, kind)
            scene = mitsonar.load_scene(xml)
            depth = args.max_depth or scene.integrator().max_depth
            t0 = time.perf_counter()
            mean, count, peak, n_row, sensor = audit(scene, args.paths, args.seeds, depth)
            res = summarise(mean, count, peak, n_row, sensor)
            line = verdict(name, kind, res)
            entry = {"converted": converted, "max_depth": depth, "paths_per_row": n_row,
                     "rows": sensor.n_pings, "seconds": round(time.perf_counter() - t0, 1), **res}
            if args.bar and kind == "multibeam" and depth >= 2:
                entry["bar"] = bar(scene, args.bar_spp, max_depth=depth)
                line += f"; bar {'met' if entry['bar']['met'] else 'MISSED'}"
            result["scenes"][f"{name}/{kind}"] = entry
            result["verdict"].append(line)
            print(line, file=sys.stderr, flush=True)
            if args.output:
                from mitsonar._files import replacing

                with replacing(args.output) as tmp, open(tmp, "w") as fh:
                    json.dump(result, fh, indent=1)
    print(json.dumps(result, indent=1))


if __name__ == "__main__":
    main()
