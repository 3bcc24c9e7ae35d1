"""Propagation an acoustician can check (issue 58): rays launched at the edges of the angle range
(horizontal where the profile turns them at once, vertical), receivers at a turning depth and
profiles of one sample trace to the closed forms of a circular arc or a straight line."""
import math
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
