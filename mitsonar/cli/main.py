"""The ``mitsonar`` command line: render scenes, plot and inspect scans, run the demo.

Every failure the user can cause ends in one line on stderr and a non-zero exit code;
set ``MITSONAR_DEBUG=1`` to see Python tracebacks.
"""
from __future__ import annotations

import argparse
import importlib
import os
import sys
import time

from mitsonar import _files
import mitsonar.kinds as kinds
from mitsonar._checks import first_line

EXIT_USAGE = 2
EXIT_ERROR = 1

HERE = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))  # the mitsonar package


#: The modules of `mitsonar.cli` that add subcommands (each has ``add_subcommands(subparsers)``).
SUBCOMMAND_MODULES = ("serial", "map", "compare", "survey", "export", "bathymetry", "dataset", "levels", "live",
                      "scene")


class CLIError(Exception):
    """A user-facing failure: the message is printed as is."""


# ----------------------------------------------------------------------------- helpers
def _parse_settings(items):
    """``name=value`` pairs for electronics overrides; numbers become int/float."""
    out = {}
    for item in items or []:
        if "=" not in item:
            raise CLIError(f"--set expects name=value, got {item!r}")
        key, value = item.split("=", 1)
        for conv in (int, float):
            try:
                value = conv(value)
                break
            except ValueError:
                continue
        out[key.strip()] = value
    return out


class _Progress:
    """A render's progress bar: call it as ``progress(done, total)``, then `close` it. The bar
    starts with the render, so its rate is spp over the time since then (``smoothing=0``; a rate
    over the moment between the bar's creation and the first pass's end means nothing), and it
    shows only after half a second (a quick render needs no bar)."""

    def __init__(self):
        self.start = time.time()
        self.bar = None

    def __call__(self, done, total):
        if self.bar is None:
            from tqdm import tqdm

            self.bar = tqdm(total=total, unit="spp", desc="rendering", leave=False, file=sys.stderr,
                            smoothing=0, delay=0.5)
            self.bar.start_t = self.start
        self.bar.update(done - self.bar.n)

    def close(self):
        if self.bar is not None:
            self.bar.close()


def _render(scene_path, spp, seed, max_depth=None, electronics=None, quiet=False, mesh=False, sensor=None):
    """Load and render a scene: ``(scene, scan, mesh)``, the ground-truth mesh (when ``mesh``, or
    ``mesh(sonar)`` is true) made before the render, so a scene that cannot be triangulated costs
    no render. ``sensor``: ``--sensor`` (an XML id or an index; None: the first sonar, with one
    warning when the scene has several)."""
    import mitsonar

    from mitsonar.sim.render import pick_sensor

    scene = mitsonar.load_scene(scene_path)
    sonar = pick_sensor(scene, sensor)
    truth = mitsonar.scene_mesh(scene) if (mesh(sonar) if callable(mesh) else mesh) else None
    progress = None if quiet else _Progress()
    try:
        scan = mitsonar.render_scan(scene, spp=spp, seed=seed, max_depth=max_depth, sensor=sonar,
                                    electronics=electronics, progress=progress)
    finally:
        if progress is not None:
            progress.close()
    return scene, scan, truth


#: The pictures that make sense for each sonar kind; the first is the default (a live view of the
#: kinds' ``pictures``, `mitsonar.kinds`).
PICTURES = kinds.by_name("pictures")
ALL_PICTURES = ("polar", "cartesian", "ascan", "waterfall")


def picture_for(sonar_kind, picture=None):
    """The picture for a scan of ``sonar_kind``: ``picture``, or the kind's default (polar, or
    waterfall for a side-scan); one line naming the allowed pictures for one that means nothing for
    it (a side-scan's rows are not bearings: no polar or cartesian fan)."""
    known = kinds.lookup(sonar_kind)
    allowed = ALL_PICTURES[:3] if known is None else known.pictures
    if picture is None:
        return allowed[0]
    if picture not in allowed:
        raise CLIError(f"--picture {picture}: not for a {sonar_kind} scan (allowed for {sonar_kind}: "
                       f"{', '.join(allowed)})")
    return picture


def _plot(scan, path, picture=None, ping=0, db=False, use="data", mesh=None):
    from mitsonar.products import plots

    picture = picture_for(scan.kind, picture)
    if picture == "polar":
        plots.plot_polar(scan, path, db=db, use=use)
    elif picture == "cartesian":
        plots.plot_cartesian(scan, mesh=mesh, path=path, db=db, use=use)
    elif picture == "waterfall":
        from mitsonar.products.sidescan_plots import plot_waterfall

        plot_waterfall(scan, path, use="intensity" if db else use)
    elif picture == "ascan":
        if not 0 <= ping < scan.n_pings:
            raise CLIError(f"--ping {ping} is outside 0..{scan.n_pings - 1}")
        plots.plot_ascan(scan, ping, path, db=db)


#: `_check_output`'s sentences (`mitsonar._files.check_output_file`).
_OUTPUT_WORDS = {"directory": "output {path!r} is a directory",
                 "extension": "output {path!r}: the extension must be one of {allowed_list}",
                 "no_folder": "output {path!r}: folder {folder!r} does not exist",
                 "not_writable": "output {path!r} is not writable"}


def _check_output(path, exts):
    """Before any work: an output that cannot be written costs a sentence, not a render."""
    _files.check_output_file(path, CLIError, extensions=exts, words=_OUTPUT_WORDS)


def make_output_folder(path, option="-o"):
    """Create an output folder (and parents), or say in one sentence why it cannot be."""
    _files.make_output_folder(path, CLIError, option)


# ----------------------------------------------------------------------------- commands
def cmd_render(args):
    from mitsonar.cli.common import check_counts

    old_picture_flag(args)
    _check_output(args.output, (".exr", ".npz"))
    if args.plot:
        _check_output(args.plot, (".png", ".pdf", ".svg"))
    check_counts(args, CLIError)
    settings = _parse_settings(args.set)
    if settings:  # name the option in the message, and before the render
        from mitsonar.receiver.electronics import Electronics, check_head_settings

        try:
            check_head_settings(settings, "--set")
            Electronics.from_dict(settings, source="--set")
        except ValueError as exc:
            raise CLIError(str(exc)) from None
    picture = args.picture

    def before_render(sonar):       # the picture, checked against the head's kind
        nonlocal picture
        if args.plot:
            picture = picture_for(sonar.kind, picture)
        return bool(args.plot) and picture == "cartesian"

    _, scan, mesh = _render(args.scene, args.spp, args.seed, args.max_depth, settings, args.quiet,
                            mesh=before_render, sensor=args.sensor)
    scan.save(args.output)
    from mitsonar.products.plots import rows_text

    print(f"wrote {args.output} ({rows_text(scan)} x {scan.n_bins} bins)")
    if args.plot:
        _plot(scan, args.plot, picture, db=args.db, mesh=mesh)
        print(f"wrote {args.plot}")
    return 0


def cmd_plot(args):
    import mitsonar

    old_picture_flag(args)
    _check_output(args.output, (".png", ".pdf", ".svg"))
    scan = mitsonar.load_scan(args.scan)
    picture_for(scan.kind, args.picture)      # before the scene's mesh is made
    mesh = None
    if args.scene:
        mesh = mitsonar.scene_mesh(mitsonar.load_scene(args.scene))
    _plot(scan, args.output, args.picture, args.ping, args.db, args.use, mesh)
    print(f"wrote {args.output}")
    return 0


def _format_value(v, most=8):
    """A value on one line; a list or array longer than ``most`` as its length, range and ends."""
    import numpy as np

    if isinstance(v, float):
        return f"{v:.10g}"
    if isinstance(v, (list, tuple, np.ndarray)) and len(v) > most:
        try:
            a = np.asarray(v)
        except ValueError:  # ragged nesting
            return f"{len(v)} values"
        if a.dtype.kind in "biuf" and a.ndim == 1:
            ends = ", ".join(_format_value(x.item()) for x in a[:3])
            return (f"{a.size} values, {_format_value(a.min().item())} .. {_format_value(a.max().item())} "
                    f"({ends}, ...)")
        return f"{len(v)} values ({type(v).__name__} of shape {a.shape})"
    return str(v)


def cmd_info(args):
    import numpy as np

    import mitsonar

    scan = mitsonar.load_scan(args.scan)
    rows = [
        ("file", args.scan), ("kind", scan.kind), (scan.row_name, scan.n_pings), ("bins", scan.n_bins),
        ("range [m]", f"{scan.range_min:g} .. {scan.range_max:g} (bin {scan.bin_width:.6g} m)"),
        ("bearings [deg]", f"{np.degrees(scan.bearings[0]):.6g} .. {np.degrees(scan.bearings[-1]):.6g}"
                           + (f" step {np.degrees(scan.bearings[1] - scan.bearings[0]):.6g}" if scan.n_pings > 1 else "")),
        ("ping times [s]", f"{scan.times[0]:.6g} .. {scan.times[-1]:.6g}"
                           + ("" if scan.meta.start_time is None else f" (start {scan.meta.start_time:.9g} on "
                              + ("the trajectory)" if scan.meta.source is None else "the head's clock)"))),
        ("beam", f"{scan.beam_pattern} {scan.beamwidth_h:g} x {scan.beamwidth_v:g} deg"),
        ("sound speed [m/s]", scan.sound_speed), ("absorption [dB/m]", scan.absorption),
        (f"position ({scan.row_name[:-1]} 0)", " ".join(f"{v:.6g}" for v in scan.positions[0])),
        (f"boresight ({scan.row_name[:-1]} 0)", " ".join(f"{v:.6g}" for v in scan.boresights[0])),
        ("intensity", f"sum {float(scan.intensity.sum()):.6g}, max {float(scan.intensity.max()):.6g}"),
        ("data", f"mean {float(scan.data.mean()):.4g}, max {int(scan.data.max())}"),
    ]
    rows += [(f"electronics.{k}", v) for k, v in scan.electronics.to_dict().items()]
    rows += [(f"meta.{k}", v) for k, v in scan.meta.to_dict().items()]
    width = max(len(k) for k, _ in rows)
    for k, v in rows:
        print(f"{k:<{width}}  {_format_value(v)}")
    return 0


def _scenes_dir():
    for cand in (os.path.join(os.getcwd(), "scenes_xml"), os.path.join(HERE, "..", "scenes_xml")):
        if os.path.isdir(cand):
            return os.path.abspath(cand)
    raise CLIError("cannot find the scenes_xml folder (run the demo from the repository root)")


#: The files `mitsonar demo` writes (besides the harbour survey's pictures).
DEMO_SCENES = ("box", "intake", "box_fls")
DEMO_FILES = tuple(f"{n}{x}" for n in DEMO_SCENES for x in (".exr", "_polar.png", "_cartesian.png", "_ascan.png"))
#: The harbour survey's pictures among them (`mitsonar.cli.survey.demo_survey`).
DEMO_HARBOUR = r"harbour_(mechanical_\d+|multibeam_\d+s|track)\.png"


def cmd_demo(args):
    from mitsonar.cli.common import check_counts

    check_counts(args, CLIError)
    scenes = _scenes_dir()
    make_output_folder(args.output)
    for name in DEMO_SCENES:
        path = os.path.join(scenes, f"{name}.xml")
        _, scan, mesh = _render(path, args.spp, args.seed, quiet=args.quiet, mesh=True)
        exr = os.path.join(args.output, f"{name}.exr")
        scan.save(exr)
        polar = os.path.join(args.output, f"{name}_polar.png")
        cart = os.path.join(args.output, f"{name}_cartesian.png")
        ascan = os.path.join(args.output, f"{name}_ascan.png")
        _plot(scan, polar, "polar")
        _plot(scan, cart, "cartesian", mesh=mesh)
        _plot(scan, ascan, "ascan", ping=scan.sonar_kind.ascan_row(scan.n_pings))  # a fan's centre row
        print(f"{name}: wrote {exr}, {polar}, {cart}, {ascan}")
    from mitsonar.cli.survey import demo_survey  # a survey scene with both heads along its track
    print(f"harbour survey: wrote {', '.join(demo_survey(scenes, args.output, args.spp, args.seed, args.quiet))}")
    return 0


# ----------------------------------------------------------------------------- parser
PICTURE_HELP = ("the picture: polar (default), cartesian or ascan for a mechanical or multibeam scan; "
                "waterfall (default) or ascan for a side-scan scan")


def add_picture(parser):
    """``--picture``, and its old name ``--kind`` (hidden; `old_picture_flag` warns until 0.4.0)."""
    parser.add_argument("--picture", choices=ALL_PICTURES, help=PICTURE_HELP)
    parser.add_argument("--kind", dest="old_picture", choices=ALL_PICTURES, help=argparse.SUPPRESS)


def old_picture_flag(args):
    """``--kind`` (the old name of ``--picture``): a warning naming the new flag, its value taken."""
    if getattr(args, "old_picture", None) is None:
        return
    import warnings

    from mitsonar._moved import warn_renamed

    with warnings.catch_warnings():
        warnings.simplefilter("always", DeprecationWarning)   # the user sees it (a console script)
        warn_renamed("mitsonar render/plot --kind")
    if args.picture is not None and args.picture != args.old_picture:
        raise CLIError(f"--kind {args.old_picture}: the old name of --picture, which says {args.picture}")
    args.picture = args.old_picture


def build_parser():
    from mitsonar.cli.common import add_force, add_output, add_sensor, files_in_folder

    from mitsonar._version import __version__

    p = argparse.ArgumentParser(prog="mitsonar", description="Physically based imaging-sonar simulation.")
    p.add_argument("--version", action="version", version=f"mitsonar {__version__}",
                   help="print the version and exit")
    p.add_argument("--variant", help="Mitsuba variant: llvm_ad_mono (default), cuda_ad_mono or auto "
                                     "(same as MITSONAR_VARIANT)")
    sub = p.add_subparsers(dest="command", metavar="COMMAND")

    r = sub.add_parser("render", help="render a scene to a scan file (EXR or NPZ)",
                       description="Render the sonar scan of a Mitsuba XML scene.")
    r.add_argument("scene", help="scene XML file")
    add_output(r, "-o", "--output", required=True, help="scan file to write (.exr or .npz)")
    r.add_argument("--spp", type=int, default=4096, help="paths per ping (default 4096)")
    r.add_argument("--seed", type=int, default=0, help="random seed (default 0)")
    r.add_argument("--max-depth", type=int, help="surface bounces (default: the scene's integrator)")
    add_sensor(r)
    r.add_argument("--set", action="append", metavar="NAME=VALUE",
                   help="override an electronics setting, e.g. --set gain=30 (repeatable)")
    add_output(r, "--plot", help="also write a picture (.png/.pdf/.svg)")
    add_picture(r)
    r.add_argument("--db", action="store_true", help="plot in dB")
    r.add_argument("-q", "--quiet", action="store_true", help="no progress bar")
    add_force(r)
    r.set_defaults(func=cmd_render)

    pl = sub.add_parser("plot", help="draw a scan file", description="Draw a scan as a sonar display.")
    pl.add_argument("scan", help="scan file (.exr or .npz)")
    add_output(pl, "-o", "--output", required=True, help="picture to write (.png/.pdf/.svg)")
    add_picture(pl)
    pl.add_argument("--ping", type=int, default=0, help="ping of the A-scan")
    pl.add_argument("--use", default="data", choices=("data", "intensity"))
    pl.add_argument("--db", action="store_true", help="dB scale")
    pl.add_argument("--scene", help="scene XML whose geometry is drawn over a cartesian plot")
    add_force(pl)
    pl.set_defaults(func=cmd_plot)

    i = sub.add_parser("info", help="print a scan file's header", description="Print a scan's settings.")
    i.add_argument("scan", help="scan file (.exr or .npz)")
    i.set_defaults(func=cmd_info)

    d = sub.add_parser("demo", help="render the demo scenes (box, intake, box_fls, a harbour survey) to EXR and pictures",
                       description="Render scenes_xml/box.xml, intake.xml (mechanical scans) and "
                                   "box_fls.xml (a multibeam frame): EXR + polar, cartesian and "
                                   "A-scan pictures; then harbour.xml's mechanical and multibeam "
                                   "heads along harbour_survey.tum, in world coordinates.")
    add_output(d, "-o", "--output", default="out", help="output folder (default out/)",
               existing=files_in_folder(DEMO_FILES, DEMO_HARBOUR))
    d.add_argument("--spp", type=int, default=4096)
    d.add_argument("--seed", type=int, default=0)
    d.add_argument("-q", "--quiet", action="store_true")
    add_force(d)
    d.set_defaults(func=cmd_demo)

    # The other subcommands, one module each in this package. A module that fails to import is a
    # bug to see, not a command to drop silently.
    for mod in SUBCOMMAND_MODULES:
        importlib.import_module(f"mitsonar.cli.{mod}").add_subcommands(sub)
    return p


def _one_line_warning(message, category, filename, lineno, file=None, line=None):
    print(f"mitsonar: warning: {message}", file=sys.stderr)


def main(argv=None):
    import warnings

    warnings.showwarning = _one_line_warning  # a sentence, not a source line
    parser = build_parser()
    args = parser.parse_args(argv)
    if args.variant:
        os.environ["MITSONAR_VARIANT"] = args.variant
    if not getattr(args, "func", None):
        parser.print_help()
        return EXIT_USAGE
    try:
        from mitsonar.cli.common import check_outputs

        check_outputs(args, CLIError)      # an output that exists, without --force: before any work
        return int(args.func(args) or 0)
    except KeyboardInterrupt:
        print("mitsonar: interrupted", file=sys.stderr)
        return 130
    except BrokenPipeError:
        # `mitsonar info x.exr | head`: the reader has gone; stop quietly (and keep Python from
        # complaining again when it flushes stdout at exit).
        os.dup2(os.open(os.devnull, os.O_WRONLY), sys.stdout.fileno())
        return EXIT_ERROR
    except Exception as exc:  # one line for the user, the traceback only on request
        if os.environ.get("MITSONAR_DEBUG"):
            raise
        msg = first_line(exc)
        if isinstance(exc, (FileNotFoundError, IsADirectoryError, PermissionError)) and exc.filename:
            msg = f"{exc.filename}: {exc.strerror}"
        print(f"mitsonar: error: {msg}", file=sys.stderr)
        return EXIT_ERROR


if __name__ == "__main__":
    sys.exit(main())
