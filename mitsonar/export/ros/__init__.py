"""ROS 2 bags without ROS: scans, their frames and detections as an MCAP file of ROS 2 messages
(marine_acoustic_msgs/ProjectedSonarImage, sensor_msgs/Image and PointCloud2, tf2_msgs/TFMessage,
nav_msgs/Odometry) that Foxglove and ``ros2 bag`` read. Needs the extra ``mitsonar[ros]``."""
from mitsonar.export.ros.bag import TOPICS, ExportError, McapBag, write_mcap

__all__ = ["TOPICS", "ExportError", "McapBag", "write_mcap"]
