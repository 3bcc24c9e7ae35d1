"""Sound-speed profiles (issue 40, the numerical core): rays in a linear profile are the circular arcs
of the closed forms (and of a brute-force integration of the ray equations), Snell's invariant is
kept, `locate` inverts `trace` through many layers and across turning points, soundings processed
with the true profile are flat and those processed with a constant speed show the refraction error
the closed form predicts, a constant profile at the nominal speed gives the straight-ray soundings,
and bad profiles are refused in one line naming the file, the row and the field."""
import math
import os

import numpy as np
import pytest
from conftest import SCENES

from mitsonar.acoustics import ProfileError, SoundSpeedProfile

C0, G = 1480.0, 0.05            # a linear profile c(z) = C0 + G z (m/s, 1/s)
LINEAR = SoundSpeedProfile([0.0, 2000.0], [C0, C0 + 2000.0 * G])
LAYERS = SoundSpeedProfile([0.0, 5.0, 20.0, 50.0, 80.0, 200.0], [1500.0, 1490.0, 1478.0, 1485.0, 1495.0, 1497.0])


def linear_closed_form(z0, theta0, z, c0=C0, g=G):
    """Horizontal distance and time of a ray of the linear profile c0 + g z from depth z0 at grazing
    theta0 down to depth z (no turn): dx = (s1 - s2)/(a g), dt = ln[c2 (1 + s1) / (c1 (1 + s2))]/g."""
    c1, c2 = c0 + g * z0, c0 + g * z
    a = math.cos(theta0) / c1
    s1, s2 = math.sin(theta0), math.sqrt(1.0 - (a * c2) ** 2)
    return (s1 - s2) / (a * g), math.log(c2 * (1 + s1) / (c1 * (1 + s2))) / g


def brute_force(profile, z0, theta0, z1, steps_per_layer=4000):
    """RK4 of dx/dz = cot(theta), dt/dz = 1/(c sin(theta)), dtheta/dz = -c'(z) cos(theta)/(c sin(theta))
    from z0 down to z1, with the steps cut at the profile's samples (c' is piecewise constant)."""
    d, c = profile.depths, profile.speeds
    knots = np.unique(np.concatenate([[z0, z1], d[(d > z0) & (d < z1)]]))
    x = t = 0.0
    th = theta0
    for za, zb in zip(knots[:-1], knots[1:]):
        mid = 0.5 * (za + zb)
        k = np.searchsorted(d, mid)
        g = 0.0 if k in (0, len(d)) else (c[k] - c[k - 1]) / (d[k] - d[k - 1])

        def f(z, y):
            cz = profile.speed(z)
            s = math.sin(y[2])
            return np.array([math.cos(y[2]) / s, 1.0 / (cz * s), -g * math.cos(y[2]) / (cz * s)])

        y = np.array([x, t, th])
        h = (zb - za) / steps_per_layer
        z = za
        for _ in range(steps_per_layer):
            k1 = f(z, y)
            k2 = f(z + h / 2, y + h / 2 * k1)
            k3 = f(z + h / 2, y + h / 2 * k2)
            k4 = f(z + h, y + h * k3)
            y = y + h / 6 * (k1 + 2 * k2 + 2 * k3 + k4)
            z += h
        x, t, th = y
    return x, t


@pytest.mark.parametrize("theta_deg", [10.0, 30.0, 60.0, 89.0])
def test_linear_profile_rays_are_circles_with_the_closed_form_time_and_distance(theta_deg):
    th, z0, z1 = math.radians(theta_deg), 3.0, 150.0
    ray = LINEAR.trace(z0, th, to_depth=z1, samples=40)
    c0 = C0 + G * z0
    R = c0 / (G * math.cos(th))                       # radius c / (g cos theta)
    xc, zc = R * math.sin(th), z0 - c0 / G            # centre: on the depth where c extrapolates to 0
    assert len(ray.x) > 40
    np.testing.assert_allclose(np.hypot(ray.x - xc, ray.depth - zc) / R, 1.0, rtol=0, atol=1e-9)
    dx, dt = linear_closed_form(z0, th, z1)
    assert ray.depth[-1] == z1
    assert ray.x[-1] == pytest.approx(dx, rel=1e-9) and ray.time[-1] == pytest.approx(dt, rel=1e-9)
    bx, bt = brute_force(LINEAR, z0, th, z1)          # independent of the closed form
    assert bx == pytest.approx(dx, rel=1e-9) and bt == pytest.approx(dt, rel=1e-9)
    x, z = LINEAR.locate(z0, th, dt)
    assert x == pytest.approx(dx, rel=1e-9) and z == pytest.approx(z1, rel=1e-9)


@pytest.mark.parametrize("theta_deg", [5.0, 25.0, 70.0])
def test_many_layers_match_a_brute_force_integration(theta_deg):
    th, z0, z1 = math.radians(theta_deg), 2.0, 120.0
    bx, bt = brute_force(LAYERS, z0, th, z1)
    ray = LAYERS.trace(z0, th, to_depth=z1)
    assert ray.x[-1] == pytest.approx(bx, rel=1e-9) and ray.time[-1] == pytest.approx(bt, rel=1e-9)
    x, z = LAYERS.locate(z0, th, ray.time[-1])
    assert x == pytest.approx(bx, rel=1e-9) and z == pytest.approx(z1, rel=1e-9)


def test_snell_invariant_is_kept_along_every_path():
    for profile in (LINEAR, LAYERS):
        for z0, deg in [(0.0, 45.0), (2.0, 1.0), (12.0, 3.0), (30.0, -20.0), (8.0, 0.0), (60.0, 89.9), (10.0, 90.0)]:
            ray = profile.trace(z0, math.radians(deg), travel_time=0.3, samples=8)
            a = math.cos(math.radians(deg)) / profile.speed(z0)
            assert ray.invariant == pytest.approx(a, rel=1e-15, abs=1e-19)   # cos(pi/2) is 6e-17
            c = profile.speed(ray.depth)
            np.testing.assert_allclose(np.cos(ray.grazing), a * c, rtol=1e-12, atol=1e-15)
            assert np.all(np.diff(ray.time) > 0) and ray.time[-1] == pytest.approx(0.3, rel=1e-12)


def test_locate_inverts_trace_through_layers_and_turns():
    depths = [0.0, 2.0, 12.0, 30.0, 60.0]
    degs = [-60.0, -5.0, 0.0, 0.5, 2.0, 4.0, 10.0, 45.0, 80.0, 90.0]
    for z0 in depths:
        for deg in degs:
            ray = LAYERS.trace(z0, math.radians(deg), travel_time=0.25, samples=5)
            x, z = LAYERS.locate(z0, math.radians(deg), ray.time)      # vectorised over the times
            np.testing.assert_allclose(x, ray.x, rtol=0, atol=1e-9)
            np.testing.assert_allclose(z, ray.depth, rtol=0, atol=1e-9)
    # many beams at once: broadcast over start depth and angle
    th = np.radians(np.linspace(10, 90, 9))
    x, z = LAYERS.locate(np.array([[3.0], [7.0]]), th, 0.05)
    assert x.shape == z.shape == (2, 9)
    for i, z0 in enumerate([3.0, 7.0]):
        for k in range(9):
            r = LAYERS.trace(z0, th[k], travel_time=0.05, samples=0)
            assert (x[i, k], z[i, k]) == (pytest.approx(r.x[-1], abs=1e-9), pytest.approx(r.depth[-1], abs=1e-9))


def test_a_shallow_ray_turns_where_the_profile_says_and_comes_back():
    th, z0 = math.radians(5.0), 10.0
    c0 = LINEAR.speed(z0)
    a = math.cos(th) / c0
    z_turn = z0 + (1.0 / a - c0) / G                                # a c = 1
    R = c0 / (G * math.cos(th))
    T = 2.0 * math.log((1.0 / a) * (1.0 + math.sin(th)) / c0) / G    # down to the turn and back
    ray = LINEAR.trace(z0, th, travel_time=T)
    assert ray.depth.max() == pytest.approx(z_turn, rel=1e-12)
    assert ray.x[np.argmax(ray.depth)] == pytest.approx(R * math.sin(th), rel=1e-9)
    assert (ray.x[-1], ray.depth[-1], ray.grazing[-1]) == (pytest.approx(2 * R * math.sin(th), rel=1e-9),
                                                            pytest.approx(z0, abs=1e-9), pytest.approx(-th, abs=1e-9))
    x, z = LINEAR.locate(z0, th, [T / 2, T])
    np.testing.assert_allclose(x, [R * math.sin(th), 2 * R * math.sin(th)], rtol=1e-9)
    np.testing.assert_allclose(z, [z_turn, z0], rtol=1e-9)
    with pytest.raises(ProfileError, match="never reaches depth 200"):
        LINEAR.trace(z0, th, to_depth=200.0)


def test_constant_profiles_are_straight_rays():
    p = SoundSpeedProfile.constant(1500.0)
    th = np.radians([-30.0, 0.0, 20.0, 90.0])
    x, z = p.locate(4.0, th, 0.01)
    np.testing.assert_allclose(x, 15.0 * np.cos(th), atol=1e-12)
    np.testing.assert_allclose(z, 4.0 + 15.0 * np.sin(th), atol=1e-12)
    assert p.speed([-5.0, 0.0, 1e4]).tolist() == [1500.0] * 3
    assert LAYERS.speed([0.0, 2.5, 500.0]).tolist() == [1500.0, 1495.0, 1497.0]     # constant beyond the ends


# ---------------------------------------------------------------------------------------------
# soundings

def fan_scan(depth_seabed, profile, head_depth=2.0, angles=np.arange(-60, 61, 5.0), c_nominal=None, head_z=None,
             travel_times=None):
    """A synthetic multibeam frame over a flat seabed: each beam's echo (a narrow symmetric
    triangle) at the range ``c_nominal * t``, ``t`` the one-way time of its ray through
    ``profile`` down to the seabed (or the given ``travel_times``)."""
    from mitsonar.scan import Scan

    a = np.radians(angles)
    c_nominal = profile.speed(head_depth) if c_nominal is None else c_nominal
    if travel_times is None:
        travel_times = [profile.trace(head_depth, math.pi / 2 - abs(b), to_depth=depth_seabed, samples=0).time[-1]
                        for b in a]
    r_echo = c_nominal * np.asarray(travel_times)
    bin_w = 0.002
    ranges = 1.0 + bin_w * (np.arange(int(60.0 / bin_w)) + 0.5)
    intensity = np.maximum(0.0, 1.0 - np.abs(ranges[None, :] - r_echo[:, None]) / 0.03)
    poses = np.zeros((len(a), 4, 4))
    poses[:, 3, 3] = 1.0
    poses[:, :3, 0] = np.stack([0 * a, np.cos(a), np.sin(a)], 1)
    poses[:, :3, 1] = [1.0, 0.0, 0.0]
    poses[:, :3, 2] = np.stack([0 * a, np.sin(a), -np.cos(a)], 1)     # positive angles to port (+y)
    poses[:, :3, 3] = [5.0, -3.0, -head_depth if head_z is None else head_z]
    return Scan(intensity=intensity, data=np.zeros(intensity.shape, np.uint8), ranges=ranges, bearings=a,
                poses=poses, range_min=1.0, range_max=61.0, kind="multibeam", beamwidth_h=1.0, beamwidth_v=1.0,
                sound_speed=float(c_nominal))


def test_soundings_processed_with_the_true_profile_are_flat():
    from mitsonar.products.bathymetry import soundings

    D = 20.0
    for truth in (LAYERS, LINEAR):
        s = soundings(fan_scan(D, truth), sound_speed_profile=truth)
        assert len(s) == 25 and np.abs(s["angle"]).max() == pytest.approx(60.0)
        np.testing.assert_allclose(-s["z"], D, rtol=0.002)
        straight = soundings(fan_scan(D, truth))                # without the profile they are not
        worst = np.abs(-straight["z"] - D).max()
        assert worst > 0.01 and worst > 20 * np.abs(-s["z"] - D).max()


def test_a_constant_speed_gives_the_refraction_error_of_the_closed_form():
    """Water with c = 1480 + 0.5 z (a strong thermocline's gradient), processed with the head's
    own speed as if constant (no profile): the beam at angle b from the vertical has travelled t
    (closed form) and is placed at depth d0 + c(d0) t cos(b). Nadir comes out too shallow (the
    water below is faster than the head's), the outer beams too deep (they bent towards the
    horizontal): the error rises with the beam angle on both sides, a smile."""
    from mitsonar.products.bathymetry import soundings

    c0, g, d0, D = 1480.0, 0.5, 2.0, 20.0
    truth = SoundSpeedProfile([0.0, 100.0], [c0, c0 + 100 * g])
    angles = np.arange(-60, 61, 5.0)
    t = [linear_closed_form(d0, math.pi / 2 - math.radians(abs(b)), D, c0, g)[1] for b in angles]
    scan = fan_scan(D, truth, d0, angles, travel_times=t)
    c_head = c0 + g * d0
    predicted = d0 + c_head * np.asarray(t) * np.cos(np.radians(angles)) - D
    for profile in (None, SoundSpeedProfile.constant(c_head)):
        s = soundings(scan, sound_speed_profile=profile)
        np.testing.assert_allclose(-s["z"] - D, predicted, rtol=0, atol=2e-4)
    assert predicted[12] == pytest.approx(d0 + c_head * math.log((c0 + g * D) / c_head) / g - D, rel=1e-9)
    assert predicted[12] < -0.05 and predicted[-1] > 0.1                         # measured -5.4 cm, +11.2 cm
    assert np.all(np.diff(predicted[12:]) > 0)                                   # rising outward
    np.testing.assert_allclose(predicted[:13], predicted[12:][::-1], rtol=1e-12)  # symmetric
    s = soundings(scan, sound_speed_profile=truth)
    np.testing.assert_allclose(-s["z"], D, rtol=0, atol=2e-4)


def test_a_constant_profile_at_the_nominal_speed_gives_the_straight_ray_soundings():
    from mitsonar.products.bathymetry import soundings

    scan = fan_scan(20.0, LAYERS, c_nominal=1493.0)
    a, b = soundings(scan), soundings(scan, sound_speed_profile=SoundSpeedProfile.constant(1493.0))
    for f in ("x", "y", "z"):
        np.testing.assert_allclose(b[f], a[f], rtol=0, atol=1e-9)
    for f in ("range", "angle", "beam", "intensity", "head_z"):
        np.testing.assert_array_equal(b[f], a[f])


def test_a_head_above_the_surface_and_a_wrong_profile_type_are_one_line():
    from mitsonar.products.bathymetry import soundings

    scan = fan_scan(20.0, LAYERS, head_z=0.5)
    soundings(scan)                                         # straight rays do not need the surface
    with pytest.raises(ValueError, match=r"^bathymetry: the head is 0.5 m above the sea surface") as e:
        soundings(scan, sound_speed_profile=LAYERS)
    assert "\n" not in str(e.value)
    with pytest.raises(ValueError, match="'sound_speed_profile': 1500 is not allowed"):
        soundings(scan, sound_speed_profile=1500)


# ---------------------------------------------------------------------------------------------
# files and bad input

def test_csv_and_ctd_round_trips(tmp_path):
    from mitsonar.acoustics import sound_speed

    path = tmp_path / "svp.csv"
    LAYERS.to_csv(path)
    assert SoundSpeedProfile.from_csv(path) == LAYERS
    assert path.read_text().splitlines()[0] == "depth,sound_speed"
    path.write_text("depth,sound_speed\n\n0,1500.5\n 10 , 1490.25\n")        # blank lines, spaces
    p = SoundSpeedProfile.from_csv(path)
    assert p.depths.tolist() == [0.0, 10.0] and p.speeds.tolist() == [1500.5, 1490.25]
    ctd = SoundSpeedProfile.from_ctd([0.0, 500.0, 1000.0], [25.0, 25.0, 25.0], 35.0)
    assert ctd.speed(1000.0) == pytest.approx(1550.744, abs=1e-3)          # Mackenzie's check value
    assert ctd.speed(500.0) == pytest.approx(sound_speed(25.0, 35.0, 500.0), rel=1e-15)
    import mitsonar

    assert mitsonar.SoundSpeedProfile is SoundSpeedProfile


@pytest.mark.parametrize("text, message", [
    ("depth,sound_speed\n0,1500\n12,1490\n10,1495\n",
     "svp.csv, row 4: depth 10.0 m is not greater than the previous 12.0 m (depths strictly increasing)"),
    ("depth,sound_speed\n0,1500\nnan,1490\n", "svp.csv, row 3: depth nan is not a finite number"),
    ("depth,sound_speed\n0,1500\n5,nan\n", "svp.csv, row 3: sound_speed nan is not a finite number"),
    ("depth,sound_speed\n0,1800\n", "svp.csv, row 2: sound_speed 1800 m/s is outside 1300 to 1700 m/s"),
    ("depth,sound_speed\n0,1250\n", "svp.csv, row 2: sound_speed 1250 m/s is outside 1300 to 1700 m/s"),
    ("depth,sound_speed\n-3,1500\n", "svp.csv, row 2: depth -3 m is outside 0 to 12000 m"),
    ("depth,sound_speed\n0,fast\n", "svp.csv, row 2: sound_speed 'fast' is not a number"),
    ("depth,sound_speed\n0,1500,7\n", "svp.csv, row 2: 3 fields, expected 2 (depth,sound_speed)"),
    ("depth,speed\n0,1500\n", "svp.csv, row 1: header 'depth,speed' is not depth,sound_speed"),
    ("", "svp.csv: empty file"),
    ("depth,sound_speed\n", "svp.csv: no samples after the header"),
])
def test_bad_csv_is_one_line_naming_the_file_row_and_field(tmp_path, text, message):
    path = tmp_path / "svp.csv"
    path.write_text(text)
    with pytest.raises(ProfileError) as e:
        SoundSpeedProfile.from_csv(path)
    line = str(e.value)
    assert "\n" not in line and line.startswith(str(path) + message.split("svp.csv", 1)[1])
    assert isinstance(e.value, ValueError)


@pytest.mark.parametrize("call, message", [
    (lambda: SoundSpeedProfile([0, 10, 10], [1500, 1500, 1500]),
     "SoundSpeedProfile, sample 2: depth 10.0 m is not greater than the previous 10.0 m"),
    (lambda: SoundSpeedProfile([0, 10], [1500, float("nan")]), "SoundSpeedProfile, sample 1: sound_speed nan"),
    (lambda: SoundSpeedProfile([], []), "SoundSpeedProfile: no samples"),
    (lambda: SoundSpeedProfile([0, 1], [1500]), "must be 1-D arrays of one length"),
    (lambda: SoundSpeedProfile.constant(343.0), "sound_speed 343 m/s is outside 1300 to 1700 m/s"),
    (lambda: SoundSpeedProfile.from_ctd([0, 10], [45, 10], 35, strict=True), "from_ctd: sound_speed: temperature 45"),
    (lambda: LAYERS.locate(-1.0, 0.5, 0.1), "locate: depth -1 m is above the sea surface"),
    (lambda: LAYERS.locate(1.0, 2.0, 0.1), "locate: grazing 2.0 is not allowed"),
    (lambda: LAYERS.locate(1.0, 0.5, -0.1), "locate: travel_time -0.1 is not allowed"),
    (lambda: LAYERS.trace(1.0, 0.5), "trace: give travel_time (s) or to_depth (m)"),
])
def test_bad_arguments_are_one_line(call, message):
    with pytest.raises(ProfileError) as e:
        call()
    assert message in str(e.value) and "\n" not in str(e.value)


def test_ray_diagram_draws_the_profile_and_the_fan_depth_down(tmp_path):
    from mitsonar.products.raydiagram import ray_diagram

    path = tmp_path / "rays.png"
    fig = ray_diagram(LAYERS, head_depth=2.0, seabed_depth=40.0, angles=[-60, 0, 30, 60], nominal_speed=1495.0,
                      path=path)
    assert path.stat().st_size > 10000
    profile_ax, rays_ax = fig.axes[:2]
    assert profile_ax.get_xlabel() == "sound speed [m/s]" and "depth [m]" in profile_ax.get_ylabel()
    assert "across-track distance [m]" in rays_ax.get_xlabel()
    lo, hi = rays_ax.get_ylim()
    assert lo > hi == 0.0                                       # depth increasing downward
    th = math.radians(90.0 - 30.0)                               # the 30 deg beam's grazing angle
    x, z = LAYERS.locate(2.0, th, LAYERS.trace(2.0, th, to_depth=40.0).time[-1])
    ray_lines = [ln for ln in rays_ax.get_lines() if ln.get_linestyle() == "-" and len(ln.get_xdata()) > 2]
    assert len(ray_lines) == 4
    end = [(ln.get_xdata()[-1], ln.get_ydata()[-1]) for ln in ray_lines][1:3]
    assert end[0] == (pytest.approx(0.0, abs=1e-9), pytest.approx(40.0))          # nadir beam
    assert end[1] == (pytest.approx(x, rel=1e-9), pytest.approx(40.0))             # 30 deg to port: +
    with pytest.raises(ProfileError, match="give seabed_depth"):
        ray_diagram(LAYERS)


def test_cli_refuses_a_bad_processing_svp_before_any_render(tmp_path, capsys):
    from mitsonar.cli import main

    svp = tmp_path / "svp.csv"
    svp.write_text("depth,sound_speed\n0,1500\n12,1490\n10,1495\n")
    out = tmp_path / "run"
    args = ["bathymetry", os.path.join(SCENES, "rocky_slope.xml"), "--trajectory",
            os.path.join(SCENES, "rocky_slope_survey.tum"), "-q", "-o", str(out), "--processing-svp", str(svp)]
    assert main(args) == 1
    err = capsys.readouterr().err.strip()
    assert err.count("\n") == 0 and f"{svp}, row 4: depth 10.0 m is not greater than the previous 12.0 m" in err, err
    assert not out.exists()
    track = tmp_path / "high.tum"
    track.write_text("0 0 0 1.5 0 0 0 1\n1 1 0 1.5 0 0 0 1\n")
    svp.write_text("depth,sound_speed\n0,1500\n")
    assert main(args[:3] + [str(track)] + args[4:]) == 1
    err = capsys.readouterr().err.strip()
    assert err.count("\n") == 0 and "track rises 1.5 m above the sea surface" in err, err
    assert not out.exists()


def test_cli_processing_svp_at_the_nominal_speed_changes_nothing_and_is_recorded(tmp_path):
    """End to end: the same survey processed with a constant profile at the head's nominal
    1500 m/s gives the straight-ray depth errors, and errors.json names the profile."""
    import json

    from mitsonar.cli import main

    svp = tmp_path / "svp.csv"
    SoundSpeedProfile.constant(1500.0).to_csv(svp)
    args = ["bathymetry", os.path.join(SCENES, "rocky_slope.xml"), "--trajectory",
            os.path.join(SCENES, "rocky_slope_survey.tum"), "--beams", "16", "--max-scans", "2", "--spp", "16",
            "--range-max", "20", "--bin-width", "0.025", "--max-depth", "1", "-q"]
    assert main(args + ["-o", str(tmp_path / "a")]) == 0
    assert main(args + ["-o", str(tmp_path / "b"), "--processing-svp", str(svp)]) == 0
    a, b = (json.loads((tmp_path / d / "errors.json").read_text()) for d in "ab")
    assert a["processing_svp"] is None and b["processing_svp"] == str(svp)
    assert b["sonar"]["processing_svp"] == {"depth": [0.0], "sound_speed": [1500.0]}
    assert a["n_soundings"] == b["n_soundings"] > 20
    for ra, rb in zip(a["per_angle"], b["per_angle"]):
        assert rb["angle"] == ra["angle"] and rb["mean"] == pytest.approx(ra["mean"], abs=1e-9)
