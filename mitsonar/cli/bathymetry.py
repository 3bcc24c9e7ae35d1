"""``mitsonar bathymetry``: a bathymetric survey with a preset echo sounder, its soundings, depth map
and depth errors against the scene's true seabed.

    mitsonar bathymetry scenes_xml/rocky_slope.xml --trajectory scenes_xml/rocky_slope_survey.tum \\
        --preset r2sonic_2024 --beams 128 --max-scans 40 -o out/bathy

replaces the scene's sonar by the preset head looking down from the vehicle, renders the survey,
detects the bottom in every beam and writes, into the output folder: ``soundings.ply`` (the point
cloud, world frame), ``depth.npz`` (the gridded depth map: ``depth``, ``count``, ``transform``),
``depth.tif`` (the same as a GeoTIFF, when ``rasterio`` is installed), ``errors.json`` (depth error
statistics per beam angle, `mitsonar.products.bathymetry.SurveyResult.summary`) and ``bathymetry.png`` (the
depth map over the track, and the depth error against beam angle with the centroid's predicted rms).
``--processing-svp CSV`` places the soundings by ray tracing through that sound-speed profile
(`mitsonar.acoustics.SoundSpeedProfile.from_csv`) instead of straight beams at the head's
nominal speed: the rendered water itself is uniform at that nominal speed, so a profile that
differs from it shows the refraction error a wrong profile gives (depth error against beam angle).
``--svp CSV`` renders the survey in that water instead (refracted echo paths, `mitsonar.sim.render_scan`'s
``sound_speed_profile``): processed straight at the nominal speed its soundings bend up or down
towards the outer beams (the smile, or frown, of a wrong profile); ``--processing-svp`` with the
same file corrects them.
With ``--origin LAT LON [HEIGHT]`` (and ``--crs EPSG:NNNN``, `mitsonar.geometry.geodesy`) the run is
georeferenced: ``depth.tif`` carries the CRS, and ``soundings.las``, ``soundings.csv``,
``soundings.kmall`` (#MRZ per ping) and (when GDAL has its BAG driver) ``depth.bag`` are written too
(`mitsonar.export`).
Every option is checked before the first render; all files are written under temporary names and
renamed together at the end.
"""
from __future__ import annotations

import contextlib
import json
import os

import numpy as np

#: Every file a run may write (``depth.tif`` only when ``rasterio`` is installed; ``soundings.las``,
#: ``soundings.csv``, ``soundings.kmall`` and ``depth.bag`` (when GDAL has its BAG driver) only with
#: ``--origin``).
OUTPUTS = ("soundings.ply", "depth.npz", "depth.tif", "errors.json", "bathymetry.png")
GEO_OUTPUTS = ("soundings.las", "soundings.csv", "soundings.kmall", "depth.bag")


class BathymetryCLIError(ValueError):
    """A user's mistake on the command line: printed as one line by ``mitsonar``'s main."""


def plot_bathymetry(result, grid, path, trajectory=None):
    """Two panels: the depth grid (with the track), and each sounding's depth error against its
    beam angle with the rms per angle bin and `mitsonar.products.bathymetry.predicted_rms` for a flat
    seabed at the survey's median altitude."""
    from matplotlib.figure import Figure

    import mitsonar.kinds as kinds
    from mitsonar.products.bathymetry import predicted_rms
    from mitsonar.products.plots import _save

    fig = Figure(figsize=(12.0, 5.0), dpi=120)
    ax, bx = fig.subplots(1, 2)
    im = ax.imshow(grid.depth, extent=grid.extent, origin="upper", cmap="viridis_r", interpolation="nearest")
    fig.colorbar(im, ax=ax, label="depth below z = 0 [m]")
    if trajectory is not None:
        ax.plot(trajectory.positions[:, 0], trajectory.positions[:, 1], "r-", lw=0.8, label="track")
        ax.legend(loc="upper right", fontsize=8)
        ax.set_xlim(grid.extent[:2])
        ax.set_ylim(grid.extent[2:])
    ax.set(xlabel="x [m]", ylabel="y [m]", title=f"depth grid, {grid.cell:g} m cells", aspect="equal")
    s, err = result.soundings, result.error
    ok = np.isfinite(err)
    bx.plot(s["angle"][ok], 100 * err[ok], ".", ms=1.5, color="0.6", alpha=0.5, label="soundings")
    rows = result.errors
    info = result.sonar
    if rows:     # soundings with a ground truth under them
        ang = np.array([r["angle"] for r in rows])
        bx.plot(ang, [100 * r["rms"] for r in rows], "o-", color="C3", label="rms per beam angle")
        bx.plot(ang, [100 * r["mean"] for r in rows], "s--", color="C0", ms=3, label="mean (bias)")
        altitude = float(np.nanmedian(s["head_z"] - result.true_z))
        a = np.linspace(ang.min(), ang.max(), 200)
        fan = getattr(kinds.lookup(info.get("kind")), "transmit_fan", False)    # receive beams across a fan
        if info.get("speckle") and info.get("method") == "centroid" and fan:
            pred = predicted_rms(altitude / np.cos(np.radians(a)), a, info["beamwidth_h"], info["bin_width"],
                                 resolution=info.get("speckle_resolution"))
            bx.plot(a, 100 * pred, "k:", label=f"predicted rms (flat, {altitude:.1f} m)")
    else:
        bx.text(0.5, 0.5, "no sounding has a seabed under it in the scene:\nno depth error to show",
                ha="center", va="center", transform=bx.transAxes)
    lim = np.nanpercentile(np.abs(100 * err[ok]), 99.5) if ok.any() else 1.0
    svp = ", ray-traced through the SVP" if info.get("processing_svp") else ""
    bx.set(xlabel="beam angle [deg] (port +)", ylabel="depth error [cm] (+: too deep)", ylim=(-1.2 * lim, 1.2 * lim),
           title=f"depth error per beam angle ({len(s)} soundings{svp})")
    bx.grid(True, alpha=0.3)
    if rows or ok.any():
        bx.legend(fontsize=8)
    _save(fig, path)


#: The options that shape the preset head: refused beside ``--sensor`` (the scene's own head).
HEAD_OPTIONS = (("preset", "--preset"), ("swath", "--swath"), ("beams", "--beams"), ("range_max", "--range-max"),
                ("bin_width", "--bin-width"))
DEFAULT_PRESET = "r2sonic_2024"


def cmd_bathymetry(args):
    from mitsonar.products import bathymetry
    from mitsonar.scenes import echosounders
    from mitsonar.cli.common import check_counts, sensor_of
    from mitsonar._files import StagedFiles, check_output_folder
    from mitsonar.scenes.sea_surface import load_survey_scene
    from mitsonar.products.soundings import grid_depths, write_ply
    from mitsonar.cli.survey import trajectory_from_args

    check_counts(args, BathymetryCLIError)
    head = None
    if args.sensor is not None:   # the scene's own head: the preset's options mean nothing
        given = [flag for dest, flag in HEAD_OPTIONS if getattr(args, dest) is not None]
        if given:
            raise BathymetryCLIError(f"{given[0]} shapes the preset echo sounder; with --sensor the scene's own "
                                     "sensor surveys: give one or the other")
    try:   # every option, before any file or render
        if args.sensor is None:
            head = echosounders.configure(args.preset or DEFAULT_PRESET, swath=args.swath, n_beams=args.beams,
                                          range_max=args.range_max, bin_width=args.bin_width)
        bathymetry.check_options(args.threshold_db, args.method or "centroid")
        grid_depths(np.zeros(1, bathymetry.SOUNDING_DTYPE), args.cell)
        from mitsonar.acoustics.profile import SoundSpeedProfile

        svp = None if args.processing_svp is None else SoundSpeedProfile.from_csv(args.processing_svp)
        water = None if args.svp is None else SoundSpeedProfile.from_csv(args.svp)
    except ValueError as exc:
        raise BathymetryCLIError(str(exc)) from None
    traj = trajectory_from_args(args, "bathymetry")
    frame = _geo_frame(args)
    for flag, given in (("--processing-svp", svp), ("--svp", water)):
        if given is not None and (traj.positions[:, 2] > 0).any():
            raise BathymetryCLIError(f"bathymetry {flag}: the track rises {traj.positions[:, 2].max():g} m above "
                                     "the sea surface (z = 0): a sound-speed profile needs the head in the water (z <= 0)")
    scene = load_survey_scene(args.scene, surface=args.surface,
                              sonar=None if head is None else echosounders.sonar_xml(head))
    sensor = sensor_of(scene, args, BathymetryCLIError)
    check_output_folder(args.output, BathymetryCLIError)   # a file is no folder; a run in it: check_outputs
    with _output_folder(args.output):   # made now; removed again if the run fails and leaves it empty
        return _run(args, bathymetry, scene, traj, sensor, head, svp, grid_depths, write_ply, StagedFiles, water,
                    frame)


def _geo_frame(args):
    """The `GeoFrame` of ``--origin``/``--crs`` (None without); with one, laspy and rasterio are
    needed (soundings.las, depth.tif with its CRS): refused here, before any render, if missing."""
    from mitsonar.geometry.geodesy import frame_from_args

    frame = frame_from_args(args)
    if frame is not None:
        for module, extra in (("laspy", "geo"), ("rasterio", "geotiff")):
            try:
                __import__(module)
            except ImportError:
                raise BathymetryCLIError(f"bathymetry --origin: writes soundings.las and depth.tif with their CRS, "
                                         f"which needs {module}: pip install 'mitsonar[{extra}]'") from None
    return frame


def _uncertainty(run):
    """Each sounding's predicted depth sigma (m, `predicted_rms` at its range and angle) where the
    model holds (speckled centroid detection across a transmit fan), else None."""
    import mitsonar.kinds as kinds
    from mitsonar.products.bathymetry import predicted_rms

    info, s = run.sonar, run.soundings
    fan = getattr(kinds.lookup(info.get("kind")), "transmit_fan", False)
    if not (info.get("speckle") and info.get("method") == "centroid" and fan):
        return None
    return predicted_rms(s["range"], s["angle"], info["beamwidth_h"], info["bin_width"],
                         resolution=info.get("speckle_resolution"))


@contextlib.contextmanager
def _output_folder(folder):
    """Create ``folder`` (and its parents) for the block; if the block fails, remove the folders it
    created that are still empty (a failed run leaves no empty output folder behind)."""
    from mitsonar._files import make_output_folder

    made, f = [], os.path.abspath(folder)
    while not os.path.exists(f):
        made.append(f)
        f = os.path.dirname(f)
    make_output_folder(folder, BathymetryCLIError)
    try:
        yield
    except BaseException:
        for f in made:                 # innermost first
            try:
                os.rmdir(f)
            except OSError:
                break
        raise


def _run(args, bathymetry, scene, traj, sensor, head, svp, grid_depths, write_ply, StagedFiles, water=None,
         frame=None):
    run = bathymetry.survey(scene, traj, spp=args.spp, seed=args.seed, threshold_db=args.threshold_db,
                            method=args.method, speckle=not args.no_speckle, max_scans=args.max_scans,
                            max_depth=args.max_depth, progress=not args.quiet, sensor=sensor,
                            sound_speed_profile=svp, water_profile=water)
    grid = grid_depths(run.soundings, args.cell)
    out = args.output
    written = [f for f in OUTPUTS if f != "depth.tif"]
    with StagedFiles() as files:
        write_ply(files.temporary(os.path.join(out, "soundings.ply")), run.soundings)
        grid.save_npz(files.temporary(os.path.join(out, "depth.npz")))
        summary = run.summary()
        summary.update(preset=head.sounder.name if head else None, model=head.sounder.model if head else None,
                       sensor=sensor.id() if head is None else None, scene=args.scene, cell=args.cell,
                       surface=args.surface, transform=list(grid.transform), processing_svp=args.processing_svp,
                       svp=args.svp)
        if frame is not None:
            summary.update(origin=[frame.lat, frame.lon, frame.height], crs=frame.crs)
        with open(files.temporary(os.path.join(out, "errors.json")), "w") as f:
            json.dump(summary, f, indent=1)
        plot_bathymetry(run, grid, files.temporary(os.path.join(out, "bathymetry.png")), traj)
        from mitsonar.export.geotiff import write_depth_geotiff

        if frame is not None:   # georeferenced: the grid in the CRS, the soundings as LAS and CSV
            from mitsonar.export.las import write_csv, write_las

            from mitsonar.export.bag import bag_available, write_bag

            sigma = _uncertainty(run)
            write_depth_geotiff(files.temporary(os.path.join(out, "depth.tif")), grid, frame)
            write_las(files.temporary(os.path.join(out, "soundings.las")), run.soundings, frame, uncertainty=sigma)
            write_csv(files.temporary(os.path.join(out, "soundings.csv")), run.soundings, frame)
            from mitsonar.export.kmall import write_kmall

            write_kmall(files.temporary(os.path.join(out, "soundings.kmall")), run.soundings, traj, frame,
                        n_beams=int(run.sonar["beams"]), sound_speed=float(run.sonar["sound_speed"]),
                        uncertainty=sigma)
            written += ["depth.tif", "soundings.las", "soundings.csv", "soundings.kmall"]
            if bag_available():
                write_bag(files.temporary(os.path.join(out, "depth.bag")), grid, frame, run.soundings, sigma)
                written.append("depth.bag")
        else:
            try:
                import rasterio  # noqa: F401
            except ImportError:
                pass
            else:
                write_depth_geotiff(files.temporary(os.path.join(out, "depth.tif")), grid)
                written.append("depth.tif")
    print(summary_line(summary, written, out))
    return 0


def summary_line(summary, written, out) -> str:
    """The line the command prints: what it wrote, and the rms depth error (or why there is none:
    no sounding with the scene's seabed under it)."""
    rms = summary.get("rms_error")
    error = (f"rms depth error {100 * rms:.2f} cm" if rms is not None
             else "no depth error (no sounding has a seabed under it in the scene)")
    return (f"wrote {', '.join(written)} to {out}: {summary['n_soundings']} soundings from {summary['n_pings']} "
            f"pings, {error}")


def add_subcommands(sub):
    from mitsonar.products.bathymetry import METHODS
    from mitsonar.scenes.echosounders import PRESETS
    from mitsonar.cli.survey import add_trajectory_options

    s = sub.add_parser("bathymetry", help="a bathymetric survey: soundings, depth grid, depth errors",
                       description="Survey a scene with a preset downward echo sounder (it replaces the "
                                   "scene's sonar, mounted looking down at the vehicle's origin) and write "
                                   "the soundings, the depth grid and the depth errors per beam angle.")
    s.add_argument("scene", help="scene XML file (its sonar is replaced by the preset)")
    from mitsonar.cli.common import add_output, files_in_folder

    add_output(s, "-o", "--output", required=True, help="output folder", existing=files_in_folder(OUTPUTS + GEO_OUTPUTS))
    s.add_argument("--preset", choices=sorted(PRESETS), help="echo sounder (default r2sonic_2024)")
    s.add_argument("--sensor", metavar="ID|INDEX",
                   help="survey with the scene's own sensor (its XML id or index) instead of a preset head")
    s.add_argument("--swath", type=float, help="deg between the outermost beams (default the preset's)")
    s.add_argument("--beams", type=int, help="receive beams (default the preset's)")
    s.add_argument("--range-max", type=float, help="m, end of the range window (default the preset's)")
    s.add_argument("--bin-width", type=float, help="m, range bin (default the preset's)")
    s.add_argument("--threshold-db", type=float, default=10.0, help="echo window, dB below its peak (default 10)")
    s.add_argument("--method", choices=METHODS, help="bottom detection (default centroid; leading_edge for an altimeter)")
    s.add_argument("--no-speckle", action="store_true", help="detect on the noise-free intensity")
    s.add_argument("--surface", action="store_true", help="add a flat specular sea surface at z = 0 (multipath)")
    s.add_argument("--cell", type=float, default=0.5, help="depth grid cell, m (default 0.5)")
    s.add_argument("--processing-svp", metavar="CSV",
                   help="sound-speed profile (header depth,sound_speed) the soundings are ray-traced through "
                        "(default: straight beams at the head's nominal speed)")
    s.add_argument("--svp", metavar="CSV",
                   help="sound-speed profile (header depth,sound_speed) of the water the survey is rendered in: "
                        "refracted echo paths (default: uniform water at the head's nominal speed)")
    add_trajectory_options(s)
    s.add_argument("--spp", type=int, default=128, help="paths per beam (default 128)")
    s.add_argument("--seed", type=int, default=0,
                   help="survey seed of the paths (default 0); the speckle is the scene's (the sensor's speckle_seed)")
    s.add_argument("--max-scans", type=int, help="stop after this many pings")
    s.add_argument("--max-depth", type=int, help="surface bounces (default: the scene's integrator)")
    s.add_argument("-q", "--quiet", action="store_true", help="no progress bar")
    s.add_argument("--force", action="store_true", help="overwrite the outputs of a run already in the folder")
    from mitsonar.geometry.geodesy import add_geo_options

    add_geo_options(s)   # with --origin: depth.tif in the CRS, soundings.las and soundings.csv
    s.set_defaults(func=cmd_bathymetry)
