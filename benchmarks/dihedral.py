"""How many paths the corner (dihedral) echoes of the quay wall need to converge with ``sonar_tof``.

The quay wall (``scenes_xml/quay_wall.xml``) stands on the seabed, as do two piles: their corners
are dihedral reflectors, whose double-bounce echo (seabed - wall - sonar, or wall - seabed - sonar)
returns at the corner's range. For path tracing it is a heavy-tailed part of the integrand: the
second bounce must leave the first surface inside the second surface's glossy lobe that points back
at the transducer. This script isolates that echo exactly: with the same seed, a render with
``max_depth`` 3 and one with ``max_depth`` 1 share every path's first bounce, so their difference
is the multipath echo of those paths. Per spp and seed it measures, in the corner region (the bins
from the wall-seabed corner's range to 0.3 m beyond it, on the beams that see the wall, and the
same around the piles' feet), the relative L2 error of the multipath echo against a reference of
``--reference-spp`` paths per beam (its own noise removed: the reference's error is estimated from
two half-references), and prints JSON: the error per spp, the spp at which the error falls below
10 % and 5 % (a power law fitted to the measured points), and the multipath share of the region's
energy.

Usage: python benchmarks/dihedral.py [--spp 1024,4096,16384] [--seeds 4] [--reference-spp 65536]
"""
from __future__ import annotations

import argparse
import json
import math
import os
import time

import numpy as np

HERE = os.path.dirname(os.path.abspath(__file__))
SCENE = os.path.join(HERE, "..", "scenes_xml", "quay_wall.xml")

WALL_X, SEABED_Z, PILES = 10.0, -3.0, ((6.0, -3.0), (6.0, 3.0))
PILE_RADIUS = 0.3
DEPTH = 3
BAND = 0.3  # m beyond the corner's range


def corner_mask(sensor):
    """(rows, bins) bool: the bins of the wall-seabed corner and of the piles' feet."""
    bearings = np.radians(sensor.bearings_deg())
    r = sensor.bin_centres()
    mask = np.zeros((sensor.n_pings, sensor.n_bins), bool)
    head = sensor.to_world_np[:3, 3]
    for k, b in enumerate(bearings):
        # the wall's foot along this beam's horizontal direction (the head looks along +x)
        if abs(b) < math.radians(60):
            rc = math.hypot(WALL_X / math.cos(b), SEABED_Z - head[2])
            mask[k] |= (r >= rc) & (r < rc + BAND)
        for px, py in PILES:
            az = math.atan2(py - head[1], px - head[0])
            if abs(b - az) < math.radians(3):
                rc = math.hypot(math.hypot(px - head[0], py - head[1]) - PILE_RADIUS, SEABED_Z - head[2])
                mask[k] |= (r >= rc) & (r < rc + BAND)
    return mask


def multipath(scene, spp, seed):
    import mitsonar

    deep = mitsonar.render_scan(scene, spp=spp, seed=seed, max_depth=DEPTH).intensity.astype(np.float64)
    single = mitsonar.render_scan(scene, spp=spp, seed=seed, max_depth=1).intensity.astype(np.float64)
    return deep - single, deep


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--spp", default="1024,4096,16384")
    ap.add_argument("--seeds", type=int, default=4)
    ap.add_argument("--reference-spp", type=int, default=1 << 16)
    args = ap.parse_args(argv)
    spps = [int(s) for s in args.spp.split(",")]

    import mitsonar

    scene = mitsonar.load_scene(SCENE)
    sensor = scene.sensors()[0]
    mask = corner_mask(sensor)
    t0 = time.perf_counter()
    half = args.reference_spp // 2
    ref_a, deep_a = multipath(scene, half, 1000)
    ref_b, _ = multipath(scene, half, 1001)
    ref = 0.5 * (ref_a + ref_b)
    norm = np.linalg.norm(ref[mask])
    # the reference's own error: half the distance between its halves (each has twice its variance)
    ref_err = 0.5 * np.linalg.norm((ref_a - ref_b)[mask]) / norm
    share = float(ref[mask].sum() / (ref[mask].sum() + (deep_a - ref_a)[mask].sum()))
    rows = []
    for spp in spps:
        errs = []
        for seed in range(args.seeds):
            m, _ = multipath(scene, spp, seed)
            e2 = (np.linalg.norm((m - ref)[mask]) / norm) ** 2 - ref_err ** 2
            errs.append(math.sqrt(max(e2, 0.0)))
        rows.append({"spp": spp, "rel_l2": [round(e, 4) for e in errs], "rms": round(float(np.sqrt(np.mean(np.square(errs)))), 4)})
    x = np.log([r["spp"] for r in rows])
    y = np.log([max(r["rms"], 1e-12) for r in rows])
    slope, icpt = np.polyfit(x, y, 1) if len(rows) > 1 else (-0.5, y[0] + 0.5 * x[0])
    need = {f"{int(t * 100)}%": int(math.exp((math.log(t) - icpt) / slope)) for t in (0.10, 0.05)}
    print(json.dumps({"scene": "quay_wall", "max_depth": DEPTH, "beams": sensor.n_pings,
                      "corner_bins": int(mask.sum()), "multipath_share_of_corner_energy": round(share, 3),
                      "reference_spp": args.reference_spp, "reference_rel_error": round(float(ref_err), 4),
                      "convergence": rows, "error_slope": round(float(slope), 3), "spp_needed": need,
                      "seconds": round(time.perf_counter() - t0, 1)}, indent=1))


if __name__ == "__main__":
    main()
