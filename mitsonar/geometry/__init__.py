"""Geometry: sonar frames and kinds, trajectories, north-up grids, PLY meshes."""
