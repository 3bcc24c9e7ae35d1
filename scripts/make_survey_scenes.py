"""Write the survey scenes' seabed meshes and example trajectories into scenes_xml/ (the files are
committed; this script is how they were made, and remakes them byte for byte):

    .venv/bin/python scripts/make_survey_scenes.py

The committed meshes are coarser than a 1000-bin side-scan ping's bins (file size: about 1 MB for
the wreck's seabed); for renders at full resolution, write a finer one over them, e.g.
``--fine`` (0.03 m cells: about 16 MB for the wreck) -- see mitsonar/scenes/terrain.py for the rule.
"""
import math
import os
import sys

from mitsonar.scenes.terrain import Terrain
from mitsonar.geometry.trajectory import Trajectory, pose

HERE = os.path.join(os.path.dirname(os.path.abspath(__file__)), "..", "scenes_xml")

# name: terrain arguments (the XML comment blocks repeat them).
TERRAINS = {
    "wreck_seabed.ply": dict(size=(24.0, 16.0), resolution=0.12, depth=-8.0, ripple_wavelength=0.6,
                             ripple_height=0.04, ripple_direction=0.0, roughness=0.01,
                             correlation_length=1.0, seed=19),
    "rocky_slope.ply": dict(size=(24.0, 16.0), resolution=0.2, depth=-10.0, slope=(0.0, 0.25),
                            roughness=0.08, correlation_length=1.5, rocks=40, rock_radius=(0.3, 1.0),
                            seed=23),
}

# name: (duration s, speed m/s, start position, heading deg)
TRACKS = {
    "harbour_survey.tum": (50.0, 0.5, (-10.0, -14.0, -2.0), 0.0),
    "wreck_survey.tum": (14.0, 1.5, (-10.5, -7.0, -4.0), 0.0),
}


def main(fine=False):
    for name, kw in TERRAINS.items():
        if fine:
            kw = dict(kw, resolution=0.03)
        nv, nf = Terrain(**kw).write_ply(os.path.join(HERE, name))
        print(f"{name}: {nv} vertices, {nf} triangles")
    for name, (duration, speed, start, heading) in TRACKS.items():
        Trajectory.straight(duration, speed, start=pose(start, math.radians(heading))).to_tum(os.path.join(HERE, name))
        print(name)
    track = Trajectory.lawnmower(-9.0, 9.0, -5.0, 5.0, 5.0, 1.0, depth=5.0)
    track.to_tum(os.path.join(HERE, "rocky_slope_survey.tum"))
    print("rocky_slope_survey.tum")


if __name__ == "__main__":
    main(fine="--fine" in sys.argv[1:])
