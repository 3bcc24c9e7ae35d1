"""Foxglove outputs of a live head (``mitsonar live --foxglove [PORT]``), with the
``foxglove-sdk`` package (imported here only, when the flag is used).

`FoxgloveChannels` logs each ping on the channels of a ``foxglove.Context``
(`mitsonar.live.outputs.messages.TOPICS`):

===================== ======================================= =========================================
``/sonar/fan``        foxglove.RawImage (protobuf), mono8     the picture (`mitsonar.live.outputs.
                                                              pictures`), frame ``sonar``
``/sonar/ping``       mitsonar.SonarPing (JSON)               the raw ping: device bytes, ranges, bearings
``/sonar/points``     sensor_msgs/msg/PointCloud2 (ros2msg,   a volumetric frame's point cloud in ``map``
                      CDR)                                    (`messages.frame_points`); advertised at the
                                                              first volumetric frame
``/tf``               foxglove.FrameTransforms (protobuf)     ``map -> base_link -> sonar``
``/vehicle/pose``     foxglove.PoseInFrame (protobuf)         the vehicle in ``map``
===================== ======================================= =========================================

Every message's timestamp and log time are the ping's time (ns since the Unix epoch).
`FoxgloveServer` serves them over Foxglove's WebSocket protocol (``foxglove.websocket.v1``) on
127.0.0.1; `mitsonar.live.outputs.mcapfile.McapRecording` writes them into an MCAP file.
"""
from __future__ import annotations

from mitsonar.live.outputs.base import OutputError
from mitsonar.live.outputs.messages import (PING_SCHEMA, SONAR_FRAME, VEHICLE_FRAME, WORLD_FRAME, frame_points,
                                               ping_message, pointcloud2_cdr, sonar_in_vehicle,
                                               translation_rotation)
from mitsonar.live.outputs.pictures import Pictures

__all__ = ["DEFAULT_PORT", "FoxgloveChannels", "FoxgloveServer", "require_foxglove"]

#: Foxglove's usual WebSocket port.
DEFAULT_PORT = 8765


def require_foxglove(flag: str = "--foxglove"):
    """The ``foxglove`` module, or `OutputError` naming ``flag`` and the extra to install."""
    try:
        import foxglove
        import foxglove.channels  # noqa: F401
        import foxglove.messages  # noqa: F401
    except ImportError:
        raise OutputError(f"{flag} needs the foxglove-sdk package: pip install 'mitsonar[live]'") from None
    return foxglove


class FoxgloveChannels:
    """The live channels on a new ``foxglove.Context`` (module doc); `publish` logs one ping.
    ``pictures``: a `Pictures` shared with other outputs (each ping drawn once)."""

    def __init__(self, pictures: Pictures | None = None, flag: str = "--foxglove"):
        fg = require_foxglove(flag)
        from foxglove import channels as ch

        self._fg = fg
        self.pictures = pictures if pictures is not None else Pictures()
        self.context = fg.Context()
        self.fan = ch.RawImageChannel("/sonar/fan", context=self.context)
        self.ping = fg.Channel("/sonar/ping", schema=PING_SCHEMA, context=self.context)
        self.tf = ch.FrameTransformsChannel("/tf", context=self.context)
        self.pose = ch.PoseInFrameChannel("/vehicle/pose", context=self.context)
        self.points = None      # /sonar/points, made at the first volumetric frame
        self.count = 0

    def _points_channel(self):
        if self.points is None:
            from mitsonar.export.ros import msgdefs

            name = "sensor_msgs/msg/PointCloud2"
            schema = self._fg.Schema(name=name, encoding="ros2msg", data=msgdefs.definition(name).encode("utf-8"))
            self.points = self._fg.Channel("/sonar/points", schema=schema, message_encoding="cdr",
                                           context=self.context)
        return self.points

    def publish(self, t_ns: int, vehicle, mount, scan) -> None:
        m = self._fg.messages
        stamp = m.Timestamp(int(t_ns // 1_000_000_000), int(t_ns % 1_000_000_000))
        pixels = self.pictures.of(scan)
        h, w = pixels.shape
        self.fan.log(m.RawImage(timestamp=stamp, frame_id=SONAR_FRAME, width=w, height=h, encoding="mono8",
                                step=w, data=pixels.tobytes()), log_time=t_ns)
        self.ping.log(ping_message(t_ns, scan), log_time=t_ns)
        cloud = frame_points(t_ns, scan)
        if cloud is not None:
            self._points_channel().log(pointcloud2_cdr(cloud), log_time=t_ns)

        def tf(pose, parent, child):
            (x, y, z), (qx, qy, qz, qw) = translation_rotation(pose)
            return m.FrameTransform(timestamp=stamp, parent_frame_id=parent, child_frame_id=child,
                                    translation=m.Vector3(x=x, y=y, z=z),
                                    rotation=m.Quaternion(x=qx, y=qy, z=qz, w=qw))

        self.tf.log(m.FrameTransforms(transforms=[tf(vehicle, WORLD_FRAME, VEHICLE_FRAME),
                                                  tf(sonar_in_vehicle(mount), VEHICLE_FRAME, SONAR_FRAME)]),
                    log_time=t_ns)
        (x, y, z), (qx, qy, qz, qw) = translation_rotation(vehicle)
        self.pose.log(m.PoseInFrame(timestamp=stamp, frame_id=WORLD_FRAME,
                                    pose=m.Pose(position=m.Vector3(x=x, y=y, z=z),
                                                orientation=m.Quaternion(x=qx, y=qy, z=qz, w=qw))),
                      log_time=t_ns)
        self.count += 1


class FoxgloveServer(FoxgloveChannels):
    """The channels served over Foxglove's WebSocket protocol on ``127.0.0.1:port`` (0 picks a
    free port; ``port`` then says which). `OutputError` if it cannot listen."""

    def __init__(self, port: int = DEFAULT_PORT, pictures: Pictures | None = None, name: str = "mitsonar live"):
        super().__init__(pictures)
        try:
            self.server = self._fg.start_server(name=name, host="127.0.0.1", port=int(port), context=self.context)
        except Exception as e:          # noqa: BLE001 - the SDK's error types are not public
            raise OutputError(f"--foxglove {port}: cannot listen on 127.0.0.1:{port} ({e})") from None
        self.port = int(self.server.port)

    @property
    def url(self) -> str:
        return f"ws://127.0.0.1:{self.port}"

    def close(self) -> None:
        self.server.stop()
