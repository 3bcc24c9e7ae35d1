"""Foreign formats, one subpackage or module per format: ROS 2 bags (`mitsonar.export.ros`)."""
