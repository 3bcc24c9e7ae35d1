"""Survey benchmark (issue 18): moving versus static render time of the same scan, and survey
throughput with streaming to disk.

Prints one JSON object. Everything is measured in this one run (shared machines are noisy):
  * ``static_s``, ``moving_s``: median seconds of a full 200-ping box scan (kernels compiled,
    interleaved repeats), static and on a trajectory turning from the static pose at 0.5 m/s and
    5 deg/s (the head stays inside the box, a few cm to 1 m from the static pose, so the paths
    are nearly the same); ``still_s``: through the trajectory machinery on a trajectory that does
    not move (the very same paths: the cost of per-row poses alone); ``moving_over_static`` and
    ``still_over_static`` the ratios (target: within 1.10);
  * ``survey``: pings per second and scans per second of `render_survey` writing every scan to a
    temporary folder (``.npz``), including the electronics and the file writes.

Usage: python benchmarks/survey.py [--spp 4096] [--repeats 7] [--scans 10]
"""
from __future__ import annotations

import argparse
import json
import os
import platform
import statistics
import sys
import tempfile
import time

import mitsonar

HERE = os.path.dirname(os.path.abspath(__file__))
BOX = os.path.join(HERE, "..", "scenes_xml", "box.xml")


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--spp", type=int, default=4096)
    ap.add_argument("--repeats", type=int, default=7)
    ap.add_argument("--scans", type=int, default=10)
    args = ap.parse_args(argv)

    scene = mitsonar.load_scene(BOX)
    sensor = scene.sensors()[0]
    sweep = sensor.scan_period
    traj = mitsonar.Trajectory.turn(sweep * (args.scans + 1), 0.5, 5.0, dt=0.1)
    still = mitsonar.Trajectory([0.0, 2 * sweep], [mitsonar.geometry.trajectory.pose()] * 2)

    def static():
        mitsonar.render_scan(scene, spp=args.spp, seed=1)

    def moving():
        mitsonar.render_scan(scene, spp=args.spp, seed=1, trajectory=traj, start_time=sweep / 2)

    def held():
        mitsonar.render_scan(scene, spp=args.spp, seed=1, trajectory=still, start_time=sweep / 2)

    static(), moving(), held()  # compile
    times = {"static": [], "moving": [], "still": []}
    for _ in range(args.repeats):
        for name, fn in (("static", static), ("moving", moving), ("still", held)):
            t = time.perf_counter()
            fn()
            times[name].append(time.perf_counter() - t)
    s, m, h = (statistics.median(times[k]) for k in ("static", "moving", "still"))

    with tempfile.TemporaryDirectory() as folder:
        t = time.perf_counter()
        n = sum(1 for _ in mitsonar.render_survey(scene, traj, folder, spp=args.spp, max_scans=args.scans,
                                                  progress=False))
        wall = time.perf_counter() - t
        size = sum(os.path.getsize(os.path.join(folder, f)) for f in os.listdir(folder))

    print(json.dumps({
        "benchmark": "survey",
        "machine": {"cpus": os.cpu_count(), "platform": platform.platform(), "python": sys.version.split()[0],
                    "variant": mitsonar.sim.variant()},
        "scan": {"scene": "box.xml", "pings": sensor.n_pings, "bins": sensor.n_bins, "spp": args.spp,
                 "ping_period_s": sensor.ping_period, "repeats": args.repeats},
        "static_s": round(s, 4), "moving_s": round(m, 4), "still_s": round(h, 4),
        "moving_over_static": round(m / s, 3), "still_over_static": round(h / s, 3),
        "survey": {"scans": n, "seconds": round(wall, 3), "pings_per_s": round(n * sensor.n_pings / wall, 1),
                   "scans_per_s": round(n / wall, 3), "bytes_written": size,
                   "track_seconds_per_wall_second": round(n * sweep / wall, 2)},
    }, indent=1))


if __name__ == "__main__":
    main()
