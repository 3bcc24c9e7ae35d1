"""The survey scenes (harbour, wreck, rocky slope): they load, their ground-truth meshes are what
their comment blocks say, the committed seabeds are what the generator makes, their example
trajectories stay above the seabed, and the wreck casts its shadow."""
import os

import numpy as np
import pytest

from conftest import ROOT, SCENES, script

# scene: (trajectory file, ground-truth extent (min, max) from its comment block)
SURVEYS = {
    "harbour": ("harbour_survey.tum", ((-30, -20, -6), (30, 20, 1.5))),
    "wreck": ("wreck_survey.tum", ((-12, -8, -9.3), (12, 7.96, -6.1))),
    "rocky_slope": ("rocky_slope_survey.tum", ((-12, -8, -12.17), (12, 8, -7.61))),
}


def maker():
    return script("scripts/make_survey_scenes.py")


@pytest.mark.parametrize("name", sorted(SURVEYS))
def test_scene_loads_with_its_ground_truth_and_a_track_above_the_seabed(mitsonar_mod, name):
    tum, (lo, hi) = SURVEYS[name]
    scene = mitsonar_mod.load_scene(os.path.join(SCENES, f"{name}.xml"))
    V, F = mitsonar_mod.scene_mesh(scene)
    np.testing.assert_allclose(V.min(0), lo, atol=0.01)
    np.testing.assert_allclose(V.max(0), hi, atol=0.01)
    assert F.max() < len(V)
    track = mitsonar_mod.Trajectory.from_tum(os.path.join(SCENES, tum))
    p = track.positions
    # At least 2 m of water under the vehicle all along: a ray straight down meets the seabed.
    import mitsuba as mi

    q = p[:: max(1, len(p) // 50)]
    n = len(q)
    ray = mi.Ray3f(mi.Point3f(q[:, 0], q[:, 1], q[:, 2]), mi.Vector3f(np.zeros(n), np.zeros(n), -np.ones(n)))
    depth = np.array(scene.ray_intersect(ray).t)
    assert np.all(np.isfinite(depth)) and depth.min() > 2.0, f"{name}: {depth.min():.2f} m under the track"


def test_committed_seabeds_and_tracks_are_what_the_generator_makes(tmp_path):
    from mitsonar.scenes.terrain import Terrain

    mod = maker()
    for name, kw in mod.TERRAINS.items():
        Terrain(**kw).write_ply(tmp_path / name)
        with open(os.path.join(SCENES, name), "rb") as f:
            assert (tmp_path / name).read_bytes() == f.read(), f"{name} differs from its generator"
    assert set(mod.TRACKS) | {"rocky_slope_survey.tum"} == {t for t, _ in SURVEYS.values()}


def test_wreck_pass_shows_the_hull_and_the_deckhouse_shadow(mitsonar_mod):
    """Side-scan lines abeam of the wreck against lines over bare rippled sand (the track runs at
    y = -7, 4 m above the seabed): the hull's near side and its corner with the seabed (slant 6.67
    to 7.05 m) echo far above the sand there, and behind the deckhouse (x in [-2.7, -0.3]) the
    seabed from 11 to 14 m slant is in its shadow (the line over the deckhouse meets the seabed
    beyond the terrain's far edge): no echo at all, where bare sand lines have one."""
    scene = mitsonar_mod.load_scene(os.path.join(SCENES, "wreck.xml"))
    track = mitsonar_mod.Trajectory.from_tum(os.path.join(SCENES, "wreck_survey.tum"))
    rows, xs = [], []
    for start in (0.0, 4.5):   # vehicle x from -10.5 to -3 and from -3.75 to 3.8
        scan = mitsonar_mod.render_scan(scene, spp=256, seed=1, trajectory=track, start_time=start)
        rows.append(scan.intensity.astype(np.float64))
        xs.append(scan.poses[:, 0, 3])
    intensity, x, r = np.concatenate(rows), np.concatenate(xs), scan.ranges
    band = lambda a, b: intensity[:, (r > a) & (r < b)].sum(1)  # noqa: E731
    bare, deckhouse = x < -6.0, (x > -2.2) & (x < -0.8)
    assert bare.sum() > 20 and deckhouse.sum() > 10
    hull = band(6.6, 7.1)
    assert np.min(hull[deckhouse]) > 20 * np.max(hull[bare])
    shadow = band(11.0, 14.0)
    assert np.all(shadow[bare] > 0)
    assert np.all(shadow[deckhouse] < 1e-3 * np.median(shadow[bare]))


def test_demo_survey_draws_both_heads_along_the_harbour_track(tmp_path):
    import warnings

    from mitsonar.cli.survey import demo_survey

    with warnings.catch_warnings():
        warnings.simplefilter("error")   # both heads picked by object: no "2 sonar sensors" warning
        written = demo_survey(SCENES, str(tmp_path), spp=8, seed=0)
    names = [os.path.basename(p) for p in written]
    # 50 s of track, 14 s sweeps (200 pings of 2 x 30.5 / 1500 + 0.03 s): three whole sweeps.
    assert names == ["harbour_mechanical_0.png", "harbour_mechanical_1.png", "harbour_mechanical_2.png",
                     "harbour_multibeam_10s.png", "harbour_multibeam_25s.png", "harbour_multibeam_40s.png",
                     "harbour_track.png"]
    for p in written:
        with open(p, "rb") as f:
            assert f.read(8) == b"\x89PNG\r\n\x1a\n"
