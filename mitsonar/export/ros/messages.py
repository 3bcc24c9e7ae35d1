"""ROS 2 messages (as the dicts `mcap_ros2` encodes) from a `Scan`: the sonar images, the fan and
waterfall pictures, the detected returns and the frames; and a 3D sonar's point cloud
(`point_cloud_message`). No file I/O here (see `bag`).

Frames (REP-103/105): ``map`` is the world of the scan's poses (z up); ``sonar`` is the head
in the marine_acoustic_msgs convention, z forward (the boresight at bearing 0), x up, the beams
in its y-z plane at azimuth ``a`` (rotation about x): direction ``(0, -sin a, cos a)``. mitsonar's
beam frame (+z boresight, +y the scan axis, bearing ``b`` a right-handed turn about +y) maps onto
it as ``x_sonar = y_beam``, ``y_sonar = -x_beam``, ``z_sonar = z_beam``; so azimuth = bearing.

A side-scan head has two channel frames, ``sonar_port`` and ``sonar_starboard``, in the same
convention: z the channel's boresight, x up. A side-scan beam frame's +y points down, to the
nadir side of the fan (`mitsonar.geometry.frames.sidescan_rotation`), so there ``x_sonar =
-y_beam``, ``y_sonar = x_beam``, ``z_sonar = z_beam`` (`SIDESCAN_AXES`). Their parent ``sonar``
is then the head itself (REP-103: x forward, y port, z up), which the waterfall is stamped with.
"""
from __future__ import annotations

import math

import numpy as np

from mitsonar.geometry.frames import bearing_rotation, sidescan_rotation
from mitsonar.geometry.trajectory import matrix_to_quat
from mitsonar.scan.electronics import ElectronicsSettings
from mitsonar.scan.meta import ScanMeta

WORLD_FRAME = "map"
SONAR_FRAME = "sonar"
VEHICLE_FRAME = "base_link"
#: A side-scan head's two channels look opposite ways: each has its own sonar frame.
CHANNEL_FRAMES = ("sonar_port", "sonar_starboard")

PROJECTED = "marine_acoustic_msgs/msg/ProjectedSonarImage"
IMAGE = "sensor_msgs/msg/Image"
CLOUD = "sensor_msgs/msg/PointCloud2"
TF = "tf2_msgs/msg/TFMessage"
ODOMETRY = "nav_msgs/msg/Odometry"
NAVSATFIX = "sensor_msgs/msg/NavSatFix"

#: The sonar frame's axes in mitsonar's beam frame (columns): x = +y_beam, y = -x_beam, z = +z_beam.
SONAR_AXES = np.array([[0.0, -1.0, 0.0, 0.0],
                       [1.0, 0.0, 0.0, 0.0],
                       [0.0, 0.0, 1.0, 0.0],
                       [0.0, 0.0, 0.0, 1.0]])
#: A side-scan channel frame's axes in its beam frame: x = -y_beam (up: the beam frame's +y
#: points down to the nadir side), y = +x_beam, z = +z_beam (the boresight).
SIDESCAN_AXES = np.array([[0.0, 1.0, 0.0, 0.0],
                          [-1.0, 0.0, 0.0, 0.0],
                          [0.0, 0.0, 1.0, 0.0],
                          [0.0, 0.0, 0.0, 1.0]])

#: Fields a scan needs for each message (a scan lacking one is refused naming it).
NEEDS = ("data", "ranges", "bearings", "poses", "times", "sound_speed", "beamwidth_h", "beamwidth_v",
         "range_min", "range_max")


def stamp_ns(seconds: float) -> int:
    return int(round(float(seconds) * 1e9))


def header(ns: int, frame: str) -> dict:
    return {"stamp": {"sec": int(ns // 1_000_000_000), "nanosec": int(ns % 1_000_000_000)}, "frame_id": frame}


def pings(scan) -> list:
    """The scan's rows grouped by ping and sonar frame: ``[(time, row indices, frame), ...]`` in
    time order (a multibeam frame is one ping of all its rows in ``sonar``; a mechanical sweep one
    ping per row; a side-scan ping one group per channel, in ``sonar_port`` then
    ``sonar_starboard``, since the two channels look opposite ways)."""
    times = np.asarray(scan.times, dtype=np.float64)
    channel = getattr(scan, "channel", None)     # None but for a side-scan's rows
    out = []
    for t in np.unique(times):
        rows = np.flatnonzero(times == t)
        if channel is None:
            out.append((float(t), rows, SONAR_FRAME))
            continue
        for c, frame in enumerate(CHANNEL_FRAMES):
            mine = rows[channel[rows] == c]
            if len(mine):
                out.append((float(t), mine, frame))
    return out


def sonar_pose(scan, row: int, frame: str = SONAR_FRAME) -> np.ndarray:
    """World pose (4x4) of the sonar frame ``frame`` at row ``row``'s ping: its head at bearing 0
    in the marine_acoustic_msgs convention (z the boresight, x up; `SIDESCAN_AXES` for a
    side-scan channel's frame)."""
    head = scan.poses[row] @ np.linalg.inv(bearing_rotation(scan.bearings[row]))
    return head @ (SIDESCAN_AXES if frame in CHANNEL_FRAMES else SONAR_AXES)


def depression(scan) -> float:
    """A side-scan scan's depression in radians: ``meta.depression`` (deg) when it holds one, else
    half the angle by which its first ping's two boresights miss being opposite (both channels
    turned down by ``d`` meet at 180 - 2d deg), else 0."""
    v = _meta(scan).depression
    if v is not None:
        return math.radians(float(v))
    channel = np.asarray(scan.channel)
    times = np.asarray(scan.times, np.float64)
    port = np.flatnonzero(channel == 0)
    for p in port:
        stbd = np.flatnonzero((channel == 1) & (times == times[p]))
        if len(stbd):
            cos = float(np.dot(scan.poses[p][:3, 2], scan.poses[stbd[0]][:3, 2]))
            return 0.5 * math.acos(min(1.0, max(-1.0, -cos)))
    return 0.0


def head_pose(scan, row: int) -> np.ndarray:
    """World pose (4x4) of the ``sonar`` frame at row ``row``'s ping: `sonar_pose`, but for a
    side-scan the head whose channels are ``sonar_port`` and ``sonar_starboard`` (x forward, y
    port, z up: ``poses[row]`` undone by its channel's `sidescan_rotation`)."""
    channel = getattr(scan, "channel", None)
    if channel is None:
        return sonar_pose(scan, row)
    return scan.poses[row] @ np.linalg.inv(sidescan_rotation(channel[row], depression(scan)))


def channel_mounts(scan) -> dict:
    """A side-scan's channel frames in its ``sonar`` head frame (fixed: ``{frame: 4x4}``, from the
    first row of each channel); an empty dict for other heads."""
    channel = getattr(scan, "channel", None)
    if channel is None:
        return {}
    out = {}
    for c, frame in enumerate(CHANNEL_FRAMES):
        rows = np.flatnonzero(np.asarray(channel) == c)
        if len(rows):
            out[frame] = np.linalg.inv(head_pose(scan, rows[0])) @ sonar_pose(scan, rows[0], frame)
    return out


def frequency(scan) -> float:
    v = _meta(scan).frequency
    if v is None:     # a settings key of the dict era
        v = ElectronicsSettings.from_dict(getattr(scan, "electronics", None) or {}).extra.get("frequency")
    if isinstance(v, (int, float)) and math.isfinite(v):
        return float(v)
    return 0.0          # PingInfo: "Set to 0 if unavailable"


def tx_beamwidth_v(scan) -> float:
    """The transmit beam's vertical width (deg): ``meta['tx_beamwidth_v']`` when the head has its
    own transmit pattern, else the scan's ``beamwidth_v`` (one pattern both ways)."""
    v = _meta(scan).tx_beamwidth_v
    return float(scan.beamwidth_v) if v is None else float(v)


def _meta(scan) -> ScanMeta:
    """A scan's (or a scan-like object's) metadata, typed."""
    return ScanMeta.from_dict(getattr(scan, "meta", None) or {})


#: SonarImageData ``dtype`` of a scan's data: DTYPE_UINT8, DTYPE_UINT16, DTYPE_UINT32
SONAR_IMAGE_DTYPES = {np.dtype(np.uint8): 0, np.dtype(np.uint16): 2, np.dtype(np.uint32): 4}


def projected_image(scan, rows, ns: int, frame: str = SONAR_FRAME) -> dict:
    """One ping as a ProjectedSonarImage: the rows' device levels (bytes; a 16- or 32-bit A/D's
    uint16, uint32 codes as they are, little-endian, with ``dtype`` DTYPE_UINT16, DTYPE_UINT32),
    the bin-centre ranges and each beam's unit direction in the sonar frame. The levels are
    range-major, every beam of range 0, then of range 1 (sample ``range * beam_count + beam``), as
    the message's reference reader indexes them (APL's sonar_image_proc,
    ``SonarImageMsgInterface::index``), so a scan's (beams, bins) levels go in transposed."""
    world = sonar_pose(scan, rows[0], frame)
    rot = world[:3, :3].T
    dirs = (rot @ scan.poses[rows][:, :3, 2].T).T
    data = np.asarray(scan.data)[rows].T
    image_dtype = SONAR_IMAGE_DTYPES[data.dtype]
    data = np.ascontiguousarray(data, dtype=data.dtype.newbyteorder("<"))
    n = len(rows)
    return {
        "header": header(ns, frame),
        "ping_info": {"frequency": frequency(scan), "sound_speed": float(scan.sound_speed),
                      "tx_beamwidths": [math.radians(tx_beamwidth_v(scan))] * n,
                      "rx_beamwidths": [math.radians(scan.beamwidth_h)] * n},
        "beam_directions": [{"x": float(d[0]), "y": float(d[1]), "z": float(d[2])} for d in dirs],
        "ranges": np.asarray(scan.ranges, dtype=np.float32).tolist(),
        "image": {"is_bigendian": False, "dtype": image_dtype, "beam_count": n, "data": data.tobytes()},
    }


def mono8(ns: int, frame: str, pixels: np.ndarray) -> dict:
    pixels = np.ascontiguousarray(pixels, dtype=np.uint8)
    h, w = pixels.shape
    return {"header": header(ns, frame), "height": h, "width": w, "encoding": "mono8", "is_bigendian": 0,
            "step": w, "data": pixels.tobytes()}


def mono(ns: int, frame: str, pixels: np.ndarray) -> dict:
    """An Image of device levels: ``mono8`` of bytes, ``mono16`` (little-endian) of a 16-bit A/D's
    uint16 codes; a 32-bit A/D's uint32 codes go as ``mono16`` of the same levels on 16 bits
    (`mitsonar.scan.model.data_as`: ``round(65535 code / 4294967295)``), as sensor_msgs has no
    unsigned 32-bit grey encoding (32SC1 is signed, 32FC1 float)."""
    pixels = np.asarray(pixels)
    if pixels.dtype == np.uint8:
        return mono8(ns, frame, pixels)
    from mitsonar.scan.model import data_as
    pixels = np.ascontiguousarray(data_as(pixels, np.uint16), dtype="<u2")
    h, w = pixels.shape
    return {"header": header(ns, frame), "height": h, "width": w, "encoding": "mono16", "is_bigendian": 0,
            "step": 2 * w, "data": pixels.tobytes()}


def waterfall(scan, ns: int) -> dict:
    """The scan's rows (pings of a mechanical head, beams of a multibeam frame) top to bottom,
    range bins left to right: ``scan.data`` itself as an image (`mono`: mono8 of bytes, mono16 of
    a 16- or 32-bit A/D's codes)."""
    return mono(ns, SONAR_FRAME, scan.data)


def fan_pixels(scan, size: int = 400) -> np.ndarray:
    """The scan drawn in its fan's plane seen from the beam frame's +y (the scan axis: from above
    for an upright head), as `mitsonar.products.plots.plot_fan` draws it: the boresight up the
    picture, positive bearings counter-clockwise (the beam frame's +x, port for an upright head,
    to the left); each pixel the level of the nearest beam and bin (0 outside the fan), in the
    data's own type (uint8; uint16, uint32 of a wider A/D); ``size`` pixels across the fan's
    widest extent."""
    r_max = float(scan.range_max)
    az = np.asarray(scan.bearings, dtype=np.float64)
    wrapped = np.mod(az + math.pi, 2 * math.pi) - math.pi
    order = np.argsort(wrapped)
    sorted_az = wrapped[order]
    gaps = np.diff(sorted_az)
    half = 0.5 * (float(np.median(gaps)) if len(gaps) else math.radians(scan.beamwidth_h))
    half = max(half, 1e-9)
    edge = np.linspace(sorted_az[0] - half, sorted_az[-1] + half, 64)
    xs = np.concatenate([[0.0], -r_max * np.sin(edge)])
    zs = np.concatenate([[0.0], r_max * np.cos(edge)])
    x0, x1, z0, z1 = xs.min(), xs.max(), zs.min(), zs.max()
    if len(gaps) and sorted_az[-1] - sorted_az[0] + 2 * half >= 2 * math.pi - 1e-6:
        x0, x1, z0, z1 = -r_max, r_max, -r_max, r_max
    px = max(x1 - x0, z1 - z0) / size
    w, h = max(1, int(math.ceil((x1 - x0) / px))), max(1, int(math.ceil((z1 - z0) / px)))
    x = x0 + (np.arange(w) + 0.5) * px
    z = z1 - (np.arange(h) + 0.5) * px
    xx, zz = np.meshgrid(x, z)
    r = np.hypot(xx, zz)
    a = np.arctan2(-xx, zz)
    k = np.searchsorted(sorted_az, a)
    lo, hi = np.clip(k - 1, 0, len(sorted_az) - 1), np.clip(k, 0, len(sorted_az) - 1)
    d_lo = np.abs(np.mod(a - sorted_az[lo] + math.pi, 2 * math.pi) - math.pi)
    d_hi = np.abs(np.mod(a - sorted_az[hi] + math.pi, 2 * math.pi) - math.pi)
    # the wrap-around neighbours (first and last beams of a full circle)
    d_first = np.abs(np.mod(a - sorted_az[0] + math.pi, 2 * math.pi) - math.pi)
    d_last = np.abs(np.mod(a - sorted_az[-1] + math.pi, 2 * math.pi) - math.pi)
    cand = np.stack([lo, hi, np.zeros_like(lo), np.full_like(lo, len(sorted_az) - 1)])
    dist = np.stack([d_lo, d_hi, d_first, d_last])
    best = np.argmin(dist, axis=0)
    beam = np.take_along_axis(cand, best[None], 0)[0]
    ok = np.take_along_axis(dist, best[None], 0)[0] <= half
    n_bins = scan.data.shape[1]
    width = (float(scan.range_max) - float(scan.range_min)) / n_bins
    b = np.floor((r - float(scan.range_min)) / width).astype(np.int64)
    ok &= (b >= 0) & (b < n_bins)
    out = np.zeros((h, w), dtype=scan.data.dtype)
    out[ok] = scan.data[order[beam[ok]], b[ok]]
    return out


def fan_image(scan, ns: int, size: int = 400) -> dict:
    return mono(ns, SONAR_FRAME, fan_pixels(scan, size))


def detections(scan, threshold: int) -> tuple:
    """Detected returns: each row's strongest bin when its level is ``threshold`` or more, as
    world points ``(n, 3)`` and their levels ``(n,)``: levels 0..255, a 16- or 32-bit A/D's codes
    on that scale (``255 code / full scale``, not rounded)."""
    from mitsonar.scan.model import data_levels

    data = np.asarray(scan.data)
    k = np.argmax(data, axis=1)
    level = data_levels(data[np.arange(len(k)), k])
    keep = level >= threshold
    r = np.asarray(scan.ranges, dtype=np.float64)[k[keep]]
    poses = np.asarray(scan.poses)[keep]
    pts = poses[:, :3, 3] + r[:, None] * poses[:, :3, 2]
    return pts, level[keep].astype(np.float32)


def point_cloud(points: np.ndarray, values: np.ndarray, ns: int, frame: str = WORLD_FRAME) -> dict:
    """An unordered PointCloud2 of float32 x, y, z, intensity (16 bytes a point, little-endian)."""
    rec = np.zeros(len(points), dtype=[("x", "<f4"), ("y", "<f4"), ("z", "<f4"), ("intensity", "<f4")])
    if len(points):
        rec["x"], rec["y"], rec["z"] = points[:, 0], points[:, 1], points[:, 2]
        rec["intensity"] = values
    fields = [{"name": n, "offset": 4 * i, "datatype": 7, "count": 1}
              for i, n in enumerate(("x", "y", "z", "intensity"))]
    return {"header": header(ns, frame), "height": 1, "width": len(points), "fields": fields,
            "is_bigendian": False, "point_step": 16, "row_step": 16 * len(points),
            "data": rec.tobytes(), "is_dense": True}


#: PointCloud2 field types (sensor_msgs/PointField): FLOAT32 7, INT32 5.
_FIELD_TYPES = {"<f4": 7, "<i4": 5}


def point_cloud_message(points, stamp_ns=0, frame="map") -> dict:
    """A ROS 2 ``sensor_msgs/msg/PointCloud2`` (the dict the bag writer serialises) of a 3D sonar's
    point cloud (`mitsonar.signals.volumetric.point_cloud`): one unordered row of its
    `~mitsonar.signals.volumetric.POINT_DTYPE` records
    (x, y, z, intensity float32; elevation_index, azimuth_index int32; range float32), 28 bytes a
    point, little-endian."""
    from mitsonar.signals.volumetric import POINT_DTYPE

    pts = np.ascontiguousarray(np.asarray(points))
    if pts.dtype != POINT_DTYPE:
        raise ValueError(f"point_cloud_message 'points': dtype {pts.dtype} is not allowed (point_cloud's POINT_DTYPE)")
    fields = [{"name": n, "offset": int(POINT_DTYPE.fields[n][1]), "count": 1,
               "datatype": _FIELD_TYPES[POINT_DTYPE.fields[n][0].str]} for n in POINT_DTYPE.names]
    step = POINT_DTYPE.itemsize
    return {"header": header(int(stamp_ns), frame), "height": 1, "width": len(pts), "fields": fields,
            "is_bigendian": False, "point_step": step, "row_step": step * len(pts), "data": pts.tobytes(),
            "is_dense": True}


def transform(pose: np.ndarray, ns: int, parent: str, child: str) -> dict:
    q = matrix_to_quat(pose[:3, :3])
    t = pose[:3, 3]
    return {"header": header(ns, parent), "child_frame_id": child,
            "transform": {"translation": {"x": float(t[0]), "y": float(t[1]), "z": float(t[2])},
                          "rotation": {"x": float(q[0]), "y": float(q[1]), "z": float(q[2]), "w": float(q[3])}}}


def velocity(trajectory, t: float, h: float = 1e-3) -> tuple:
    """The vehicle's linear and angular velocity at ``t`` in its own frame (REP-105: an Odometry's
    twist is in its child frame), by central differences over ``[t - h, t + h]`` within the span."""
    from scipy.spatial.transform import Rotation

    lo, hi = trajectory.span
    t0, t1 = max(lo, t - h), min(hi, t + h)
    if t1 <= t0:
        return np.zeros(3), np.zeros(3)
    a, b, now = trajectory.at(t0), trajectory.at(t1), trajectory.at(t)
    linear = now[:3, :3].T @ (b[:3, 3] - a[:3, 3]) / (t1 - t0)
    angular = Rotation.from_matrix(a[:3, :3].T @ b[:3, :3]).as_rotvec() / (t1 - t0)
    return linear, angular


def odometry(pose: np.ndarray, ns: int, parent: str, child: str, linear=(0, 0, 0), angular=(0, 0, 0)) -> dict:
    """The pose of ``child`` in ``parent`` and its twist in ``child`` (zero when not known)."""
    tf = transform(pose, ns, parent, child)["transform"]

    def vec(v):
        return {"x": float(v[0]), "y": float(v[1]), "z": float(v[2])}

    return {"header": header(ns, parent), "child_frame_id": child,
            "pose": {"pose": {"position": tf["translation"], "orientation": tf["rotation"]},
                     "covariance": [0.0] * 36},
            "twist": {"twist": {"linear": vec(linear), "angular": vec(angular)}, "covariance": [0.0] * 36}}


def navsatfix(lat: float, lon: float, altitude: float, ns: int, frame: str) -> dict:
    """A sensor_msgs/NavSatFix of WGS 84 ``lat``, ``lon`` (deg) and ``altitude`` (m above the
    ellipsoid): status FIX, service GPS, covariance unknown (a simulated fix is exact)."""
    return {"header": header(ns, frame), "status": {"status": 0, "service": 1}, "latitude": float(lat),
            "longitude": float(lon), "altitude": float(altitude), "position_covariance": [0.0] * 9,
            "position_covariance_type": 0}
