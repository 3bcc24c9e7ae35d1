"""The Tritech Micron's published figures: its beam, 3 deg horizontal (across the scan) by 35 deg
vertical (Tritech, Micron sonar data sheet; the full -3 dB widths a scan assembled from its bytes
carries, `mitsonar.devices.micron.assembler`). Its transmit frequency is a head setting
(`mitsonar.devices.micron.seanet.settings.HeadSettings.frequency`)."""
from __future__ import annotations

__all__ = ["BEAMWIDTH_H", "BEAMWIDTH_V"]

#: the head's beam, full widths in degrees (Tritech Micron data sheet)
BEAMWIDTH_H, BEAMWIDTH_V = 3.0, 35.0
