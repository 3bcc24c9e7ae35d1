"""``mitsonar map``: learn a Hilbert map from scan files.

    mitsonar map scans/*.exr -o map.npz [--inducing 3000] [--plot slices.png] [--mesh map.ply]

The main CLI calls :func:`add_subcommands`. Every failure the user can cause ends in one line on
stderr and a non-zero exit code.
"""
from __future__ import annotations

import os
import sys

EXIT_ERROR = 1
EXIT_USAGE = 2


def add_subcommands(subparsers) -> None:
    m = subparsers.add_parser(
        "map", help="learn a 3-D occupancy map (Hilbert map) from scan files",
        description="Learn a continuous 3-D occupancy map (Hilbert map, thesis chapter 4) from scans "
                    "(.exr or .npz written by `mitsonar render` or Scan.save) and save it as .npz.")
    m.add_argument("scans", nargs="+", help="scan files (.exr or .npz) or raw SeaNet logs from `mitsonar record`")
    m.add_argument("-o", "--output", required=True, help="map file to write (.npz)")
    m.add_argument("--inducing", type=int, default=3000, help="Nystroem inducing points (default 3000)")
    m.add_argument("--passes", type=int, default=None, help="SGD passes over the samples (default: the map's)")
    m.add_argument("--source", choices=("auto", "data", "intensity"), default="auto",
                   help="what the bins are classified on (default auto: data unless all zero)")
    m.add_argument("--seed", type=int, default=0, help="random seed (default 0)")
    m.add_argument("--plot", help="also write cross-sections through the sonar (.png/.pdf/.svg)")
    m.add_argument("--mesh", help="also write the surface as a triangle mesh (.ply or .obj)")
    m.add_argument("--surface", choices=("ridge", "level"), default="ridge",
                   help="surface of --mesh: the probability ridge (default) or the 0.5 level")
    m.add_argument("--resolution", type=float, default=None, help="mesh grid step in metres (default auto)")
    m.add_argument("-q", "--quiet", action="store_true", help="print nothing on success")
    m.set_defaults(func=cmd_map)


def _fail(msg: str, code: int = EXIT_ERROR) -> int:
    print(f"mitsonar map: error: {msg}", file=sys.stderr)
    return code


# The map's own messages name its parameters; on the command line they are these options.
_OPTIONS = (("n_inducing", "--inducing"), ("n_passes", "--passes"), ("resolution", "--resolution"))


def _map_error(exc: Exception) -> str:
    msg = str(exc).replace("HilbertMap: ", "")
    for name, option in _OPTIONS:
        msg = msg.replace(name, option)
    return msg


def cmd_map(args) -> int:
    if args.inducing is None or args.inducing < 1:
        return _fail("--inducing must be a positive integer", EXIT_USAGE)
    if args.passes is not None and args.passes < 1:
        return _fail("--passes must be a positive integer", EXIT_USAGE)
    if args.resolution is not None and not args.resolution > 0:
        return _fail("--resolution must be positive", EXIT_USAGE)
    out_ext = os.path.splitext(args.output)[1].lower()
    if out_ext != ".npz":
        return _fail(f"{args.output}: the map is written as .npz", EXIT_USAGE)
    if args.mesh and os.path.splitext(args.mesh)[1].lower() not in (".ply", ".obj"):
        return _fail(f"{args.mesh}: meshes are written as .ply or .obj", EXIT_USAGE)
    if args.plot and os.path.splitext(args.plot)[1].lower() not in (".png", ".pdf", ".svg", ".jpg"):
        return _fail(f"{args.plot}: pictures are written as .png, .pdf, .svg or .jpg", EXIT_USAGE)
    for path in args.scans:
        if not os.path.exists(path):
            return _fail(f"{path}: no such file")
        if os.path.isdir(path):
            return _fail(f"{path}: is a directory, not a scan file")

    from mitsonar import load_scan  # lazily: the map command needs no renderer
    from mitsonar.micron import LOG_MAGIC, replay

    scans = []
    for path in args.scans:
        try:
            with open(path, "rb") as fh:
                is_log = fh.read(len(LOG_MAGIC)) == LOG_MAGIC
            # A device log holds whole turns of a real (or virtual) head: each becomes a scan.
            if is_log:
                got = replay(path)
                if not got:
                    return _fail(f"{path}: no complete scan in the log (the recording ends before the head "
                                 "finished its first sweep)")
                scans.extend(got)
            else:
                scans.append(load_scan(path))
        except Exception as exc:  # one line: which file, and why
            reason = str(exc).strip().splitlines()[0] if str(exc).strip() else type(exc).__name__
            return _fail(f"{path}: cannot read the scan ({reason})")

    from hilbertmap import HilbertMap, write_mesh

    params = dict(n_inducing=args.inducing, random_state=args.seed, source=args.source)
    if args.passes is not None:
        params["n_passes"] = args.passes
    hm = HilbertMap(**params)
    try:
        hm.fit(scans)
    except ValueError as exc:
        return _fail(_map_error(exc))
    if args.mesh:  # before anything is written: a grid too fine for the region fails here
        try:
            V, F = hm.surface(args.surface, resolution=args.resolution)
        except ValueError as exc:
            return _fail(_map_error(exc))
    try:
        hm.save(args.output)
    except OSError as exc:
        return _fail(f"{args.output}: {exc.strerror or exc}")
    written = [args.output]
    if args.mesh:
        try:
            write_mesh(args.mesh, V, F)
        except OSError as exc:
            return _fail(f"{args.mesh}: {exc.strerror or exc}")
        written.append(f"{args.mesh} ({len(F)} triangles)")
    if args.plot:
        from hilbertmap.plots import plot_slices

        c = hm.sensor_positions_.mean(axis=0) if len(hm.sensor_positions_) else (0.0, 0.0, 0.0)
        slices = (("z", float(c[2])), ("y", float(c[1])), ("x", float(c[0])))
        try:
            plot_slices(hm, slices, path=args.plot, title=f"Hilbert map of {len(scans)} scan(s)")
        except OSError as exc:
            return _fail(f"{args.plot}: {exc.strerror or exc}")
        written.append(args.plot)
    if not args.quiet:
        t = hm.timings_
        print(f"map: {len(scans)} scan(s), {hm.n_schedule_} training samples, "
              f"{len(hm.inducing_points_)} inducing points "
              f"(length-scale {hm.lengthscale_:.3f} m), fit {t['total_s']:.1f} s; wrote {', '.join(written)}")
    return 0
