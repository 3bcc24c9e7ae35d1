"""Propagation an acoustician can check (issue 58): rays launched at the edges of the angle range
(horizontal where the profile turns them at once, vertical), receivers at a turning depth and
profiles of one sample trace to the closed forms of a circular arc or a straight line."""
import math
import re
import warnings

import numpy as np
import pytest

from mitsonar.acoustics import ProfileError, SoundSpeedProfile

# c(z) = 1450 + 0.05 z: a ray launched horizontally at 1000 m is a circle of radius R = c/g above it
STEEP = SoundSpeedProfile([0.0, 5000.0], [1450.0, 1700.0])


def horizontal_circle(c1, g, rise):
    """Distance and time of a ray launched horizontally where the speed is ``c1`` (gradient
    ``g > 0``) when it has climbed ``rise`` m: a circle of radius R = c1/g about the depth where c
    extrapolates to 0, so ``x = sqrt(R^2 - (R - rise)^2)`` and ``t = atanh(x / R) / g`` (Jensen et al.
    2011, sec. 3.2: ``dt = (1/g) ln tan(pi/4 + theta/2)``, ``sin theta = x / R``)."""
    R = c1 / g
    x = math.sqrt(R * R - (R - rise) ** 2)
    return x, math.atanh(x / R) / g


@pytest.mark.parametrize("launch", [0.0, -0.0])
def test_a_horizontal_launch_that_turns_upward_at_once_reaches_a_shallower_depth(launch):
    x_ref, t_ref = horizontal_circle(1500.0, 0.05, 1.0)
    assert x_ref == pytest.approx(244.947, abs=1e-3) and t_ref == pytest.approx(0.16330, abs=1e-5)
    ray = STEEP.trace(1000.0, launch, to_depth=999.0)
    assert ray.x[-1] == pytest.approx(x_ref, rel=1e-9)
    assert ray.time[-1] == pytest.approx(t_ref, rel=1e-9)
    assert ray.depth[-1] == 999.0
    assert np.all(ray.depth <= 1000.0)
    # locate inverts it
    x, z = STEEP.locate(1000.0, launch, t_ref)
    assert float(x) == pytest.approx(x_ref, rel=1e-7) and float(z) == pytest.approx(999.0, abs=1e-6)


def test_vertical_launches_go_straight_up_and_down_with_the_closed_form_time():
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        down = STEEP.trace(1000.0, math.pi / 2, to_depth=2000.0)
        up = STEEP.trace(1000.0, -math.pi / 2, to_depth=0.0)
    assert np.all(down.x == 0) and np.all(up.x == 0)
    assert down.time[-1] == pytest.approx(math.log(1550.0 / 1500.0) / 0.05, rel=1e-12)
    assert up.time[-1] == pytest.approx(math.log(1500.0 / 1450.0) / 0.05, rel=1e-12)
    with pytest.raises(ProfileError, match="never reaches depth 2000"):
        STEEP.trace(1000.0, -math.pi / 2, to_depth=2000.0)


def test_a_receiver_at_the_turning_depth_of_a_horizontal_launch_is_reached():
    # a channel with its axis at 100 m: a ray launched horizontally at 50 m (1490 m/s) turns at 150 m
    duct = SoundSpeedProfile([0.0, 100.0, 200.0], [1500.0, 1480.0, 1500.0])
    ray = duct.trace(50.0, 0.0, to_depth=150.0)
    assert ray.depth[-1] == 150.0
    # down a circle of radius 1490/0.2 to the axis, then up the mirror circle of radius 1490/0.2
    R = 1490.0 / 0.2
    half = math.sqrt(R * R - (R - 50.0) ** 2)
    assert ray.x[-1] == pytest.approx(2 * half, rel=1e-9)
    assert ray.grazing[-1] == pytest.approx(0.0, abs=1e-6)


def test_a_profile_of_one_sample_is_straight_rays_even_horizontal():
    one = SoundSpeedProfile([10.0], [1500.0])
    ray = one.trace(5.0, 0.3, to_depth=20.0)
    assert ray.x[-1] == pytest.approx(15.0 / math.tan(0.3), rel=1e-12)
    assert ray.time[-1] == pytest.approx(15.0 / math.sin(0.3) / 1500.0, rel=1e-12)
    flat = one.trace(5.0, 0.0, travel_time=1.0)
    assert flat.x[-1] == pytest.approx(1500.0) and flat.depth[-1] == 5.0
    with pytest.raises(ProfileError, match="never reaches"):
        one.trace(5.0, 0.0, to_depth=20.0)


def test_repeated_depths_are_refused_in_one_line():
    with pytest.raises(ProfileError, match=r"sample 2: depth 10.0 m is not greater than the previous 10.0 m"):
        SoundSpeedProfile([0.0, 10.0, 10.0], [1500.0, 1490.0, 1480.0])


# ---------------------------------------------------------------------------------------------
# eigenrays against closed forms


def test_isovelocity_eigenrays_are_the_image_sources_with_spherical_spreading():
    c, zs, zr, D, R, alpha, rb = 1500.0, 20.0, 60.0, 100.0, 300.0, 0.002, 0.5
    table = SoundSpeedProfile.constant(c).eigenrays(zs, zr, R, water_depth=D, bottom=rb, absorption=alpha,
                                                    max_bounces=2)
    # (surface, bottom) bounces -> the image's depth below the receiver's (positive: the ray
    # arrives heading down) and the reflection coefficient's product
    images = {(0, 0): (zr - zs, 1.0), (1, 0): (zr + zs, -1.0), (0, 1): (-(2 * D - zs - zr), rb),
              (1, 1): None, (1, 1, "sb"): (-(2 * D + zs - zr), -rb), (1, 1, "bs"): (2 * D - zs + zr, -rb)}
    assert table.size == 5
    seen = set()
    for row in table:
        key = (int(row["surface_bounces"]), int(row["bottom_bounces"]))
        if key == (1, 1):
            key = key + ("sb" if row["launch"] < 0 else "bs",)
        seen.add(key)
        dz, refl = images[key]
        L = math.hypot(R, dz)
        assert row["time"] == pytest.approx(L / c, rel=1e-12)
        assert row["length"] == pytest.approx(L, rel=1e-9)
        assert row["arrival"] == pytest.approx(math.atan2(dz, R), abs=1e-9)
        assert abs(row["launch"]) == pytest.approx(abs(row["arrival"]), abs=1e-9)
        assert row["spreading_loss"] == pytest.approx(20 * math.log10(L), abs=1e-5)
        assert row["absorption_loss"] == pytest.approx(alpha * L, rel=1e-9)
        assert row["boundary_loss"] == pytest.approx(-20 * math.log10(abs(refl)), abs=1e-12)
        assert row["transmission_loss"] == pytest.approx(20 * math.log10(L) + alpha * L
                                                         - 20 * math.log10(abs(refl)), abs=1e-5)
        assert row["phase"] == pytest.approx(0.0 if refl > 0 else math.pi, abs=1e-12)
    assert len(seen) == 5
    assert np.all(np.diff(table["time"]) >= 0)


def _linear_family(zs, zr, c0=1480.0, g=0.05):
    """x(theta0), t(theta0) and dx/dtheta0 of the rays of c = c0 + g z from zs to their first
    crossing of zr > zs heading down (``up=False``) or, after the turn, heading up (``up=True``):
    circular arcs, ``x = (s0 -+ s_r) / (a g)``, ``t = (atanh s0 -+ atanh s_r) / g`` (Jensen et al. 2011,
    sec. 3.2), and the derivative of x in closed form."""
    cs, cr = c0 + g * zs, c0 + g * zr

    def family(theta0, up):
        a = math.cos(theta0) / cs
        da = -math.sin(theta0) / cs
        s0 = math.sin(theta0)
        sr = math.sqrt(1 - (a * cr) ** 2)
        sign = 1.0 if up else -1.0
        x = (s0 + sign * sr) / (a * g)
        dsr = -a * cr * cr * da / sr
        dx = (math.cos(theta0) + sign * dsr) / (a * g) - x * da / a
        t = (math.atanh(s0) + sign * math.atanh(sr)) / g
        return x, t, dx, -sign * sr        # the signed sine at the receiver (positive: heading down)

    return family, cs, cr


@pytest.mark.parametrize("up, R", [(False, 1500.0), (True, 5000.0)])
def test_linear_gradient_eigenrays_are_arcs_with_the_closed_form_ray_tube(up, R):
    from scipy.optimize import brentq

    zs, zr = 100.0, 300.0
    profile = SoundSpeedProfile([0.0, 2000.0], [1480.0, 1580.0])
    family, cs, cr = _linear_family(zs, zr)
    table = profile.eigenrays(zs, zr, R, max_bounces=0, absorption=0.0)
    row = table[(table["arrival"] < 0) == up]
    assert row.size == 1
    # the closed form's eigenray: x(theta0) = R on the family
    guess = float(row["launch"][0])
    theta0 = brentq(lambda th: family(th, up)[0] - R, guess - 1e-3, guess + 1e-3, xtol=1e-15)
    x, t, dx, sr = family(theta0, up)
    assert row["launch"][0] == pytest.approx(theta0, abs=1e-10)
    assert row["time"][0] == pytest.approx(t, rel=1e-10)
    a = math.cos(theta0) / cs
    assert row["arrival"][0] == pytest.approx(math.atan2(sr, a * cr), abs=1e-9)
    tl = 10 * math.log10(cs * R * abs(dx * sr) / (cr * math.cos(theta0)))
    assert row["spreading_loss"][0] == pytest.approx(tl, abs=1e-4)


def test_transmission_loss_sums_the_eigenrays_intensities_and_a_shadow_is_silent():
    from mitsonar.acoustics import transmission_loss

    profile = SoundSpeedProfile([0.0, 2000.0], [1480.0, 1580.0])
    table = profile.eigenrays(100.0, 300.0, 1500.0, max_bounces=0)
    tl = transmission_loss(profile, 100.0, 300.0, 1500.0, max_bounces=0)
    assert tl == pytest.approx(-10 * math.log10(np.sum(10 ** (-table["transmission_loss"] / 10))), abs=1e-9)
    assert profile.transmission_loss(100.0, 300.0, 1500.0, max_bounces=0) == tl
    # a thermocline refracts down: no ray from 10 m reaches 5 m at 3 km in 100 m of water with 3
    # bounces (a ray shallow enough to come back from the bottom turns below 28 m), some with 12
    thermocline = SoundSpeedProfile([0.0, 30.0, 100.0], [1520.0, 1480.0, 1480.0])
    assert thermocline.eigenrays(10.0, 5.0, 3000.0, water_depth=100.0, max_bounces=3).size == 0
    assert transmission_loss(thermocline, 10.0, 5.0, 3000.0, water_depth=100.0, max_bounces=3) == math.inf
    many = thermocline.eigenrays(10.0, 5.0, 3000.0, water_depth=100.0, max_bounces=12)
    assert many.size > 0 and np.all(many["surface_bounces"] + many["bottom_bounces"] >= 4)
    listed = profile.arrivals(100.0, 300.0, 1500.0, max_bounces=0)
    assert [r["time"] for r in listed] == list(table["time"])


@pytest.mark.parametrize("kwargs, message", [
    (dict(range=-1.0), "range -1.0 is not allowed"),
    (dict(water_depth=0.0), "water_depth 0.0 is not allowed"),
    (dict(bottom=2.0), "bottom 2.0 is not allowed"),
    (dict(bottom="sand"), "bottom 'sand' is not a reflection coefficient"),
    (dict(max_bounces=-1), "max_bounces -1 is not allowed"),
    (dict(angles=(10.0, -10.0)), "angles (10.0, -10.0) is not allowed"),
    (dict(receiver_depth=150.0, water_depth=100.0), "receiver_depth 150.0 is not allowed"),
    (dict(bottom_slope=2.0), "bottom_slope 2.0 needs a water_depth"),
    (dict(bottom_slope=40.0, water_depth=100.0), "bottom_slope 40.0 is not allowed (-30 to 30 deg)"),
])
def test_bad_eigenray_arguments_are_one_line(kwargs, message):
    args = dict(source_depth=10.0, receiver_depth=20.0, range=100.0)
    args.update({k: kwargs.pop(k) for k in list(kwargs) if k in args})
    with pytest.raises(ProfileError, match=re.escape(message)):
        SoundSpeedProfile.constant(1500.0).eigenrays(args["source_depth"], args["receiver_depth"], args["range"],
                                                     **kwargs)


def test_the_two_way_loss_is_renamed_and_the_old_name_warns():
    from mitsonar.sonar_equation import transmission_loss as old, two_way_transmission_loss

    r = np.array([10.0, 100.0])
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        new = two_way_transmission_loss(r, 0.01)
    np.testing.assert_array_equal(new, 40 * np.log10(r) + 2 * 0.01 * r)
    with pytest.warns(DeprecationWarning, match="two_way_transmission_loss"):
        np.testing.assert_array_equal(old(r, 0.01), new)
    # the one-way loss of straight water without absorption is half of it: 20 log10 of the path
    one = SoundSpeedProfile.constant(1500.0).transmission_loss(10.0, 110.0, 100.0, max_bounces=0)
    assert one == pytest.approx(two_way_transmission_loss(math.hypot(100.0, 100.0)) / 2, abs=1e-5)


@pytest.mark.parametrize("slope", [-3.0, 2.0, 5.0])
def test_a_sloping_bottom_reflects_as_the_image_in_its_plane(slope):
    """Uniform water over a bottom z = D + x tan(slope): the bottom-reflected eigenray comes from
    the source's image in that line, with its time L/c and angles, and the 2-D model's cylindrical
    spreading ``R L / cos(theta0)`` (R the horizontal range, L the image's distance)."""
    c, zs, zr, R, D = 1500.0, 20.0, 30.0, 800.0, 100.0
    tb = math.tan(math.radians(slope))
    table = SoundSpeedProfile.constant(c).eigenrays(zs, zr, R, water_depth=D, bottom_slope=slope, max_bounces=1)
    row = table[(table["bottom_bounces"] == 1) & (table["surface_bounces"] == 0)]
    assert row.size == 1
    n = np.array([-tb, 1.0]) / math.hypot(tb, 1.0)
    image = np.array([0.0, zs]) - 2.0 * (zs - D) / math.hypot(tb, 1.0) * n
    to_rx = np.array([R, zr]) - image
    L = float(np.linalg.norm(to_rx))
    v = to_rx / L
    before = v - 2.0 * (v @ n) * n
    theta0 = math.atan2(before[1], before[0])
    assert row["time"][0] == pytest.approx(L / c, rel=1e-12)
    assert row["launch"][0] == pytest.approx(theta0, abs=1e-10)
    assert row["arrival"][0] == pytest.approx(math.atan2(v[1], v[0]), abs=1e-10)
    assert row["spreading_loss"][0] == pytest.approx(10 * math.log10(R * L / math.cos(theta0)), abs=1e-6)
    # the flat bottom's direct path is there too, unchanged
    assert table[(table["bottom_bounces"] == 0) & (table["surface_bounces"] == 0)]["time"][0] == pytest.approx(
        math.hypot(R, zr - zs) / c, rel=1e-12)


def test_a_source_on_the_surface_launches_each_ray_once():
    # a ray launched up from 0 m is the downward ray's reflected twin: one arrival per path
    table = SoundSpeedProfile.constant(1500.0).eigenrays(0.0, 20.0, 300.0, water_depth=100.0, max_bounces=1)
    assert sorted(np.round(table["time"] * 1500.0, 6)) == pytest.approx([math.hypot(300.0, 20.0),
                                                                         math.hypot(300.0, 180.0)])
    assert np.all(table["surface_bounces"] == 0)


def test_a_fan_ray_landing_on_the_receiver_gives_one_eigenray():
    # the fan -45, -22.5, ..., 67.5 deg: the 45 deg ray reaches 20 m at exactly 10 m in uniform water,
    # so the pairs on both sides of it bracket the same eigenray
    table = SoundSpeedProfile.constant(1500.0).eigenrays(10.0, 20.0, 10.0, angles=(-45.0, 67.5), rays=6,
                                                         max_bounces=0)
    assert table.size == 1 and table["launch"][0] == pytest.approx(math.pi / 4, abs=1e-12)
