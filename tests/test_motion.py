"""Scans rendered from a moving platform (issue 18, parts 2 and 3): per-row poses and ping times,
echo ranges against the closed-form distance from each ping's own pose, surveys, and the errors."""
import math
import os

import numpy as np
import pytest
from conftest import SCENES, jit_kernels, matrix_attr, scene_xml, sonar_xml

from mitsonar.geometry.trajectory import pose as trajectory_pose

HALF = 8.0  # the walls: x = +-8, y = +-8 (vertical, 10 m tall)
RANGE_MAX, N_BINS = 16.0, 400
BIN = RANGE_MAX / N_BINS

# The mount, in the vehicle frame (x forward, y port, z up): the head 0.5 m ahead, 0.1 m to port and
# 0.2 m up, scanning about the vehicle's z axis, boresight forward at bearing 0.
MOUNT = np.array([[0.0, 0.0, 1.0, 0.5], [1.0, 0.0, 0.0, 0.1], [0.0, 1.0, 0.0, 0.2], [0.0, 0.0, 0.0, 1.0]])


def wall(matrix):
    bsdf = ('<bsdf type="twosided"><bsdf type="acoustic"><float name="diffuse" value="0.8"/>'
            '<float name="specular" value="0"/></bsdf></bsdf>')
    return f'<shape type="rectangle"><transform name="to_world"><matrix value="{matrix_attr(matrix)}"/></transform>{bsdf}</shape>'


def walls():
    out = []
    for sign in (-1.0, 1.0):
        out.append(wall([[0, 0, 1, sign * HALF], [HALF, 0, 0, 0], [0, 5, 0, 0], [0, 0, 0, 1]]))  # x = +-8
        out.append(wall([[HALF, 0, 0, 0], [0, 0, 1, sign * HALF], [0, 5, 0, 0], [0, 0, 0, 1]]))  # y = +-8
    return out


@pytest.fixture(scope="module")
def room(mitsonar_mod):
    sensor = sonar_xml(MOUNT, range_max=RANGE_MAX, n_bins=N_BINS, n_pings=200, bearing_step=1.8,
                       beamwidth_h=1.0, beamwidth_v=1.0, ping_period=0.05)
    return mitsonar_mod.load_scene(scene_xml(sensor, *walls()))


def wall_distance(origin, direction):
    """Closed form: distance along a horizontal ray from inside the square to the nearest wall."""
    s = []
    for axis in (0, 1):
        d = direction[axis]
        if abs(d) > 1e-12:
            s.append(((HALF if d > 0 else -HALF) - origin[axis]) / d)
    return min(s)


def echo_ranges(scan):
    """Energy-weighted mean range of each ping (single bounce: one wall echo per ping)."""
    w = scan.intensity.astype(np.float64)
    return (w * scan.ranges).sum(1) / np.maximum(w.sum(1), 1e-300)


def checked_pings(scan):
    """The pings whose boresight hits a wall away from the corners, within the range window."""
    keep, expect = [], []
    for k in range(scan.n_pings):
        p, d = scan.poses[k, :3, 3], scan.poses[k, :3, 2]
        s = wall_distance(p, d)
        hit = p + s * d
        if s < RANGE_MAX - 0.5 and min(HALF - abs(hit[0]), HALF - abs(hit[1])) < 1e-9 \
                and max(HALF - abs(hit[0]), HALF - abs(hit[1])) > 0.5:
            keep.append(k)
            expect.append(s)
    return np.array(keep), np.array(expect)


def test_moving_mechanical_scan_pings_from_its_own_poses(mitsonar_mod, room):
    from mitsonar.scan import bearing_rotation

    m = mitsonar_mod
    # 1 m/s forward while turning 6 deg/s: an arc of radius 9.5 m, 10 m and 60 deg over the scan
    start = trajectory_pose([-3.0, -2.0, 0.0], 0.0)
    traj = m.Trajectory.turn(12.0, 1.0, 6.0, start=start, dt=0.1)
    scan = m.render_scan(room, spp=64, seed=1, trajectory=traj, start_time=0.5, max_depth=1)
    np.testing.assert_array_equal(scan.times, np.arange(200) * 0.05)
    mount = room.sensors()[0].to_world_np        # MOUNT as Mitsuba holds it (float32 entries)
    np.testing.assert_allclose(mount, MOUNT, atol=1e-7)
    expected_poses = traj.at(0.5 + scan.times) @ mount @ bearing_rotation(scan.bearings)
    np.testing.assert_array_equal(scan.poses, expected_poses)       # exactly the poses used
    keep, closed = checked_pings(scan)
    assert len(keep) > 150
    got = echo_ranges(scan)[keep]
    assert np.abs(got - closed).max() < 1.5 * BIN

    # The same head held still at the scan's first pose: its echoes differ from the moving scan's
    # by the difference of the closed forms (the distortion of a mechanical scan in motion).
    still = m.render_scan(room, spp=64, seed=1, pose=traj.at(0.5) @ MOUNT, max_depth=1)
    keep_s, closed_s = checked_pings(still)
    both = np.intersect1d(keep, keep_s)
    moving_minus_still = (echo_ranges(scan) - echo_ranges(still))[both]
    expected = np.array([wall_distance(scan.poses[k, :3, 3], scan.poses[k, :3, 2])
                         - wall_distance(still.poses[k, :3, 3], still.poses[k, :3, 2]) for k in both])
    assert len(both) > 100 and np.median(np.abs(expected)) > 1.0     # metres of distortion
    assert np.abs(moving_minus_still - expected).max() < 3 * BIN


def test_static_trajectory_gives_todays_static_scan(mitsonar_mod):
    m = mitsonar_mod
    scene = m.load_scene(os.path.join(SCENES, "box.xml"))
    static = m.render_scan(scene, spp=128, seed=3)
    still = m.Trajectory([0.0, 60.0], np.stack([np.eye(4)] * 2))
    moved = m.render_scan(scene, spp=128, seed=3, trajectory=still, start_time=2.0)
    for name in ("intensity", "data", "poses", "times", "bearings"):
        np.testing.assert_array_equal(getattr(moved, name), getattr(static, name), err_msg=name)
    sensor = scene.sensors()[0]
    period = 2 * sensor.range_max / sensor.sound_speed + 0.03
    assert static.meta.ping_period == pytest.approx(period)
    np.testing.assert_allclose(static.times, np.arange(static.n_pings) * period)


def test_a_new_trajectory_compiles_no_new_kernel(mitsonar_mod, room):
    m = mitsonar_mod
    a = m.Trajectory.turn(12.0, 1.0, 6.0, dt=0.1)
    b = m.Trajectory.straight(12.0, 2.0, start=trajectory_pose([1.0, 1.0, 0.0], 1.0), dt=0.2)
    m.render_scan(room, spp=16, trajectory=a)
    _, fresh = jit_kernels(m.render_scan, room, spp=16, trajectory=b, start_time=1.0)
    assert fresh == []


def test_multibeam_frame_in_motion_shares_one_time_and_pose(mitsonar_mod):
    from mitsonar.scan import bearing_rotation

    m = mitsonar_mod
    scene = m.load_scene(os.path.join(SCENES, "box_fls.xml"))
    mount = scene.sensors()[0].to_world_np
    traj = m.Trajectory.straight(3.0, 1.0, dt=0.5)
    scan = m.render_scan(scene, spp=32, trajectory=traj, start_time=1.25)
    np.testing.assert_array_equal(scan.times, np.zeros(scan.n_pings))
    np.testing.assert_array_equal(scan.poses, traj.at(1.25) @ mount @ bearing_rotation(scan.bearings))


def test_survey_is_consecutive_scans_bit_for_bit_and_streams_to_disk(mitsonar_mod, room, tmp_path):
    m = mitsonar_mod
    traj = m.Trajectory.turn(25.0, 0.5, 3.0, start=trajectory_pose([-2.0, -2.0, 0.0], 0.0), dt=0.2)
    period = 200 * 0.05
    scans = list(m.render_survey(room, traj, tmp_path / "a", spp=16, seed=5, progress=False))
    assert len(scans) == 2                                            # 25 s holds two 10 s sweeps
    assert [s.meta.start_time for s in scans] == [0.0, period]
    again = list(m.render_survey(room, traj, tmp_path / "b", spp=16, seed=5, progress=False))
    for x, y in zip(scans, again):
        np.testing.assert_array_equal(x.intensity, y.intensity)
        np.testing.assert_array_equal(x.data, y.data)
    assert not np.array_equal(scans[0].intensity, scans[1].intensity)
    from mitsonar.sim.survey import survey_files

    files = survey_files(tmp_path / "a")
    assert [os.path.basename(f) for f in files] == ["scan_00000.npz", "scan_00001.npz"]
    back = m.load_scan(files[1])
    np.testing.assert_array_equal(back.times, scans[1].times)
    np.testing.assert_array_equal(back.poses, scans[1].poses)
    np.testing.assert_array_equal(m.Trajectory.from_tum(tmp_path / "a" / "trajectory.tum").times, traj.times)


def test_interrupted_survey_keeps_the_scans_written(mitsonar_mod, room, tmp_path):
    m = mitsonar_mod
    traj = m.Trajectory.straight(40.0, 0.1, dt=1.0)
    calls = []

    def stop_after_two(done, total):
        calls.append(done)
        if len(calls) == 2:
            raise KeyboardInterrupt

    with pytest.raises(KeyboardInterrupt):
        for _ in m.render_survey(room, traj, tmp_path, spp=8, progress=stop_after_two):
            pass
    names = sorted(os.listdir(tmp_path))
    assert names == ["scan_00000.npz", "scan_00001.npz", "trajectory.tum"]   # no temporary file
    assert m.load_scan(tmp_path / "scan_00001.npz").meta.survey_index == 1


def test_bad_motion_arguments_are_one_sentence_before_any_render(mitsonar_mod, room):
    m = mitsonar_mod
    traj = m.Trajectory.straight(12.0, 1.0)
    with pytest.raises(m.SceneError, match=r"pings at 5 \.\. 14\.95 s .* do not fit in the trajectory's span \[0, 12\] s"):
        m.render_scan(room, spp=8, trajectory=traj, start_time=5.0)
    with pytest.raises(m.SceneError, match="'trajectory': expected a mitsonar.Trajectory"):
        m.render_scan(room, spp=8, trajectory=np.eye(4))
    with pytest.raises(m.SceneError, match="'start_time': only used with a 'trajectory'"):
        m.render_scan(room, spp=8, start_time=1.0)
    with pytest.raises(m.SceneError, match="'start_time': nan is not allowed"):
        m.render_scan(room, spp=8, trajectory=traj, start_time=math.nan)
    with pytest.raises(m.SceneError, match="one scan takes 9.95 s"):
        m.render_survey(room, m.Trajectory.straight(5.0, 1.0))


def test_ping_period_is_refused_below_the_two_way_flight(mitsonar_mod):
    with pytest.raises(mitsonar_mod.SceneError, match=r"sonar 'ping_period': 0.01 is not allowed .*0.016 s"):
        mitsonar_mod.load_scene(scene_xml(sonar_xml(ping_period=0.01)))


def test_scan_times_are_checked_saved_and_optional_in_old_files(mitsonar_mod, tmp_path):
    import dataclasses

    m = mitsonar_mod
    scan = m.render_scan(m.load_scene(os.path.join(SCENES, "box.xml")), spp=8)
    with pytest.raises(ValueError, match=r"Scan 'times': 0.0 at index 3 is not allowed \(ping times do not decrease"):
        dataclasses.replace(scan, times=np.r_[0.0, 1.0, 2.0, 0.0, np.arange(4, scan.n_pings)])
    with pytest.raises(ValueError, match=r"Scan 'times': shape \(3,\)"):
        dataclasses.replace(scan, times=np.zeros(3))
    for ext in (".exr", ".npz"):
        scan.save(tmp_path / f"s{ext}")
        np.testing.assert_array_equal(m.load_scan(tmp_path / f"s{ext}").times, scan.times)
    # a file written before scans had times: the same archive without the 'times' array
    with np.load(tmp_path / "s.npz") as z:
        arrays = {k: z[k] for k in z.files if k != "times"}
    np.savez(tmp_path / "old.npz", **arrays)
    old = m.load_scan(tmp_path / "old.npz")
    np.testing.assert_array_equal(old.times, np.zeros(scan.n_pings))
    np.testing.assert_array_equal(old.intensity, scan.intensity)


def test_metropolis_renders_in_motion_from_the_same_poses(mitsonar_mod):
    """The per-row poses reach `sonar_mlt` through the same PathSetup: same poses, and the same
    expected total echo energy as path tracing (4 seeds at 256 spp: ratios 0.97 to 1.06)."""
    m = mitsonar_mod
    scene = m.load_scene(os.path.join(SCENES, "box.xml"))
    traj = m.Trajectory.turn(20.0, 0.5, 5.0)
    mlt = m.render_scan(scene, spp=256, seed=2, trajectory=traj, integrator="sonar_mlt", start_time=1.0)
    tof = m.render_scan(scene, spp=256, seed=2, trajectory=traj, start_time=1.0)
    np.testing.assert_array_equal(mlt.poses, tof.poses)
    assert mlt.intensity.sum() / tof.intensity.sum() == pytest.approx(1.0, abs=0.15)
