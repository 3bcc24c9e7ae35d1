"""``mitsonar map``: learn a Hilbert map from scan files.

    mitsonar map scans/*.exr -o map.npz [--inducing 3000] [--plot slices.png] [--mesh map.ply]
    mitsonar map survey_dir/ --incremental -o map.npz [--elevation seabed.tif] [--plot plan.png]

The main CLI calls :func:`add_subcommands`. Every failure the user can cause ends in one line on
stderr and a non-zero exit code. The output paths are checked before any scan is read; the files
are written under temporary names in their own folders and renamed only when all are written, so
a failed run leaves nothing behind.
"""
from __future__ import annotations

import os
import sys
import time

from mitsonar._checks import first_line
from mitsonar._files import StagedFiles, check_output_file

EXIT_ERROR = 1
# A value argparse accepted but this command refuses is a validation error, exit 1 like every other
# command's (docs/howto/command_line.rst, "Exit codes"); only argparse's own errors exit 2.
EXIT_USAGE = EXIT_ERROR


def add_subcommands(subparsers) -> None:
    from mitsonar.cli.common import add_force, add_output

    m = subparsers.add_parser(
        "map", help="learn a 3-D occupancy map (Hilbert map) from scan files",
        description="Learn a continuous 3-D occupancy map (Hilbert map, thesis chapter 4) from scans "
                    "(.exr or .npz written by `mitsonar render` or Scan.save, or .bin raw SeaNet logs "
                    "written by `mitsonar record`) and save it as .npz.")
    m.add_argument("scans", nargs="+", help="scan files (.exr or .npz) or raw SeaNet logs (.bin) from `mitsonar record`")
    add_output(m, "-o", "--output", required=True, help="map file to write (.npz)")
    m.add_argument("--inducing", type=int, default=3000, help="Nystroem inducing points (default 3000)")
    m.add_argument("--passes", type=int, default=None, help="SGD passes over the samples (default: the map's)")
    m.add_argument("--source", choices=("auto", "data", "intensity"), default="auto",
                   help="what the bins are classified on (default auto: data unless all zero)")
    m.add_argument("--seed", type=int, default=0, help="random seed (default 0)")
    add_output(m, "--plot", help="also write cross-sections through the sonar (.png/.pdf/.svg)")
    add_output(m, "--mesh", help="also write the surface as a triangle mesh (.ply or .obj)")
    m.add_argument("--surface", choices=("ridge", "level"), default="ridge",
                   help="surface of --mesh: the probability ridge (default) or the 0.5 level")
    m.add_argument("--resolution", type=float, default=None,
                   help="mesh grid step in metres (default: a quarter of the length-scale, coarser where the region "
                        "seen would need more than 2e7 grid points; the step used is printed)")
    m.add_argument("--incremental", action="store_true",
                   help="map the scans one after another as a survey (IncrementalHilbertMap.partial_fit, every "
                        "row at its own pose, bounded memory); a folder argument stands for its scan_*.npz/.exr "
                        "files in order (what `mitsonar survey` writes)")
    m.add_argument("--node-spacing", type=float, default=0.15,
                   help="--incremental: lattice pitch of the map's nodes in metres (default 0.15)")
    m.add_argument("--max-nodes", type=int, default=200000,
                   help="--incremental: at most this many nodes; the least recently used are forgotten")
    add_output(m, "--elevation", help="--incremental: also write the seabed elevation grid (.tif GeoTIFF with "
                                       "rasterio, or .npz with 'elevation' and its 'transform')")
    m.add_argument("--elevation-resolution", type=float, default=0.25, help="elevation grid cell in metres")
    m.add_argument("-q", "--quiet", action="store_true", help="print nothing on success")
    add_force(m)
    m.set_defaults(func=cmd_map)


#: With no --resolution the mesh's grid holds at most this many points (each one a map query, about
#: a million a second on one core: the harbour survey's elevation grid is 2.6e7); the default step
#: is coarsened until it fits, and the step used is printed.
AUTO_MESH_POINTS = 20_000_000


def _fail(msg: str, code: int = EXIT_ERROR) -> int:
    print(f"mitsonar map: error: {msg}", file=sys.stderr)
    return code


# The map's own messages name its parameters; on the command line they are these options.
_OPTIONS = (("n_inducing", "--inducing"), ("n_passes", "--passes"), ("resolution", "--resolution"),
            ("node_spacing", "--node-spacing"), ("max_nodes", "--max-nodes"))


def _map_error(exc: Exception) -> str:
    msg = str(exc).replace("HilbertMap: ", "")
    for name, option in _OPTIONS:
        msg = msg.replace(name, option)
    return msg


# What `map` reads: scans by extension, raw logs by their magic bytes (whatever the extension).
SCAN_EXTENSIONS = (".exr", ".npz")
LOG_EXTENSION = ".bin"
ACCEPTED = ".exr or .npz scans, or .bin raw SeaNet logs"


class _Unwritable(ValueError):
    pass


def _output_problem(option: str, path: str) -> str | None:
    """Why ``path`` cannot be written (None if it can): its folder exists, is a folder and is
    writable, and the path itself is not a folder (`mitsonar._files.check_output_file`)."""
    try:
        check_output_file(path, _Unwritable, words={
            "directory": f"{option} {{path}}: is a folder, not a file name",
            "no_folder": f"{option} {{path}}: the folder {{given_folder}} does not exist",
            "not_a_folder": f"{option} {{path}}: {{given_folder}} is not a folder",
            "not_writable": f"{option} {{path}}: cannot write in the folder {{given_folder}} (permission denied)"})
    except _Unwritable as exc:
        return str(exc)
    return None


def _expand_folders(paths) -> list:
    """Each folder replaced by its survey scans (``scan_*.npz``, else ``scan_*.exr``) in name order."""
    out = []
    for p in paths:
        if os.path.isdir(p):
            names = sorted(f for f in os.listdir(p) if f.startswith("scan_") and f.endswith(".npz")) or \
                sorted(f for f in os.listdir(p) if f.startswith("scan_") and f.endswith(".exr"))
            out.extend(os.path.join(p, f) for f in names)
        else:
            out.append(p)
    return out


def _read_scans(paths):
    """(scans, None) or (None, the one-line reason) for the scan files and raw logs given."""
    from mitsonar.scan.io import load_scan  # lazily: reading scans needs no renderer
    from mitsonar.devices.rawlog import LOG_MAGIC
    from mitsonar.devices.recording import replay

    scans = []
    for path in paths:
        ext = os.path.splitext(path)[1].lower()
        try:
            with open(path, "rb") as fh:
                is_log = fh.read(len(LOG_MAGIC)) == LOG_MAGIC
            # A device log holds whole turns of a real (or virtual) head: each becomes a scan.
            if is_log:
                got = replay(path)
                if not got:
                    return None, (f"{path}: no complete scan in the log (the recording ends before the head "
                                  "finished its first sweep)")
                scans.extend(got)
            elif ext == LOG_EXTENSION:
                return None, (f"{path}: not a raw SeaNet log (it does not start with the log header "
                              f"{LOG_MAGIC.decode()!r} that `mitsonar record` writes)")
            elif ext not in SCAN_EXTENSIONS:
                return None, f"{path}: map reads {ACCEPTED}, not {ext or 'a file without extension'}"
            else:
                scans.append(load_scan(path))
        except Exception as exc:  # one line: which file, and why
            return None, f"{path}: cannot read the scan ({first_line(exc)})"
    return scans, None


def _reach(scans):
    """(lo, hi): the box every sample of these scans lies in, the pings' positions +- range_max
    (a bound on the region the map will have seen, known before the fit)."""
    import numpy as np

    lo = np.full(3, np.inf)
    hi = np.full(3, -np.inf)
    for scan in scans:
        p = np.asarray(scan.poses, dtype=np.float64).reshape(-1, 4, 4)[:, :3, 3]
        r = float(scan.range_max)
        lo, hi = np.minimum(lo, p.min(axis=0) - r), np.maximum(hi, p.max(axis=0) + r)
    return lo, hi


def _resolution_problem(resolution: float, scans) -> str | None:
    """Why the mesh grid of ``--resolution`` cannot be made for these scans (None if it can),
    decided before the fit on the box the survey can reach (`_reach`)."""
    import math

    from hilbertmap.surfaces import MAX_GRID_POINTS, fitting_resolution, grid_shape

    lo, hi = _reach(scans)
    n = grid_shape(resolution, lo, hi)
    if math.prod(n) <= MAX_GRID_POINTS:
        return None
    ext = " x ".join(f"{e:.3g}" for e in hi - lo)
    return (f"--resolution {resolution:g} m: the scans reach {ext} m (their positions +- range_max), a grid of "
            f"{math.prod(n):.3g} points (at most {MAX_GRID_POINTS:.0e}); use --resolution "
            f"{fitting_resolution(resolution, lo, hi):g} or coarser, or leave it out (map then picks the finest "
            f"step that fits the region seen)")


class _Stages:
    """Wall-clock seconds of the command's stages, in order, from the moment it started."""

    def __init__(self):
        self.start = self.mark = time.perf_counter()
        self.seconds = {}

    def done(self, name: str) -> None:
        now = time.perf_counter()
        self.seconds[name] = self.seconds.get(name, 0.0) + now - self.mark
        self.mark = now

    def line(self) -> str:
        parts = ", ".join(f"{name} {s:.1f}" for name, s in self.seconds.items())
        return f"{time.perf_counter() - self.start:.1f} s ({parts})"


class _FitProgress:
    """The fit's progress on stderr, one tqdm bar per stage (as ``mitsonar render``'s): called as
    ``progress(stage, done, total)`` (`hilbertmap.HilbertMap.fit`'s stages, or ``scans`` for
    --incremental); nothing with --quiet. A bar shows once its stage has taken half a second (a
    quick stage, or a refusal in one, needs none) and is cleared when the stage ends."""

    DELAY = 0.5     # s a stage runs before its bar shows
    WORDS = {"embedding": ("embedding scans", "scan"), "features": ("inducing points and kernel features", "step"),
             "sgd": ("SGD", "batch"), "sgd multi-echo": ("SGD, multi-echo refit", "batch"),
             "scans": ("mapping scans", "scan")}

    def __init__(self, quiet: bool = False):
        self.quiet = quiet
        self.stage = self.bar = None

    def __call__(self, stage: str, done: int, total: int) -> None:
        if self.quiet:
            return
        if stage != self.stage:
            self.close()
            from tqdm import tqdm

            desc, unit = self.WORDS.get(stage, (stage, "step"))
            self.stage = stage
            self.bar = tqdm(total=total, desc=f"map: {desc}", unit=unit, leave=False, file=sys.stderr,
                            delay=self.DELAY)
        self.bar.update(done - self.bar.n)

    def close(self) -> None:
        if self.bar is not None:
            self.bar.close()
        self.stage = self.bar = None


def _leave_if_abandoned() -> None:
    """Interrupted (Ctrl-C) while the fit's eigen-decomposition still runs in its worker thread
    (`hilbertmap._threads`): nothing is written yet, so end the process now, exit code 130 as
    `mitsonar.cli.main`'s, with ``os._exit``: a normal exit could wait forever in OpenBLAS's exit
    handler for the abandoned call."""
    from hilbertmap._threads import abandoned

    if abandoned():
        print("mitsonar: interrupted", file=sys.stderr, flush=True)
        sys.stdout.flush()
        os._exit(130)


def _elevation_frame(args, scans):
    """(the `GeoFrame` the scans' metadata hold, None without; or None and the one-line reason)
    for a GeoTIFF ``--elevation``: the grid is then written in that CRS. Scans holding different
    origins are refused."""
    if not (getattr(args, "elevation", None) or "").lower().endswith((".tif", ".tiff")):
        return None, None
    from mitsonar.geometry.geodesy import GeoError, GeoFrame

    frames = []
    for path, scan in zip(args.scans, scans):
        try:
            frames.append(GeoFrame.from_meta(scan.meta, f"{path}: meta"))
        except GeoError as exc:
            return None, str(exc)
    if any(f != frames[0] for f in frames):
        return None, (f"--elevation {args.elevation}: the scans hold different origins/CRS in their metadata "
                      "(allowed: one survey's scans, all with the same origin, or none)")
    return frames[0], None


def cmd_map(args) -> int:
    stages = _Stages()
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
    # every output before any input is read: a bad path must not cost a fit
    if not args.incremental:
        for option in ("elevation",):
            if getattr(args, option):
                return _fail(f"--{option} needs --incremental", EXIT_USAGE)
    else:
        if not (args.node_spacing > 0):
            return _fail("--node-spacing must be positive", EXIT_USAGE)
        if args.max_nodes < 1:
            return _fail("--max-nodes must be a positive integer", EXIT_USAGE)
        if not (args.elevation_resolution > 0):
            return _fail("--elevation-resolution must be positive", EXIT_USAGE)
        if args.elevation and os.path.splitext(args.elevation)[1].lower() not in (".tif", ".tiff", ".npz"):
            return _fail(f"{args.elevation}: elevation grids are written as .tif/.tiff (GeoTIFF) or .npz", EXIT_USAGE)
        if args.elevation and args.elevation.lower().endswith((".tif", ".tiff")):
            try:
                import rasterio  # noqa: F401
            except ImportError:
                return _fail(f"{args.elevation}: writing GeoTIFF needs rasterio (pip install rasterio); "
                             "name an .npz instead")
        args.scans = _expand_folders(args.scans)
        if not args.scans:
            return _fail("the survey is empty: no scan files (scan_*.npz or scan_*.exr in the folders given)")
    for option, path in (("-o", args.output), ("--mesh", args.mesh), ("--plot", args.plot),
                         ("--elevation", getattr(args, "elevation", None))):
        problem = path and _output_problem(option, path)
        if problem:
            return _fail(problem)
    for path in args.scans:
        if not os.path.exists(path):
            return _fail(f"{path}: no such file")
        if os.path.isdir(path):
            return _fail(f"{path}: is a directory, not a scan file")

    scans, problem = _read_scans(args.scans)
    if problem:
        return _fail(problem)
    args.geo, problem = _elevation_frame(args, scans)
    if problem:
        return _fail(problem)
    # a mesh grid too fine for what the scans can reach: refused now, not after the fit
    if args.mesh and args.resolution is not None:
        problem = _resolution_problem(args.resolution, scans)
        if problem:
            return _fail(problem)
    stages.done("read")

    from hilbertmap import HilbertMap, IncrementalHilbertMap

    if args.incremental:
        params = dict(node_spacing=args.node_spacing, max_nodes=args.max_nodes, random_state=args.seed,
                      source=args.source)
        if args.passes is not None:
            params["partial_passes"] = args.passes
        hm = IncrementalHilbertMap(**params)
        progress = _FitProgress(args.quiet)
        try:
            progress("scans", 0, len(scans))
            for k, (path, scan) in enumerate(zip(args.scans, scans)):
                try:
                    hm.partial_fit(scan)
                except ValueError as exc:
                    raise ValueError(f"{path}: {exc}") from None
                progress("scans", k + 1, len(scans))
            progress.close()
            hm.n_schedule_ = hm.n_samples_seen_
            stages.done("fit")
            args.elevation_grid = None
            if args.elevation or (args.plot and args.incremental):
                from hilbertmap.elevation import elevation_grid

                args.elevation_grid = elevation_grid(hm, resolution=args.elevation_resolution)
                stages.done("elevation")
        except ValueError as exc:
            progress.close()
            return _fail(_map_error(exc))
    else:
        params = dict(n_inducing=args.inducing, random_state=args.seed, source=args.source)
        if args.passes is not None:
            params["n_passes"] = args.passes
        hm = HilbertMap(**params)
        progress = _FitProgress(args.quiet)
        try:
            hm.fit(scans, progress=progress)
        except ValueError as exc:
            return _fail(_map_error(exc))
        except KeyboardInterrupt:
            progress.close()
            _leave_if_abandoned()
            raise
        finally:
            progress.close()
        stages.done("fit")
    V = F = None
    note = None
    if args.mesh:  # before anything is written
        resolution = args.resolution
        if resolution is None:   # the default step, or the finest coarser one the region seen allows
            from hilbertmap.surfaces import mesh_resolution

            resolution, default, points = mesh_resolution(hm, AUTO_MESH_POINTS)
            lo, hi = hm.coverage_.bounds()
            note = (f"mesh grid step {resolution:g} m" + ("" if resolution == default else
                    f" (the default {default:g} m would need {points:.3g} grid points over the "
                    f"{' x '.join(f'{e:.3g}' for e in hi - lo)} m seen, more than {AUTO_MESH_POINTS:.0e}; "
                    "--resolution sets it)"))
        try:
            V, F = hm.surface(args.surface, resolution=resolution)
        except ValueError as exc:
            return _fail(_map_error(exc))
        stages.done("mesh")
    outputs = StagedFiles()
    try:
        code = _write(args, hm, len(scans), V, F, outputs, stages)
        if code:
            return code
        try:
            outputs.commit()
        except OSError as exc:
            return _fail(f"{exc.filename or args.output}: cannot put the output in place ({exc.strerror or exc})")
    finally:
        outputs.discard()
    written = [args.output] + ([f"{args.mesh} ({len(F)} triangles)"] if args.mesh else []) + \
        ([args.plot] if args.plot else []) + ([args.elevation] if getattr(args, "elevation", None) else [])
    stages.done("write")
    if not args.quiet:
        if note:
            print(f"map: {note}")
        print(f"map: {len(scans)} scan(s), {hm.n_schedule_} training samples, "
              f"{len(hm.inducing_points_)} inducing points "
              f"(length-scale {hm.lengthscale_:.3f} m), {stages.line()}; wrote {', '.join(written)}")
    return 0


def _write(args, hm, n_scans: int, V, F, outputs: StagedFiles, stages: _Stages) -> int:
    """Write the map, mesh and plot under temporary names; 0, or the exit code of a failure."""
    from hilbertmap import write_mesh

    option, path = "-o", args.output
    try:
        if args.plot:   # timed on its own: the survey plan view samples the map
            option, path = "--plot", args.plot
            _plot(args, hm, n_scans, outputs)
            stages.done("plot")
        option, path = "-o", args.output
        hm.save(outputs.temporary(args.output))
        if args.mesh:
            option, path = "--mesh", args.mesh
            write_mesh(outputs.temporary(args.mesh), V, F)
        if getattr(args, "elevation", None):
            option, path = "--elevation", args.elevation
            if args.elevation.lower().endswith((".tif", ".tiff")):   # mitsonar's one GeoTIFF writer
                from mitsonar.export.geotiff import write_elevation_geotiff

                write_elevation_geotiff(outputs.temporary(args.elevation), args.elevation_grid, args.geo)
            else:
                from hilbertmap.elevation import write_elevation

                write_elevation(outputs.temporary(args.elevation), args.elevation_grid)
    except OSError as exc:
        return _fail(f"{option} {path}: {exc.strerror or exc}")
    return 0


def _plot(args, hm, n_scans: int, outputs: StagedFiles) -> None:
    if args.incremental:
        from hilbertmap.plots import plot_survey_map

        plot_survey_map(hm, outputs.temporary(args.plot), elevation=args.elevation_grid,
                        title=f"survey map of {n_scans} scan(s)")
    else:
        from hilbertmap.plots import plot_slices

        c = hm.sensor_positions_.mean(axis=0) if len(hm.sensor_positions_) else (0.0, 0.0, 0.0)
        slices = (("z", float(c[2])), ("y", float(c[1])), ("x", float(c[0])))
        plot_slices(hm, slices, path=outputs.temporary(args.plot), title=f"Hilbert map of {n_scans} scan(s)")
