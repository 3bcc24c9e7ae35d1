"""What every live output sends for a ping, whatever its encoding: the frames (as in the bags
of `mitsonar.export.ros`: ``map`` the world, ``base_link`` the vehicle, ``sonar`` the head in
the marine_acoustic_msgs convention, z forward and x up, so ``vehicle <- sonar`` is
``mount @ SONAR_AXES``), the raw ping as a JSON object (`PING_SCHEMA`), and the topics' names.
"""
from __future__ import annotations

import base64

import numpy as np

from mitsonar.export.ros.messages import SONAR_AXES, SONAR_FRAME, VEHICLE_FRAME, WORLD_FRAME
from mitsonar.geometry.trajectory import matrix_to_quat

__all__ = ["TOPICS", "PING_SCHEMA", "WORLD_FRAME", "VEHICLE_FRAME", "SONAR_FRAME", "sonar_in_vehicle",
           "translation_rotation", "ping_message"]

#: topic -> what it carries (Foxglove and MCAP; over DDS the same names with ROS 2 types).
TOPICS = {
    "/sonar/fan": "the sonar picture: a mechanical head's sweep so far, a multibeam frame's fan (mono8)",
    "/sonar/ping": "the raw ping: device bytes, bin ranges and bearings (JSON, mitsonar.SonarPing)",
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
                        "description": "uint8 device levels, beam_count x bin_count, row-major"},
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
    data = np.ascontiguousarray(scan.data, np.uint8)
    return {"timestamp": {"sec": int(t_ns // 1_000_000_000), "nsec": int(t_ns % 1_000_000_000)},
            "frame_id": SONAR_FRAME,
            "bearings": [float(b) for b in np.asarray(scan.bearings, np.float64)],
            "ranges": [float(r) for r in np.asarray(scan.ranges, np.float64)],
            "range_min": float(scan.range_min), "range_max": float(scan.range_max),
            "sound_speed": float(scan.sound_speed),
            "beam_count": int(data.shape[0]), "bin_count": int(data.shape[1]),
            "intensities": base64.b64encode(data.tobytes()).decode("ascii")}
