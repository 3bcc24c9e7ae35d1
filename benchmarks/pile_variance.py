#!/usr/bin/env python
"""Where ``pile_quay``'s variance is: per ping, per range window, per bounce, and which paths carry it.

Traces ``--paths`` Sobol paths per ping of ``sonar_tof``'s path function (its guide) on
``scenes_xml/pile_quay.xml`` and prints the share of the per-path variance (summed over bins)
of each ping, of the pile's window (range >= 6.5 m: the wall-pile-wall echo), of each bounce's
echoes, the share of the bounce-2 echoes' second moment held by their largest paths, where those
paths met the pile (the angle about its axis: -90 deg faces the sonar's image in the wall) and
the wall, and how many paths meet the pile within 2 deg of that strip.

    python benchmarks/pile_variance.py [--paths 65536] [--seed 0] [--no-strip-guide]
"""
from __future__ import annotations

import argparse
import os

import numpy as np

HERE = os.path.dirname(os.path.abspath(__file__))


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--paths", type=int, default=65536, help="paths per ping (default 65536)")
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--no-strip-guide", action="store_true",
                    help="without the strip guide (plugins/integrators/paths/image_guide.py STRIP_GUIDE)")
    args = ap.parse_args(argv)
    if args.paths < 16:
        ap.error("--paths: at least 16 per ping")
    import drjit as dr
    import mitsuba as mi

    import mitsonar
    from mitsonar.plugins.integrators.paths import image_guide
    from mitsonar.plugins.integrators.paths.samples import SobolSamples, row_lanes

    image_guide.STRIP_GUIDE = not args.no_strip_guide
    scene = mitsonar.load_scene(os.path.join(HERE, "..", "scenes_xml", "pile_quay.xml"))
    tof = mi.load_dict({"type": "sonar_tof"})
    setup = tof.setup(scene)
    P, B, D, N = setup.sensor.n_pings, setup.sensor.n_bins, setup.depth, args.paths
    ping, samples = row_lanes(SobolSamples, P, args.seed, 0, N)
    lane = dr.arange(mi.UInt32, P * N)
    E, BIN = dr.zeros(mi.Float, P * N * D), dr.zeros(mi.UInt32, P * N * D)
    PX = dr.zeros(mi.Float, P * N * D * 3)

    def record(k, rng, energy, valid, hit):
        b, valid = setup.bins.index(rng, valid)
        slot = lane * D + k
        dr.scatter(E, energy, slot, valid)
        dr.scatter(BIN, b, slot, valid)
        for c in range(3):
            dr.scatter(PX, hit.p[c], slot * 3 + c)

    tof.sample(setup, ping, samples, record)
    dr.eval(E, BIN, PX)
    E = E.numpy().reshape(P, N, D).astype(np.float64)
    BIN = BIN.numpy().reshape(P, N, D)
    PX = PX.numpy().reshape(P, N, D, 3)
    hist, sq = np.zeros((P, B)), np.zeros((P, B))
    rows = np.repeat(np.arange(P), N)
    for k in range(D):
        np.add.at(hist, (rows, BIN[:, :, k].ravel()), E[:, :, k].ravel())
        np.add.at(sq, (rows, BIN[:, :, k].ravel()), E[:, :, k].ravel() ** 2)
    mean = hist / N
    var = sq / N - mean ** 2
    r = (np.arange(B) + 0.5) * 10.0 / B      # pile_quay's range window: 0 to 10 m
    window = r >= 6.5
    print(f"per-path variance summed over bins {var.sum():.4e}; relative (over the squared mean) "
          f"{var.sum() / (mean ** 2).sum():.2f}")
    print("variance share per ping:", np.round(var.sum(1) / var.sum(), 3).tolist())
    print(f"pile window (>= 6.5 m): {var[:, window].sum() / var.sum():.4f} of the variance, "
          f"{(mean[:, window] ** 2).sum() / (mean ** 2).sum():.4f} of the squared signal")
    for k in range(D):
        print(f"bounce {k}: {E[:, :, k].sum() / E.sum():.3f} of the energy, "
              f"{(E[:, :, k] ** 2).sum() / (E ** 2).sum():.3f} of the second moment, "
              f"{np.mean(E[:, :, k] > 0):.4f} of the paths echo")
    e2 = E[:, :, 2].ravel()
    order = np.argsort(e2)[::-1]
    for frac in (1e-4, 1e-3, 1e-2):
        top = order[:max(1, int(frac * e2.size))]
        print(f"largest {frac:g} of the bounce-2 echoes: {(e2[top] ** 2).sum() / (e2 ** 2).sum():.3f} of their "
              f"second moment, {e2[top].sum() / e2.sum():.3f} of their energy")
    pile, wall = PX[:, :, 1].reshape(-1, 3), PX[:, :, 0].reshape(-1, 3)
    top = order[:max(1, int(1e-3 * e2.size))]
    angle = np.degrees(np.arctan2(pile[:, 1] - 3.0, pile[:, 0] - 4.0))
    print("largest 0.1 %: pile angle (deg) 5/50/95 %", np.percentile(angle[top], [5, 50, 95]).round(2).tolist(),
          "pile z", np.percentile(pile[top, 2], [5, 50, 95]).round(3).tolist(),
          "wall z", np.percentile(wall[top, 2], [5, 50, 95]).round(3).tolist())
    on_pile = np.abs(np.hypot(pile[:, 0] - 4.0, pile[:, 1] - 3.0) - 0.3) < 1e-3
    print(f"paths whose second vertex is on the pile: {on_pile.mean():.4f}; within 2 deg of the strip: "
          f"{np.mean(on_pile & (np.abs(angle + 90.0) < 2.0)):.4f}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
