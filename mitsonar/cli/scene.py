"""``mitsonar scene from-grid`` and ``mitsonar scene from-sdf``: a scene from a bathymetric grid
(`mitsonar.scenes.grid`) or from a Gazebo SDF world (`mitsonar.scenes.sdf`).

    mitsonar scene from-grid site.tif -o site.xml            # + site_seabed.ply, the frame recorded
    mitsonar scene from-sdf world.sdf --model-path models/ -o world.xml

Every input is checked before anything is written; an existing output is refused without
``--force``; the scene and its meshes are written under temporary names and renamed together.
"""
from __future__ import annotations


class SceneCLIError(ValueError):
    """A user's mistake on the ``scene`` command line: one line printed by ``mitsonar``'s main."""


def cmd_from_grid(args):
    from mitsonar.scenes.grid import GridError, seabed_from_grid

    try:
        site = seabed_from_grid(args.grid, args.output, material=args.material, sediment=args.sediment,
                                sediment_map=args.sediment_map, bounds=args.bounds, resolution=args.resolution,
                                resampling=args.resampling, crs=args.crs, positive=args.positive,
                                vertical_offset=args.vertical_offset, origin=args.origin, sensor=args.sensor,
                                force=args.force)
    except GridError as exc:
        raise SceneCLIError(str(exc)) from None
    print(site.line())
    return 0


def cmd_from_sdf(args):
    from mitsonar.scenes.sdf import SdfError, scene_from_sdf

    try:
        world = scene_from_sdf(args.world, args.output, model_path=args.model_path, materials=args.materials,
                               material=args.material, scale=args.scale, sensor=args.sensor,
                               sensor_pose=args.sensor_pose, origin=args.origin, crs=args.crs, force=args.force)
    except SdfError as exc:
        raise SceneCLIError(str(exc)) from None
    for line in world.skipped:
        print(f"not converted: {line}")
    print(world.line())
    return 0


def add_subcommands(sub):
    from mitsonar.cli.common import add_force, add_output
    from mitsonar.scenes.grid import POSITIVE, RESAMPLING
    from mitsonar.scenes.echosounders import PRESETS

    s = sub.add_parser("scene", help="make a scene from a bathymetric grid or a Gazebo SDF world",
                       description="Convert your world into a mitsonar scene: a bathymetric grid (GeoTIFF, BAG, "
                                   "NetCDF, ASCII grid) into a seabed mesh in its CRS, or a Gazebo SDF world's "
                                   "static models into shapes.")
    ss = s.add_subparsers(dest="scene_command", metavar="SUBCOMMAND")
    sensor_help = (f"the sonar: an echo-sounder preset ({', '.join(sorted(PRESETS))}; default r2sonic_2024) or an "
                   "XML file holding one <sensor> element")

    g = ss.add_parser("from-grid", help="a seabed scene from a bathymetric grid, in the grid's CRS",
                      description="Write a scene (XML) and its seabed mesh (PLY, shape id 'seabed') from a raster "
                                  "GDAL reads; the scene records its origin and CRS, so survey and bathymetry over "
                                  "it write products at the grid's coordinates without --origin.")
    g.add_argument("grid", help="the grid: GeoTIFF, BAG, NetCDF (GEBCO), ASCII grid, ...")
    add_output(g, "-o", "--output", required=True, help="scene file to write (.xml; the PLY files go beside it)")
    g.add_argument("--material", help="the seabed's material (default seabed_sand)")
    g.add_argument("--sediment", metavar="MAP.tif", help="a raster of integer sediment classes (with --sediment-map)")
    g.add_argument("--sediment-map", metavar="CSV", help="class,material per line, for --sediment")
    g.add_argument("--bounds", nargs=4, type=float, metavar=("XMIN", "YMIN", "XMAX", "YMAX"),
                   help="crop to these bounds, in the grid's CRS")
    g.add_argument("--resolution", type=float, metavar="M", help="resample to cells of M metres (default the file's)")
    g.add_argument("--resampling", choices=RESAMPLING, default="bilinear", help="resampling (default bilinear)")
    g.add_argument("--positive", choices=POSITIVE,
                   help="up: the values are heights; down: depths (needed when the file does not say)")
    g.add_argument("--vertical-offset", type=float, default=0.0, metavar="M",
                   help="height of the grid's vertical datum above the sea surface, m (default 0)")
    g.add_argument("--crs", metavar="EPSG:NNNN",
                   help="reproject into this projected CRS (default: the grid's own; a geographic grid goes to the "
                        "UTM zone of its centre)")
    g.add_argument("--origin", nargs="+", type=float, metavar="LAT/LON/HEIGHT",
                   help="LAT LON [HEIGHT] of the world frame's origin (default: the grid's centre rounded to the metre)")
    g.add_argument("--sensor", help=sensor_help)
    add_force(g)
    g.set_defaults(func=cmd_from_grid)

    w = ss.add_parser("from-sdf", help="a scene from a Gazebo SDF world's static models",
                      description="Place a Gazebo world's static models (mesh, box, cylinder, sphere, plane and the "
                                  "first heightmap geometries, with their poses) in a scene; what cannot be converted "
                                  "is listed one line each.")
    w.add_argument("world", help="the .sdf or .world file")
    add_output(w, "-o", "--output", required=True,
               help="scene file to write (.xml; its meshes go beside it as <stem>_mesh_<k>.ply)")
    w.add_argument("--model-path", action="append", default=[], metavar="DIR",
                   help="a folder of models for model:// URIs (repeatable; GAZEBO_MODEL_PATH and "
                        "GZ_SIM_RESOURCE_PATH are searched after)")
    w.add_argument("--materials", metavar="CSV|YAML", help="model-name patterns to materials (fnmatch, first match)")
    w.add_argument("--material", help="the material of models no pattern matches (default rock)")
    w.add_argument("--scale", type=float, default=1.0, help="scale of STL and OBJ meshes to metres (default 1)")
    w.add_argument("--sensor", help=sensor_help)
    w.add_argument("--sensor-pose", nargs=6, type=float, metavar=("X", "Y", "Z", "ROLL", "PITCH", "YAW"),
                   help="the sonar's pose in the world (m, rad, as an SDF <pose>; default at the origin)")
    w.add_argument("--origin", nargs="+", type=float, metavar="LAT/LON/HEIGHT",
                   help="record this origin in the scene (the world's x, y are grid offsets from it)")
    w.add_argument("--crs", metavar="EPSG:NNNN", help="with --origin: the projected CRS (default its UTM zone)")
    add_force(w)
    w.set_defaults(func=cmd_from_sdf)

    def no_subcommand(args):
        raise SceneCLIError("scene: give a subcommand: from-grid or from-sdf")

    s.set_defaults(func=no_subcommand)
