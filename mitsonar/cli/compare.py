"""``mitsonar compare``: integrators at equal time against a cached reference (see `mitsonar.jobs.compare`)."""
from __future__ import annotations

import sys

from mitsonar.jobs.compare import DEFAULT_REFERENCE_FACTOR, DEFAULT_REPEATS


def add_subcommands(subparsers):
    """Add the ``compare`` subcommand to the ``mitsonar`` parser's subparsers."""
    c = subparsers.add_parser(
        "compare", help="error versus time of sonar integrators against a cached reference",
        description="Render a high-sample sonar_tof reference of SCENE once (cached in the output folder), "
                    "then every integrator at every time budget, and write compare.json (errors per ping "
                    "and overall versus seconds, settings), convergence.png and polar.png.",
        epilog="Which integrator where (docs/howto/choose_integrator.rst, numbers in docs/benchmarks.rst): "
               "sonar_tof, the default, on every scene measured (its pilot's allocation: 2.2x less error at "
               "equal time on pile_quay, 1.8x on intake, 1.4x on box); sonar_mlt with no parameters is sonar_tof, its "
               "chains lost 2-16x at equal time (split=off, split=auto); sonar_bdpt to check echoes "
               "through openings. Compared here, sonar_mlt runs its chains (split=off) unless "
               "--param sonar_mlt.split=... says otherwise.")
    c.add_argument("scene", help="scene XML file")
    c.add_argument("--integrators", default="sonar_tof,sonar_mlt",
                   help="comma-separated integrator plugins; the first is the baseline (default sonar_tof,sonar_mlt)")
    c.add_argument("--budget", default="2,4,8,16", help="seconds per render, comma-separated (default 2,4,8,16)")
    from mitsonar.cli.common import add_output

    add_output(c, "-o", "--output", default="cmp", reused=True,
               help="output folder (default cmp/; its cached reference is reused, its results replaced)")
    c.add_argument("--reference-spp", type=int,
                   help="paths per ping of the reference (default: --reference-factor times the spp sonar_tof "
                        "reached at the largest budget, or a larger cached reference)")
    c.add_argument("--reference-factor", type=float, default=DEFAULT_REFERENCE_FACTOR,
                   help=f"see --reference-spp (default {DEFAULT_REFERENCE_FACTOR:g})")
    c.add_argument("--seed", type=int, default=0, help="base seed (default 0)")
    c.add_argument("--repeats", type=int, default=DEFAULT_REPEATS,
                   help=f"renders per integrator and budget (default {DEFAULT_REPEATS})")
    c.add_argument("--max-depth", type=int, help="surface bounces (default: the scene's integrator)")
    c.add_argument("--param", action="append", metavar="INTEGRATOR.NAME=VALUE",
                   help="an integrator parameter, e.g. --param sonar_mlt.large_step=0.3 (repeatable)")
    c.add_argument("--region", action="append", metavar="NAME=LO:HI",
                   help="also score the bins with range in [LO, HI) metres, e.g. --region chamber=3.6:12 (repeatable)")
    c.add_argument("--calibration-seconds", type=float,
                   help="length of the longest timing render (default min(0.5, smallest budget / 2))")
    c.add_argument("--warm", action="store_true",
                   help="render once, untimed, at each new spp before timing: steady-state speed of an integrator "
                        "that compiles kernels per spp (default: wall-clock time, compilations included)")
    c.add_argument("--paths-per-second", type=float, metavar="R",
                   help="time renders by a deterministic count instead of the wall clock: a render of N paths per "
                        "ping over P pings takes N*P/R seconds, so each budget fixes the spp (equal work; the same "
                        "results on any machine and load)")
    c.add_argument("--no-plots", action="store_true", help="write compare.json only")
    c.add_argument("-q", "--quiet", action="store_true", help="no progress lines")
    c.set_defaults(func=cmd_compare)


def cmd_compare(args):
    from mitsonar.jobs.compare import compare
    from mitsonar.jobs.compare.parsing import parse_budgets, parse_integrators, parse_params, parse_regions

    # Parse everything before the slow part starts, so typos fail at once (compare checks the
    # rest, the scene, the integrators and the output folder, before it creates anything).
    names = parse_integrators(args.integrators)
    budgets = parse_budgets(args.budget)
    params = parse_params(args.param)
    regions = parse_regions(args.region)

    def log(line):
        print(line, file=sys.stderr, flush=True)

    result = compare(args.scene, names, budgets, args.output, reference_spp=args.reference_spp, seed=args.seed,
                     repeats=args.repeats, max_depth=args.max_depth, integrator_params=params, regions=regions,
                     reference_factor=args.reference_factor, calibration_seconds=args.calibration_seconds,
                     warm=args.warm, plots=not args.no_plots, log=None if args.quiet else log,
                     paths_per_second=args.paths_per_second)
    print(report(result))
    return 0


def report(result) -> str:
    """The printed summary of a `compare` result: the reference, one line per run (the integrator
    with the parameters it ran with) with the asked and the achieved seconds (``*`` where they
    differ by more than `TIME_TOLERANCE`), the warnings (printed here only), files."""
    from mitsonar.jobs.compare import TIME_TOLERANCE, off_budget

    ref = result["reference"]
    off = {(r["integrator"], r["budget_s"]) for r in off_budget(result["runs"])}
    # each integrator with the parameters it ran with (``sonar_mlt (split=off)``: its chains)
    shown = {lab: info.get("shown_as", lab) for lab, info in result.get("integrators", {}).items()}
    width = max([16] + [len(v) for v in shown.values()])
    lines = [f"reference: {ref['integrator']} {ref['spp']} spp, own rel L2 {ref['self_rel_l2']:.3g}"
             + (" (cached)" if ref["from_cache"] else f" ({ref['seconds']:.3g} s)"),
             f"{'integrator':<{width}} {'asked s':>8} {'took s':>8} {'spp':>10} {'rel L2':>9} {'rel L1':>9}"]
    for r in result["runs"]:
        mark = " *" if (r["integrator"], r["budget_s"]) in off else ""
        lines.append(f"{shown.get(r['integrator'], r['integrator']):<{width}} {r['budget_s']:>8g} "
                     f"{r['seconds_mean']:>8.3g} {r['spp']:>10d} {r['rel_l2']:>9.4g} {r['rel_l1']:>9.4g}{mark}")
    if off:
        lines.append(f"* took more than {100 * TIME_TOLERANCE:.0f} % more or less than asked")
    lines += [f"warning: {w}" for w in result["warnings"]]
    lines.append("wrote " + ", ".join(result["files"].values()))
    return "\n".join(lines)
