"""Geometry: sonar frames, trajectories, north-up grids, PLY meshes (the sonar kinds are `mitsonar.kinds`)."""
