"""Live simulation (``mitsonar live``): a scene rendered ping by ping at the vehicle's pose of the
moment, answered in a head's protocol or as multibeam frames at their period. `heads` (the scene
reduced to one ping, `heads.PingRenderer`, the live Micron, Ping360 and Oculus), `framing`
(multibeam frames at their ping period), `realtime` (each ping's path budget, its error model and
log), `poses` (pose datagrams and buffers, trajectory replay), `mavlink` (poses from an
autopilot), `outputs` (Foxglove, MCAP, ROS 2 over DDS). The heads' protocols and drivers are
`mitsonar.devices`."""
