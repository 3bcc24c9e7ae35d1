"""The Blue Robotics Ping360's published figures: its beam, 2 deg horizontal (across the scan) by
25 deg vertical (Blue Robotics, Ping360 specifications). Its settings' ranges are the protocol's
(`mitsonar.devices.ping360.head`)."""
from __future__ import annotations

__all__ = ["BEAMWIDTH_H", "BEAMWIDTH_V"]

#: the head's beam, full widths in degrees (Blue Robotics' Ping360 specifications)
BEAMWIDTH_H, BEAMWIDTH_V = 2.0, 25.0
