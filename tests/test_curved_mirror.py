"""The image guide through curved mirrors (`plugins/integrators/paths/curved_mirror.py`): the reflection point on a
sphere and a cylinder against its defining condition, the mirror read from the surface, agreement
with the unguided and the planar-guided path tracer on the curved-mirror scenes, the noise it
removes behind a ship's bow, determinism.

Statistics as in test_image_guide: means over 10 seeds, z = difference / combined standard error
(t with about 9 degrees of freedom: |z| > 6 has probability about 2e-4 per cell).
"""
import math

import numpy as np
import pytest

from test_bdpt import SEEDS, integrator, load, stats, z_scores
from test_image_guide import window_variance


@pytest.fixture
def curved(monkeypatch):
    """The curved-mirror guide on (`image_guide.CURVED_GUIDE`, off by default), kernels traced anew."""
    from mitsonar.plugins.integrators.paths import frozen_pass
    from mitsonar.plugins.integrators.paths import image_guide

    monkeypatch.setattr(image_guide, "CURVED_GUIDE", True)
    frozen_pass.clear()
    yield
    frozen_pass.clear()


def xyz(p):
    return np.array([p.x[0], p.y[0], p.z[0]], dtype=np.float64)


@pytest.mark.parametrize("name, centre, axis, radius", [
    ("tank_target", (4, -2.2, 0), (0, 0, 1), 2.6),     # the tank: a vertical cylinder
    ("hull_target", (8, -4.5, 0), (0, 0, 0), 5.5),     # the bow: a sphere (no axis)
])
def test_the_mirror_is_read_from_the_surface_and_reflects_at_its_specular_point(mitsonar_mod, name, centre,
                                                                                    axis, radius):
    """The boresight's hit gives the shape's centre, axis and radius (the scene's ground truth);
    the point found for a target off the way out lies on the surface and its normal bisects the
    directions to the target and to the transducer (the law of reflection), with the angle of
    incidence it reports."""
    import mitsuba as mi
    from mitsonar.plugins.integrators.paths import curved_mirror as cm

    scene = load(mitsonar_mod, name)
    si = scene.ray_intersect(mi.Ray3f(mi.Point3f(0, 0, 0), mi.Vector3f(1, 0, 0)), cm.RAY_FLAGS, False, True)
    c, a, r = cm.local_mirror(si, mi.Vector3f(1, 0, 0))
    assert np.allclose(xyz(c), centre, atol=1e-3) and np.allclose(np.abs(xyz(a)), axis, atol=1e-4)
    assert r[0] == pytest.approx(radius, rel=1e-4)
    for x in ((3.9, 2.7, 0.3), (6.0, 3.0, -0.5), (2.0, 1.5, 0.8)):
        S, ok, cos_t = cm.specular_point(mi.Point3f(*x), mi.Point3f(0, 0, 0), c, a, r)
        assert bool(ok[0]), x
        S = xyz(S)
        n = S - np.array(centre, float)
        if any(axis):
            n[2] = 0.0
        assert np.linalg.norm(n) == pytest.approx(radius, rel=1e-4)
        n /= np.linalg.norm(n)
        u1 = (np.array(x) - S) / np.linalg.norm(np.array(x) - S)
        u2 = -S / np.linalg.norm(S)
        assert np.linalg.norm(np.cross(n, u1 + u2)) < 1e-4 * np.linalg.norm(u1 + u2)   # n bisects them
        assert np.dot(n, u1) == pytest.approx(np.dot(n, u2), abs=1e-4) == pytest.approx(cos_t[0], abs=1e-4)


def test_flat_and_concave_mirrors_keep_the_tangent_plane(mitsonar_mod):
    """A plate has no curvature and the inside of a tank is concave: radius 0, the planar image."""
    import mitsuba as mi
    from mitsonar.plugins.integrators.paths import curved_mirror as cm

    plate = load(mitsonar_mod, "hidden_target")
    si = plate.ray_intersect(mi.Ray3f(mi.Point3f(0, 0, 0), mi.Vector3f(1, 0, 0)), cm.RAY_FLAGS, False, True)
    assert cm.local_mirror(si, mi.Vector3f(1, 0, 0))[2][0] == 0
    tank = load(mitsonar_mod, "tank_target")
    inside = mi.Point3f(4, -2.2, 0)
    si = tank.ray_intersect(mi.Ray3f(inside, mi.Vector3f(1, 0, 0)), cm.RAY_FLAGS, False, True)
    assert bool(si.is_valid()[0]) and cm.local_mirror(si, mi.Vector3f(1, 0, 0))[2][0] == 0


def test_the_kernel_solves_only_where_a_curved_mirror_is(mitsonar_mod, monkeypatch):
    """`scene_guide`: the planar scenes keep the planar kernel (no extra cost), a mirror-like sphere
    or cylinder asks for the curved one when the curved guide is on, a scene without mirrors for
    none. (With the strip guide, on by default, pile_quay's kernel is a `image_guide.Guide`:
    tests/test_strip_guide.py.)"""
    from mitsonar.plugins.integrators.paths import image_guide

    names = ("hidden_target", "periscope", "tank_target", "hull_target", "pile_quay", "box")
    scenes = {name: load(mitsonar_mod, name) for name in names}
    monkeypatch.setattr(image_guide, "STRIP_GUIDE", False)
    monkeypatch.setattr(image_guide, "CURVED_GUIDE", True)
    assert {n: image_guide.scene_guide(s) for n, s in scenes.items()} == {
        "hidden_target": True, "periscope": True, "tank_target": "curved", "hull_target": "curved",
        "pile_quay": "curved", "box": False}
    monkeypatch.setattr(image_guide, "CURVED_GUIDE", False)
    assert {n: image_guide.scene_guide(s) for n, s in scenes.items()} == {
        "hidden_target": True, "periscope": True, "tank_target": True, "hull_target": True, "pile_quay": True,
        "box": False}
    monkeypatch.setattr(image_guide, "STRIP_GUIDE", True)
    assert image_guide.scene_guide(scenes["pile_quay"]) == image_guide.Guide(False, image_guide.scene_guide(
        scenes["pile_quay"]).mirrors)
    monkeypatch.setattr(image_guide, "CURVED_GUIDE", True)
    assert image_guide.is_curved(image_guide.scene_guide(scenes["pile_quay"]))


@pytest.mark.parametrize("name, spp", [("tank_target", 2048), ("hull_target", 2048), ("pile_quay", 1024)])
def test_curved_guide_agrees_with_unguided(mitsonar_mod, curved, name, spp):
    """Same expectation as the unguided path tracer (8x its paths: its estimate of the echoes behind
    the mirrors is heavy tailed), cell by cell over the cells holding 0.1 % of the energy, and the
    total."""
    scene = load(mitsonar_mod, name, 9, bearing_start=-4)
    guided = stats(integrator(type="sonar_tof", max_depth=5, guide="image"), scene, spp)
    plain = stats(integrator(type="sonar_tof", max_depth=5, guide="none"), scene, 8 * spp)
    z = z_scores(guided, plain, 20, 1e-3)
    assert len(z) >= 8
    assert np.max(np.abs(z)) < 6.0, f"max |z| = {np.max(np.abs(z)):.2f}"
    assert np.mean(z ** 2) < 2.5, f"mean z^2 = {np.mean(z ** 2):.2f}"
    se_total = math.hypot(*(s.sum() for _, s in (guided, plain)))
    assert abs(guided[0].sum() - plain[0].sum()) < 4 * se_total


def test_curved_guide_cuts_the_variance_per_path_behind_a_bow(mitsonar_mod, monkeypatch):
    """The block seen only in the bow (from 7.4 m), 21 pings x 32768 independent paths each way: the
    variance per path (summed over the window's bins) is at least 1.4x lower with the curved guide
    than with the tangent-plane image (1.75-1.86x measured on three seeds of twice as many paths),
    and the echo's energy agrees. (Sobol renders of a few seeds are no measure here: the planar
    guide's estimate is heavy tailed, one seed in ten holds most of its spread.)"""
    scene = load(mitsonar_mod, "hull_target")
    lo, paths = int(7.4 / 10 * 400), 32768
    var_c, e_c, se_c = window_variance(monkeypatch, scene, "CURVED_GUIDE", True, 5, lo, paths)
    var_p, e_p, se_p = window_variance(monkeypatch, scene, "CURVED_GUIDE", False, 5, lo, paths)
    assert e_c > 0
    assert var_p > 1.4 * var_c, (var_p, var_c)
    assert abs(e_c - e_p) < 4 * math.hypot(se_c, se_p)


@pytest.mark.parametrize("name", ["tank_target", "hull_target", "pile_quay"])
def test_same_seed_same_scan(mitsonar_mod, curved, name):
    scene = load(mitsonar_mod, name, 5, bearing_start=-2)
    integ = integrator(type="sonar_tof", guide="image")
    a, b, c = (integ.render_histogram(scene, 0, seed=seed, spp=256) for seed in (3, 3, 4))
    assert np.array_equal(a, b)
    assert not np.array_equal(a, c)
