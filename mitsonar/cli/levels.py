"""``mitsonar levels``: the sonar equation of a scene's head (`mitsonar.sonar_equation.report`)."""
from __future__ import annotations

import os

from mitsonar.sonar_equation.report import plot_levels, sonar_equation_report


class LevelsCLIError(ValueError):
    pass


def add_subcommands(sub):
    s = sub.add_parser("levels", help="the sonar equation of a scene's head: SL, TL, EL, NL, DI, SNR",
                       description="Render a scene (or read a scan file) and print the sonar equation: the "
                                   "head's source level, noise, receiver bandwidth and directivity index, and per ping "
                                   "the strongest echo's range, echo level, transmission loss, implied target "
                                   "strength (or S_b + 10 log A) and SNR; optionally a figure of echo level "
                                   "and noise against range.")
    s.add_argument("scene", help="scene XML file, or a scan file (.exr/.npz)")
    s.add_argument("--sensor", type=int, default=0, help="sensor index in the scene (default 0)")
    s.add_argument("--spp", type=int, default=256, help="paths per ping (default 256)")
    s.add_argument("--seed", type=int, default=0, help="seed of the paths (default 0)")
    s.add_argument("--rows", type=int, default=20, help="pings listed, evenly spaced (default 20; 0: all)")
    from mitsonar.cli.common import add_force, add_output

    add_output(s, "-o", "--output", help="figure of echo level and noise against range (.png/.pdf/.svg)")
    add_force(s)
    s.set_defaults(func=cmd_levels)


def cmd_levels(args):
    if args.output is not None:
        from mitsonar._files import check_output_file

        check_output_file(args.output, LevelsCLIError, extensions=(".png", ".pdf", ".svg"), words={
            "extension": "-o {path!r}: the extension must be one of {allowed_list}",
            "directory": "-o {path!r}: not a file in an existing folder",
            "no_folder": "-o {path!r}: not a file in an existing folder",
            "not_writable": "-o {path!r}: folder {folder!r} is not writable"})
    if args.spp < 1 or args.rows < 0 or args.sensor < 0:
        raise LevelsCLIError("--spp must be >= 1, --rows and --sensor >= 0")
    if os.path.isdir(args.scene):
        raise LevelsCLIError(f"{args.scene}: is a directory; expected a scene XML file or a scan file (.exr/.npz)")
    if not os.path.isfile(args.scene):
        raise LevelsCLIError(f"{args.scene}: no such file")
    report = sonar_equation_report(args.scene, spp=args.spp, seed=args.seed, sensor=args.sensor)
    print(report.table(args.rows))
    if args.output:
        plot_levels(report, args.output)
        print(f"wrote {args.output}")
    return 0
