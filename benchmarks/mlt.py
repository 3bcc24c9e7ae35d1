"""Metropolis versus path tracing at equal time, on an easy scene and a hard one.

Runs `mitsonar.jobs.compare.compare` (the engine of ``mitsonar compare``) on scenes_xml/box.xml (easy:
open walls, every echo is found by path tracing), scenes_xml/slot_chamber.xml (hard: a chamber
seen through a slot), scenes_xml/glossy_corridor.xml (hard: glossy multipath) and
scenes_xml/hidden_target.xml (diagnostic, no target: a boulder seen only in a glossy plate; see
benchmarks/mlt_oracle.py for what an ideal Metropolis sampler could gain there) and
scenes_xml/quay_wall.xml (diagnostic, no target: a multibeam frame of a quay wall and piles on the
seabed, whose dihedral corner echoes need about 28 000 paths per beam for 5 % with path tracing; see
benchmarks/dihedral.py), with path tracing (``sonar_tof``, the baseline)
and ``sonar_mlt`` at the same time budgets, and prints one JSON object.

The headline figure per scene is the equal-time error ratio ``rel_l2(sonar_tof) / rel_l2(sonar_mlt)``
(> 1: Metropolis is better), the geometric mean over the budgets of the time-adjusted ratios
(each error scaled by sqrt(its measured seconds), i.e. compared at exactly equal time), on the
relative L2 error over all bins with the reference's own noise removed (`rel_l2_debiased`).
Targets (issue "Metropolis that wins", `TARGETS`): hidden_target and periscope >= 2, glossy_corridor
>= 1.2, box, slot_chamber and intake >= 1/1.1. The JSON says for each scene whether its target is met,
and the lines of ``verdict`` say it in words, including where Metropolis loses.

Renders are timed warm: each new spp is rendered once untimed first, so an integrator whose kernels
are compiled again for every spp is timed at its steady-state speed (the compilations it needed
are counted in ``kernels_compiled``; ``--cold`` times wall-clock renders instead).

The references are cached in the output folder (default out/benchmark_mlt/<scene>/), so a second
run only renders the comparisons (the JSON's ``seconds_total`` says how long a run took). Six
repeats by default, because the errors are heavy-tailed (rare glossy paths): the ratio of a few
repeats swings between runs (README, Benchmarks).

Usage: python benchmarks/mlt.py [--budget 0.25,0.5,1,2] [--repeats 6] [--integrators sonar_tof,sonar_mlt] [--split auto]
                                [--scenes box,slot_chamber,glossy_corridor,hidden_target,quay_wall]
                                [-o out/benchmark_mlt] [--reference-factor 16]
"""
from __future__ import annotations

import argparse
import json
import math
import os
import sys
import time

HERE = os.path.dirname(os.path.abspath(__file__))
SCENES = os.path.join(HERE, "..", "scenes_xml")

#: Role, target ratio (err_baseline / err_mlt must reach it) and its wording, per scene (issue
#: "Metropolis that wins"; the baseline is sonar_tof with its defaults, image guided since then).
TARGETS = {
    "box": ("easy", 1 / 1.1, "no worse than 1.1x path tracing's error"),
    "slot_chamber": ("easy", 1 / 1.1, "no worse than 1.1x path tracing's error"),
    "intake": ("easy", 1 / 1.1, "no worse than 1.1x path tracing's error"),
    "glossy_corridor": ("hard", 1.2, "at least 1.2x lower error than path tracing"),
    "hidden_target": ("hard", 2.0, "at least 2x lower error than path tracing"),
    "periscope": ("hard", 2.0, "at least 2x lower error than path tracing"),
    "quay_wall": ("diagnostic", None, None),
}
#: Range windows scored on their own (information only; the targets use the whole scan).
REGIONS = {
    "slot_chamber": {"beyond_wall": (3.6, 12.0)},
    "glossy_corridor": {"beyond_8m": (8.0, 12.0)},
    "hidden_target": {"boulder_by_mirror": (6.0, 10.0)},
    "periscope": {"boulder_by_two_mirrors": (10.4, 14.0)},
    "quay_wall": {"wall_corner": (10.4, 12.0)},
}


def _geomean(values):
    vals = [v for v in values if v is not None and math.isfinite(v) and v > 0]
    return math.exp(sum(math.log(v) for v in vals) / len(vals)) if vals else None


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--budget", default="0.25,0.5,1,2", help="seconds per render (default 0.25,0.5,1,2)")
    ap.add_argument("--repeats", type=int, default=6)
    ap.add_argument("--integrators", default="sonar_tof,sonar_mlt",
                    help="baseline,contender (default sonar_tof,sonar_mlt; sonar_tof,sonar_tof tests the machinery)")
    ap.add_argument("--scenes", default=",".join(TARGETS),
                    help=f"scene names in scenes_xml/ (default {','.join(TARGETS)})")
    ap.add_argument("--split", default="auto",
                    help="sonar_mlt's split (auto: the pilot's share; a share in [0, 0.9]; off: chains over every "
                         "echo); its default, 0, is the path tracer itself (default auto)")
    ap.add_argument("-o", "--output", default=os.path.join("out", "benchmark_mlt"))
    ap.add_argument("--reference-factor", type=float, default=16.0)
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--cold", action="store_true",
                    help="time renders cold (compilations at a new spp included) instead of warm")
    ap.add_argument("-q", "--quiet", action="store_true", help="no progress lines on stderr")
    args = ap.parse_args(argv)

    import mitsonar  # noqa: F401  (variant and plugins)
    from mitsonar.jobs.compare import CompareError, compare, jsonable, load_integrator
    from mitsonar.jobs.compare.parsing import parse_budgets, parse_integrators

    try:
        names = parse_integrators(args.integrators)
        budgets = parse_budgets(args.budget)
        if len(names) != 2:
            raise CompareError(f"--integrators {args.integrators!r}: give exactly two, the baseline first")
        for name in names:
            load_integrator(name)
    except CompareError as exc:
        print(f"benchmarks/mlt.py: {exc}", file=sys.stderr)
        return 2
    scenes = [s.strip() for s in args.scenes.split(",") if s.strip()]
    for s in scenes:
        if not os.path.isfile(os.path.join(SCENES, f"{s}.xml")):
            print(f"benchmarks/mlt.py: scene {s!r}: scenes_xml/{s}.xml does not exist", file=sys.stderr)
            return 2

    def log(line):
        if not args.quiet:
            print(line, file=sys.stderr, flush=True)

    base, other = names[0], (names[1] if names[1] != names[0] else f"{names[1]}#2")
    try:
        split = float(args.split)
    except ValueError:
        split = args.split
    params = {other: {"split": split}} if names[1] == "sonar_mlt" else None
    t_start = time.perf_counter()
    out = {"benchmark": "mlt_vs_path_tracing_equal_time", "integrators": [base, other], "budgets_s": budgets,
           "repeats": args.repeats, "timing": "cold (compilations included)" if args.cold else
           "warm (an untimed render at each new spp first: steady-state speed)",
           "reference_factor": args.reference_factor, "seed": args.seed,
           "ratio": f"rel_l2_debiased({base}) / rel_l2_debiased({other}) at equal time (> 1: {other} better); "
                    "headline = geometric mean over budgets of the time-adjusted ratios",
           "scenes": {}, "verdict": []}
    for s in scenes:
        role, target, wording = TARGETS.get(s, ("unclassified", None, None))
        folder = os.path.join(args.output, s)
        log(f"== {s} ({role})")
        result = compare(os.path.join(SCENES, f"{s}.xml"), names, budgets, folder, seed=args.seed,
                         repeats=args.repeats, regions=REGIONS.get(s), reference_factor=args.reference_factor,
                         warm=not args.cold, log=log, integrator_params=params)
        et = result["equal_time"]
        adjusted = [e["ratios"][other]["ratio_time_adjusted"] for e in et]
        raw = [e["ratios"][other]["ratio_raw"] for e in et]
        headline = _geomean(adjusted)
        runs = {lab: [r for r in result["runs"] if r["integrator"] == lab] for lab in (base, other)}
        entry = {
            "role": role,
            "target": None if target is None else {"ratio_at_least": target, "meaning": f"{other} {wording}"},
            "ratio": headline,
            "ratio_per_budget": [{"budget_s": e["budget_s"], "time_adjusted": a, "raw": r}
                                 for e, a, r in zip(et, adjusted, raw)],
            "meets_target": None if target is None or headline is None else bool(headline >= target),
            "errors": {lab: [{"budget_s": r["budget_s"], "spp": r["spp"], "seconds": r["seconds_mean"],
                              "rel_l2": r["rel_l2"], "rel_l2_debiased": r["rel_l2_debiased"], "rel_l1": r["rel_l1"]}
                             for r in rr] for lab, rr in runs.items()},
            "regions": {rn: _geomean([e["ratios"][other]["regions"][rn]["ratio_time_adjusted"] for e in et])
                        for rn in result["settings"]["regions"]},
            "reference": {k: result["reference"][k] for k in ("spp", "seconds", "self_rel_l2", "from_cache")},
            "kernels_compiled": {lab: {"timed": sum(sum(r["compiled_kernels"]) for r in rr),
                                       "warm_up": sum(r["warmup_compiled_kernels"] or 0 for r in rr)}
                                 for lab, rr in runs.items()},
            "warnings": result["warnings"],
            "output": result["files"]["json"],
        }
        out["scenes"][s] = entry
        if headline is None:
            out["verdict"].append(f"{s}: no finite ratio (see {entry['output']})")
        else:
            better = f"{headline:.2f}x lower" if headline >= 1 else f"{1 / headline:.2f}x higher"
            line = f"{s} ({role}): {other}'s relative L2 error is {better} than {base}'s at equal time"
            if target is not None:
                line += (f"; target ({wording}) met" if entry["meets_target"]
                         else f"; target ({wording}) MISSED")
            out["verdict"].append(line)
    out["seconds_total"] = time.perf_counter() - t_start
    out["environment"] = result["environment"] if scenes else {}
    json.dump(jsonable(out), sys.stdout, indent=2)
    print()
    return 0


if __name__ == "__main__":
    sys.exit(main())
