"""What every live output sends for a ping, whatever its encoding: the frames (as in the bags
of `mitsonar.export.ros`: ``map`` the world, ``base_link`` the vehicle, ``sonar`` the head in
the marine_acoustic_msgs convention, z forward and x up, so ``vehicle <- sonar`` is
``mount @ SONAR_AXES``), the raw ping as a JSON object (`PING_SCHEMA`), and the topics' names.
"""
from __future__ import annotations

import base64
import struct

import numpy as np

from mitsonar.export.ros.messages import SONAR_AXES, SONAR_FRAME, VEHICLE_FRAME, WORLD_FRAME, point_cloud_message
from mitsonar.geometry.trajectory import matrix_to_quat
from mitsonar.scan.model import data_bytes

__all__ = ["TOPICS", "PING_SCHEMA", "WORLD_FRAME", "VEHICLE_FRAME", "SONAR_FRAME", "POINTS_THRESHOLD_DB",
           "sonar_in_vehicle", "translation_rotation", "ping_message", "frame_points", "pointcloud2_cdr"]

#: topic -> what it carries (Foxglove and MCAP; over DDS the same names with ROS 2 types).
TOPICS = {
    "/sonar/fan": "the sonar picture: a mechanical head's sweep so far, a multibeam frame's fan (mono8)",
    "/sonar/ping": "the raw ping: device bytes, bin ranges and bearings (JSON, mitsonar.SonarPing)",
    "/sonar/points": f"a volumetric frame's point cloud in {WORLD_FRAME} (sensor_msgs/msg/PointCloud2, CDR)",
    "/tf": f"{WORLD_FRAME} -> {VEHICLE_FRAME} (the vehicle) and {VEHICLE_FRAME} -> {SONAR_FRAME} (the mount)",
    "/vehicle/pose": f"the vehicle's pose in {WORLD_FRAME}",
}

#: JSON Schema of ``/sonar/ping`` (schema name ``mitsonar.SonarPing``), after
#: marine_acoustic_msgs/RawSonarImage: ``intensities`` are the device bytes, row-major
#: (``beam_count`` rows of ``bin_count`` bins), base64 as Foxglove's JSON schemas carry bytes.
PING_SCHEMA = {
    "title": "mitsonar.SonarPing",
    "type": "object",
    "properties": {
        "timestamp": {"type": "object", "properties": {"sec": {"type": "integer"}, "nsec": {"type": "integer"}}},
        "frame_id": {"type": "string"},
        "bearings": {"type": "array", "items": {"type": "number"},
                     "description": "each row's azimuth in the sonar frame (rad, about its x axis)"},
        "ranges": {"type": "array", "items": {"type": "number"}, "description": "bin-centre ranges (m)"},
        "range_min": {"type": "number"},
        "range_max": {"type": "number"},
        "sound_speed": {"type": "number"},
        "beam_count": {"type": "integer"},
        "bin_count": {"type": "integer"},
        "intensities": {"type": "string", "contentEncoding": "base64",
                        "description": "uint8 device levels, beam_count x bin_count, row-major (a "
                                       "16- or 32-bit head's codes as bytes: round(255 code / full scale))"},
    },
}


def sonar_in_vehicle(mount) -> np.ndarray:
    """The ``sonar`` frame (z forward, x up) in the vehicle: ``mount @ SONAR_AXES``."""
    return np.asarray(mount, np.float64) @ SONAR_AXES


def translation_rotation(pose) -> tuple:
    """``(x, y, z)`` and the quaternion ``(x, y, z, w)`` of a 4x4 pose, as floats."""
    pose = np.asarray(pose, np.float64)
    q = matrix_to_quat(pose[:3, :3]).reshape(4)
    return tuple(float(v) for v in pose[:3, 3]), tuple(float(v) for v in q)


def ping_message(t_ns: int, scan) -> dict:
    """The ``/sonar/ping`` object of a ping (`PING_SCHEMA`)."""
    data = np.ascontiguousarray(data_bytes(scan.data))      # a wider A/D's codes: the same levels as bytes
    return {"timestamp": {"sec": int(t_ns // 1_000_000_000), "nsec": int(t_ns % 1_000_000_000)},
            "frame_id": SONAR_FRAME,
            "bearings": [float(b) for b in np.asarray(scan.bearings, np.float64)],
            "ranges": [float(r) for r in np.asarray(scan.ranges, np.float64)],
            "range_min": float(scan.range_min), "range_max": float(scan.range_max),
            "sound_speed": float(scan.sound_speed),
            "beam_count": int(data.shape[0]), "bin_count": int(data.shape[1]),
            "intensities": base64.b64encode(data.tobytes()).decode("ascii")}


#: dB re a volumetric frame's peak above which its beams' strongest returns are ``/sonar/points``.
POINTS_THRESHOLD_DB = -20.0


def frame_points(t_ns: int, scan) -> dict | None:
    """The ``/sonar/points`` message of a ping: for a frame of a ``volumetric`` head, the
    sensor_msgs/msg/PointCloud2 dict of its point cloud (`mitsonar.signals.volumetric.point_cloud`
    of `scan_volume`: each beam's strongest return within `POINTS_THRESHOLD_DB` of the frame's peak,
    world x, y, z in ``map``), as the bags' ``/sonar/points``; None for the other kinds."""
    if not scan.sonar_kind.grid:
        return None
    from mitsonar.signals.volumetric import point_cloud, scan_volume

    return point_cloud_message(point_cloud(scan_volume(scan), POINTS_THRESHOLD_DB), t_ns, WORLD_FRAME)


def pointcloud2_cdr(msg: dict) -> bytes:
    """ROS 2's serialisation of a sensor_msgs/msg/PointCloud2 dict (`frame_points`): CDR, little
    endian (the encapsulation header ``00 01 00 00``), each primitive aligned to its size from the
    end of that header, strings as a uint32 length with their NUL then the bytes, sequences as a
    uint32 count then the elements (OMG CDR, as rmw's Fast-CDR and Cyclone write it)."""
    out = bytearray()

    def u32(v, fmt="<I"):
        out.extend(b"\0" * (-len(out) % 4))
        out.extend(struct.pack(fmt, int(v)))

    def string(s):
        b = s.encode("utf-8") + b"\0"
        u32(len(b))
        out.extend(b)

    h = msg["header"]
    u32(h["stamp"]["sec"], "<i")
    u32(h["stamp"]["nanosec"])
    string(h["frame_id"])
    u32(msg["height"])
    u32(msg["width"])
    u32(len(msg["fields"]))
    for f in msg["fields"]:
        string(f["name"])
        u32(f["offset"])
        out.append(int(f["datatype"]))
        u32(f["count"])
    out.append(1 if msg["is_bigendian"] else 0)
    u32(msg["point_step"])
    u32(msg["row_step"])
    u32(len(msg["data"]))
    out.extend(bytes(msg["data"]))
    out.append(1 if msg["is_dense"] else 0)
    return b"\x00\x01\x00\x00" + bytes(out)
