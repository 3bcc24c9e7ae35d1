"""Side-scan speed benchmark (issue "Side-scan sonar"): pings per second at 2 channels x 1000 bins
and 5 % relative L2 error, on the wreck survey scene (``scenes_xml/wreck_sidescan.xml``).

Prints one JSON object. Everything is measured in this one run (shared machines are noisy):
  * the error of a render at ``spp`` paths per ping and channel is the relative L2 error of its
    ``intensity`` (all rows and bins together, ``|I - I_ref| / |I_ref|``) against a reference of the
    same pings at ``--ref-spp`` (independent seeds); the reference's own noise adds a factor
    ``sqrt(1 + spp / ref_spp)`` to the measured error (reported as ``ref_inflation``, below 1.02 at the
    chosen spp by default, so the measured error slightly overstates the true one);
  * ``spp_at_target``: the smallest power of two whose error is at most ``--target`` (0.05);
  * ``pings_per_s``: pings (each with both channels: 2 rows of 1000 bins) per second of wall time of
    `render_scan` at that spp, electronics included, kernels compiled beforehand, median of
    ``--repeats``; Dr.Jit limited to ``--threads`` worker threads (2: the issue's two cores);
  * ``meets_30_pings_per_s``: whether it reaches the issue's 30 pings/s (twice the real ping rate
    at 50 m range, 2 x 50 m / 1500 m/s = 67 ms per ping).
The pings are the 250 of one scan abeam of the wreck (t = 4.7 s on the survey: hull, deckhouse,
shadow and rippled sand in every row), with the scene's max_depth (2). There the scan's energy is
dominated by the hull-seabed corner (a dihedral: its double-bounce bins hold most of the L2 norm),
so the relative L2 error is mostly that of those bins; ``--max-depth 1`` measures single-bounce
rows, whose energy spreads over the hull, the shadow edge and the sand.

Usage: python benchmarks/sidescan.py [--target 0.05] [--threads 2] [--repeats 5] [--ref-spp 65536]
"""
from __future__ import annotations

import argparse
import json
import os
import platform
import statistics
import sys
import time

import numpy as np

HERE = os.path.dirname(os.path.abspath(__file__))
SCENES = os.path.join(HERE, "..", "scenes_xml")
START = 4.7            # s: the scan's pings run from x = -3 to x = 3 along the first line


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--target", type=float, default=0.05)
    ap.add_argument("--threads", type=int, default=2)
    ap.add_argument("--repeats", type=int, default=5)
    ap.add_argument("--ref-spp", type=int, default=262144)
    ap.add_argument("--ref-pings", type=int, default=25, help="pings of the error measurement, spread over the scan")
    ap.add_argument("--max-depth", type=int, default=None, help="surface bounces (default: the scene's, 2)")
    args = ap.parse_args(argv)

    import drjit as dr

    import mitsonar

    dr.set_thread_count(args.threads)
    path = os.path.join(SCENES, "wreck_sidescan.xml")
    scene = mitsonar.load_scene(path)
    track = mitsonar.Trajectory.from_tum(os.path.join(SCENES, "wreck_sidescan_survey.tum"))
    sonar = scene.sensors()[0]
    # The error is measured on a scan of --ref-pings pings spread over the same stretch of track (the
    # same scene with fewer pings and a longer ping period): the reference costs 10x less.
    every = sonar.pings // args.ref_pings
    with open(path, encoding="utf-8") as fh:
        xml = fh.read()
    xml = (xml.replace('name="n_pings" value="250"', f'name="n_pings" value="{args.ref_pings}"')
           .replace('<float name="range_max" value="12"/>', '<float name="range_max" value="12"/><float '
                    f'name="ping_period" value="{every * sonar.ping_period!r}"/>')
           .replace('value="wreck_seabed.ply"', f'value="{os.path.join(SCENES, "wreck_seabed.ply")}"'))
    few = mitsonar.load_scene(xml)
    assert few.sensors()[0].pings == args.ref_pings

    def render(spp, seed, scene=scene):
        return mitsonar.render_scan(scene, spp=spp, seed=seed, trajectory=track, start_time=START,
                                    max_depth=args.max_depth)

    t = time.perf_counter()
    ref = render(args.ref_spp, 12345, few).intensity.astype(np.float64)
    ref_s = time.perf_counter() - t
    norm = np.linalg.norm(ref)
    errors, spp = {}, 8
    while spp <= args.ref_spp // 8:
        err = float(np.linalg.norm(render(spp, spp, few).intensity - ref) / norm)
        errors[spp] = err
        if err <= args.target:
            break
        spp *= 2
    found = spp if errors.get(spp, 1.0) <= args.target else None
    out = {"scene": "wreck_sidescan.xml", "channels": 2, "bins": sonar.n_bins, "pings_per_scan": sonar.pings,
           "max_depth": int(args.max_depth or scene.integrator().max_depth), "target_rel_l2": args.target,
           "rel_l2_by_spp": {str(k): round(v, 4) for k, v in errors.items()}, "ref_spp": args.ref_spp,
           "ref_render_s": round(ref_s, 2), "spp_at_target": found}
    if found is not None:
        out["ref_inflation"] = round(float(np.sqrt(1 + found / args.ref_spp)), 4)
        render(found, 1)                                    # compiled, caches warm
        times = []
        for r in range(args.repeats):
            t = time.perf_counter()
            render(found, 100 + r)
            times.append(time.perf_counter() - t)
        med = statistics.median(times)
        out.update(scan_s=[round(x, 3) for x in times], pings_per_s=round(sonar.pings / med, 1),
                   rows_per_s=round(2 * sonar.pings / med, 1), meets_30_pings_per_s=bool(sonar.pings / med >= 30))
    out.update(threads=args.threads, cpu_count=os.cpu_count(), python=sys.version.split()[0],
               platform=platform.platform(), variant=__import__("mitsuba").variant())
    print(json.dumps(out, indent=1))


if __name__ == "__main__":
    main()
