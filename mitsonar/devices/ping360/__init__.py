"""Blue Robotics Ping360: the ping-protocol codec (`protocol`), what the head is (`head`), the
driver (`driver`), the virtual head (`virtual`) and what the head is to `mitsonar.devices.registry`
(`registration`)."""
