"""Refracted transport (issue 40, item 2): echo paths through a sound-speed profile
(``plugins/integrators/paths/refraction.py``) against the closed forms of `SoundSpeedProfile` (exact circular arcs
per constant-gradient layer): echo ranges over a flat seabed per beam, the position where a
refracted beam lands (a target there echoes, one on the straight beam's footprint does not), the
straight-ray scan from a constant profile at the sensor's speed, every kind of head, a moving
head, and the one-line refusals (bad CSV through the XML path, integrators and modes without
refraction)."""
import math
import os

import numpy as np
import pytest
from conftest import acoustic_xml, frame_matrix, rectangle_xml, scene_xml, sonar_xml, sphere_xml

from mitsonar.acoustics import SoundSpeedProfile

C_SENSOR = 1500.0
LINEAR = SoundSpeedProfile([0.0, 200.0], [1450.0, 1650.0])      # c(z) = 1450 + 1.0 z
HEAD, SEABED = 2.0, 30.0
# per-row multibeam paths: every beam gets its spp (shared paths favour the inner beams, whose
# outer echo peaks then wander by a few bins, refracted or not)
PER_ROW = {"type": "sonar_tof", "max_depth": 1, "share_beams": False}


def flat_seabed_scene(mitsonar, sensor, integrator='<integrator type="sonar_tof"><integer name="max_depth" value="1"/></integrator>'):
    floor = np.diag([400.0, 400.0, 1.0, 1.0])
    floor[2, 3] = -SEABED
    return mitsonar.load_scene(scene_xml(sensor, rectangle_xml(floor, acoustic_xml(diffuse=0.5)), integrator=integrator))


def echo_sounder(n_beams=9, bin_width=0.05, range_max=60.0):
    from mitsonar.scenes import echosounders

    head = echosounders.configure("r2sonic_2024", swath=100.0, n_beams=n_beams, range_max=range_max,
                                  bin_width=bin_width)
    pose = np.array(head.mount, float)
    pose[2, 3] = -HEAD
    return head, echosounders.sonar_xml(head), pose


def peak_ranges(scan):
    return scan.ranges[np.argmax(scan.intensity, axis=1)]


def beam_angles(scan):
    """Each row's boresight angle from the vertical (rad)."""
    return np.arccos(np.clip(-scan.poses[:, 2, 2], -1.0, 1.0))


def refracted_range(profile, angle, depth=SEABED, head=HEAD):
    """The closed-form range of a beam at ``angle`` from the vertical: sensor speed x one-way time
    of the exact ray (arcs per layer) down to the seabed."""
    return C_SENSOR * profile.trace(head, math.pi / 2 - angle, to_depth=depth, samples=0).time[-1]


def centroids(scan):
    w = scan.intensity.astype(float)
    return (w * scan.ranges).sum(axis=1) / w.sum(axis=1)


def test_flat_seabed_echo_ranges_follow_the_linear_profile_closed_form(mitsonar_mod):
    head, sensor, pose = echo_sounder()
    scene = flat_seabed_scene(mitsonar_mod, sensor)
    scan = mitsonar_mod.render_scan(scene, spp=1024, seed=1, pose=pose, sound_speed_profile=LINEAR, integrator=PER_ROW)
    ang = beam_angles(scan)
    bin_w = scan.ranges[1] - scan.ranges[0]
    expected = np.array([refracted_range(LINEAR, a) for a in ang])
    straight = (SEABED - HEAD) / np.cos(ang)
    assert np.all(np.abs(expected - straight) > 8 * bin_w)       # the profile matters at every beam
    np.testing.assert_array_less(np.abs(peak_ranges(scan) - expected), 1.5 * bin_w)
    # the sensor's nominal speed is still what the scan records
    assert scan.sound_speed == C_SENSOR
    # the frame's paths shared between the beams (each echo scored into the beams that hear its
    # eigenray's arrival, the default for a still multibeam head): the same echoes
    shared = mitsonar_mod.render_scan(scene, spp=1024, seed=1, pose=pose, sound_speed_profile=LINEAR)
    np.testing.assert_array_less(np.abs(centroids(shared) - centroids(scan)), 1.5 * bin_w)
    np.testing.assert_allclose(shared.intensity.sum(axis=1), scan.intensity.sum(axis=1), rtol=0.1)


def test_a_constant_profile_at_the_sensor_speed_is_the_straight_scan_and_another_speed_scales_time(mitsonar_mod):
    head, sensor, pose = echo_sounder()
    scene = flat_seabed_scene(mitsonar_mod, sensor)
    plain = mitsonar_mod.render_scan(scene, spp=256, seed=4, pose=pose)
    same = mitsonar_mod.render_scan(scene, spp=256, seed=4, pose=pose,
                                    sound_speed_profile=SoundSpeedProfile.constant(C_SENSOR))
    np.testing.assert_array_equal(same.intensity, plain.intensity)
    np.testing.assert_array_equal(same.data, plain.data)
    # uniform water at 1470 m/s: straight rays, times longer by 1500/1470, ranges too
    slow = mitsonar_mod.render_scan(scene, spp=1024, seed=4, pose=pose, integrator=PER_ROW,
                                    sound_speed_profile=SoundSpeedProfile.constant(1470.0))
    ang = beam_angles(slow)
    bin_w = slow.ranges[1] - slow.ranges[0]
    np.testing.assert_array_less(np.abs(peak_ranges(slow) - C_SENSOR / 1470.0 * (SEABED - HEAD) / np.cos(ang)),
                                 1.5 * bin_w)


def pencil_scene(mitsonar, target, grazing, integrator=None):
    """A one-ping 1 deg pencil beam from depth HEAD launched ``grazing`` below the horizontal
    along +x, and a 0.15 m sphere at ``target`` (world x, z)."""
    bore = (math.cos(grazing), 0.0, -math.sin(grazing))
    sensor = sonar_xml(frame_matrix(bore, (0.0, 0.0, 1.0), (0.0, 0.0, -HEAD)), n_pings=1, beamwidth_h=1.0,
                       beamwidth_v=1.0, range_max=100.0, n_bins=1000)
    ball = sphere_xml((target[0], 0.0, target[1]), 0.15, acoustic_xml(diffuse=0.8))
    return mitsonar.load_scene(scene_xml(sensor, ball, integrator=integrator or
                                         '<integrator type="sonar_tof"><integer name="max_depth" value="1"/></integrator>'))


def test_a_target_where_the_refracted_beam_lands_echoes_and_one_on_the_straight_footprint_does_not(mitsonar_mod):
    grazing, t = math.radians(10.0), 0.06
    # the sphere's near side where the exact ray is after t (its centre 0.15 m further along)
    c_front = float(LINEAR.speed(LINEAR.locate(HEAD, grazing, t)[1]))
    x_r, z_r = LINEAR.locate(HEAD, grazing, t + 0.15 / c_front)
    r_straight = C_SENSOR * t + 0.15
    x_s, z_s = r_straight * math.cos(grazing), HEAD + r_straight * math.sin(grazing)
    assert math.hypot(x_r - x_s, z_r - z_s) > 2.0       # apart by more than the beam's footprint there
    on_arc = pencil_scene(mitsonar_mod, (float(x_r), -float(z_r)), grazing)
    on_line = pencil_scene(mitsonar_mod, (x_s, -z_s), grazing)
    bent = mitsonar_mod.render_scan(on_arc, spp=4096, seed=2, sound_speed_profile=LINEAR)
    bin_w = bent.ranges[1] - bent.ranges[0]
    assert bent.intensity.max() > 0
    assert abs(peak_ranges(bent)[0] - C_SENSOR * t) < 1.5 * bin_w
    missed = mitsonar_mod.render_scan(on_line, spp=4096, seed=2, sound_speed_profile=LINEAR)
    assert missed.intensity.max() < 1e-4 * bent.intensity.max()
    # and without the profile it is the other way round
    straight = mitsonar_mod.render_scan(on_line, spp=4096, seed=2)
    assert straight.intensity.max() > 0.1 * bent.intensity.max()
    assert mitsonar_mod.render_scan(on_arc, spp=4096, seed=2).intensity.max() < 1e-4 * straight.intensity.max()


@pytest.mark.parametrize("kind", ["mechanical", "sidescan", "pa500"])
def test_every_kind_refracts(mitsonar_mod, kind):
    """A mechanical head pinging down at 30 deg, a side-scan head (both channels) and the
    single-beam altimeter see the flat seabed at the closed-form refracted range."""
    if kind == "pa500":
        from mitsonar.scenes import echosounders

        head = echosounders.configure("tritech_pa500", range_max=40.0, bin_width=0.05)
        sensor = echosounders.sonar_xml(head)
        pose = np.array(head.mount, float)
        pose[2, 3] = -HEAD
    elif kind == "mechanical":
        pose = frame_matrix((math.sin(math.radians(30.0)), 0.0, -math.cos(math.radians(30.0))), (0.0, 1.0, 0.0),
                            (0.0, 0.0, -HEAD))
        sensor = sonar_xml(None, n_pings=3, bearing_start=-2.0, bearing_step=2.0, beamwidth_h=1.0, beamwidth_v=1.0,
                           range_max=40.0, n_bins=800)
    else:
        pose = np.eye(4)       # the head frame: x along track, y port, z up
        pose[2, 3] = -HEAD
        sensor = sonar_xml(None, kind="sidescan", n_pings=2, depression=60.0, beamwidth_v=60.0, range_max=60.0,
                           n_bins=1200)
    scene = flat_seabed_scene(mitsonar_mod, sensor)
    scan = mitsonar_mod.render_scan(scene, spp=2048, seed=3, pose=pose, sound_speed_profile=LINEAR)
    bin_w = scan.ranges[1] - scan.ranges[0]
    if kind == "sidescan":     # the first echo of each channel: its nearest seabed point, straight below
        first = scan.ranges[np.argmax(scan.intensity > 1e-3 * scan.intensity.max(axis=1, keepdims=True), axis=1)]
        expected = refracted_range(LINEAR, 0.0)
        assert np.all(first >= expected - 1.5 * bin_w) and np.all(first < expected + 6 * bin_w), (first, expected)
        return
    expected = np.array([refracted_range(LINEAR, a) for a in beam_angles(scan)])
    np.testing.assert_array_less(np.abs(peak_ranges(scan) - expected), 1.5 * bin_w)


def test_a_moving_head_refracts_at_each_ping(mitsonar_mod):
    """A mechanical pencil beam on a vehicle diving from 2 m to 12 m: every ping from its own
    depth, at its own closed-form range."""
    from mitsonar.geometry.trajectory import Trajectory

    mount = frame_matrix((math.sin(math.radians(30.0)), 0.0, -math.cos(math.radians(30.0))), (0.0, 1.0, 0.0))
    sensor = sonar_xml(mount, n_pings=12, bearing_step=0.01, beamwidth_h=1.0, beamwidth_v=1.0, range_max=40.0,
                       n_bins=800)
    scene = flat_seabed_scene(mitsonar_mod, sensor)
    poses = np.tile(np.eye(4), (2, 1, 1))
    poses[:, 2, 3] = [-HEAD, -HEAD - 10.0]
    traj = Trajectory([0.0, 2.0], poses)
    scan = mitsonar_mod.render_scan(scene, spp=1024, seed=5, trajectory=traj, sound_speed_profile=LINEAR)
    depth = -scan.poses[:, 2, 3]
    assert depth.max() - depth.min() > 4.0
    expected = np.array([refracted_range(LINEAR, a, head=d) for a, d in zip(beam_angles(scan), depth)])
    bin_w = scan.ranges[1] - scan.ranges[0]
    np.testing.assert_array_less(np.abs(peak_ranges(scan) - expected), 1.5 * bin_w)


# ---------------------------------------------------------------------------------------------
# the XML parameter and the refusals

def scene_file(tmp_path, csv_text, integrator="sonar_tof"):
    head, sensor, pose = echo_sounder(n_beams=3)
    (tmp_path / "water").mkdir(exist_ok=True)
    (tmp_path / "water" / "svp.csv").write_text(csv_text)
    floor = np.diag([400.0, 400.0, 1.0, 1.0])
    floor[2, 3] = -SEABED
    xml = scene_xml(sensor, rectangle_xml(floor, acoustic_xml(diffuse=0.5)),
                    integrator=f'<integrator type="{integrator}"><integer name="max_depth" value="1"/>'
                               '<string name="sound_speed_profile" value="water/svp.csv"/></integrator>')
    path = tmp_path / "scene.xml"
    path.write_text(xml)
    return str(path), pose


def test_the_xml_profile_is_a_csv_relative_to_the_scene_file(mitsonar_mod, tmp_path):
    path, pose = scene_file(tmp_path, "depth,sound_speed\n0,1450\n200,1650\n")
    cwd = os.getcwd()
    try:
        os.chdir(os.path.dirname(os.path.dirname(__file__)))     # not the scene's folder
        scene = mitsonar_mod.load_scene(path)
    finally:
        os.chdir(cwd)
    scan = mitsonar_mod.render_scan(scene, spp=512, seed=1, pose=pose)
    direct = mitsonar_mod.render_scan(flat_seabed_scene(mitsonar_mod, echo_sounder(n_beams=3)[1]), spp=512, seed=1,
                                      pose=pose, sound_speed_profile=LINEAR)
    np.testing.assert_array_equal(scan.intensity, direct.intensity)


@pytest.mark.parametrize("text, message", [
    ("depth,sound_speed\n0,1500\n12,1490\n10,1495\n", "row 4: depth 10.0 m is not greater than the previous 12.0 m"),
    ("depth,sound_speed\n0,1500\n5,nan\n", "row 3: sound_speed nan is not a finite number"),
    ("depth,sound_speed\n0,1500\n5,1750\n", "row 3: sound_speed 1750 m/s is outside 1300 to 1700 m/s"),
    ("", "empty file"),
])
def test_a_bad_xml_profile_is_one_line_naming_the_file_row_and_field(mitsonar_mod, tmp_path, text, message):
    path, _ = scene_file(tmp_path, text)
    with pytest.raises(mitsonar_mod.SceneError) as err:
        mitsonar_mod.load_scene(path)
    line = str(err.value)
    assert "\n" not in line and str(tmp_path / "water" / "svp.csv") in line and message in line, line


def test_integrators_and_modes_without_refraction_refuse_a_profile_in_one_line(mitsonar_mod, tmp_path):
    path, _ = scene_file(tmp_path, "depth,sound_speed\n0,1450\n200,1650\n", integrator="sonar_mlt")
    with pytest.raises(mitsonar_mod.SceneError, match="sonar_mlt 'sound_speed_profile': refracted paths are traced by "
                                                      "the sonar_tof integrator only"):
        mitsonar_mod.load_scene(path)
    head, sensor, pose = echo_sounder(n_beams=3)
    scene = flat_seabed_scene(mitsonar_mod, sensor)
    with pytest.raises(mitsonar_mod.SceneError, match="sonar_tof integrator only, not SonarMLTIntegrator"):
        mitsonar_mod.render_scan(scene, spp=16, pose=pose, integrator="sonar_mlt", sound_speed_profile=LINEAR)
    with pytest.raises(mitsonar_mod.SceneError, match="expected a mitsonar.acoustics.SoundSpeedProfile, got list"):
        mitsonar_mod.render_scan(scene, spp=16, pose=pose, sound_speed_profile=[1500.0])
    with pytest.raises(mitsonar_mod.SceneError, match="'svp_chords': 0 is not allowed"):
        mitsonar_mod.render_scan(scene, spp=16, pose=pose, integrator={"type": "sonar_tof", "svp_chords": 0})


def _integrator_plugins():
    from mitsonar.sim.render import sonar_integrators

    return list(sonar_integrators())


@pytest.mark.parametrize("name", _integrator_plugins())
def test_every_integrator_honours_or_refuses_a_profile(mitsonar_mod, tmp_path, name):
    """Issue 56: ``sonar_bdpt`` took a profile (XML and ``render_scan``) and rendered the straight
    scan byte for byte. Every integrator plugin either renders another scan through the profile
    than without it, or refuses it in one line naming itself, before any work."""
    path, pose = scene_file(tmp_path, "depth,sound_speed\n0,1450\n200,1650\n", integrator=name)
    plain = f'<integrator type="{name}"><integer name="max_depth" value="1"/></integrator>'
    straight = mitsonar_mod.render_scan(flat_seabed_scene(mitsonar_mod, echo_sounder(n_beams=3)[1], plain),
                                        spp=64, seed=1, pose=pose).intensity
    try:
        scene = mitsonar_mod.load_scene(path)
    except mitsonar_mod.SceneError as exc:
        line = str(exc)
        assert "\n" not in line and f"{name} 'sound_speed_profile'" in line and str(tmp_path) in line, line
    else:
        bent = mitsonar_mod.render_scan(scene, spp=64, seed=1, pose=pose).intensity
        assert not np.array_equal(bent, straight), f"{name} ignored the XML sound_speed_profile"
    scene = flat_seabed_scene(mitsonar_mod, echo_sounder(n_beams=3)[1], plain)
    try:
        bent = mitsonar_mod.render_scan(scene, spp=64, seed=1, pose=pose, sound_speed_profile=LINEAR).intensity
    except mitsonar_mod.SceneError as exc:
        line = str(exc)
        assert "\n" not in line and "render_scan 'sound_speed_profile'" in line and type(
            scene.integrator()).__name__ in line, line
    else:
        assert not np.array_equal(bent, straight), f"{name} ignored render_scan's sound_speed_profile"


def test_gradients_refuse_a_profile_in_one_line(mitsonar_mod, tmp_path):
    import drjit as dr
    import mitsuba as mi

    if not dr.is_diff_v(mi.Float):
        pytest.skip("needs an AD variant")
    path, _ = scene_file(tmp_path, "depth,sound_speed\n0,1450\n200,1650\n")
    scene = mitsonar_mod.load_scene(path)
    params = mitsonar_mod.scan_parameters(scene, "echosounder.absorption")
    dr.enable_grad(params["echosounder.absorption"])
    for render in (scene.integrator().render_forward, lambda s, p, spp: scene.integrator().render_backward(
            s, p, dr.zeros(mi.TensorXf, (3, scene.sensors()[0].n_bins, 1)), spp=spp)):
        with pytest.raises(ValueError, match="gradients of a render through a sound_speed_profile are not implemented"):
            render(scene, params, spp=4)


# ---------------------------------------------------------------------------------------------
# the Dr.Jit ray functions against the float64 closed forms

LAYERED = SoundSpeedProfile([0.0, 2, 4, 6, 8, 10, 12, 14, 16, 18, 20, 23, 26, 29, 32, 35, 40, 50, 70, 100],
                            np.interp([0.0, 2, 4, 6, 8, 10, 12, 14, 16, 18, 20, 23, 26, 29, 32, 35, 40, 50, 70, 100],
                                      [0, 10, 40, 100], [1520.0, 1519.0, 1490.0, 1491.0]))


def refraction_of(profile):
    import mitsonar  # noqa: F401  (the variant and the plugins)
    from mitsonar.plugins.integrators.paths import refraction

    class Head:
        sound_speed, range_max = C_SENSOR, 100.0

    return refraction.from_profile(profile, Head())


@pytest.mark.parametrize("series", [False, True], ids=["goldberg", "series"])
def test_log1p_over_y_has_no_cancellation_either_way(series):
    """`log1p_over` by Goldberg's quotient (llvm) and by the atanh series below |y| = 0.25 (what
    cuda uses: its float32 log is approximate) against float64, from -0.9 to 3 and near 0:
    within 6e-7 relative (1.9e-7 on llvm, 4.1e-7 on an H100, whose log is approximate above 0.25
    too; Goldberg's quotient there: 2.5e-2)."""
    import mitsuba as mi

    from conftest import on_cuda
    from mitsonar.plugins.integrators.paths.refraction import log1p_over

    if on_cuda() and not series:
        pytest.skip("Goldberg's quotient needs a correctly rounded log: cuda's float32 log is approximate")
    y = np.concatenate([np.linspace(-0.9, 3.0, 200001), [1e-8, -1e-8, 1e-4, -1e-4, 0.0]]).astype(np.float32)
    y64 = y.astype(np.float64)
    ref = np.ones_like(y64)
    nz = y64 != 0
    ref[nz] = np.log1p(y64[nz]) / y64[nz]
    got = log1p_over(mi.Float(y), series=series).numpy()
    assert np.abs(got / ref - 1).max() < 6e-7


@pytest.mark.parametrize("profile", [LINEAR, LAYERED], ids=["linear", "20 layers"])
def test_advance_is_locate_and_keeps_snell_invariant(profile):
    """The ray state after a time ``tau`` (`Refraction.advance`, float32, layer by layer) is
    `SoundSpeedProfile.locate`'s (float64), through turning points too, and cos(grazing) / c is
    the launch's at every step."""
    import mitsuba as mi

    refr = refraction_of(profile)
    grazing = np.radians([-40.0, -5.0, 3.0, 10.0, 30.0, 60.0, 85.0])
    z0 = np.array([2.0, 15.0, 2.0, 6.0, 1.0, 33.0, 2.0])
    c0 = profile.speed(z0)
    a = np.cos(grazing) / c0
    z, s, down, x = mi.Float(z0), mi.Float(np.sin(grazing)), mi.Bool(np.sin(grazing) >= 0), np.zeros_like(z0)
    for k in range(1, 9):     # eight steps of 5 ms
        dx, z, s, down, ok, _ = refr.advance(z, s, down, mi.Float(a), mi.Float(0.005))
        x += dx.numpy()
        assert ok.numpy().all()
        xe, ze = profile.locate(z0, grazing, 0.005 * k)
        np.testing.assert_allclose(x, xe, rtol=2e-5, atol=2e-4)
        np.testing.assert_allclose(z.numpy(), ze, rtol=2e-5, atol=2e-4)
        # (not the 85 deg ray: a float32 sine of 0.996 holds its cosine to 1e-7 / cos^2 only)
        cos = np.sqrt(1.0 - np.square(s.numpy().astype(float)))
        inv = cos / profile.speed(z.numpy().astype(float))
        np.testing.assert_allclose(inv[:-1], a[:-1], rtol=1e-5)


def test_near_horizontal_eigenrays_are_found_with_their_time():
    """Points reached by rays launched 0.5-5 deg below the horizontal (float64 `trace`, out to
    280 m): every eigenray is found and its time is trace's within 1e-5. Before the sines were
    formed without cancellation (`_sin_below`) the 0.5 deg points were declared unreachable and
    the times were up to 9e-4 off (13 cm of range at 280 m) in float32."""
    import mitsuba as mi

    refr = refraction_of(LAYERED)
    launch = np.radians([0.5, 1.0, 2.0, 3.0, 5.0])
    for head, dz in ((2.0, 1.0), (2.0, 3.0), (20.0, 1.0), (40.0, 2.0)):
        ends = [LAYERED.trace(head, th, to_depth=head + dz, samples=0) for th in launch]
        X = np.array([r.x[-1] for r in ends])
        T = np.array([r.time[-1] for r in ends])
        p = mi.Point3f(X.astype(np.float32), np.zeros(len(X)), np.full(len(X), -(head + dz)))
        o = mi.Point3f(np.zeros(len(X)), np.zeros(len(X)), np.full(len(X), -head))
        ok, t, *_ = refr.eigenray(p, o, mi.Bool(True))
        assert ok.numpy().all(), (head, dz, X)
        np.testing.assert_allclose(t.numpy(), T, rtol=1e-5)


def test_the_eigenray_joins_the_two_points_with_trace_s_time_and_angle():
    """A ray traced (float64) from the head to a point: the eigenray solved back from that point
    has the same one-way time, and its arrival at the head is the launch direction."""
    import mitsuba as mi

    refr = refraction_of(LAYERED)
    head = 2.0
    launch = np.radians([5.0, 20.0, 45.0, 70.0, 89.0])
    ends = [LAYERED.trace(head, th, to_depth=60.0, samples=0) for th in launch]
    X = np.array([r.x[-1] for r in ends])
    T = np.array([r.time[-1] for r in ends])
    p = mi.Point3f(X.astype(np.float32), np.zeros(len(X)), np.full(len(X), -60.0))
    o = mi.Point3f(np.zeros(len(X)), np.zeros(len(X)), np.full(len(X), -head))
    ok, t, length, back, rx = refr.eigenray(p, o, mi.Bool(True))
    assert ok.numpy().all()
    np.testing.assert_allclose(t.numpy(), T, rtol=1e-5)     # 0.25 s to a microsecond: float32
    # from the head towards +x and down at the launch angle
    np.testing.assert_allclose(np.arctan2(-rx.z.numpy(), rx.x.numpy()), launch, atol=2e-4)
    assert (length.numpy() >= np.hypot(X, 58.0) - 1e-3).all()     # an arc is no shorter than its chord
    # a point no direct ray reaches: 1 m below the head and 300 m away in c = 1450 + z, where the
    # ray from it that arrives horizontally (an arc of radius c / g = 1460 m) has gone 54 m only
    linear = refraction_of(LINEAR)
    assert not linear.eigenray(mi.Point3f(300.0, 0.0, -10.0), mi.Point3f(0.0, 0.0, -9.0), mi.Bool(True))[0].numpy().any()
    assert linear.eigenray(mi.Point3f(50.0, 0.0, -10.0), mi.Point3f(0.0, 0.0, -9.0), mi.Bool(True))[0].numpy().all()


# ---------------------------------------------------------------------------------------------
# the bathymetry CLI: a survey rendered in one water, processed with another

def test_cli_svp_renders_the_water_and_processing_with_it_corrects_the_soundings(tmp_path, capsys):
    """``--svp`` renders the survey in c = 1450 + z: processed straight at the head's nominal
    1500 m/s the soundings are ~20 cm too deep; ``--processing-svp`` with the same file brings
    them to the uniform-water error. A bad ``--svp`` is one line before any render."""
    import json

    from conftest import SCENES

    from mitsonar.cli import main

    svp = tmp_path / "true.csv"
    LINEAR.to_csv(svp)
    args = ["bathymetry", os.path.join(SCENES, "rocky_slope.xml"), "--trajectory",
            os.path.join(SCENES, "rocky_slope_survey.tum"), "--beams", "16", "--max-scans", "2", "--spp", "32",
            "--range-max", "20", "--bin-width", "0.025", "--max-depth", "1", "-q", "--svp", str(svp)]
    assert main(args + ["-o", str(tmp_path / "wrong")]) == 0
    assert main(args + ["-o", str(tmp_path / "right"), "--processing-svp", str(svp)]) == 0
    wrong, right = (json.loads((tmp_path / d / "errors.json").read_text()) for d in ("wrong", "right"))
    assert wrong["svp"] == right["svp"] == str(svp)
    assert wrong["n_soundings"] > 15 and right["n_soundings"] > 15
    assert wrong["mean_error"] > 0.1 and wrong["rms_error"] > 0.1         # too deep (slower water, taken at 1500)
    assert right["rms_error"] < 0.1 * wrong["rms_error"]
    capsys.readouterr()
    svp.write_text("depth,sound_speed\n0,1500\n12,1490\n10,1495\n")
    out = tmp_path / "bad"
    assert main(args + ["-o", str(out)]) == 1
    err = capsys.readouterr().err.strip()
    assert err.count("\n") == 0 and f"{svp}, row 4: depth 10.0 m is not greater than the previous 12.0 m" in err, err
    assert not out.exists()


# ---------------------------------------------------------------------------------------------
# the approximations that make refracted renders fast, against their stated bounds

def test_merged_layers_stay_within_the_tolerance_and_move_travel_times_by_at_most_tol_over_c():
    """`merge_layers` drops samples within MERGE_TOL of the line between their kept neighbours:
    the merged profile is within the tolerance at every given depth, and a ray's travel time to
    the seabed moves by at most tol / c_min of itself (Fermat: the path's change is second order)."""
    from mitsonar.plugins.integrators.paths import refraction

    tol = refraction.MERGE_TOL
    rng = np.random.default_rng(5)
    depths = np.linspace(0.0, 80.0, 41)
    base = np.interp(depths, [0, 15, 45, 80], [1515.0, 1512.0, 1488.0, 1490.0])
    speeds = base + rng.uniform(-0.4, 0.4, depths.size) * tol          # rounding-level wiggles: merged
    speeds[20] += 3 * tol                                                # a real feature: kept
    md, ms = refraction.merge_layers(list(depths), list(speeds))
    assert len(md) < 12                                                  # merged: fewer layers to cross
    assert np.max(np.abs(np.interp(depths, md, ms) - speeds)) <= tol + 1e-9
    full, merged = SoundSpeedProfile(depths, speeds), SoundSpeedProfile(md, ms)
    for grazing in np.radians([20.0, 45.0, 70.0, 90.0]):
        t_full = full.trace(2.0, grazing, to_depth=75.0, samples=0).time[-1]
        t_merged = merged.trace(2.0, grazing, to_depth=75.0, samples=0).time[-1]
        assert abs(t_merged - t_full) <= tol / speeds.min() * t_full
    # exact collinear runs (a profile resampled from a few knots) are single layers
    assert refraction.merge_layers(list(LAYERED.depths), list(LAYERED.speeds))[0] == [0.0, 10.0, 40.0, 100.0]


def test_one_chord_per_window_gives_the_echo_ranges_of_sixty_four(mitsonar_mod):
    """The hit's time is one Newton step on the exact arc to the surface's plane, not the chord's
    linear-speed interpolation: the same seed's echoes land in the same place with 1 chord per
    window as with 64, through a thermocline whose kink the long chords cross (the interpolation
    alone moved them by 0.7 bins)."""
    head, sensor, pose = echo_sounder(bin_width=0.05, range_max=60.0)

    scene = flat_seabed_scene(mitsonar_mod, sensor)

    def scan(chords):
        return mitsonar_mod.render_scan(scene, spp=256, seed=3, pose=pose, sound_speed_profile=LAYERED,
                                        integrator=dict(PER_ROW, svp_chords=chords))

    one, many = scan(1), scan(64)
    bin_w = one.ranges[1] - one.ranges[0]
    np.testing.assert_array_less(np.abs(centroids(one) - centroids(many)), 0.05 * bin_w)
    expected = np.array([refracted_range(LAYERED, a) for a in beam_angles(one)])
    np.testing.assert_array_less(np.abs(peak_ranges(one) - expected), 1.5 * bin_w)


def test_another_profile_of_as_many_samples_reuses_the_kernels(mitsonar_mod):
    """The profile's values are opaque in the kernels (only its sample count shapes them): a
    second profile renders with the kernels the first compiled (it compiled new ones when the
    eigenray's layer sum held the speeds as literals)."""
    from conftest import jit_kernels

    scene = mitsonar_mod.load_scene(mitsonar_mod.example_scene("box"))

    def render(c):
        svp = mitsonar_mod.SoundSpeedProfile([0, 5, 10, 20], [1500, c, 1490, 1495])
        return mitsonar_mod.render_scan(scene, spp=16, seed=0, sound_speed_profile=svp)

    jit_kernels(render, 1480)  # the first render records what later ones replay
    warm, _ = jit_kernels(render, 1480)
    other, _ = jit_kernels(render, 1460)
    assert other == warm
