"""Blue Robotics Ping360: the ping-protocol codec (`protocol`), what the head is (`head`), the
driver (`driver`) and the virtual head (`virtual`)."""
