"""The strip guide (`plugins/integrators/paths/curved_mirror.py` strip_lobe, `image_guide.STRIP_GUIDE`): at a
mirror-like vertex the bounce may aim at a convex curved mirror's specular point towards the
transducer's image after the vertex (``scenes_xml/pile_quay.xml``: the quay wall's bounce aimed at
the strip of the pile that sends the echo home). The mirrors read from the scene, the specular
point and the lobe's widths against their closed forms, the lobe's density against its samples,
agreement with the unguided path tracer, the noise it removes, determinism with any thread count.

Statistics as in test_image_guide: means over 10 seeds, z = difference / combined standard error.
"""
import math

import numpy as np
import pytest

from test_bdpt import integrator, load
from test_image_guide import window_variance


@pytest.fixture
def strip(monkeypatch):
    """``set(flag)``: the strip guide on or off, kernels traced anew."""
    from mitsonar.plugins.integrators.paths import frozen_pass
    from mitsonar.plugins.integrators.paths import image_guide

    def set_flag(flag):
        monkeypatch.setattr(image_guide, "STRIP_GUIDE", flag)
        frozen_pass.clear()

    yield set_flag
    frozen_pass.clear()


def test_the_curved_mirrors_are_read_from_the_scene(mitsonar_mod):
    """pile_quay's pile (a cylinder from p0/p1/radius, through Mitsuba's to_world) is the one
    curved mirror; a scene whose only mirror is the curved one (the tank, the bow) has none to aim
    at, and keeps the planar kernel; planar scenes and scenes without mirrors likewise."""
    from mitsonar.plugins.integrators.paths import curved_mirror
    from mitsonar.plugins.integrators.paths import image_guide

    (centre, axis, radius, n), = curved_mirror.scene_mirrors(load(mitsonar_mod, "pile_quay"), image_guide.MIN_EXPONENT,
                                                             image_guide.lobe_exponent)
    assert np.allclose(centre, (4, 3, -3)) and np.allclose(axis, (0, 0, 1)) and math.isclose(radius, 0.3, rel_tol=1e-6)
    assert math.isclose(n, image_guide.lobe_exponent(load(mitsonar_mod, "pile_quay").shapes()[0].bsdf()))
    kinds = {name: image_guide.scene_guide(load(mitsonar_mod, name))
             for name in ("pile_quay", "tank_target", "hull_target", "hidden_target", "box")}
    assert isinstance(kinds.pop("pile_quay"), image_guide.Guide)
    assert kinds == {"tank_target": True, "hull_target": True, "hidden_target": True, "box": False}


def test_the_lobe_aims_at_the_specular_strip_with_the_echo_widths(mitsonar_mod):
    """From the wall's centre W = (4, 0, 0) with the sonar's image I = (4, -4, 0) (the sonar at the
    origin, the wall's plane y = x - 4), the pile's specular point is (4, 2.7, 0): its normal (0,
    -1, 0) bisects the directions to W and I. Widths: a = 2.7, b = 6.7, D / b = 9.4 / 6.7; across
    the pile k1 = D / b + 2 a / R, along it k2 = D / b; sigma = STRIP_WIDEN / (k sqrt(n)). From a
    point inside the pile there is no strip."""
    import mitsuba as mi
    from mitsonar.plugins.integrators.paths import curved_mirror as cm

    mirror = ((4.0, 3.0, -3.0), (0.0, 0.0, 1.0), 0.3, 200.0)
    d, e1, e2, s1, s2, ok = cm.strip_lobe(mi.Point3f(4, 0, 0), mi.Point3f(4, -4, 0), mirror)
    assert bool(ok[0])
    assert np.allclose([d.x[0], d.y[0], d.z[0]], (0, 1, 0), atol=1e-5)
    plane = 9.4 / 6.7
    k1, k2 = plane + 2 * 2.7 / 0.3, plane
    assert math.isclose(s1[0], cm.STRIP_WIDEN / (k1 * math.sqrt(200)), rel_tol=1e-4)
    assert math.isclose(s2[0], cm.STRIP_WIDEN / (k2 * math.sqrt(200)), rel_tol=1e-4)
    assert abs(e1.z[0]) < 1e-6 and math.isclose(abs(e2.z[0]), 1.0, rel_tol=1e-6)   # e1 across, e2 along
    assert not bool(cm.strip_lobe(mi.Point3f(4, 2.9, 0), mi.Point3f(4, -4, 0), mirror)[-1][0])


def test_the_lobe_density_integrates_to_one_and_matches_its_samples(mitsonar_mod):
    """The density of `strip_sample` (a Gaussian through the gnomonic map): its integral over the
    sphere is 1 (quadrature in angle about the axis), and the share of samples within each of three
    cones about the axis is the density's integral over the cone (2e5 samples: within 0.006)."""
    import drjit as dr
    import mitsuba as mi
    from mitsonar.plugins.integrators.paths import curved_mirror as cm

    d = mi.Vector3f(0.36, 0.48, 0.8)
    fr = mi.Frame3f(d)
    lobe = (d, fr.s, fr.t, mi.Float(0.05), mi.Float(0.2), mi.Bool(True))
    # quadrature over (theta, phi) about the axis, theta to 1.2 rad (beyond: below 1e-6 of the mass)
    th = (np.arange(1200) + 0.5) * (1.2 / 1200)
    ph = (np.arange(720) + 0.5) * (2 * np.pi / 720)
    T, P = (a.ravel() for a in np.meshgrid(th, ph, indexing="ij"))
    local = mi.Vector3f(np.sin(T) * np.cos(P), np.sin(T) * np.sin(P), np.cos(T))
    pdf = cm.strip_pdf(lobe, fr.to_world(local)).numpy().astype(np.float64)
    cell = (1.2 / 1200) * (2 * np.pi / 720) * np.sin(T)
    assert math.isclose((pdf * cell).sum(), 1.0, rel_tol=2e-3)
    n = 200_000
    u = mi.Point2f(dr.arange(mi.Float, n) / n, mi.Float(np.random.default_rng(3).random(n)))
    w = cm.strip_sample(lobe, u)
    ang = np.arccos(np.clip(dr.dot(w, d).numpy(), -1, 1))
    for cone in (0.05, 0.15, 0.3):
        assert abs((ang < cone).mean() - (pdf * cell)[T < cone].sum()) < 0.006, cone


def test_the_strip_guide_agrees_with_unguided(mitsonar_mod, strip):
    """Same expectation as the unguided path tracer (64x its paths), per ping in two cells: the
    wall's own echo (before 6.5 m) and the pile's through the wall (from 6.7 m, 80 % of the
    energy), and the total: z of the means over 10 seeds against the standard error of the
    per-render sums (t with 9 degrees of freedom: |z| > 6 has probability about 2e-4 per cell).
    The unguided estimate of a finer cell is heavy tailed (1-2 paths in 10^4 carry it): 10 seeds
    of 8192 or 65536 paths missed parts of the pile's echo by 3-10 of their standard errors, where
    2^20 paths agreed with the guided estimate. Six seed sets of this test: |z| at most 3.6, mean
    z^2 0.3-2.6 over the 15 cells (1.29 expected for t with 9 degrees of freedom; the cells are
    correlated through the total, hence the bound of 4)."""
    strip(True)
    scene = load(mitsonar_mod, "pile_quay", 7, bearing_start=-3)
    start = int(6.5 / 10 * 400)

    def cells(integ, spp):
        runs = []
        for seed in range(10):
            h = integ.render_histogram(scene, 0, seed=seed, spp=spp)
            runs.append(np.concatenate([h[:, :start].sum(1), h[:, start:].sum(1), [h.sum()]]))
        runs = np.array(runs)
        return runs.mean(0), runs.std(0, ddof=1) / math.sqrt(len(runs))

    (mg, sg), (mp, sp) = (cells(integrator(type="sonar_tof", max_depth=3, guide=g), spp)
                          for g, spp in (("image", 2048), ("none", 131072)))
    z = (mg - mp) / np.hypot(sg, sp)
    lit = mp > 1e-3 * mp[-1]
    assert lit.sum() >= 12
    assert np.max(np.abs(z[lit])) < 6.0, f"max |z| = {np.max(np.abs(z[lit])):.2f}"
    assert np.mean(z[lit] ** 2) < 4.0, f"mean z^2 = {np.mean(z[lit] ** 2):.2f}"
    assert mg[7:14].sum() > 0.7 * mg[-1]      # the pile's echo is most of what is tested


def test_the_strip_guide_cuts_the_variance_per_path_behind_the_quay(mitsonar_mod, monkeypatch):
    """The pile's echo (from 6.7 m), 21 pings x 16384 independent paths each way: the variance per
    path (summed over the window's bins) is at least 3x lower with the strip guide (6.1x measured
    with Sobol paths, 65536 a ping), and the echo's energy agrees."""
    scene = load(mitsonar_mod, "pile_quay")
    lo, paths = int(6.5 / 10 * 400), 16384
    var_s, e_s, se_s = window_variance(monkeypatch, scene, "STRIP_GUIDE", True, 5, lo, paths)
    var_p, e_p, se_p = window_variance(monkeypatch, scene, "STRIP_GUIDE", False, 5, lo, paths)
    assert e_s > 0
    assert var_p > 3 * var_s, (var_p, var_s)
    assert abs(e_s - e_p) < 4 * math.hypot(se_s, se_p)


def test_same_seed_same_bytes_with_any_thread_count(mitsonar_mod, strip):
    import drjit as dr

    strip(True)
    scene = load(mitsonar_mod, "pile_quay", 5, bearing_start=-2)
    before = dr.thread_count()
    try:
        out = []
        for n in (1, 2, 1):
            dr.set_thread_count(n)
            integ = integrator(type="sonar_tof", guide="image")
            out.append([integ.render_histogram(scene, 0, seed=seed, spp=512) for seed in (3, 4)])
            mlt = integrator(type="sonar_mlt", split=0.5)
            out[-1].append(mlt.render_histogram(scene, 0, seed=3, spp=512))
    finally:
        dr.set_thread_count(before)
    assert out[0][0][:, 260:].sum() > 0
    for run in out[1:]:
        assert all(a.tobytes() == b.tobytes() for a, b in zip(run, out[0]))
    assert not np.array_equal(out[0][0], out[0][1])


def test_the_variance_diagnostic_finds_the_pile(mitsonar_mod, capsys, monkeypatch):
    """benchmarks/pile_variance.py: the pile's window holds nearly all of the variance, the bounce-2
    echoes nearly all of the second moment, and the guide puts more paths on the strip (256 paths a
    ping: 0.7 % and 12 % with 65536)."""
    import re

    from conftest import script
    from mitsonar.plugins.integrators.paths import frozen_pass
    from mitsonar.plugins.integrators.paths import image_guide

    monkeypatch.setattr(image_guide, "STRIP_GUIDE", image_guide.STRIP_GUIDE)
    bench = script("benchmarks/pile_variance.py")
    strip_share = []
    for extra in ([], ["--no-strip-guide"]):
        frozen_pass.clear()
        assert bench.main(["--paths", "2048", *extra]) == 0
        out = capsys.readouterr().out
        assert float(re.search(r"\(>= 6\.5 m\): ([0-9.]+) of the variance", out).group(1)) > 0.95
        assert float(re.search(r"bounce 2: [0-9.]+ of the energy, ([0-9.]+) of the second", out).group(1)) > 0.95
        strip_share.append(float(re.search(r"within 2 deg of the strip: ([0-9.]+)", out).group(1)))
    frozen_pass.clear()
    assert strip_share[0] > 5 * strip_share[1] > 0
    with pytest.raises(SystemExit):
        bench.main(["--paths", "4"])
