"""Live ray-casting bound: the paths a live ping could take if it cost nothing but its rays.

The live targets of issue 55 ask for more paths per ping under the same budget (`benchmarks/live.py`,
A/B against an older installation). A ping cannot trace more paths than its rays allow: this
script measures, on the live cases' scene (scenes_xml/harbour.xml), per case

* ``segments_per_path``: intersections and visibility rays per path of the ping as the live head
  traces it (the mechanical head's one-row ping for ``micron`` and ``ping360``, which ping the
  same head; the shared paths of the 256-beam frame for ``multibeam256``; `render.count_segments`,
  `frame_targets.shared_segments`);
* ``bare_loop_segments_per_s``: the bare ray-casting loop's rate on that scene and head
  (`render.ceiling`: ray_intersect and ray_test alone, the same lanes and bounces), and
* ``bound_paths_per_s``: their quotient, the paths per second of a ping that cost only its rays.

With ``--ab PATH`` (the JSON of ``benchmarks/live.py --baseline-python ...``) it also gives per
case the paths a ping's budget allows at that bound (``bound_paths_per_ping``: the budget's p50
times the live budget's headroom, `mitsonar.live.realtime.PathBudget`, times the bound), the
paths the target asks for (``target_factor`` x the baseline's paths p50) and their quotient
``target_over_bound`` (above 1: the target needs the ping's rays cast faster than the bare loop
casts them on these cores). The counts are paths per row (the live record's ``paths``); a
multibeam frame traces that many per beam.

Usage: python benchmarks/live_bound.py [--ab ab.json] [--repeats 5]
"""
from __future__ import annotations

import argparse
import json
import os
import sys
import tempfile
import xml.etree.ElementTree as ET

HERE = os.path.dirname(os.path.abspath(__file__))
sys.path.insert(0, HERE)

import live  # noqa: E402  (benchmarks/live.py)
import render as bench  # noqa: E402  (benchmarks/render.py)

import mitsonar  # noqa: E402,F401

HARBOUR = live.HARBOUR
#: the issue's factors: paths per budget at least 3x (Micron, Ping360) and 4x (256-beam multibeam)
TARGETS = {"micron": 3.0, "ping360": 3.0, "multibeam256": 4.0}
#: paths per row at which the rays are counted and the bare loop timed (a live ping's size)
SPP = {"micron": 16384, "ping360": 16384, "multibeam256": 1536}


def harbour(sensor_id, beams=None):
    """The harbour scene with only ``sensor_id``'s sensor (the multibeam widened to ``beams``
    beams at the same swath, as `live.multibeam` serves it: `live.widened_multibeam`)."""
    from mitsonar.sim.scene import load_scene

    root = ET.parse(HARBOUR).getroot() if beams is None else live.widened_multibeam(beams)
    for s in [e for e in root.findall("sensor") if e.get("id") != sensor_id]:
        root.remove(s)
    with tempfile.NamedTemporaryFile("w", suffix=".xml", dir=os.path.dirname(HARBOUR), delete=False) as f:
        ET.ElementTree(root).write(f, encoding="unicode")
    try:
        return load_scene(f.name)
    finally:
        os.unlink(f.name)


def bound(scene, spp, shared, repeats):
    """(segments per path, bare-loop segments/s, paths/s at that rate) of ``scene``'s head."""
    from frame_targets import shared_segments

    # the per-row head's lanes, bounces and visibility rays: what the bare loop repeats (for the
    # multibeam: its receive beams' rows); a shared frame's own segments counted as it traces them
    hits, shadows, per_lane = bench.count_segments(scene, spp, seed=1, per_lane=True)
    if shared:
        hits, shadows = shared_segments(scene, scene.integrator(), spp)
    per_path = (hits + shadows) / (spp * scene.sensors()[0].n_pings)
    rate, _, _ = bench.ceiling(scene, spp, per_lane, repeats)
    return per_path, rate, rate / per_path


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--ab", default=None, help="the JSON of benchmarks/live.py --baseline-python (budgets, B's paths)")
    ap.add_argument("--repeats", type=int, default=5, help="timed bare loops per case (default 5)")
    args = ap.parse_args(argv)
    if args.repeats < 1:
        ap.error(f"--repeats: {args.repeats}; allowed: an integer >= 1")
    ab = None
    if args.ab is not None:
        try:
            with open(args.ab) as f:
                ab = {c["case"]: c for c in json.load(f)["cases"]}
        except (OSError, ValueError, KeyError, TypeError) as e:
            ap.error(f"--ab: {args.ab} is not the JSON of benchmarks/live.py --baseline-python ({e})")
    from mitsonar.live.realtime import PathBudget

    headroom = PathBudget(1.0).headroom
    mechanical = harbour("sonar")
    per_path, rate, paths_per_s = bound(mechanical, SPP["micron"], False, args.repeats)
    mb = harbour("multibeam", beams=256)
    mb_per_path, mb_rate, mb_paths_per_s = bound(mb, SPP["multibeam256"], True, args.repeats)
    rows = {"micron": 1, "ping360": 1, "multibeam256": 256}
    measured = {"micron": (per_path, rate, paths_per_s), "ping360": (per_path, rate, paths_per_s),
                "multibeam256": (mb_per_path, mb_rate, mb_paths_per_s)}
    out = {"benchmark": "live ray-casting bound", "scene": "scenes_xml/harbour.xml", "cpus": os.cpu_count(),
           "headroom": headroom, "cases": {}}
    for case, (pp, r, pps) in measured.items():
        c = {"rows": rows[case], "segments_per_path": round(pp, 4), "bare_loop_segments_per_s": round(r),
             "bound_paths_per_s": round(pps)}
        if ab is not None and case in ab and "B" in ab[case] and "A" in ab[case]:
            budget_s = ab[case]["A"]["budget_ms_p50"] / 1e3
            per_ping = headroom * budget_s * pps / rows[case]
            target = TARGETS[case] * ab[case]["B"]["paths_p50"]
            c.update({"budget_ms_p50": ab[case]["A"]["budget_ms_p50"], "bound_paths_per_ping": round(per_ping),
                      "a_paths_p50": ab[case]["A"]["paths_p50"], "b_paths_p50": ab[case]["B"]["paths_p50"],
                      "target_factor": TARGETS[case], "target_paths": target,
                      "target_over_bound": float(f"{target / per_ping:.4g}")})
        out["cases"][case] = c
    print(json.dumps(out, indent=1))


if __name__ == "__main__":
    main()
