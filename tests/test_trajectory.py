"""`mitsonar.Trajectory` (issue 18, part 1): interpolation against hand-computed poses, TUM files
(round trip, one-line errors naming file, line and field), the generators and the seeded drift."""
import math

import numpy as np
import pytest

from mitsonar.geometry.trajectory import Trajectory, TrajectoryError, pose


def rot(axis, angle):
    """Rodrigues: 3x3 rotation by ``angle`` (rad) about ``axis``."""
    k = np.asarray(axis, float) / np.linalg.norm(axis)
    K = np.array([[0, -k[2], k[1]], [k[2], 0, -k[0]], [-k[1], k[0], 0]])
    return np.eye(3) + math.sin(angle) * K + (1 - math.cos(angle)) * K @ K


def rigid(r, p):
    m = np.eye(4)
    m[:3, :3], m[:3, 3] = r, p
    return m


def test_at_interpolates_position_linearly_and_rotation_by_slerp():
    a = rigid(np.eye(3), [1.0, 2.0, 3.0])
    axis = [1.0, 1.0, 1.0]
    b = rigid(rot(axis, math.radians(120)), [5.0, -2.0, 3.0])
    traj = Trajectory([10.0, 14.0], [a, b])
    for f in (0.0, 0.25, 0.5, 0.9, 1.0):
        got = traj.at(10.0 + 4.0 * f)
        np.testing.assert_allclose(got[:3, 3], [1 + 4 * f, 2 - 4 * f, 3.0], atol=1e-12)
        # slerp from identity to a rotation of 120 deg about an axis: f * 120 deg about that axis
        np.testing.assert_allclose(got[:3, :3], rot(axis, math.radians(120 * f)), atol=1e-12)
        np.testing.assert_array_equal(got[3], [0, 0, 0, 1])
    # a yaw of 90 deg over 2 s with a translation: at 0.5 s, 22.5 deg and a quarter of the way
    traj = Trajectory([0.0, 2.0], [np.eye(4), pose([2.0, 4.0, 0.0], math.pi / 2)])
    np.testing.assert_allclose(traj.at(0.5), pose([0.5, 1.0, 0.0], math.pi / 8), atol=1e-12)
    # an array of times gives an array of poses; samples come back exactly as given
    many = traj.at(np.array([[0.0, 2.0]]))
    assert many.shape == (1, 2, 4, 4)
    np.testing.assert_array_equal(many[0, 1], traj.poses[1])


def test_at_outside_the_span_is_an_error_naming_the_time_and_the_span():
    traj = Trajectory.straight(5.0, 1.0)
    for t in (-0.5, 5.25, math.nan):
        with pytest.raises(TrajectoryError, match=r"outside the trajectory's span \[0, 5\] s"):
            traj.at(t)
    with pytest.raises(TrajectoryError, match="5.25 s"):
        traj.at([1.0, 5.25])


def test_constructor_refuses_bad_input():
    with pytest.raises(TrajectoryError, match="'times'.*not after"):
        Trajectory([0.0, 1.0, 1.0], np.stack([np.eye(4)] * 3))
    with pytest.raises(TrajectoryError, match=r"'poses'\[1\].*rigid"):
        Trajectory([0.0, 1.0], np.stack([np.eye(4), np.diag([2.0, 1, 1, 1])]))
    with pytest.raises(TrajectoryError, match="shape"):
        Trajectory([0.0, 1.0], np.eye(4))


def test_tum_round_trip_is_exact(tmp_path):
    traj = Trajectory.turn(3.0, 1.5, 25.0, start=pose([1, 2, -3], 0.3), dt=0.25).with_drift(seed=4)
    first, second = tmp_path / "a.tum", tmp_path / "b.tum"
    traj.to_tum(first)
    back = Trajectory.from_tum(first)
    np.testing.assert_array_equal(back.times, traj.times)
    np.testing.assert_array_equal(back.positions, traj.positions)
    np.testing.assert_array_equal(back.quaternions, traj.quaternions)
    np.testing.assert_allclose(back.poses, traj.poses, atol=1e-15)
    back.to_tum(second)
    assert first.read_text() == second.read_text()
    again = Trajectory.from_tum(second)
    np.testing.assert_array_equal(again.poses, back.poses)
    np.testing.assert_array_equal(Trajectory.from_numpy(traj.to_numpy()).to_numpy(), traj.to_numpy())
    assert sorted(p.name for p in tmp_path.iterdir()) == ["a.tum", "b.tum"]  # no temporary left


GOOD = "0 0 0 0 0 0 0 1\n"
BAD_FILES = {  # content of line 3 (after a comment and a good line): words of the message
    "1 0 0 0 0 0 1\n": ["7 fields, expected 8", "timestamp tx ty tz qx qy qz qw"],
    "1 0 0 zero 0 0 0 1\n": ["field 'tz'", "'zero' is not a number"],
    "0 1 0 0 0 0 0 1\n": ["field 'timestamp'", "not after the previous"],
    "1 0 0 0 0 0 0.5 0.5\n": ["field 'qx qy qz qw'", "norm 0.707", "unit quaternion"],
    "1 nan 0 0 0 0 0 1\n": ["field 'tx'", "nan", "finite"],
}


@pytest.mark.parametrize("line", list(BAD_FILES))
def test_bad_tum_lines_are_named_by_file_line_and_field(tmp_path, line):
    path = tmp_path / "track.tum"
    path.write_text("# a comment\n" + GOOD + line)
    with pytest.raises(TrajectoryError) as info:
        Trajectory.from_tum(path)
    msg = str(info.value)
    assert msg.startswith(f"{path}:3: ") and "\n" not in msg
    for word in BAD_FILES[line]:
        assert word in msg
    with pytest.raises(TrajectoryError, match="cannot read"):
        Trajectory.from_tum(tmp_path / "missing.tum")


def test_straight_and_turn_follow_their_closed_forms():
    start = pose([1.0, 2.0, -4.0], math.radians(30))
    line = Trajectory.straight(10.0, 2.0, start=start, dt=0.5)
    for t in (0.0, 3.3, 10.0):
        np.testing.assert_allclose(line.at(t)[:3, 3], [1, 2, -4] + 2.0 * t * start[:3, 0], atol=1e-12)
    v, w = 1.0, 9.0  # m/s, deg/s: a circle of radius v / w
    arc = Trajectory.turn(20.0, v, w, dt=0.1)
    r = v / math.radians(w)
    for t in (0.0, 7.0, 20.0):
        a = math.radians(w) * t
        np.testing.assert_allclose(arc.at(t), pose([r * math.sin(a), r * (1 - math.cos(a)), 0.0], a), atol=1e-9)
    # between samples the interpolation stays on the circle to second order in the step
    mid = arc.at(np.arange(0.05, 20.0, 0.1))[:, :3, 3]
    assert np.abs(np.hypot(mid[:, 0], mid[:, 1] - r) - r).max() < 1e-3


def test_lawnmower_covers_its_rectangle_with_the_requested_spacing():
    traj = Trajectory.lawnmower(-10.0, 30.0, 5.0, 25.0, 4.0, speed=1.5, depth=12.0)
    p = traj.positions
    assert np.all(p[:, 2] == -12.0)
    assert p[:, 0].min() == -10.0 and p[:, 0].max() == 30.0 and p[:, 1].min() == 5.0 and p[:, 1].max() == 25.0
    along_x = np.isin(p[:, 1], 5.0 + 4.0 * np.arange(6))
    lines = np.unique(p[along_x, 1])
    np.testing.assert_array_equal(lines, 5.0 + 4.0 * np.arange(6))   # 6 lines 4 m apart, the last at y_max
    for y in lines:  # each line runs the whole width
        xs = p[p[:, 1] == y, 0]
        assert xs.min() == -10.0 and xs.max() == 30.0
    # the vehicle heads where it goes: on a line its x axis is +x or -x
    inside = along_x & (p[:, 0] > -10.0) & (p[:, 0] < 30.0)   # (it turns on the spot at the ends)
    heads = traj.poses[inside][:, :3, 0]
    np.testing.assert_allclose(np.abs(heads[:, 0]), 1.0, atol=1e-9)
    # speed: 6 lines of 40 m and 5 legs of 4 m at 1.5 m/s, plus 10 quarter turns at 20 deg/s
    assert traj.span[1] == pytest.approx((6 * 40 + 5 * 4) / 1.5 + 10 * 90 / 20.0)
    odd = Trajectory.lawnmower(0.0, 10.0, 0.0, 10.0, 3.0, speed=1.0, altitude=2.0)
    ys = np.unique(odd.positions[:, 1][np.isin(odd.positions[:, 1], np.linspace(0, 10, 5))])
    np.testing.assert_allclose(ys, np.linspace(0, 10, 5))           # 10 m at most 3 m apart: 2.5 m
    assert np.all(odd.positions[:, 2] == 2.0)
    with pytest.raises(TrajectoryError, match="exactly one of 'altitude'"):
        Trajectory.lawnmower(0, 1, 0, 1, 1, 1)


def test_drift_is_seeded_and_grows_like_a_random_walk():
    base = Trajectory.straight(400.0, 1.0, dt=1.0)
    a, b = base.with_drift(seed=7), base.with_drift(seed=7)
    np.testing.assert_array_equal(a.poses, b.poses)
    assert not np.array_equal(a.poses, base.with_drift(seed=8).poses)
    np.testing.assert_array_equal(base.with_drift(seed=7, position_sigma=0, yaw_sigma=0).poses, base.poses)
    # position error after T s: sigma sqrt(T) per axis; over 200 seeds the spread is within 15 %
    ends = np.array([base.with_drift(seed=s, yaw_sigma=0).positions[-1] - base.positions[-1] for s in range(200)])
    assert ends.std() == pytest.approx(0.05 * math.sqrt(400.0), rel=0.15)
