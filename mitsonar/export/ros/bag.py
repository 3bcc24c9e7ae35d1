"""Writing scans into an MCAP file of ROS 2 messages (what ``ros2 bag`` and Foxglove read), with
``mcap`` and ``mcap-ros2-support`` only (no ROS install): `write_mcap` for scans in hand, `McapBag`
to add scans one at a time (a survey).

Topics (see the README, "ROS 2 bags"):

=================== ========================================= =====================================
``/sonar/image``    marine_acoustic_msgs/ProjectedSonarImage  one per ping, frame ``sonar`` (side-scan:
                                                              one per channel, ``sonar_port`` and
                                                              ``sonar_starboard``)
``/sonar/fan``      sensor_msgs/Image (mono8)                 one per scan, the Cartesian fan (none
                                                              for side-scan: a line has no fan)
``/sonar/waterfall`` sensor_msgs/Image (mono8)                one per scan, rows x bins
``/sonar/detections`` sensor_msgs/PointCloud2                 one per scan, frame ``map``
``/tf``             tf2_msgs/TFMessage                        one per ping
``/odom``           nav_msgs/Odometry                         one per ping (twist: trajectory)
=================== ========================================= =====================================

Stamps: ``start + base + scan.times[k]`` seconds, ``start`` given by the caller (default 0) and
``base`` the scan's own start on its clock (``meta.start_time``: a trajectory's for a rendered
scan, the wall clock for a real head's; 0 when it has none).
"""
from __future__ import annotations

import math
import os
from collections.abc import Mapping

import numpy as np

from mitsonar._files import StagedFiles, check_output_file
from mitsonar.export.ros import messages as M
from mitsonar.export.ros import msgdefs
from mitsonar.scan.meta import ScanMeta
from mitsonar.scan.model import as_scans

TOPICS = {"/sonar/image": M.PROJECTED, "/sonar/fan": M.IMAGE, "/sonar/waterfall": M.IMAGE,
          "/sonar/detections": M.CLOUD, "/tf": M.TF, "/odom": M.ODOMETRY}

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
    v = ScanMeta.from_dict(scan.meta).start_time if isinstance(getattr(scan, "meta", None), Mapping) else None
    return 0.0 if v is None else float(v)


def check_scan(scan, name="scan") -> None:
    """Refuse, naming ``name`` and the field, a scan missing a field the messages need."""
    for field in M.NEEDS:
        v = getattr(scan, field, None)
        if v is None:
            raise ExportError(f"{name}: the scan has no '{field}', which the ROS messages need "
                              f"(needed: {', '.join(M.NEEDS)})")
    data = np.asarray(scan.data)
    if data.dtype != np.uint8 or data.ndim != 2:
        raise ExportError(f"{name}: 'data' is {data.dtype} {data.shape}; allowed: uint8 (rows, bins)")
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
    (its clock that of the scans' ``start_time``): then ``/tf`` holds ``map -> base_link ->
    sonar`` and ``/odom`` the vehicle; without it ``map -> sonar`` and the sonar's pose."""

    def __init__(self, path, *, start=0.0, trajectory=None, threshold=THRESHOLD, force=False):
        Writer = _require_mcap()
        self.path = check_output(path, force)
        if not (isinstance(start, (int, float)) and math.isfinite(start) and start >= 0):
            raise ExportError(f"start: {start!r} is not allowed (seconds, finite and 0 or more)")
        if not (isinstance(threshold, (int, np.integer)) and 0 <= threshold <= 255):
            raise ExportError(f"threshold: {threshold!r} is not allowed (a level from 0 to 255)")
        self.start, self.trajectory, self.threshold = float(start), trajectory, int(threshold)
        self.staged = StagedFiles()
        self.counts = {t: 0 for t in TOPICS}
        self._fh = open(self.staged.temporary(self.path), "wb")
        self._writer = Writer(self._fh)
        self._schemas = {}

    def _write(self, topic, message, ns):
        datatype = TOPICS[topic]
        if datatype not in self._schemas:
            self._schemas[datatype] = self._writer.register_msgdef(datatype, msgdefs.definition(datatype))
        self._writer.write_message(topic, self._schemas[datatype], message, log_time=ns, publish_time=ns)
        self.counts[topic] += 1

    def add(self, scan, name="scan") -> None:
        """Write one scan's messages (refused, naming ``name`` and the field, if it lacks one)."""
        check_scan(scan, name)
        base = scan_base(scan)
        groups = M.pings(scan)
        previous = None
        for i, (t, rows, frame) in enumerate(groups):
            ns = M.stamp_ns(self.start + base + t)
            sonar = M.sonar_pose(scan, rows[0])
            first_of_ping = ns != previous      # a side-scan ping has one group per channel
            previous = ns
            if self.trajectory is not None:
                vehicle = self.trajectory.at(base + t)
                tfs = [M.transform(vehicle, ns, M.WORLD_FRAME, M.VEHICLE_FRAME),
                       M.transform(np.linalg.inv(vehicle) @ sonar, ns, M.VEHICLE_FRAME, frame)]
                odom = M.odometry(vehicle, ns, M.WORLD_FRAME, M.VEHICLE_FRAME, *M.velocity(self.trajectory, base + t))
            else:
                tfs = [M.transform(sonar, ns, M.WORLD_FRAME, frame)]
                odom = M.odometry(sonar, ns, M.WORLD_FRAME, frame)
            self._write("/tf", {"transforms": tfs}, ns)
            if first_of_ping:
                self._write("/odom", odom, ns)
            self._write("/sonar/image", M.projected_image(scan, rows, ns, frame), ns)
            if i == 0:
                if scan.sonar_kind.has_fan:   # a side-scan line has no fan to draw
                    self._write("/sonar/fan", M.fan_image(scan, ns), ns)
                self._write("/sonar/waterfall", M.waterfall(scan, ns), ns)
        last = M.stamp_ns(self.start + base + groups[-1][0])
        pts, levels = M.detections(scan, self.threshold)
        self._write("/sonar/detections", M.point_cloud(pts, levels, last), last)

    def close(self) -> dict:
        """Finish the file and rename it into place; returns the message count per topic."""
        self._writer.finish()
        self._fh.close()
        self.staged.commit()
        return dict(self.counts)

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


def write_mcap(path, scans, *, start=0.0, trajectory=None, threshold=THRESHOLD, force=False, names=None) -> dict:
    """Write ``scans`` (a `Scan` or a list) into the MCAP file ``path``; returns the message count
    per topic. Every scan is checked before the file is opened; ``names`` label them in errors."""
    scans = as_scans(scans)
    names = names or [f"scan {i}" for i in range(len(scans))]
    if not scans:
        raise ExportError("no scans to export")
    for scan, name in zip(scans, names):
        check_scan(scan, name)
    with McapBag(path, start=start, trajectory=trajectory, threshold=threshold, force=force) as bag:
        for scan, name in zip(scans, names):
            bag.add(scan, name)
    return bag.counts
