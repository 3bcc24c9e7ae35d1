"""Ray-tube amplitudes in the renderer (issue 58): the way back of a refracted path is weighted by
its ray tube's spreading (`refraction.Refraction.tube`, float32, Dr.Jit), which is the float64
eigenrays' (`mitsonar.acoustics.eigenrays`) for direct and turned rays, and 1 / L^2 in uniform water."""
import math

import numpy as np
import pytest

from mitsonar.acoustics import SoundSpeedProfile, eigenrays

THERMOCLINE = SoundSpeedProfile([0.0, 30.0, 100.0], [1520.0, 1480.0, 1480.0])
LINEAR = SoundSpeedProfile([0.0, 200.0], [1450.0, 1650.0])     # c = 1450 + z: rays launched down turn up


def refraction_of(profile):
    import mitsonar  # noqa: F401  (the variant and the plugins)
    from mitsonar.plugins.integrators.paths import refraction

    class Head:
        sound_speed, range_max, frequency = 1500.0, 2500.0, 700e3

    return refraction.from_profile(profile, Head())


def tube_db(refr, zs, rows):
    """-10 log10 of `Refraction.tube` for eigenray rows launched from depth zs."""
    import mitsuba as mi

    n = len(rows)
    th = np.array([r["launch"] for r in rows])
    o = mi.Point3f(np.zeros(n), np.zeros(n), np.full(n, -zs))
    launch = mi.Vector3f(np.cos(th), np.zeros(n), -np.sin(th))
    p2 = refr.tube(o, launch, mi.Float([r["time"] for r in rows]), mi.Float([r["range"] for r in rows]),
                   mi.Float(np.sin([r["arrival"] for r in rows])), mi.Float([r["depth"] for r in rows]),
                   mi.Float([r["length"] for r in rows]), mi.Bool(True))
    return -10.0 * np.log10(p2.numpy().astype(float))


@pytest.mark.parametrize("profile, zs, points", [
    (THERMOCLINE, 10.0, [(20.0, 100.0), (20.0, 200.0), (5.0, 100.0)]),
    # direct rays, and rays that have turned and climb back to the receiver's depth
    (LINEAR, 10.0, [(20.0, 50.0), (20.0, 150.0), (20.0, 250.0), (12.0, 400.0), (40.0, 60.0)]),
])
def test_the_renderers_ray_tube_is_the_eigenrays_spreading(profile, zs, points):
    rows = []
    for zr, X in points:
        for r in eigenrays(profile, zs, zr, X, max_bounces=0):
            rows.append(dict(launch=r["launch"], arrival=r["arrival"], time=r["time"], range=X, depth=zr,
                             length=r["length"], spreading=r["spreading_loss"]))
    assert any(r["arrival"] < 0 < r["launch"] for r in rows) or profile is THERMOCLINE   # turned rays are in
    got = tube_db(refraction_of(profile), zs, rows)
    ref = np.array([r["spreading"] for r in rows])
    np.testing.assert_allclose(got, ref, atol=0.02)
    # and it is not 1 / L^2: focusing and defocusing are in it
    straight = np.array([20.0 * math.log10(r["length"]) for r in rows])
    assert np.max(np.abs(ref - straight)) > 0.02


def test_uniform_water_spreads_as_one_over_l_squared():
    uniform = SoundSpeedProfile.constant(1490.0)
    rows = [dict(r, range=X, depth=zr) for zr, X in ((20.0, 100.0), (60.0, 30.0), (11.0, 500.0))
            for r in ({n: e[n] for n in ("launch", "arrival", "time", "length")}
                      for e in eigenrays(uniform, 10.0, zr, X, max_bounces=0))]
    got = tube_db(refraction_of(uniform), 10.0, rows)
    np.testing.assert_allclose(got, [20.0 * math.log10(r["length"]) for r in rows], atol=0.01)
