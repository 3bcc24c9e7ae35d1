"""ROS 2 topics over DDS (``mitsonar live --dds [DOMAIN]``), with the ``cyclonedds`` Python
binding (imported here only, when the flag is used): the live topics as the ROS 2 messages a
node subscribes to without a bridge, under ROS 2's DDS names (topic ``rt/`` + the ROS name,
type ``package::msg::dds_::Type_``) and its default QoS (reliable, volatile, keep last 10).

====================== ===========================================================================
``rt/sonar/fan``       sensor_msgs/msg/Image (mono8): the picture (`mitsonar.live.outputs.pictures`)
``rt/sonar/image``     marine_acoustic_msgs/msg/ProjectedSonarImage: the raw ping, as the bags'
                       ``/sonar/image`` (`mitsonar.export.ros.messages.projected_image`)
``rt/tf``              tf2_msgs/msg/TFMessage: ``map -> base_link -> sonar``
``rt/vehicle/pose``    geometry_msgs/msg/PoseStamped: the vehicle in ``map``
``rt/sonar/points``    sensor_msgs/msg/PointCloud2: a volumetric frame's point cloud in ``map``
                       (`mitsonar.live.outputs.messages.frame_points`; its writer made at the
                       first volumetric frame, `POINT_TOPICS`)
====================== ===========================================================================

The message types are declared below as ``cyclonedds.idl`` structs, field for field the ROS 2
``.msg`` definitions (`mitsonar.export.ros.msgdefs`), so their CDR is what ``rclcpp`` reads.
The network DDS uses is Cyclone's own configuration (the ``CYCLONEDDS_URI`` environment
variable, e.g. to keep it on the loopback).
"""
from __future__ import annotations

from mitsonar.live.outputs.base import OutputError
from mitsonar.live.outputs.messages import (SONAR_FRAME, VEHICLE_FRAME, WORLD_FRAME, sonar_in_vehicle,
                                               translation_rotation)
from mitsonar.live.outputs.pictures import Pictures

__all__ = ["DdsOutput", "TOPICS", "POINT_TOPICS", "check_domain", "ros_types"]

#: DDS topic -> ROS 2 type of each live topic (module doc).
TOPICS = {"rt/sonar/fan": "sensor_msgs/msg/Image", "rt/sonar/image": "marine_acoustic_msgs/msg/ProjectedSonarImage",
          "rt/tf": "tf2_msgs/msg/TFMessage", "rt/vehicle/pose": "geometry_msgs/msg/PoseStamped"}
#: The topics of volumetric frames only, written from the first such frame on.
POINT_TOPICS = {"rt/sonar/points": "sensor_msgs/msg/PointCloud2"}


def check_domain(domain) -> int:
    """``domain`` as an int, or `OutputError` (one line) if it is not a DDS domain id (0 to 232)
    or cyclonedds is missing."""
    if isinstance(domain, bool) or not isinstance(domain, int) or not 0 <= domain <= 232:
        raise OutputError(f"--dds {domain!r}: expected a DDS domain id from 0 to 232")
    try:
        import cyclonedds  # noqa: F401
    except ImportError:
        raise OutputError("--dds needs the cyclonedds package: pip install 'mitsonar[live]'") from None
    return domain


def ros_types() -> dict:
    """The ROS 2 message types as cyclonedds IDL structs, by ROS name (``sensor_msgs/msg/Image``
    ...): `mitsonar.live.outputs.ros2types`."""
    from mitsonar.live.outputs.ros2types import TYPES
    return TYPES


def ros_qos():
    """ROS 2's default QoS profile: reliable, volatile, keep last 10."""
    from cyclonedds.core import Policy, Qos
    from cyclonedds.util import duration

    return Qos(Policy.Reliability.Reliable(duration(seconds=1)), Policy.Durability.Volatile,
               Policy.History.KeepLast(10))


class DdsOutput:
    """The live topics as ROS 2 messages on DDS domain ``domain`` (module doc).
    ``pictures``: a `Pictures` shared with other outputs (each ping drawn once)."""

    def __init__(self, domain: int = 0, pictures: Pictures | None = None):
        self.domain = check_domain(domain)
        from cyclonedds.domain import DomainParticipant
        from cyclonedds.pub import DataWriter
        from cyclonedds.topic import Topic

        self.types = ros_types()
        self.pictures = pictures if pictures is not None else Pictures()
        try:
            self.participant = DomainParticipant(self.domain)
        except Exception as e:        # noqa: BLE001 - cyclonedds' errors name no flag
            raise OutputError(f"--dds {domain}: cannot join the DDS domain ({e})") from None
        qos = ros_qos()
        self.writers = {name: DataWriter(self.participant, Topic(self.participant, name, self.types[ros]), qos=qos)
                        for name, ros in TOPICS.items()}
        self._qos = qos
        self.count = 0

    def publish(self, t_ns: int, vehicle, mount, scan) -> None:
        from mitsonar.live.outputs.messages import frame_points
        from mitsonar.export.ros.messages import mono8, projected_image

        T = self.types
        stamp = T["builtin_interfaces/msg/Time"](sec=int(t_ns // 1_000_000_000), nanosec=int(t_ns % 1_000_000_000))

        def header(frame):
            return T["std_msgs/msg/Header"](stamp=stamp, frame_id=frame)

        image = mono8(t_ns, SONAR_FRAME, self.pictures.of(scan))     # the bags' Image fields
        self.writers["rt/sonar/fan"].write(T["sensor_msgs/msg/Image"](**{**image, "header": header(SONAR_FRAME)}))
        m = projected_image(scan, list(range(scan.data.shape[0])), t_ns)
        vec = T["geometry_msgs/msg/Vector3"]
        self.writers["rt/sonar/image"].write(T["marine_acoustic_msgs/msg/ProjectedSonarImage"](
            header=header(SONAR_FRAME),
            ping_info=T["marine_acoustic_msgs/msg/PingInfo"](**m["ping_info"]),
            beam_directions=[vec(**d) for d in m["beam_directions"]], ranges=m["ranges"],
            image=T["marine_acoustic_msgs/msg/SonarImageData"](**m["image"])))

        def pose_parts(pose):
            (x, y, z), (qx, qy, qz, qw) = translation_rotation(pose)
            return (x, y, z), T["geometry_msgs/msg/Quaternion"](x=qx, y=qy, z=qz, w=qw)

        def tf(pose, parent, child):
            (x, y, z), q = pose_parts(pose)
            return T["geometry_msgs/msg/TransformStamped"](
                header=header(parent), child_frame_id=child,
                transform=T["geometry_msgs/msg/Transform"](translation=vec(x=x, y=y, z=z), rotation=q))

        self.writers["rt/tf"].write(T["tf2_msgs/msg/TFMessage"](transforms=[
            tf(vehicle, WORLD_FRAME, VEHICLE_FRAME), tf(sonar_in_vehicle(mount), VEHICLE_FRAME, SONAR_FRAME)]))
        (x, y, z), q = pose_parts(vehicle)
        self.writers["rt/vehicle/pose"].write(T["geometry_msgs/msg/PoseStamped"](
            header=header(WORLD_FRAME),
            pose=T["geometry_msgs/msg/Pose"](position=T["geometry_msgs/msg/Point"](x=x, y=y, z=z), orientation=q)))
        cloud = frame_points(t_ns, scan)
        if cloud is not None:
            if "rt/sonar/points" not in self.writers:
                from cyclonedds.pub import DataWriter
                from cyclonedds.topic import Topic

                name = "rt/sonar/points"
                self.writers[name] = DataWriter(self.participant, Topic(self.participant, name,
                                                                        T[POINT_TOPICS[name]]), qos=self._qos)
            self.writers["rt/sonar/points"].write(point_cloud2(T, cloud, header(cloud["header"]["frame_id"])))
        self.count += 1

    def close(self) -> None:
        self.writers = {}
        self.participant = None       # cyclonedds deletes the entities with their last reference


def point_cloud2(types, cloud: dict, header):
    """The ``sensor_msgs/msg/PointCloud2`` IDL struct of a `frame_points` dict, with ``header``."""
    fields = [types["sensor_msgs/msg/PointField"](**f) for f in cloud["fields"]]
    return types["sensor_msgs/msg/PointCloud2"](**{**cloud, "header": header, "fields": fields,
                                                   "data": list(cloud["data"])})
