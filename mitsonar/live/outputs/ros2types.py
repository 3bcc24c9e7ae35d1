"""ROS 2 message types as cyclonedds IDL structs (`mitsonar.live.outputs.dds`), field for field
the ROS 2 ``.msg`` definitions (`mitsonar.export.ros.msgdefs`), under ROS 2's DDS type names
(``package::msg::dds_::Type_``). Imports cyclonedds: imported only for ``--dds``. (No
``from __future__ import annotations`` here: cyclonedds reads the field types at run time.)"""
from dataclasses import dataclass

from cyclonedds.idl import IdlStruct
from cyclonedds.idl.types import float32, float64, int32, sequence, uint8, uint32

__all__ = ["TYPES"]


def ros(name: str) -> str:
    """ROS 2's DDS name of a message type: ``sensor_msgs/msg/Image`` -> ``sensor_msgs::msg::dds_::Image_``."""
    pkg, _, typ = name.split("/")
    return f"{pkg}::msg::dds_::{typ}_"


@dataclass
class Time(IdlStruct, typename=ros("builtin_interfaces/msg/Time")):
    sec: int32
    nanosec: uint32


@dataclass
class Header(IdlStruct, typename=ros("std_msgs/msg/Header")):
    stamp: Time
    frame_id: str


@dataclass
class Image(IdlStruct, typename=ros("sensor_msgs/msg/Image")):
    header: Header
    height: uint32
    width: uint32
    encoding: str
    is_bigendian: uint8
    step: uint32
    data: sequence[uint8]


@dataclass
class Vector3(IdlStruct, typename=ros("geometry_msgs/msg/Vector3")):
    x: float64
    y: float64
    z: float64


@dataclass
class Point(IdlStruct, typename=ros("geometry_msgs/msg/Point")):
    x: float64
    y: float64
    z: float64


@dataclass
class Quaternion(IdlStruct, typename=ros("geometry_msgs/msg/Quaternion")):
    x: float64
    y: float64
    z: float64
    w: float64


@dataclass
class Transform(IdlStruct, typename=ros("geometry_msgs/msg/Transform")):
    translation: Vector3
    rotation: Quaternion


@dataclass
class TransformStamped(IdlStruct, typename=ros("geometry_msgs/msg/TransformStamped")):
    header: Header
    child_frame_id: str
    transform: Transform


@dataclass
class TFMessage(IdlStruct, typename=ros("tf2_msgs/msg/TFMessage")):
    transforms: sequence[TransformStamped]


@dataclass
class Pose(IdlStruct, typename=ros("geometry_msgs/msg/Pose")):
    position: Point
    orientation: Quaternion


@dataclass
class PoseStamped(IdlStruct, typename=ros("geometry_msgs/msg/PoseStamped")):
    header: Header
    pose: Pose


@dataclass
class PingInfo(IdlStruct, typename=ros("marine_acoustic_msgs/msg/PingInfo")):
    frequency: float32
    sound_speed: float32
    tx_beamwidths: sequence[float32]
    rx_beamwidths: sequence[float32]


@dataclass
class SonarImageData(IdlStruct, typename=ros("marine_acoustic_msgs/msg/SonarImageData")):
    is_bigendian: bool
    dtype: uint32
    beam_count: uint32
    data: sequence[uint8]


@dataclass
class ProjectedSonarImage(IdlStruct, typename=ros("marine_acoustic_msgs/msg/ProjectedSonarImage")):
    header: Header
    ping_info: PingInfo
    beam_directions: sequence[Vector3]
    ranges: sequence[float32]
    image: SonarImageData


@dataclass
class PointField(IdlStruct, typename=ros("sensor_msgs/msg/PointField")):
    name: str
    offset: uint32
    datatype: uint8
    count: uint32


@dataclass
class PointCloud2(IdlStruct, typename=ros("sensor_msgs/msg/PointCloud2")):
    header: Header
    height: uint32
    width: uint32
    fields: sequence[PointField]
    is_bigendian: bool
    point_step: uint32
    row_step: uint32
    data: sequence[uint8]
    is_dense: bool


#: ROS 2 name -> IDL struct.
TYPES = {name: c for name, c in (
    ("builtin_interfaces/msg/Time", Time), ("std_msgs/msg/Header", Header), ("sensor_msgs/msg/Image", Image),
    ("geometry_msgs/msg/Vector3", Vector3), ("geometry_msgs/msg/Point", Point),
    ("geometry_msgs/msg/Quaternion", Quaternion), ("geometry_msgs/msg/Transform", Transform),
    ("geometry_msgs/msg/TransformStamped", TransformStamped), ("tf2_msgs/msg/TFMessage", TFMessage),
    ("geometry_msgs/msg/Pose", Pose), ("geometry_msgs/msg/PoseStamped", PoseStamped),
    ("marine_acoustic_msgs/msg/PingInfo", PingInfo), ("marine_acoustic_msgs/msg/SonarImageData", SonarImageData),
    ("marine_acoustic_msgs/msg/ProjectedSonarImage", ProjectedSonarImage),
    ("sensor_msgs/msg/PointField", PointField), ("sensor_msgs/msg/PointCloud2", PointCloud2))}
