"""``mitsonar export SCANS... --mcap OUT`` (and/or ``--xtf OUT --origin LAT LON``: side-scan
pings as XTF, `mitsonar.export.xtf`): scans as an MCAP file of ROS 2 messages (Foxglove,
``ros2 bag``), written with ``mcap`` and ``mcap-ros2-support`` only; topics and frames in
`mitsonar.export.ros.bag` and docs/howto/ros2_bags.rst.

Every scan file (and the trajectory) is read and checked before the output is opened; the file is
written under a temporary name and renamed at the end, so a failure leaves nothing behind.
"""
from __future__ import annotations

from mitsonar.export.ros.bag import THRESHOLD, ExportError, McapBag, _geo_of, check_output, check_scan, scan_base


def add_mcap_options(parser, *, scans_help=True, force_help="overwrite an existing MCAP file"):
    """The options `mitsonar export` and `mitsonar survey --mcap` share."""
    parser.add_argument("--force", action="store_true", help=force_help)
    parser.add_argument("--start", type=float, default=0.0, metavar="S",
                        help="seconds added to every stamp (e.g. a Unix time); default 0")
    parser.add_argument("--threshold", type=int, default=THRESHOLD, metavar="LEVEL",
                        help=f"a row's strongest bin at this level (0-255) or more is a detected return "
                             f"(default {THRESHOLD})")


def cmd_export(args):
    from mitsonar.scan.io import load_scan
    from mitsonar.geometry.trajectory import Trajectory

    if args.mcap is None and args.xtf is None:
        raise ExportError("export: give --mcap OUT.mcap and/or --xtf OUT.xtf")
    if args.mcap is not None:
        check_output(args.mcap, args.force)
    if args.xtf is not None:
        from mitsonar.export.xtf import check_xtf_output

        check_xtf_output(args.xtf, args.force)
    from mitsonar.geometry.geodesy import frame_from_args

    frame = frame_from_args(args)                 # a bad --origin/--crs: refused before reading scans
    traj = Trajectory.from_tum(args.trajectory) if args.trajectory else None
    scans = []
    for path in args.scans:                       # every input read and checked before any output
        scan = load_scan(path)
        check_scan(scan, path)
        if args.mcap is not None and frame is None:
            _geo_of(scan, path)                   # an origin in its metadata that /fix cannot use
        t0, t1 = scan_base(scan) + scan.times[0], scan_base(scan) + scan.times[-1]
        if traj is not None and not traj.covers(t0, t1):
            lo, hi = traj.span
            raise ExportError(f"{path}: 'times' (+ meta start_time) span [{t0:.9g}, {t1:.9g}] s; allowed: "
                              f"within the trajectory's span [{lo:.9g}, {hi:.9g}] s")
        scans.append(scan)
    if args.xtf is not None:
        _export_xtf(args, scans, traj)
    if args.mcap is None:
        return 0
    with McapBag(args.mcap, start=args.start, trajectory=traj, threshold=args.threshold, force=args.force,
                 frame=frame) as bag:
        for scan, path in zip(scans, args.scans):
            bag.add(scan, path)
    summary = ", ".join(f"{n} on {t}" for t, n in bag.written().items())
    print(f"wrote {args.mcap}: {summary}")
    return 0


def _export_xtf(args, scans, traj):
    from mitsonar.export.xtf import check_scan as check_xtf_scan, frame_for, write_xtf

    for scan, path in zip(scans, args.scans):
        check_xtf_scan(scan, path)
    frame = frame_for(args, scans, args.scans)
    n = write_xtf(args.xtf, scans, frame, names=args.scans, start=args.start, trajectory=traj)
    print(f"wrote {args.xtf}: {n} side-scan pings, navigation in lat/lon ({frame.crs} grid)")


def add_xtf_options(parser):
    """``--xtf OUT`` and the georeference flags (``--origin``, ``--crs``)."""
    from mitsonar.geometry.geodesy import add_geo_options

    from mitsonar.cli.common import add_output

    add_output(parser, "--xtf", metavar="OUT", help="also write the side-scan pings as an XTF file (needs --origin, "
                                                    "or scans whose metadata hold one)")
    add_geo_options(parser)


def add_subcommands(sub):
    e = sub.add_parser("export", help="write scans as a ROS 2 bag (MCAP) for Foxglove and ros2 bag",
                       description="Write scans as an MCAP file of ROS 2 messages: "
                                   "marine_acoustic_msgs/ProjectedSonarImage per ping, the fan and the "
                                   "waterfall as sensor_msgs/Image, detections as PointCloud2, /tf, /tf_static and /odom, and with "
                                   "an origin (--origin, or the scans' metadata) NavSatFix on /fix.")
    e.add_argument("scans", nargs="+", help="scan files (.npz or .exr), in time order")
    from mitsonar.cli.common import add_output

    add_output(e, "--mcap", metavar="OUT", help="output file (.mcap)")
    e.add_argument("--trajectory", metavar="TUM", help="the vehicle's trajectory (a survey's trajectory.tum): "
                                                       "/tf gets map -> base_link -> sonar and /odom the vehicle")
    add_mcap_options(e)
    add_xtf_options(e)
    e.set_defaults(func=cmd_export)
