"""Writing scans into an MCAP file of ROS 2 messages (what ``ros2 bag`` and Foxglove read), with
``mcap`` and ``mcap-ros2-support`` only (no ROS install): `write_mcap` for scans in hand, `McapBag`
to add scans one at a time (a survey).

Topics (see docs/howto/ros2_bags.rst):

=================== ========================================= =====================================
``/sonar/image``    marine_acoustic_msgs/ProjectedSonarImage  one per ping, frame ``sonar`` (side-scan:
                                                              one per channel, ``sonar_port`` and
                                                              ``sonar_starboard``)
``/sonar/fan``      sensor_msgs/Image (mono8)                 one per scan, the Cartesian fan (none
                                                              for side-scan: a line has no fan)
``/sonar/waterfall`` sensor_msgs/Image (mono8)                one per scan, rows x bins
``/sonar/detections`` sensor_msgs/PointCloud2                 one per scan, frame ``map``
``/sonar/points``   sensor_msgs/PointCloud2                   a 3D sonar's point clouds
                                                              (`McapBag.add_point_cloud`), frame ``map``
``/tf``             tf2_msgs/TFMessage                        one per ping: ``map -> sonar``, or
                                                              ``map -> base_link`` with a trajectory
``/tf_static``      tf2_msgs/TFMessage                        the fixed mounts (``base_link ->
                                                              sonar``; a side-scan's ``sonar ->
                                                              sonar_port``, ``sonar_starboard``),
                                                              transient-local, when they change
``/odom``           nav_msgs/Odometry                         one per ping (twist: trajectory)
``/fix``            sensor_msgs/NavSatFix                     one per ping, with a geodetic origin
=================== ========================================= =====================================

Device levels: bytes (uint8 ``data``) go as they are; a 16-bit A/D's uint16 codes as DTYPE_UINT16
in ``/sonar/image`` and ``mono16`` images; a 32-bit A/D's uint32 codes as DTYPE_UINT32 in
``/sonar/image`` and as ``mono16`` images of the same levels on 16 bits (sensor_msgs has no unsigned
32-bit grey encoding); ``/sonar/detections`` and the ``threshold`` are on the 0..255 scale
(`mitsonar.export.ros.messages.detections`).

Stamps: ``start + base + scan.times[k]`` seconds, ``start`` given by the caller (default 0) and
``base`` the scan's own start on its clock (``meta.start_time``: a trajectory's for a rendered
scan, the wall clock for a real head's; 0 when it has none).
"""
from __future__ import annotations

import math
import os

import numpy as np

from mitsonar._files import StagedFiles, check_output_file
from mitsonar.export.ros import messages as M
from mitsonar.export.ros import msgdefs
from mitsonar.scan.meta import ScanMeta
from mitsonar.scan.model import as_scans

TOPICS = {"/sonar/image": M.PROJECTED, "/sonar/fan": M.IMAGE, "/sonar/waterfall": M.IMAGE,
          "/sonar/detections": M.CLOUD, "/sonar/points": M.CLOUD, "/tf": M.TF, "/tf_static": M.TF, "/odom": M.ODOMETRY, "/fix": M.NAVSATFIX}

#: The QoS ``ros2 bag`` records for a latched static-transform topic (rosbag2's
#: ``offered_qos_profiles`` channel metadata; rmw enums: history 1 keep-last, reliability 1
#: reliable, durability 1 transient-local, liveliness 1 automatic), so that ``ros2 bag play``
#: republishes ``/tf_static`` transient-local and a late subscriber (RViz, tf2) still gets it.
_FOREVER = "{sec: 2147483647, nsec: 4294967295}"
STATIC_QOS = (f"- history: 1\n  depth: 1\n  reliability: 1\n  durability: 1\n  deadline: {_FOREVER}\n"
              f"  lifespan: {_FOREVER}\n  liveliness: 1\n  liveliness_lease_duration: {_FOREVER}\n"
              "  avoid_ros_namespace_conventions: false\n")
QOS = {"/tf_static": STATIC_QOS}
#: How far (m, and radians as rotation-matrix entries) a mount may move between pings and still
#: be one static transform.
MOUNT_TOLERANCE = 1e-6

#: Default level (0-255) a row's strongest bin must reach to be a detected return.
THRESHOLD = 128


class ExportError(ValueError):
    """A scan or an output path that cannot be exported: one line naming the file and the field."""


def _require_mcap():
    try:
        from mcap_ros2.writer import Writer
    except ImportError:
        raise ExportError("writing MCAP needs the packages mcap and mcap-ros2-support: "
                          "pip install 'mitsonar[ros]'") from None
    return Writer


def scan_base(scan) -> float:
    """The scan's own start time in seconds (its ``meta.start_time``, else 0)."""
    v = ScanMeta.from_dict(getattr(scan, "meta", None) or {}).start_time
    return 0.0 if v is None else float(v)


def check_scan(scan, name="scan") -> None:
    """Refuse, naming ``name`` and the field, a scan missing a field the messages need."""
    for field in M.NEEDS:
        v = getattr(scan, field, None)
        if v is None:
            raise ExportError(f"{name}: the scan has no '{field}', which the ROS messages need "
                              f"(needed: {', '.join(M.NEEDS)})")
    data = np.asarray(scan.data)
    if data.dtype not in M.SONAR_IMAGE_DTYPES or data.ndim != 2:
        raise ExportError(f"{name}: 'data' is {data.dtype} {data.shape}; allowed: uint8, uint16 or uint32 "
                          f"(rows, bins)")
    rows, bins = data.shape
    for field, shape in (("ranges", (bins,)), ("bearings", (rows,)), ("times", (rows,)), ("poses", (rows, 4, 4))):
        a = np.asarray(getattr(scan, field))
        if a.shape != shape:
            raise ExportError(f"{name}: '{field}' has shape {a.shape}; allowed: {shape} for data of shape {data.shape}")
        if not np.all(np.isfinite(a)):
            raise ExportError(f"{name}: '{field}' holds values that are not finite; allowed: finite numbers")


#: `check_output`'s sentences (`mitsonar._files.check_output_file`).
_OUTPUT_WORDS = {"directory": "{path}: is a folder; give an .mcap file name",
                 "extension": "{path}: the file name must end in .mcap",
                 "no_folder": "{path}: the folder {folder} does not exist"}


def check_output(path, force=False, folder_may_be=None) -> str:
    """The output path as a string; an existing one is refused unless ``force``. Its folder must
    exist, unless it is ``folder_may_be`` (a folder the caller is about to make)."""
    _require_mcap()
    return check_output_file(path, ExportError, extensions=(".mcap",), force=force, folder_may_be=folder_may_be,
                             words=_OUTPUT_WORDS)


class McapBag:
    """An MCAP file being written: `add` scans, then `close` (renames it into place); `discard`
    (or an exception inside ``with``) leaves nothing. ``trajectory``: the vehicle's `Trajectory`
    (its clock that of the scans' ``start_time``): then ``/tf`` holds ``map -> base_link``,
    ``/tf_static`` the mount ``base_link -> sonar`` (when it is the same at every ping of a scan;
    else on ``/tf``) and ``/odom`` the vehicle; without it ``/tf`` holds ``map -> sonar`` and
    ``/odom`` the sonar's pose. ``frame``: a `GeoFrame` (default: the one a scan's metadata
    holds, if any): then ``/fix`` holds the vehicle's (or the sonar's) latitude, longitude and
    height above the ellipsoid (the origin's height + z) at every ping."""

    def __init__(self, path, *, start=0.0, trajectory=None, threshold=THRESHOLD, force=False, frame=None):
        Writer = _require_mcap()
        self.path = check_output(path, force)
        if not (isinstance(start, (int, float)) and math.isfinite(start) and start >= 0):
            raise ExportError(f"start: {start!r} is not allowed (seconds, finite and 0 or more)")
        if not (isinstance(threshold, (int, np.integer)) and 0 <= threshold <= 255):
            raise ExportError(f"threshold: {threshold!r} is not allowed (a level from 0 to 255)")
        self.start, self.trajectory, self.threshold = float(start), trajectory, int(threshold)
        self.frame = frame
        self.staged = StagedFiles()
        self.counts = {t: 0 for t in TOPICS}
        self._fh = open(self.staged.temporary(self.path), "wb")
        self._writer = Writer(self._fh)
        self._schemas = {}
        self._static = {}           # child frame -> (parent, 4x4): what /tf_static holds so far

    def _write(self, topic, message, ns):
        datatype = TOPICS[topic]
        if datatype not in self._schemas:
            self._schemas[datatype] = self._writer.register_msgdef(datatype, msgdefs.definition(datatype))
        ids = getattr(self._writer, "_channel_ids", None)   # mcap_ros2 0.5-0.6's; without it, no QoS metadata
        if topic in QOS and isinstance(ids, dict) and topic not in ids and hasattr(self._writer, "_writer"):
            # mcap_ros2's Writer registers a channel without metadata on a topic's first message:
            # register this one first, with the QoS rosbag2 reads (its documented channel metadata).
            ids[topic] = self._writer._writer.register_channel(
                topic=topic, message_encoding="cdr", schema_id=self._schemas[datatype].id,
                metadata={"offered_qos_profiles": QOS[topic]})
        self._writer.write_message(topic, self._schemas[datatype], message, log_time=ns, publish_time=ns)
        self.counts[topic] += 1

    def _static_transforms(self, mounts: dict, ns: int) -> None:
        """Publish on ``/tf_static`` every static transform so far (as tf2's static broadcaster
        does) when ``mounts`` (``{child: (parent, 4x4)}``) adds or changes one."""
        changed = False
        for child, (parent, pose) in mounts.items():
            old = self._static.get(child)
            if old is None or old[0] != parent or not np.allclose(old[1], pose, rtol=0, atol=MOUNT_TOLERANCE):
                self._static[child] = (parent, pose)
                changed = True
        if changed:
            tfs = [M.transform(pose, ns, parent, child) for child, (parent, pose) in self._static.items()]
            self._write("/tf_static", {"transforms": tfs}, ns)

    def add(self, scan, name="scan") -> None:
        """Write one scan's messages (refused, naming ``name`` and the field, if it lacks one)."""
        check_scan(scan, name)
        geo = self.frame if self.frame is not None else _geo_of(scan, name)
        base = scan_base(scan)
        groups = M.pings(scan)
        firsts = [(t, rows[0]) for i, (t, rows, _) in enumerate(groups) if i == 0 or t != groups[i - 1][0]]
        heads = {row: M.head_pose(scan, row) for _, row in firsts}
        vehicles = {row: self.trajectory.at(base + t) for t, row in firsts} if self.trajectory is not None else None
        ns0 = M.stamp_ns(self.start + base + groups[0][0])
        mounts = {child: (M.SONAR_FRAME, pose) for child, pose in M.channel_mounts(scan).items()}
        static_mount = False
        if vehicles is not None:
            mount = [np.linalg.inv(vehicles[row]) @ heads[row] for _, row in firsts]
            static_mount = all(np.allclose(m, mount[0], rtol=0, atol=MOUNT_TOLERANCE) for m in mount)
            if static_mount:
                mounts[M.SONAR_FRAME] = (M.VEHICLE_FRAME, mount[0])
        self._static_transforms(mounts, ns0)
        fix = None
        if geo is not None:
            where = vehicles if vehicles is not None else heads
            xyz = np.array([where[row][:3, 3] for _, row in firsts])
            lon, lat = geo.to_lonlat(xyz[:, 0], xyz[:, 1])
            fix = {row: (lat[k], lon[k], geo.height + xyz[k, 2]) for k, (_, row) in enumerate(firsts)}
        previous = None
        for i, (t, rows, frame) in enumerate(groups):
            ns = M.stamp_ns(self.start + base + t)
            if ns != previous:              # a side-scan ping has one group per channel: one /tf, /odom, /fix
                previous = ns
                head = heads[rows[0]]
                if vehicles is not None:
                    vehicle = vehicles[rows[0]]
                    tfs = [M.transform(vehicle, ns, M.WORLD_FRAME, M.VEHICLE_FRAME)]
                    if not static_mount:
                        tfs.append(M.transform(np.linalg.inv(vehicle) @ head, ns, M.VEHICLE_FRAME, M.SONAR_FRAME))
                    odom = M.odometry(vehicle, ns, M.WORLD_FRAME, M.VEHICLE_FRAME,
                                      *M.velocity(self.trajectory, base + t))
                else:
                    tfs = [M.transform(head, ns, M.WORLD_FRAME, M.SONAR_FRAME)]
                    odom = M.odometry(head, ns, M.WORLD_FRAME, M.SONAR_FRAME)
                self._write("/tf", {"transforms": tfs}, ns)
                self._write("/odom", odom, ns)
                if fix is not None:
                    child = M.VEHICLE_FRAME if vehicles is not None else M.SONAR_FRAME
                    self._write("/fix", M.navsatfix(*fix[rows[0]], ns, child), ns)
            self._write("/sonar/image", M.projected_image(scan, rows, ns, frame), ns)
            if i == 0:
                if scan.sonar_kind.has_fan:   # a side-scan line has no fan to draw
                    self._write("/sonar/fan", M.fan_image(scan, ns), ns)
                self._write("/sonar/waterfall", M.waterfall(scan, ns), ns)
        last = M.stamp_ns(self.start + base + groups[-1][0])
        pts, levels = M.detections(scan, self.threshold)
        self._write("/sonar/detections", M.point_cloud(pts, levels, last), last)

    def add_point_cloud(self, points, t=0.0) -> None:
        """Write a 3D sonar's point cloud (`mitsonar.signals.volumetric.point_cloud`: world x, y, z,
        intensity, beam indices, range) on ``/sonar/points`` at ``start + t`` s, frame ``map``."""
        if not (isinstance(t, (int, float)) and math.isfinite(t) and t >= 0):
            raise ExportError(f"add_point_cloud t: {t!r} is not allowed (seconds, finite and 0 or more)")
        ns = M.stamp_ns(self.start + t)
        self._write("/sonar/points", M.point_cloud_message(points, ns, M.WORLD_FRAME), ns)

    def close(self) -> dict:
        """Finish the file and rename it into place; returns the message count per topic written.
        A failure to finish leaves no file (the temporary one is removed)."""
        try:
            self._writer.finish()
            self._fh.close()
        except BaseException:
            self.discard()
            raise
        self.staged.commit()
        return self.written()

    def written(self) -> dict:
        """The message count of each topic written to so far."""
        return {t: n for t, n in self.counts.items() if n}

    def discard(self) -> None:
        try:
            self._fh.close()
        finally:
            self.staged.discard()

    def __enter__(self):
        return self

    def __exit__(self, exc_type, exc, tb):
        if exc_type is None:
            self.close()
        else:
            self.discard()
        return False


def _geo_of(scan, name):
    """The `GeoFrame` a scan's metadata holds (``origin``, ``crs``), or None."""
    meta = ScanMeta.from_dict(getattr(scan, "meta", None) or {})
    if meta.origin is None:
        return None
    from mitsonar.geometry.geodesy import GeoError, GeoFrame

    try:
        return GeoFrame.from_meta(meta, f"{name}: meta")
    except GeoError as exc:
        raise ExportError(str(exc)) from None


def write_mcap(path, scans, *, start=0.0, trajectory=None, threshold=THRESHOLD, force=False, names=None,
               frame=None) -> dict:
    """Write ``scans`` (a `Scan` or a list) into the MCAP file ``path``; returns the message count
    per topic written. Every scan is checked before the file is opened; ``names`` label them in
    errors. ``frame``: a `GeoFrame` for ``/fix`` (default: the scans' metadata's, if any)."""
    scans = as_scans(scans)
    names = names or [f"scan {i}" for i in range(len(scans))]
    if not scans:
        raise ExportError("no scans to export")
    for scan, name in zip(scans, names):
        check_scan(scan, name)
        if frame is None:
            _geo_of(scan, name)
    with McapBag(path, start=start, trajectory=trajectory, threshold=threshold, force=force, frame=frame) as bag:
        for scan, name in zip(scans, names):
            bag.add(scan, name)
    return bag.written()
