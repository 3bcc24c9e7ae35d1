"""Simulation: the Mitsuba variant, loading scenes, `render_scan`, surveys along a track, and the
scene's ground truth. Data flows scene -> paths (the plugins) -> histogram -> receiver -> `Scan`."""
