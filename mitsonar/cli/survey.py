"""``mitsonar survey``: render a survey along a trajectory (a TUM file or a lawnmower pattern).

Writes, into the output folder: ``scan_00000.npz``, ``scan_00001.npz``, ... (one per sweep of a
mechanical head, one per frame of a multibeam head, one per ``n_pings`` pings of a side-scan head),
``trajectory.tum`` (the trajectory used, drift included), ``track.png`` (the track and every ping's
position) and ``scan_00000_world.png`` (the first scan drawn in world coordinates, each ping from
its own pose: the motion distortion shows; both top views x east, y north, the scan's ground truth
only inside its beams, `plots.plot_cartesian`); for a side-scan head instead ``scan_00000_waterfall.png``
(the first scan's waterfall) and ``mosaic.png`` (+ ``mosaic.pgw``, ``mosaic.npz``: the survey's
georeferenced mosaic, `mitsonar.products.mosaic`, in cells of a range bin (0.1 m at least, coarser for a
grid of more than 2e7 cells), flat bottom at the measured altitude).
With ``--origin LAT LON [HEIGHT]`` (``--crs``; `mitsonar.geometry.geodesy`) every scan carries the
origin and CRS in its metadata, a side-scan survey also writes ``mosaic.tif`` (the mosaic in the
CRS), and ``--xtf OUT`` writes its pings as XTF (`mitsonar.export.xtf`).
Everything is checked (trajectory file, scene, folder, that a scan fits in the track) before the
first file is written; each file is written under a temporary name and renamed.
"""
from __future__ import annotations

import math
import os


class SurveyCLIError(ValueError):
    """A user's mistake on the survey command line: printed as one line by ``mitsonar``'s main
    (this module does not import ``mitsonar.cli``, which registers it)."""


CLIError = SurveyCLIError


def add_trajectory_options(parser):
    """The trajectory flags a survey-like command takes: ``--trajectory TUM`` or ``--lawnmower
    X_MIN X_MAX Y_MIN Y_MAX`` with ``--spacing``, ``--speed``, ``--depth``/``--altitude``,
    ``--yaw-rate``, and ``--drift SEED`` (read back by `trajectory_from_args`)."""
    parser.add_argument("--trajectory", metavar="TUM", help="trajectory file: 'timestamp tx ty tz qx qy qz qw' per line "
                                                             "(TUM), or lat/lon as .csv (time,lat,lon,depth[,heading]) "
                                                             "or .nmea (GGA/VTG) with --origin")
    parser.add_argument("--lawnmower", nargs=4, type=float, metavar=("X_MIN", "X_MAX", "Y_MIN", "Y_MAX"),
                        help="a lawnmower survey of this world rectangle (lines along x)")
    parser.add_argument("--spacing", type=float, default=10.0, help="lawnmower line spacing, m (default 10)")
    parser.add_argument("--speed", type=float, default=1.5, help="lawnmower speed, m/s (default 1.5)")
    parser.add_argument("--depth", type=float, help="lawnmower depth below z = 0, m")
    parser.add_argument("--altitude", type=float, help="lawnmower altitude above z = 0, m")
    parser.add_argument("--yaw-rate", type=float, default=20.0, help="lawnmower turn rate at the corners, deg/s")
    parser.add_argument("--drift", type=int, metavar="SEED", help="add seeded navigation drift (a random walk)")


def trajectory_from_args(args, command="survey"):
    """The `Trajectory` the flags of `add_trajectory_options` give (a TUM file, or a lawnmower
    pattern; plus drift), or a `SurveyCLIError` of one line naming ``command`` and the flags."""
    from mitsonar.geometry.trajectory import Trajectory

    if (args.trajectory is None) == (args.lawnmower is None):
        raise CLIError(f"{command}: give exactly one of --trajectory FILE or --lawnmower X_MIN X_MAX Y_MIN Y_MAX")
    if args.trajectory is not None:
        from mitsonar.geometry import geotrack

        if geotrack.is_geo_trajectory(args.trajectory):   # lat/lon (CSV, NMEA): into the --origin grid
            from mitsonar.geometry.geodesy import frame_from_args

            frame = frame_from_args(args)
            if frame is None:
                raise CLIError(f"{command} --trajectory {args.trajectory}: a lat/lon trajectory needs "
                               "--origin LAT LON [HEIGHT] (the world grid's origin)")
            traj = geotrack.read_geo_trajectory(args.trajectory, frame)
        else:
            traj = Trajectory.from_tum(args.trajectory)
    else:
        if (args.depth is None) == (args.altitude is None):
            raise CLIError(f"{command} --lawnmower: give exactly one of --depth or --altitude")
        x0, x1, y0, y1 = args.lawnmower
        traj = Trajectory.lawnmower(x0, x1, y0, y1, args.spacing, args.speed, depth=args.depth,
                                    altitude=args.altitude, yaw_rate=args.yaw_rate)
    if args.drift is not None:
        traj = traj.with_drift(args.drift)
    return traj


def cmd_survey(args):
    import mitsonar

    from mitsonar.cli.common import check_counts, sensor_of
    from mitsonar._files import check_output_folder

    check_counts(args, CLIError)
    from mitsonar.geometry.geodesy import frame_from_args

    frame_from_args(args)                           # a bad --origin/--crs: refused before the scene loads
    traj = trajectory_from_args(args)               # a bad file: one line, nothing written
    if getattr(args, "surface", False):             # + a flat specular sea surface at z = 0
        from mitsonar.scenes.sea_surface import load_survey_scene

        scene = load_survey_scene(args.scene, surface=True)
    else:
        scene = mitsonar.load_scene(args.scene)
    sensor = sensor_of(scene, args)                 # --sensor, or the first sonar (one warning if several)
    out = args.output
    check_output_folder(out, CLIError)              # a file is no folder; one holding a survey: check_outputs
    if args.mcap is not None:   # refused before any render (its folder may be the one -o makes)
        from mitsonar.export.ros.bag import check_output

        check_output(args.mcap, args.force, folder_may_be=out)
    frame, kept = _check_xtf(args, scene, sensor, out)   # --origin/--crs, --xtf: refused before any render
    ext = "." + args.format
    mosaic = _mosaic_grid(scene, traj, sensor)      # a side-scan survey's mosaic, checked before any render
    try:   # checks every argument and the plan, then makes the folder; renders nothing yet
        scans = mitsonar.render_survey(scene, traj, out, spp=args.spp, seed=args.seed, max_scans=args.max_scans,
                                       ext=ext, progress=not args.quiet, sensor=sensor,
                                       meta=None if frame is None else frame.meta())
    except OSError as exc:
        raise CLIError(f"-o {out!r}: cannot create the output folder ({exc.strerror})") from None
    if args.force:                                  # --force: the folder holds this survey only
        for name in _survey_files(out):
            os.remove(os.path.join(out, name))
    bag = None
    if args.mcap is not None:   # the ROS 2 bag, written beside the scans, renamed into place at the end
        from mitsonar.export.ros.bag import McapBag

        bag = McapBag(args.mcap, start=args.start, trajectory=traj, threshold=args.threshold, force=args.force,
                      frame=frame)
    if kept is not None:
        scans = _keeping(scans, kept)
    try:
        n = _draw(args, scene, traj, out, scans, bag, mosaic)
    except BaseException:
        if bag is not None:
            bag.discard()
        raise
    if bag is not None:
        bag.close()
    if kept is not None:
        from mitsonar.export.xtf import write_xtf

        write_xtf(args.xtf, kept, frame, start=args.start, trajectory=traj)
    print(f"wrote {n} scans, trajectory.tum and track.png to {out}" + (f" and {args.mcap}" if bag else "") +
          (f" and {args.xtf}" if kept is not None else "") +
          f" ({traj.span[1] - traj.span[0]:.6g} s of track)")
    return 0


def _check_xtf(args, scene, sensor, out):
    """The survey's `GeoFrame` (None without ``--origin``) and, with ``--xtf``, the list the scans
    are kept in for it; a bad flag is refused here, before any render."""
    from mitsonar.geometry.geodesy import frame_from_args

    from mitsonar.sim.scene import sonar_of

    frame = frame_from_args(args)
    kind = sonar_of(scene, sensor).sonar_kind
    if frame is not None and kind.mosaic:          # mosaic.tif with its CRS
        try:
            import rasterio  # noqa: F401
        except ImportError:
            raise CLIError("survey --origin: a side-scan survey writes mosaic.tif with its CRS, which needs "
                           "rasterio: pip install 'mitsonar[geo]'") from None
    if args.xtf is None:
        return frame, None
    from mitsonar.export.xtf import check_xtf_output

    check_xtf_output(args.xtf, args.force, folder_may_be=out)
    if not kind.sided:
        raise CLIError(f"survey --xtf: the scene's sonar is a {kind.name} head; XTF holds side-scan pings only")
    if frame is None:
        raise CLIError("survey --xtf: give --origin LAT LON [HEIGHT] (XTF navigation is in latitude and longitude)")
    return frame, []


def _keeping(scans, kept):
    for scan in scans:
        kept.append(scan)
        yield scan


def _draw(args, scene, traj, out, scans, bag, mosaic=None):
    import mitsonar
    from mitsonar.products import plots
    from mitsonar.sim.survey import SCAN_NAME

    positions = []
    n = 0
    mesh = mitsonar.scene_mesh(scene)
    for scan in scans:
        if bag is not None:
            bag.add(scan, SCAN_NAME.format(n, "." + args.format))
        if n == 0 and scan.sonar_kind.world_picture:
            plots.plot_cartesian(scan, mesh=mesh,
                                 path=os.path.join(out, SCAN_NAME.format(0, "_world.png")))
        if scan.sonar_kind.mosaic:
            mosaic = _sidescan_products(scan, n, traj, out, mosaic)
        positions.append(scan)
        n += 1
        if len(positions) > 50:                     # keep the picture's dots, not the scans' bins
            positions = positions[::2]
    plots.plot_track(traj, os.path.join(out, "track.png"), scans=positions, mesh=mesh)
    if mosaic is not None:
        mosaic.result().save(os.path.join(out, "mosaic.png"))
        from mitsonar.geometry.geodesy import frame_from_args

        frame = frame_from_args(args)                  # --origin, or the frame the scene records
        if frame is not None:                          # georeferenced: + mosaic.tif in the CRS
            from mitsonar.export.geotiff import write_mosaic_geotiff

            write_mosaic_geotiff(os.path.join(out, "mosaic.tif"), mosaic.result(), frame)
    return n


#: The files a survey writes in its folder besides the scans and their pictures (`_survey_files`).
SURVEY_FILES = ("trajectory.tum", "track.png", "mosaic.png", "mosaic.pgw", "mosaic.npz", "mosaic.tif")
#: Its scans and the pictures named after them.
SCAN_FILES = r"scan_\d{5}(\.npz|\.exr|_world\.png|_waterfall\.png)"


def _survey_files(folder) -> list:
    """The files of a survey in ``folder``: its scans and the pictures named after them."""
    import re

    pattern = re.compile(SCAN_FILES)
    return [f for f in os.listdir(folder) if pattern.fullmatch(f)] if os.path.isdir(folder) else []


#: Most cells of a survey's mosaic: its cell grows beyond the sonar's range bin to stay under this.
MOSAIC_CELLS = 2 * 10 ** 7


def _mosaic_grid(scene, traj, sensor=0):
    """The empty mosaic of a side-scan survey (None for other heads): the track's extent plus the
    swath (``range_max``) each side, in cells of the sonar's range bin (0.1 m at least), coarser
    when that would exceed `MOSAIC_CELLS`; built before any render so a bad grid costs nothing."""
    from mitsonar.products.mosaic import MosaicBuilder
    from mitsonar.sim.scene import sonar_of

    sonar = sonar_of(scene, sensor)
    if not sonar.sonar_kind.mosaic:
        return None
    p, r = traj.positions, float(sonar.range_max)
    bounds = (p[:, 0].min() - r, p[:, 0].max() + r, p[:, 1].min() - r, p[:, 1].max() + r)
    area = (bounds[1] - bounds[0]) * (bounds[3] - bounds[2])
    cell = max(0.1, (sonar.range_max - sonar.range_min) / sonar.n_bins, math.sqrt(area / MOSAIC_CELLS))
    return MosaicBuilder(bounds, cell)


def _sidescan_products(scan, n, traj, out, mosaic):
    """A side-scan survey's pictures: the first scan's waterfall; every scan into the mosaic."""
    from mitsonar.sim.survey import SCAN_NAME

    if n == 0:
        from mitsonar.products.sidescan_plots import plot_waterfall

        plot_waterfall(scan, os.path.join(out, SCAN_NAME.format(0, "_waterfall.png")))
    return mosaic.add(scan)


DEMO_SCENE, DEMO_TRACK = "harbour.xml", "harbour_survey.tum"


def demo_survey(scenes, output, spp, seed, quiet=True):
    """The demo's survey: both heads of ``scenes/harbour.xml`` along ``harbour_survey.tum``: every
    sweep of the mechanical head and three multibeam frames (at 10, 25 and 40 s), drawn in world
    coordinates over the ground truth (``harbour_mechanical_<i>.png``, ``harbour_multibeam_<t>s.png``)
    and the track with every ping's position over the ground truth (``harbour_track.png``). Returns the files written."""
    import mitsonar
    from mitsonar.products import plots

    scene = mitsonar.load_scene(os.path.join(scenes, DEMO_SCENE))
    track = mitsonar.Trajectory.from_tum(os.path.join(scenes, DEMO_TRACK))
    mesh = mitsonar.scene_mesh(scene)
    mechanical, multibeam = scene.sensors()[:2]   # the sensor objects: an index would warn
    written, scans = [], []
    for i, scan in enumerate(mitsonar.render_survey(scene, track, spp=spp, seed=seed, sensor=mechanical,
                                                    progress=not quiet)):
        written.append(os.path.join(output, f"harbour_mechanical_{i}.png"))
        plots.plot_cartesian(scan, mesh=mesh, path=written[-1])
        scans.append(scan)
    for t in (10, 25, 40):
        scan = mitsonar.render_scan(scene, spp=spp, seed=seed, sensor=multibeam, trajectory=track, start_time=t)
        written.append(os.path.join(output, f"harbour_multibeam_{t}s.png"))
        plots.plot_cartesian(scan, mesh=mesh, path=written[-1])
    written.append(os.path.join(output, "harbour_track.png"))
    plots.plot_track(track, written[-1], scans=scans, mesh=mesh)
    return written


def add_subcommands(sub):
    s = sub.add_parser("survey", help="render consecutive scans along a vehicle trajectory",
                       description="Render a survey: the scene's sonar (its to_world is the mount on "
                                   "the vehicle, x forward, y port, z up) pinging along a trajectory.")
    s.add_argument("scene", help="scene XML file")
    from mitsonar.cli.common import add_output, files_in_folder

    add_output(s, "-o", "--output", required=True, help="output folder (scans, trajectory.tum, track.png)",
               existing=files_in_folder(SURVEY_FILES, SCAN_FILES))
    add_trajectory_options(s)
    s.add_argument("--surface", action="store_true",
                   help="add a flat specular sea surface at z = 0 (shallow-water multipath; off by default)")
    s.add_argument("--spp", type=int, default=1024, help="paths per ping (default 1024)")
    s.add_argument("--seed", type=int, default=0, help="survey seed (default 0)")
    s.add_argument("--max-scans", type=int, help="stop after this many scans")
    from mitsonar.cli.common import add_sensor

    add_sensor(s)
    s.add_argument("--format", default="npz", choices=("npz", "exr"), help="scan file format (default npz)")
    s.add_argument("-q", "--quiet", action="store_true", help="no progress bar")
    add_output(s, "--mcap", metavar="OUT", help="also write the survey as a ROS 2 bag (MCAP; see mitsonar export)")
    from mitsonar.cli.export import add_mcap_options

    add_mcap_options(s, force_help="replace a survey already in the output folder (its scan files are removed "
                                   "first) and an existing --mcap or --xtf file")
    from mitsonar.cli.export import add_xtf_options

    add_xtf_options(s)
    s.set_defaults(func=cmd_survey)
