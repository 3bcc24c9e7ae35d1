"""Sonar heads' protocols and drivers: the transports (ports, pseudo-terminals, logs) shared by
every head, raw logs and their replay, the heads by name (`registry`; their base `head.Head`), then
one subpackage per head: `micron` (Tritech Micron over SeaNet), `ping360` (Blue Robotics Ping360)
and `oculus` (Blundell Oculus M-series over Ethernet). A head's subpackage holds its codec, driver,
virtual head and assembly of scans, and says what it is to the registry in its ``registration``
module. Live simulation (rendering each ping as a client asks for it) is `mitsonar.live`."""
