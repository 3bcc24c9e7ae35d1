"""``sonar_tof`` with ``share_beams``: a multibeam frame's paths traced from the transmit fan and
scored into every receive beam that hears them (plugins/integrators/paths/shared_beams.py). Same expectation as the
per-row estimator (checked here within Monte-Carlo error), same seed same scan, and the heads it
cannot serve refused in one line."""
import numpy as np
import pytest

from conftest import acoustic_xml, frame_matrix, rectangle_xml, scene_xml, sonar_xml, sphere_xml


def corner_scene(mitsonar_mod, share=None, pattern="gaussian", kind="multibeam", sampling="sobol"):
    """A small box_fls-like frame: a tilted multibeam head (24 beams of 3 deg, stepping -2 deg:
    a mirrored fan) over a floor z = -2 meeting a wall x = 6 (a dihedral corner: two-bounce echoes)
    and a sphere on the floor."""
    head = frame_matrix((1.0, 0.0, -0.3), (0.0, 0.0, 1.0))
    params = dict(kind=kind, range_min=0.5, range_max=9.0, n_bins=34, bearing_start=23.0,
                  bearing_step=-2.0, n_pings=24, beam_pattern=pattern, beamwidth_h=3.0, beamwidth_v=20.0)
    if kind != "multibeam":
        params.pop("bearing_step")
    floor = np.diag([8.0, 8.0, 1.0, 1.0])
    floor[:3, 3] = (2.0, 0.0, -2.0)
    wall = np.eye(4)
    wall[:3, :3] = [[0, 0, -1], [0, 1, 0], [1, 0, 0]]   # normal -x
    wall[:3, :3] = wall[:3, :3] @ np.diag([2.0, 8.0, 1.0])
    wall[:3, 3] = (6.0, 0.0, 0.0)
    bsdf = acoustic_xml(diffuse=0.6, specular=0.3, shininess=20.0)
    extra = "" if share is None else f'<boolean name="share_beams" value="{str(share).lower()}"/>'
    integ = (f'<integrator type="sonar_tof"><integer name="max_depth" value="2"/>'
             f'<string name="sampling" value="{sampling}"/>{extra}</integrator>')
    return mitsonar_mod.load_scene(scene_xml(sonar_xml(head, **params), rectangle_xml(floor, bsdf),
                                             rectangle_xml(wall, bsdf), sphere_xml((4.0, -1.0, -1.5), 0.5, bsdf),
                                             integrator=integ))


def test_shared_paths_agree_with_per_row_paths_within_monte_carlo_error(mitsonar_mod):
    """Cells of 4 rows x 5 bins (the 24 holding > 1e-3 of the brightest), each estimator rendered
    with 16 seeds at spp 64: z = (mean_shared - mean_per_row) / sqrt(se_shared^2 + se_per_row^2).
    With 16 seeds per side the z of an unbiased pair is about Student-t with ~30 degrees of freedom:
    |z| > 5 has probability ~2e-5 per cell, ~5e-4 for the worst of 24 (measured over 6 seed sets:
    worst |z| 1.9 to 3.8); a beam scored in the wrong row (one row off, or a mirrored fan) or a
    factor n_rows moves whole cells by far more. The totals also agree within 3 % (their own
    standard error is about 1 %). Cells fainter than 1e-3 of the brightest (the far elevation tails
    of both beams, ~1e-5 of the peak) are left out: there both estimators sample the tails at the
    float32 resolution of the beams' sampling tables (plugins/sensors/beam.py)."""
    import mitsuba as mi

    scene = corner_scene(mitsonar_mod)
    sensor = scene.sensors()[0]
    out = {}
    for share in (False, True):
        integ = mi.load_dict({"type": "sonar_tof", "max_depth": 2, "share_beams": share})
        runs = np.array([integ.render_histogram(scene, sensor, seed=10 * s + 1, spp=64) for s in range(16)])
        cells = runs[:, :, :30].reshape(16, 6, 4, 6, 5).sum(axis=(2, 4))
        out[share] = (cells.mean(0), cells.std(0, ddof=1) / 4.0, runs.sum(axis=(1, 2)))
    (m0, s0, t0), (m1, s1, t1) = out[False], out[True]
    lit = m0 > 1e-3 * m0.max()
    assert lit.sum() >= 12        # the test looks at echoes, not at empty cells
    z = (m1 - m0)[lit] / np.sqrt(s0[lit] ** 2 + s1[lit] ** 2)
    assert np.abs(z).max() < 5.0, z
    assert t1.mean() == pytest.approx(t0.mean(), rel=0.03)


def test_shared_paths_cut_the_error_of_a_frame(mitsonar_mod):
    """At equal spp (equal paths per frame) the shared estimator's relative L2 error against a
    high-spp reference is below the per-row one's: measured 0.74-0.83x on this scene (3 seeds per
    error, four seed sets; 3 deg beams 2 deg apart share each echo with only a few neighbours),
    0.52-0.68x on quay_wall and box_fls (benchmarks/render.py). Bound: < 0.9x with the mean of 6."""
    import mitsuba as mi

    scene = corner_scene(mitsonar_mod)
    sensor = scene.sensors()[0]
    ref = mi.load_dict({"type": "sonar_tof", "max_depth": 2}).render_histogram(scene, sensor, seed=99, spp=8192)

    def err(share):
        integ = mi.load_dict({"type": "sonar_tof", "max_depth": 2, "share_beams": share})
        return np.mean([np.linalg.norm(integ.render_histogram(scene, sensor, seed=s, spp=64) - ref)
                        for s in range(6)]) / np.linalg.norm(ref)

    assert err(True) < 0.9 * err(False)


@pytest.mark.parametrize("sampling", ["sobol", "independent"])
def test_same_seed_same_scan_whatever_the_passes(mitsonar_mod, monkeypatch, sampling):
    import mitsuba as mi

    from mitsonar.plugins.integrators import sonar_tof

    scene = corner_scene(mitsonar_mod, share=True, sampling=sampling)
    a = mi.render(scene, seed=5, spp=48).numpy()
    b = mi.render(scene, seed=5, spp=48).numpy()
    np.testing.assert_array_equal(a, b)
    assert np.abs(mi.render(scene, seed=6, spp=48).numpy() - a).max() > 0
    # the frame's path i is the same path whether the render takes one pass or three
    integ, sensor = scene.integrator(), scene.sensors()[0]
    one = integ.render_histogram(scene, sensor, seed=5, spp=48)
    monkeypatch.setattr(sonar_tof, "MAX_SPP_PER_PASS", 16)
    np.testing.assert_allclose(integ.render_histogram(scene, sensor, seed=5, spp=48), one, rtol=1e-6, atol=0)
    np.testing.assert_allclose(one, a[..., 0], rtol=1e-6)


def test_heads_that_cannot_share_are_refused_in_one_line(mitsonar_mod, monkeypatch):
    from mitsonar.plugins.integrators.paths import shared_beams

    def render(scene):
        return scene.integrator().render_histogram(scene, 0, spp=4)

    with pytest.raises(ValueError, match="'share_beams': only for a sensor of kind 'multibeam'"):
        render(corner_scene(mitsonar_mod, share=True, kind="mechanical"))
    with pytest.raises(ValueError, match="'share_beams': a 'sinc' receive beam"):
        render(corner_scene(mitsonar_mod, share=True, pattern="sinc"))
    monkeypatch.setattr(shared_beams, "MAX_BEAMS", 6)   # 3 deg beams 2 deg apart: 7 per echo
    with pytest.raises(ValueError, match="'share_beams': each echo would reach 7 receive beams"):
        render(corner_scene(mitsonar_mod, share=True))
    with pytest.raises(Exception, match="share_beams"):
        mitsonar_mod.load_scene(scene_xml(sonar_xml(kind="multibeam", n_pings=4),
                                          integrator='<integrator type="sonar_tof">'
                                          '<string name="share_beams" value="yes"/></integrator>'))


def test_per_row_poses_fall_back_to_per_row_paths(mitsonar_mod):
    """A moving head gives each row its own pose: no frame to share, the per-row paths are traced
    (same result as share_beams false); equal per-row poses share."""
    import mitsuba as mi

    scene = corner_scene(mitsonar_mod)
    sensor = scene.sensors()[0]
    head = sensor.head_pose()
    poses = np.repeat(head[None], sensor.n_pings, axis=0)
    poses[:, 0, 3] = np.linspace(0.0, 0.2, sensor.n_pings)
    plain = mi.load_dict({"type": "sonar_tof", "max_depth": 2})
    shared = mi.load_dict({"type": "sonar_tof", "max_depth": 2, "share_beams": True})
    np.testing.assert_array_equal(shared.render_histogram(scene, sensor, seed=2, spp=16, pose=poses),
                                  plain.render_histogram(scene, sensor, seed=2, spp=16, pose=poses))
    same = np.repeat(head[None], sensor.n_pings, axis=0)
    np.testing.assert_array_equal(shared.render_histogram(scene, sensor, seed=2, spp=16, pose=same),
                                  shared.render_histogram(scene, sensor, seed=2, spp=16))


def test_shared_rows_follow_receive_beam_times_transmit_fan(mitsonar_mod):
    """Ladder 3 of test_physics.py with share_beams: 49 receive rows of 6 deg at 0.25 deg steps
    under a 30 deg gaussian fan, a small sphere on the axis; each row's echo against the
    quadrature of B_tx B_rx over the sphere (absolute units), |z| < 4 with the same error floor
    (1.5 % of the reference). Every echo here reaches all 49 rows (the every-row branch)."""
    from test_physics import fan_rows_against_sphere

    share = '<boolean name="share_beams" value="true"/>'
    _, _, z, _, _ = fan_rows_against_sphere(mitsonar_mod, range(6), 1 << 13, integrator_extra=share)
    assert np.max(np.abs(z)) < 4.0, f"max |z| = {np.max(np.abs(z)):.2f}"
