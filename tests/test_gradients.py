"""Gradients of a scan through mi.render (issue "Differentiable scans"), in both AD modes.

Finite differences use the primal renderer with the seed the gradient pass used (``seed_grad``),
so the two see the same paths and differ only by the estimators (plugins/integrators/paths/path_replay.py).
"""
import math
import os

import numpy as np
import pytest

from conftest import acoustic_xml, frame_matrix, matrix_attr, scene_xml, sonar_xml

SPP = 1 << 14
SEED, SEED_GRAD = 3, 11


def scene(mitsonar, shapes, boresight=(0.0, 0.0, -1.0), scan_axis=(0.0, 1.0, 0.0), depth=1, bsdf=None, **sonar):
    """A sonar ``head`` over ``shapes`` (rectangles: (4x4 to_world)), all of BSDF ``mat``."""
    params = dict(n_pings=2, n_bins=48, range_min=1.0, range_max=4.0, bearing_step=4.0, beamwidth_h=10.0,
                  beamwidth_v=10.0)
    params.update(sonar)
    head = sonar_xml(frame_matrix(boresight, scan_axis), **params).replace('type="sonar"', 'type="sonar" id="head"')
    bsdf = (bsdf or acoustic_xml(0.5)).replace('type="acoustic"', 'type="acoustic" id="mat"')
    rects = "".join(f'<shape type="rectangle"><transform name="to_world"><matrix value="{matrix_attr(m)}"/>'
                    f'</transform><ref id="mat"/></shape>' for m in shapes)
    integrator = f'<integrator type="sonar_tof"><integer name="max_depth" value="{depth}"/></integrator>'
    return mitsonar.load_scene(scene_xml(head, bsdf, rects, integrator=integrator))


def plane(z, half=30.0):
    m = np.diag([half, half, 1.0, 1.0])
    m[2, 3] = z
    return m


def ceiling(z, half=30.0):
    m = np.diag([half, -half, -1.0, 1.0])
    m[2, 3] = z
    return m


def weights(shape):
    """A smooth weighting of the scan's bins, so that the loss is well resolved by finite differences."""
    n_rows, n_bins = shape[:2]
    return np.tile(np.linspace(1.0, 2.0, n_bins), (n_rows, 1)) * np.arange(1, n_rows + 1)[:, None]


def backward_sum(sc, key):
    """Gradients enabled on parameter ``key``, the scan's sum rendered (SPP, SEED) and
    backpropagated: returns the parameters (``dr.grad(p[key])`` now holds d(sum)/d(key)) and the sum."""
    import drjit as dr
    import mitsuba as mi

    p = mi.traverse(sc)
    dr.enable_grad(p[key])
    p.update()
    total = dr.sum(mi.render(sc, p, spp=SPP, seed=SEED).array)
    dr.backward(total)
    return p, total


def check_against_fd(sc, key, h, make=None, rtol=0.02, spp=SPP):
    """Reverse and forward derivative of sum(weights * scan) along ``key`` (or along ``make(v)``,
    v the scalar the parameter is a function of) against a central finite difference."""
    import drjit as dr
    import mitsuba as mi

    p = mi.traverse(sc)
    if make is None:
        x0 = float(p[key][0])
        make = mi.Float
    else:
        x0 = 0.0
    w = None

    def primal(v):
        nonlocal w
        p[key] = make(v)
        p.update()
        img = np.asarray(mi.render(sc, spp=spp, seed=SEED_GRAD), dtype=np.float64)[..., 0]
        w = weights(img.shape) if w is None else w
        return float((img * w).sum())

    fd = (primal(x0 + h) - primal(x0 - h)) / (2 * h)
    wt = mi.Float(w.ravel().astype(np.float32))
    grads = []
    for mode in ("backward", "forward"):
        x = mi.Float(x0)
        dr.enable_grad(x)
        p[key] = make(x)
        p.update()
        loss = dr.sum(mi.render(sc, p, spp=spp, seed=SEED, seed_grad=SEED_GRAD).array * wt)
        if mode == "backward":
            dr.backward(loss)
            grads.append(float(dr.grad(x)[0]))
        else:
            dr.forward(x)
            grads.append(float(dr.grad(loss)[0]))
    p[key] = make(x0)
    p.update()
    assert abs(fd) > 1e-9
    for mode, g in zip(("reverse", "forward"), grads):
        assert g == pytest.approx(fd, rel=rtol), f"{key} ({mode}): {g} vs finite difference {fd}"
    return fd, grads


# ----------------------------------------------------------------------------- closed forms
def test_diffuse_only_scan_is_linear_in_diffuse(mitsonar_mod):
    """Single bounce, only diffuse non-zero: scan = diffuse * g, so d(sum)/d(diffuse) = sum / diffuse
    (both modes, to float rounding)."""
    import drjit as dr
    import mitsuba as mi

    sc = scene(mitsonar_mod, [plane(-2.0)], boresight=(0.4, 0.0, -1.0), bsdf=acoustic_xml(0.35, 0.0))
    p, total = backward_sum(sc, "mat.diffuse")
    expected = float(total[0]) / 0.35
    assert expected > 0
    assert float(dr.grad(p["mat.diffuse"])[0]) == pytest.approx(expected, rel=1e-4)
    dr.set_grad(p["mat.diffuse"], 0.0)
    total = dr.sum(mi.render(sc, p, spp=SPP, seed=SEED).array)
    dr.forward(p["mat.diffuse"])
    assert float(dr.grad(total)[0]) == pytest.approx(expected, rel=1e-4)


def test_plane_range_centroid_moves_with_the_head(mitsonar_mod):
    """Normal incidence on a plane at distance D: an echo of direction theta off the normal has
    range D / cos(theta) and energy D^-2 h(theta), so the centroid c = sum r I / sum I is D times a
    constant and moving the head a distance s towards the plane gives dc/ds = -c / D."""
    import drjit as dr
    import mitsuba as mi

    dist = 2.0
    sc = scene(mitsonar_mod, [plane(-dist)], n_bins=120, range_min=1.5, range_max=3.0, beamwidth_h=12.0,
               beamwidth_v=12.0, bearing_step=0.0)
    p = mi.traverse(sc)
    base = mi.Transform4f(p["head.to_world"])
    ranges = mi.Float(np.tile(sc.sensors()[0].bin_centres(), 2).astype(np.float32))

    def centroid_and_grad(mode):
        s = mi.Float(0.0)
        dr.enable_grad(s)
        p["head.to_world"] = mi.Transform4f().translate(mi.Vector3f(0.0, 0.0, -s)) @ base
        p.update()
        img = mi.render(sc, p, spp=SPP, seed=SEED).array
        c = dr.sum(img * ranges) / dr.sum(img)
        if mode == "backward":
            dr.backward(c)
            return float(c[0]), float(dr.grad(s)[0])
        dr.forward(s)
        return float(c[0]), float(dr.grad(c)[0])

    for mode in ("backward", "forward"):
        c, dc = centroid_and_grad(mode)
        assert dist < c < 1.05 * dist
        assert dc == pytest.approx(-c / dist, rel=0.01), mode


def test_textured_diffuse_gradient_is_per_texel(mitsonar_mod, tmp_path):
    """A bitmap of diffuse reflectance over a seabed (``mat.diffuse.data``): single bounce, no
    specular, the scan is linear in the texels, so sum(data * d(sum)/d(data)) = sum (Euler); forward
    mode agrees with reverse mode, and one texel's derivative matches its finite difference."""
    import drjit as dr
    import mitsuba as mi

    data = np.full((4, 4, 1), 0.3, np.float32)
    data[1, 2], data[2, 1] = 0.6, 0.1
    path = os.path.join(tmp_path, "reflectance.exr")
    mi.Bitmap(data).write(path)
    tex = (f'<bsdf type="acoustic"><texture type="bitmap" name="diffuse"><string name="filename" value="{path}"/>'
           f'<boolean name="raw" value="true"/><string name="filter_type" value="nearest"/></texture>'
           f'<float name="specular" value="0"/></bsdf>')
    sc = scene(mitsonar_mod, [plane(-2.0, half=2.0)], boresight=(0.3, 0.0, -1.0), bsdf=tex, beamwidth_h=30.0,
               beamwidth_v=30.0, bearing_step=10.0)
    key = "mat.diffuse.data"
    p, total = backward_sum(sc, key)
    grad = np.asarray(dr.grad(p[key]))
    assert float((grad * data).sum()) == pytest.approx(float(total[0]), rel=1e-4)
    assert (grad >= 0).all() and grad[1, 2, 0] > 0
    total = dr.sum(mi.render(sc, p, spp=SPP, seed=SEED).array)
    dr.forward(p[key])  # tangent 1 on every texel: d(sum) = the sum of the reverse-mode gradient
    assert float(dr.grad(total)[0]) == pytest.approx(float(grad.sum()), rel=1e-4)

    # one texel against a finite difference (same paths)
    def with_texel(v):
        d = data.copy()
        d[1, 2] = v
        p[key] = mi.TensorXf(d)
        p.update()
        return float(np.asarray(mi.render(sc, spp=SPP, seed=SEED_GRAD)).sum())

    fd = (with_texel(0.65) - with_texel(0.55)) / 0.1
    assert grad[1, 2, 0] == pytest.approx(fd, rel=0.02)


# ----------------------------------------------------------------------------- finite differences
@pytest.mark.parametrize("key, h", [("mat.diffuse", 0.05), ("mat.specular", 0.05), ("mat.shininess", 0.5)])
def test_bsdf_gradients_match_finite_differences(mitsonar_mod, key, h):
    sc = scene(mitsonar_mod, [plane(-2.0)], boresight=(0.25, 0.0, -1.0), bsdf=acoustic_xml(0.4, 0.3, 20.0))
    check_against_fd(sc, key, h)


@pytest.mark.parametrize("key, h", [("head.absorption", 0.05), ("head.beamwidth_h", 0.5), ("head.beamwidth_v", 0.5)])
def test_sensor_gradients_match_finite_differences(mitsonar_mod, key, h):
    sc = scene(mitsonar_mod, [plane(-2.0)], boresight=(0.35, 0.0, -1.0), absorption=0.5)
    check_against_fd(sc, key, h)


@pytest.mark.parametrize("motion", ["translate", "rotate"])
def test_head_pose_gradients_match_finite_differences(mitsonar_mod, motion):
    """``head.to_world`` through the echoes' ranges (a smooth weight over range) and energies."""
    import mitsuba as mi

    sc = scene(mitsonar_mod, [plane(-2.0)], boresight=(0.35, 0.0, -1.0))
    base = mi.Transform4f(mi.traverse(sc)["head.to_world"])
    if motion == "translate":
        make = lambda v: mi.Transform4f().translate(mi.Vector3f(0.3 * v, 0.2 * v, v)) @ base  # noqa: E731
    else:
        make = lambda v: base @ mi.Transform4f().rotate(mi.Vector3f(0, 1, 0), v * 180 / math.pi)  # noqa: E731
    check_against_fd(sc, "head.to_world", 0.02, make)


def test_multibounce_gradients_match_finite_differences(mitsonar_mod):
    """Three bounces between a floor and a ceiling (no edges in reach): the path replay carries the
    throughput's derivative and the hit points' Jacobians along the path."""
    import mitsuba as mi

    sc = scene(mitsonar_mod, [plane(-2.0, 60.0), ceiling(1.5, 60.0)], boresight=(1.0, 0.0, -0.8), depth=3,
               bsdf=acoustic_xml(0.8, 0.1, 20.0), n_bins=60, range_min=0.0, range_max=15.0, beamwidth_h=40.0,
               beamwidth_v=40.0, absorption=0.3)
    check_against_fd(sc, "mat.diffuse", 0.02)
    base = mi.Transform4f(mi.traverse(sc)["head.to_world"])
    check_against_fd(sc, "head.to_world", 0.03,
                     lambda v: mi.Transform4f().translate(mi.Vector3f(v, 0.5 * v, 0.3 * v)) @ base)


# ----------------------------------------------------------------------------- path replay
def test_replay_retraces_the_primal_paths(mitsonar_mod):
    """The primal replay of `render_backward` (adjoint 1 everywhere) sums to the primal scan: the
    replayed paths are the primal's, echo for echo."""
    import drjit as dr
    import mitsuba as mi

    from mitsonar.plugins.integrators.paths import path_replay

    sc = scene(mitsonar_mod, [plane(-2.0, 60.0), ceiling(1.5, 60.0)], boresight=(1.0, 0.0, -0.8), depth=3,
               bsdf=acoustic_xml(0.5, 0.4, 20.0), n_bins=60, range_min=0.0, range_max=15.0, beamwidth_h=40.0,
               beamwidth_v=40.0)
    integrator = sc.integrator()
    spp = 4096
    hist = integrator.render_histogram(sc, seed=SEED, spp=spp)
    setup = integrator.setup(sc)
    with dr.resume_grad():
        setup.attach()
    adjoint = path_replay.Adjoint(setup.bins, dr.ones(mi.Float, hist.size))
    ping, samples = integrator.lanes(2, SEED, 0, spp)
    with dr.suspend_grad():
        s = integrator.sample(setup, ping, samples, mode=dr.ADMode.Primal, δ=adjoint)
    total, seen = s
    assert float(dr.sum(total)[0]) / spp == pytest.approx(hist.sum(), rel=1e-5)
    # and the same sum by the replay itself (visibility rays traced again)
    with dr.suspend_grad():
        again = path_replay.replay(setup, dr.ADMode.Primal, ping, samples, adjoint)
    assert float(dr.sum(again)[0]) / spp == pytest.approx(hist.sum(), rel=1e-5)
    bits = np.asarray(seen)
    assert bits.max() < 8 and (bits & 1).any() and (bits & 4).any()


def test_primal_is_unchanged_by_gradient_tracking(mitsonar_mod):
    import drjit as dr
    import mitsuba as mi

    sc = scene(mitsonar_mod, [plane(-2.0)], boresight=(0.3, 0.0, -1.0), bsdf=acoustic_xml(0.4, 0.3))
    plain = np.asarray(mi.render(sc, spp=4096, seed=SEED))
    p = mi.traverse(sc)
    for k in ("mat.diffuse", "head.to_world", "head.beamwidth_h", "head.absorption"):
        dr.enable_grad(p[k])
    p.update()
    tracked = np.asarray(mi.render(sc, p, spp=4096, seed=SEED))
    assert tracked.shape == (2, 48, 1)
    np.testing.assert_array_equal(tracked, plain)
    assert plain.sum() > 0


# ----------------------------------------------------------------------------- bad input
def test_unknown_parameter_is_named_with_the_allowed_ones(mitsonar_mod):
    from mitsonar.sim.render import scan_parameters

    sc = scene(mitsonar_mod, [plane(-2.0)])
    assert set(scan_parameters(sc).keys()) == {"head.to_world", "head.absorption", "head.beamwidth_h",
                                               "head.beamwidth_v", "mat.diffuse", "mat.specular", "mat.shininess"}
    with pytest.raises(mitsonar_mod.SceneError, match=r"'mat\.difuse' is not a differentiable parameter of this "
                                                      r"scene; allowed: head\.to_world, .*mat\.diffuse"):
        scan_parameters(sc, ["mat.difuse"])


def test_gradient_on_an_undifferentiated_parameter_is_refused(mitsonar_mod):
    import drjit as dr
    import mitsuba as mi

    sc = scene(mitsonar_mod, [plane(-2.0)])
    p = mi.traverse(sc)
    key = next(k for k in p.keys() if k.endswith(".to_world") and not k.startswith("head"))
    dr.enable_grad(p[key])
    img = mi.render(sc, p, spp=16)
    with pytest.raises(ValueError, match=rf"sonar_tof: parameter '{key}' has gradients enabled but is not "
                                         r"differentiated by the sonar integrators; allowed: head\.absorption"):
        dr.backward(dr.sum(img.array))


def test_non_ad_variant_is_refused_in_one_line(mitsonar_mod, monkeypatch):
    """Only AD variants are installed here; the check is exercised by making Dr.Jit report none."""
    import drjit as dr
    import mitsuba as mi

    from mitsonar.sim.render import scan_parameters

    sc = scene(mitsonar_mod, [plane(-2.0)])
    monkeypatch.setattr(dr, "is_diff_v", lambda t: False)
    with pytest.raises(mitsonar_mod.SceneError, match=r"scan_parameters: gradients need a Mitsuba variant with "
                                                      r"automatic differentiation .*; the active variant is "
                                                      + mi.variant()):
        scan_parameters(sc)
    with pytest.raises(ValueError, match=r"sonar_tof: gradients need a Mitsuba variant with automatic "
                                         r"differentiation .*; the active variant is"):
        sc.integrator().render_backward(sc, None, mi.TensorXf(np.zeros((2, 48, 1), np.float32)))


def test_twosided_acoustic_reverse_mode_and_forward_refusal(mitsonar_mod):
    """An acoustic BSDF inside ``twosided``: reverse mode reaches it (linear in diffuse, as above);
    forward mode cannot (the parameter is read inside Mitsuba's call of the wrapper) and says so."""
    import drjit as dr
    import mitsuba as mi

    from conftest import rectangle_xml

    head = sonar_xml(frame_matrix((0.4, 0.0, -1.0), (0.0, 1.0, 0.0)), n_pings=2, n_bins=48, range_min=1.0,
                     range_max=4.0, bearing_step=4.0)
    bsdf = '<bsdf type="twosided" id="mat">' + acoustic_xml(0.35, 0.0) + "</bsdf>"
    sc = mitsonar_mod.load_scene(scene_xml(head, bsdf, rectangle_xml(plane(-2.0), '<ref id="mat"/>'),
                                           integrator='<integrator type="sonar_tof"><integer name="max_depth" '
                                                      'value="1"/></integrator>'))
    key = "mat.brdf_0.diffuse"
    p, total = backward_sum(sc, key)
    assert float(dr.grad(p[key])[0]) == pytest.approx(float(total[0]) / 0.35, rel=1e-4)
    total = dr.sum(mi.render(sc, p, spp=SPP, seed=SEED).array)
    with pytest.raises(ValueError, match=r"sonar_tof: forward-mode derivatives of 'mat\.brdf_0\.diffuse' need its "
                                         r"acoustic BSDF attached directly to the shapes .*use reverse mode"):
        dr.forward(p[key])


def test_metropolis_integrator_refuses_gradients(mitsonar_mod):
    import mitsuba as mi

    sc = scene(mitsonar_mod, [plane(-2.0)])
    mlt = mi.load_dict({"type": "sonar_mlt"})
    with pytest.raises(ValueError, match=r"sonar_mlt: gradients are rendered by the sonar_tof integrator only"):
        mlt.render_backward(sc, None, mi.TensorXf(np.zeros((2, 48, 1), np.float32)))
