"""Scenes beyond the XML files: procedural terrain, a sea surface, echo-sounder presets, the
side-scan demo, and scenes converted from a bathymetric grid (`seabed_from_grid`) or a Gazebo
SDF world (`scene_from_sdf`)."""


def __getattr__(name):
    # rasterio, pyproj and trimesh load when a converter is first used
    if name == "seabed_from_grid":
        from mitsonar.scenes.grid import seabed_from_grid

        return seabed_from_grid
    if name == "scene_from_sdf":
        from mitsonar.scenes.sdf import scene_from_sdf

        return scene_from_sdf
    raise AttributeError(f"module 'mitsonar.scenes' has no attribute {name!r}")
