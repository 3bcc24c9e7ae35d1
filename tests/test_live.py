"""`mitsonar live`: pose datagrams checked, poses interpolated on the sender's clock, each ping
rendered from the pose at its time (closed-form wall ranges in the box scene), the real clients
(brping, the SeaNet driver) served, garbage dropped and counted, clean stops."""
from __future__ import annotations

import contextlib
import io
import json
import math
import os
import signal
import socket
import subprocess
import sys
import time

import numpy as np
import pytest
from conftest import subcommand_runner

from mitsonar.live.poses import (MAX_DATAGRAM, DatagramError, PoseBuffer, parse_datagram, pose_matrix)
from mitsonar.geometry.trajectory import quat_to_matrix

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
BOX = os.path.join(ROOT, "scenes_xml", "box.xml")
# box.xml: walls x = +5, y = +4, y = -4; the mount looks along the vehicle's x (bearing 0)


def yaw_q(deg):
    h = math.radians(deg) / 2
    return [0.0, 0.0, math.sin(h), math.cos(h)]


def dgram(**kw) -> bytes:
    return json.dumps(kw).encode()


# ---------------------------------------------------------------- datagrams

def test_a_good_datagram_is_taken_and_its_quaternion_normalised():
    d = parse_datagram(dgram(t=3.5, position=[1, 2, -3], orientation=[0, 0, 0, 1.0004]))
    assert d["t"] == 3.5 and d["object"] is None
    np.testing.assert_array_equal(d["position"], [1, 2, -3])
    np.testing.assert_allclose(d["orientation"], [0, 0, 0, 1], atol=0)
    assert parse_datagram(dgram(position=[0, 0, 0], orientation=yaw_q(30)))["t"] is None


@pytest.mark.parametrize("data, reason", [
    (b"\xff\xfe not json", "not JSON"),
    (b"{\"position\": [0, 0, 0], ", "not JSON"),
    (b"[1, 2, 3]", "not an object"),
    (dgram(position=[0, 0, 0]), "missing field"),
    (dgram(position=[0, 0, 0], orientation=[0, 0, 0, 1], speed=3), "unknown field"),
    (dgram(position=[0, 0], orientation=[0, 0, 0, 1]), "wrong type"),
    (dgram(position=[0, "1", 0], orientation=[0, 0, 0, 1]), "wrong type"),
    (dgram(position=[0, True, 0], orientation=[0, 0, 0, 1]), "wrong type"),
    (dgram(t="now", position=[0, 0, 0], orientation=[0, 0, 0, 1]), "wrong type"),
    (b'{"position": [NaN, 0, 0], "orientation": [0, 0, 0, 1]}', "not finite"),
    (b'{"t": Infinity, "position": [0, 0, 0], "orientation": [0, 0, 0, 1]}', "not finite"),
    (b'{"position": [1e400, 0, 0], "orientation": [0, 0, 0, 1]}', "not finite"),
    (dgram(position=[0, 0, 0], orientation=[0, 0, 0, 1.01]), "bad quaternion"),
    (dgram(position=[0, 0, 0], orientation=[0, 0, 0, 0]), "bad quaternion"),
    (dgram(position=[0, 0, 0], orientation=[1e200, 0, 0, 1]), "bad quaternion"),
    (b"{" + b" " * MAX_DATAGRAM + b"}", "too large"),
    (b"[" * 100000, "too large"),
])
def test_bad_datagrams_are_refused_with_their_reason(data, reason):
    with pytest.raises(DatagramError) as e, np.errstate(all="raise"):     # and no numpy warning
        parse_datagram(data)
    assert e.value.reason == reason


def test_deep_nesting_within_the_size_limit_is_refused_not_a_crash():
    with pytest.raises(DatagramError):
        parse_datagram(b"[" * (MAX_DATAGRAM - 10))


# ---------------------------------------------------------------- the pose buffer

def test_a_ping_gets_the_pose_interpolated_at_its_time_on_the_senders_clock():
    """Sender clock 1000 s ahead of ours; the least delayed datagram (10 ms) fixes the offset."""
    buf = PoseBuffer()
    assert buf.at(0.0) is None
    buf.add([0, 0, 0], yaw_q(0), t=1000.0, arrival=5.010)
    buf.add([2, 0, 0], yaw_q(90), t=1001.0, arrival=6.300)                             # 300 ms late
    offset = 5.010 - 1000.0
    assert buf.offset == pytest.approx(offset, abs=1e-12)
    # our time 5.51 is the sender's 1000.5: half way
    p = buf.at(1000.5 + offset)
    np.testing.assert_allclose(p[:3, 3], [1, 0, 0], atol=1e-12)
    np.testing.assert_allclose(p[:3, :3], quat_to_matrix(yaw_q(45)), atol=1e-12)
    p = buf.at(1000.25 + offset)
    np.testing.assert_allclose(p[:3, 3], [0.5, 0, 0], atol=1e-12)
    np.testing.assert_allclose(p[:3, :3], quat_to_matrix(yaw_q(22.5)), atol=1e-12)
    # after the newest pose (the stream stopped): held
    np.testing.assert_allclose(buf.at(1e6), pose_matrix([2, 0, 0], yaw_q(90)), atol=1e-12)
    # a pose that arrives out of order is put in its place
    buf.add([4, 0, 0], yaw_q(0), t=1000.75, arrival=7.0)
    np.testing.assert_allclose(buf.at(1000.875 + offset)[:3, 3], [3, 0, 0], atol=1e-12)


def test_datagrams_without_time_are_stamped_on_arrival():
    buf = PoseBuffer()
    buf.add([0, 0, 0], yaw_q(0), arrival=10.0)
    buf.add([1, 0, 0], yaw_q(0), arrival=11.0)
    np.testing.assert_allclose(buf.at(10.25)[:3, 3], [0.25, 0, 0], atol=1e-12)


# ---------------------------------------------------------------- rendering a ping at a pose

@pytest.fixture(scope="module")
def box():
    from mitsonar.live.heads import PingRenderer, live_scene
    from mitsonar.sim.render import pick_sensor

    scene = live_scene(BOX)
    sonar = pick_sensor(scene)
    assert sonar.n_pings == 1 and sonar.bearing_start == 0
    return PingRenderer(scene, sonar, PoseBuffer(), spp=64, seed=1)


def peak_range(scan):
    return float(scan.ranges[int(np.argmax(scan.intensity[0]))])


def test_each_ping_sees_the_wall_where_the_vehicles_pose_puts_it(box):
    bin_w = 12.0 / 500
    box.poses = PoseBuffer()
    assert abs(peak_range(box.render(0.0)) - 5.0) <= bin_w         # no pose: the mount at the origin
    for x, y, yaw, bearing, expected in [(1.5, 0.0, 0, 0.0, 3.5),        # forward: wall x = 5
                                         (0.0, 1.0, 90, 0.0, 3.0),        # yawed left: wall y = 4
                                         (1.0, 0.0, 0, math.pi / 2, 4.0),  # bearing left: wall y = 4
                                         (1.0, -1.0, 0, -math.pi / 2, 3.0)]:
        box.poses.add([x, y, 0.0], yaw_q(yaw))
        scan = box.render(bearing)
        assert abs(peak_range(scan) - expected) <= bin_w, (x, y, yaw, bearing, peak_range(scan))
        assert scan.bearings[0] == bearing
        np.testing.assert_allclose(scan.poses[0][:3, 3], [x, y, 0.0], atol=1e-12)


def test_new_poses_launch_the_same_kernels(box):
    from conftest import jit_kernels

    box.render(0.0)
    box.poses.add([0.3, 0.2, 0.0], yaw_q(10))
    first, _ = jit_kernels(box.render, 0.3)
    box.poses.add([1.1, -0.4, 0.0], yaw_q(-25))
    second, _ = jit_kernels(box.render, -1.0)
    assert first and sorted(first) == sorted(second)


# ---------------------------------------------------------------- the heads, with their clients

def test_the_live_micron_answers_the_seanet_driver_from_the_new_pose(box):
    from mitsonar.live.heads import LiveMicron
    from mitsonar.devices.micron.driver import MicronSonar
    from mitsonar.devices.micron.seanet import HeadSettings

    if not hasattr(os, "openpty"):
        pytest.skip("needs pseudo-terminals")
    box.poses = PoseBuffer()
    settings = HeadSettings(range=12.0, n_bins=500)
    with LiveMicron(box, realtime=False) as vm:
        with MicronSonar(vm.port, settings=settings, timeout=20) as sonar:
            def wall():
                while True:                 # the first scanline ahead (bearing 3200)
                    m = sonar.read_ping()
                    if m.bearing == 3200:
                        return leading_edge(m.bins, settings.bin_width)
            assert abs(wall() - 5.0) <= EDGE_TOL
            box.poses.add([2.0, 0.0, 0.0], yaw_q(0))
            assert abs(wall() - 3.0) <= EDGE_TOL


def leading_edge(samples, width):
    """Range of the first of three samples in a row past 1 m at half scale or more: where the
    wall's echo starts (the strongest sample is no use through the head's 8 bits, which the wall
    saturates; the wall's echo spans many samples, while the receiver's noise alone reaches half
    scale in one or two samples of about one ping in 15 before the wall)."""
    samples = np.asarray(samples)
    i = np.arange(samples.size)
    up = ((i + 0.5) * width > 1.0) & (samples >= 128)
    hit = np.flatnonzero(up[:-2] & up[1:-1] & up[2:])
    return (hit[0] + 0.5) * width if hit.size else math.inf


EDGE_TOL = 0.1      # m: the pulse and the 8-bit receiver blur the edge by a few 2.4 cm bins


def live_process(*args):
    """``mitsonar live ARGS`` in a process: (the process, its output up to the serving line)."""
    env = dict(os.environ)
    env.pop("MITSONAR_DEBUG", None)
    proc = subprocess.Popen([sys.executable, "-m", "mitsonar", "live", *args],
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, env=env)
    lines = []
    for line in proc.stdout:        # ends (EOF) if the command dies before serving
        lines.append(line)
        if line.startswith("live "):
            break
    text = "".join(lines)
    return proc, text


def _start_live(*extra):
    return live_process(BOX, "--spp", "64", "--fast", *extra)


def test_live_ping360_over_udp_follows_pose_datagrams_and_survives_garbage():
    brping = pytest.importorskip("brping")
    proc, text = _start_live("--head", "ping360", "--port-url", "udp://127.0.0.1:0",
                             "--pose-url", "udp://127.0.0.1:0")
    try:
        assert "poses on udp://127.0.0.1:" in text and "live Ping360 on udp://" in text, (text, proc.stderr)
        pose_port = int(text.split("poses on udp://127.0.0.1:")[1].split()[0])
        head = text.split("live Ping360 on udp://")[1].split()[0]
        tx = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        p = brping.Ping360()
        with contextlib.redirect_stdout(io.StringIO()):
            p.connect_udp(*head.rsplit(":", 1)[0:1], int(head.rsplit(":", 1)[1]))
        assert p.initialize()
        n, period = 600, 1067                       # 600 samples to 12 m
        assert p.set_number_of_samples(n) is not None and p.set_sample_period(period) is not None
        width = period * 25e-9 * 1500 / 2

        def wall(angle):
            data = np.frombuffer(p.transmitAngle(angle).data, np.uint8)
            assert data.size == n
            return leading_edge(data, width)

        tol = EDGE_TOL
        assert abs(wall(0) - 5.0) <= tol
        garbage = [b"not json", b'{"position": [NaN, 0, 0], "orientation": [0, 0, 0, 1]}',
                   dgram(position=[0, 0, 0], orientation=[0, 0, 0, 2]), b"x" * 8000,
                   dgram(position="here", orientation=[0, 0, 0, 1])]
        for g in garbage:
            tx.sendto(g, ("127.0.0.1", pose_port))
        tx.sendto(dgram(t=50.0, position=[1.5, 0, 0], orientation=yaw_q(0)), ("127.0.0.1", pose_port))
        # the datagram is applied by another thread: ping until it shows (bounded)
        got = [wall(0) for _ in range(1)]
        for _ in range(50):
            if abs(got[-1] - 3.5) <= tol:
                break
            got.append(wall(0))
        assert abs(got[-1] - 3.5) <= tol, got
        # a Ping360's angle 100 gradians is 90 deg clockwise: the starboard wall y = -4
        tx.sendto(dgram(t=51.0, position=[1.5, 0.5, 0], orientation=yaw_q(0)), ("127.0.0.1", pose_port))
        got = [wall(100) for _ in range(1)]
        for _ in range(50):
            if abs(got[-1] - 4.5) <= tol:
                break
            got.append(wall(100))
        assert abs(got[-1] - 4.5) <= tol, got
        p.iodev.close()
        tx.close()
        proc.send_signal(signal.SIGINT)
        out, err = proc.communicate(timeout=60)
        assert proc.returncode == 0 and "Traceback" not in err, err
        assert "2 poses applied, 5 datagrams dropped" in out, out
        assert "dropped a pose datagram" in err
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.communicate()


def test_live_stops_after_seconds_and_on_sigterm_and_sums_up_on_sigusr1():
    proc, text = _start_live("--head", "ping360", "--port-url", "udp://127.0.0.1:0", "--seconds", "0.5")
    out, err = proc.communicate(timeout=120)
    assert proc.returncode == 0 and "live Ping360 on" in text and "0 pings rendered" in out, (text, out, err)
    proc, text = _start_live("--head", "ping360", "--port-url", "udp://127.0.0.1:0",
                             "--pose-url", "udp://127.0.0.1:0")
    try:
        assert "live Ping360 on" in text, text
        proc.send_signal(signal.SIGUSR1)            # the summary so far, and it goes on
        assert "0 pings rendered; 0 poses applied, 0 datagrams dropped" in proc.stdout.readline()
        assert proc.poll() is None
        proc.send_signal(signal.SIGTERM)
        out, err = proc.communicate(timeout=60)
        assert proc.returncode == 0 and "Traceback" not in err, err
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.communicate()


def test_bad_pose_urls_are_one_line_before_the_scene_loads(capsys):
    from mitsonar.cli import live as live_cli
    from test_serial_cli import one_error_line

    cli = subcommand_runner(live_cli)

    for url in ("udp://10.0.0.1:5000", "tcp://127.0.0.1:5000", "udp://127.0.0.1:notaport"):
        assert cli("live", BOX, "--pose-url", url) == 1
        assert "expected udp://127.0.0.1:PORT" in one_error_line(capsys, "live")
    assert cli("live", BOX, "--pose-url", "udp://127.0.0.1:0", "--trajectory", "x.tum") == 1
    assert "give one" in one_error_line(capsys, "live")


def test_a_trajectory_replays_in_real_time_and_holds_its_last_pose():
    from mitsonar.live.poses import TrajectoryReplay
    from mitsonar.geometry.trajectory import Trajectory

    traj = Trajectory.straight(duration=4.0, speed=0.5, t0=100.0)
    replay = TrajectoryReplay(traj, start=20.0)
    np.testing.assert_allclose(replay.at(21.0), traj.at(101.0), atol=1e-12)
    assert not replay.ended
    np.testing.assert_allclose(replay.at(90.0), traj.at(traj.span[1]), atol=1e-12)
    assert replay.ended


def test_an_object_datagram_moves_a_shape_and_its_echo(box):
    from mitsonar.live.heads import PoseReceiver, SceneObjects

    objects = SceneObjects(box.scene, box.lock)
    assert "wall_xpos" in objects.names and "sonar" not in objects.names
    box.poses = PoseBuffer()
    receiver = PoseReceiver(socket.socket(socket.AF_INET, socket.SOCK_DGRAM), box.poses, objects=objects.move,
                            out=io.StringIO())
    try:
        assert receiver.handle(dgram(object="wall_xpos", position=[-1.5, 0, 0], orientation=[0, 0, 0, 1]), 0.0)
        assert abs(peak_range(box.render(0.0)) - 3.5) <= 12.0 / 500
        assert not receiver.handle(dgram(object="no_such", position=[0, 0, 0], orientation=[0, 0, 0, 1]), 0.0)
        assert receiver.drops.counts == {"unknown object": 1}
        assert receiver.handle(dgram(object="wall_xpos", position=[0, 0, 0], orientation=[0, 0, 0, 1]), 0.0)
        assert abs(peak_range(box.render(0.0)) - 5.0) <= 12.0 / 500
        assert receiver.stats["objects"] == 2
    finally:
        receiver.sock.close()


# ---------------------------------------------------------------- MAVLink (ArduSub)

def _mav():
    pytest.importorskip("pymavlink")
    from pymavlink.dialects.v20 import common

    return common


def _encoded(mav, msg) -> bytes:
    return msg.pack(mav)


def test_ned_frd_to_enu_flu():
    """A level vehicle facing north: forward is world +y, port is west (-x); facing east
    (yaw 90 deg in NED): forward is +x. Positions: (north, east, down) -> (east, north, up)."""
    from mitsonar.live.mavlink import ned_to_enu

    p, q = ned_to_enu([10.0, 3.0, 2.0], [1.0, 0.0, 0.0, 0.0])
    np.testing.assert_allclose(p, [3.0, 10.0, -2.0])
    r = quat_to_matrix(q)
    np.testing.assert_allclose(r @ [1, 0, 0], [0, 1, 0], atol=1e-12)
    np.testing.assert_allclose(r @ [0, 1, 0], [-1, 0, 0], atol=1e-12)
    np.testing.assert_allclose(r @ [0, 0, 1], [0, 0, 1], atol=1e-12)
    h = math.radians(90) / 2                               # yaw about NED's down axis: north -> east
    _, q = ned_to_enu([0, 0, 0], [math.cos(h), 0.0, 0.0, math.sin(h)])
    np.testing.assert_allclose(quat_to_matrix(q) @ [1, 0, 0], [1, 0, 0], atol=1e-12)
    h = math.radians(30) / 2                               # pitch nose up 30 deg (FRD +y is right)
    _, q = ned_to_enu([0, 0, 0], [math.cos(h), 0.0, math.sin(h), 0.0])
    np.testing.assert_allclose(quat_to_matrix(q) @ [1, 0, 0], [0, math.cos(math.radians(30)),
                                                               math.sin(math.radians(30))], atol=1e-12)


def test_mavlink_messages_encoded_by_pymavlink_become_poses():
    common = _mav()
    from mitsonar.live.mavlink import MavlinkReceiver

    buf = PoseBuffer()
    rx = MavlinkReceiver("udpin:127.0.0.1:0", buf, out=io.StringIO())
    try:
        port = int(rx.address.rsplit(":", 1)[1])
        enc = common.MAVLink(None, srcSystem=1, srcComponent=1)
        dec = common.MAVLink(None)
        h = math.radians(90) / 2
        msgs = [enc.local_position_ned_encode(1000, 4.0, -1.0, 2.5, 0, 0, 0),
                enc.attitude_quaternion_encode(1000, math.cos(h), 0.0, 0.0, math.sin(h), 0, 0, 0),
                enc.attitude_quaternion_encode(1100, float("nan"), 0.0, 0.0, 1.0, 0, 0, 0)]
        wires = [_encoded(enc, m) for m in msgs]
        now = time.monotonic()      # the arrivals on our clock: the socket's below arrive on it too
        got = [rx.handle(dec.decode(bytearray(w)), now) for w in wires]
        assert got == [False, True, False] and rx.stats["dropped"] == 1 and rx.drops.counts == {"not finite": 1}
        pose = buf.at(now)
        np.testing.assert_allclose(pose[:3, 3], [-1.0, 4.0, -2.5])
        np.testing.assert_allclose(pose[:3, :3] @ [1, 0, 0], [1, 0, 0], atol=1e-6)
        # and through the socket, read by the receiver's thread
        rx.start()
        tx = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        tx.sendto(_encoded(enc, enc.local_position_ned_encode(2000, 7.0, 0.0, 0.0, 0, 0, 0)), ("127.0.0.1", port))
        for _ in range(200):
            if rx.stats["poses"] >= 2:
                break
            threading_event_wait(0.05)
        tx.close()
        assert rx.stats["poses"] == 2
        np.testing.assert_allclose(buf.at(1e9)[:3, 3], [0.0, 7.0, 0.0])
    finally:
        rx.stop()


def threading_event_wait(seconds):
    import threading

    threading.Event().wait(seconds)


def test_stale_ping360_requests_are_coalesced_to_the_newest(box):
    """Requests that wait while a ping renders: only the newest is answered."""
    from mitsonar.live.heads import LivePing360
    from mitsonar.devices.ping360.protocol import Message, StreamParser, encode

    box.poses = PoseBuffer()
    with LivePing360(box, "udp://127.0.0.1:0", realtime=False) as head:
        port = int(head.port.rsplit(":", 1)[1])
        tx = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        tx.settimeout(30)
        angles = [10, 20, 30, 40, 50]
        with box.lock:              # the head is busy rendering: the requests wait on the line
            for a in angles:
                tx.sendto(encode(Message("transducer", mode=1, gain_setting=1, angle=a, transmit_duration=32,
                                         sample_period=80, transmit_frequency=740, number_of_samples=200,
                                         transmit=1)), ("127.0.0.1", port))
            threading_event_wait(0.2)
        parser, replies = StreamParser(), []
        while not replies or replies[-1] != angles[-1]:
            for m in parser.feed(tx.recv(65536)):
                if m.name == "device_data":
                    replies.append(m.angle)
        tx.close()
        # the head may have taken one request before the others arrived (it then renders it,
        # held by the lock); all that waited together get one answer, the newest's
        assert len(replies) <= 2 and replies[-1] == angles[-1], replies
        assert head.stats["stale requests skipped"] == len(angles) - len(replies)
        assert head.stats["pings"] == len(replies)


def test_drops_are_reported_at_most_every_two_seconds_and_a_silent_stream_is_said_once():
    from mitsonar.live.heads import PoseReceiver

    out = io.StringIO()
    rx = PoseReceiver(socket.socket(socket.AF_INET, socket.SOCK_DGRAM), PoseBuffer(), out=out)
    try:
        for k in range(5):
            assert not rx.handle(b"garbage", 100.0 + 0.1 * k)
        assert not rx.handle(dgram(position=[0, 0, 0], orientation=[0, 0, 0, 3]), 102.5)
        lines = out.getvalue().splitlines()
        assert len(lines) == 2 and "not a UTF-8 JSON text" in lines[0]
        assert "norm 3" in lines[1] and "(4 more dropped since the last report)" in lines[1], lines
        assert rx.drops.counts == {"not JSON": 5, "bad quaternion": 1} and rx.stats["dropped"] == 6
        # the pose stream stops: one warning, until poses come again
        out.truncate(0), out.seek(0)
        assert rx.handle(dgram(position=[1, 2, 3], orientation=[0, 0, 0, 1]), time.monotonic() - 10)
        rx._check_stale()
        rx._check_stale()
        assert out.getvalue().count("holding the last one") == 1
        np.testing.assert_allclose(rx.buffer.at()[:3, 3], [1, 2, 3])
        assert rx.handle(dgram(position=[1, 2, 3], orientation=[0, 0, 0, 1]), time.monotonic() - 10)
        rx._check_stale()
        assert out.getvalue().count("holding the last one") == 2
    finally:
        rx.sock.close()


# ---------------------------------------------------------------- poses that would poison a session

def _wait_for(cond, what):
    for _ in range(400):
        if cond():
            return
        threading_event_wait(0.025)
    raise AssertionError(f"timed out waiting for {what}")


@pytest.mark.parametrize("wild_t", [1e300, -1e300, 10.0 + 3600.0, 10.0 - 3600.0])
def test_a_wild_time_stamp_over_udp_is_dropped_and_the_good_poses_after_it_are_applied(box, wild_t):
    """Issue 56: a stamp of 1e300 set the clock offset, and every correctly stamped pose after it
    was ignored for the rest of the session (0 dropped). Now it is refused, counted by reason, and
    the offset does not move; the next good pose moves the echo."""
    import warnings

    from mitsonar.cli.live import _summary
    from mitsonar.live.heads import PoseReceiver, pose_socket

    box.poses = PoseBuffer()
    rx = PoseReceiver(pose_socket("udp://127.0.0.1:0"), box.poses, out=io.StringIO()).start()
    tx = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    port = int(rx.url.rsplit(":", 1)[1])
    try:
        with warnings.catch_warnings(), np.errstate(all="raise"):
            warnings.simplefilter("error")
            tx.sendto(dgram(t=10.0, position=[0, 0, 0], orientation=yaw_q(0)), ("127.0.0.1", port))
            _wait_for(lambda: rx.stats["poses"] == 1, "the first pose")
            offset = box.poses.offset
            tx.sendto(dgram(t=wild_t, position=[0.5, 0, 0], orientation=yaw_q(0)), ("127.0.0.1", port))
            _wait_for(lambda: rx.stats["poses"] + rx.stats["dropped"] == 2, "the wild pose")
            assert rx.stats["dropped"] == 1 and rx.drops.counts == {"implausible time": 1}
            assert box.poses.offset == offset and len(box.poses) == 1
            tx.sendto(dgram(t=10.5, position=[1.5, 0, 0], orientation=yaw_q(0)), ("127.0.0.1", port))
            _wait_for(lambda: rx.stats["poses"] == 2, "the next good pose")
            assert abs(peak_range(box.render(0.0)) - 3.5) <= 12.0 / 500     # wall x = 5 from x = 1.5
        assert "2 poses applied, 1 datagrams dropped (1 implausible time)" in _summary(box, rx, None)
        assert "'t'" in rx.out.getvalue() and "off the sender's clock" in rx.out.getvalue()
    finally:
        tx.close()
        rx.stop()


def test_a_position_beyond_the_scene_is_dropped_and_pings_stay_finite(box):
    """Issue 56: a position of 1e308 was taken and zeroed every ping with numpy overflow warnings.
    Now positions outside the scene's box enlarged by BOUNDS_MARGIN are refused."""
    import warnings

    from mitsonar.live.heads import PoseReceiver

    box.poses = PoseBuffer()            # without a scene's bounds: |x|, |y|, |z| <= MAX_COORDINATE
    rx = PoseReceiver(socket.socket(socket.AF_INET, socket.SOCK_DGRAM), box.poses, out=io.StringIO())
    try:
        with warnings.catch_warnings(), np.errstate(all="raise"):
            warnings.simplefilter("error")
            assert not rx.handle(dgram(t=0.0, position=[1e308, 1e308, 1e308], orientation=yaw_q(0)), 100.0)
            assert len(box.poses) == 0 and rx.drops.counts == {"out of bounds": 1}
            assert rx.handle(dgram(t=0.5, position=[1.5, 0, 0], orientation=yaw_q(0)), 100.5)
            scan = box.render(0.0, now=100.5)
            assert np.all(np.isfinite(scan.intensity)) and abs(peak_range(scan) - 3.5) <= 12.0 / 500
    finally:
        rx.sock.close()
    # with the scene's: its box enlarged by BOUNDS_MARGIN
    from mitsonar.live.heads import pose_bounds
    from mitsonar.live.poses import BOUNDS_MARGIN

    lo, hi = pose_bounds(box.scene)
    np.testing.assert_allclose(hi - lo, np.array(box.scene.bbox().extents()) + 2 * BOUNDS_MARGIN, rtol=1e-6)
    box.poses = PoseBuffer(bounds=(lo, hi))
    rx = PoseReceiver(socket.socket(socket.AF_INET, socket.SOCK_DGRAM), box.poses, out=io.StringIO())
    try:
        with warnings.catch_warnings(), np.errstate(all="raise"):
            warnings.simplefilter("error")
            for k, position in enumerate([[1e308, 1e308, 1e308], [hi[0] + 1.0, 0, 0], [0, lo[1] - 1.0, 0]]):
                assert not rx.handle(dgram(t=float(k), position=position, orientation=yaw_q(0)), 100.0 + k)
            assert len(box.poses) == 0 and rx.drops.counts == {"out of bounds": 3}
            assert rx.handle(dgram(t=3.0, position=[hi[0] - 1.0, 0, 0], orientation=yaw_q(0)), 103.0)  # inside
            assert rx.handle(dgram(t=4.0, position=[1.5, 0, 0], orientation=yaw_q(0)), 104.0)
            scan = box.render(0.0, now=104.0)
            assert np.all(np.isfinite(scan.intensity)) and abs(peak_range(scan) - 3.5) <= 12.0 / 500
            # an object's offset is held to MAX_COORDINATE, with the same reason
            rx.objects = lambda *a: pytest.fail("an out-of-bounds object move was applied")
            assert not rx.handle(dgram(object="wall_xpos", position=[1e308, 0, 0], orientation=yaw_q(0)), 105.0)
        assert rx.drops.counts == {"out of bounds": 4} and rx.stats["poses"] == 2
    finally:
        rx.sock.close()


def test_a_sender_whose_clock_jumped_is_followed_after_clock_resync_poses_in_a_row():
    """A wild first stamp (nothing to refuse it against yet), or a restarted sender (MAVLink's
    time_boot_ms starts again at 0): CLOCK_RESYNC poses in a row that agree with each other
    restart the clock; fewer, or ones that disagree, do not."""
    from mitsonar.live.poses import CLOCK_RESYNC

    buf = PoseBuffer()
    buf.add([9, 9, 0], yaw_q(0), t=1e300, arrival=5.0)         # the first stamp: taken
    for k in range(CLOCK_RESYNC - 1):
        with pytest.raises(DatagramError) as e:
            buf.add([k, 0, 0], yaw_q(0), t=100.0 + 0.1 * k, arrival=5.0 + 0.1 * k)
        assert e.value.reason == "implausible time"
        np.testing.assert_allclose(buf.at(6.0)[:3, 3], [9, 9, 0])
    buf.add([7, 0, 0], yaw_q(0), t=100.0 + 0.1 * CLOCK_RESYNC, arrival=5.0 + 0.1 * CLOCK_RESYNC)
    assert buf.resyncs == 1 and len(buf) == 1
    assert buf.offset == pytest.approx(5.0 - 100.0)
    np.testing.assert_allclose(buf.at(6.0)[:3, 3], [7, 0, 0])
    # wild stamps that disagree with each other never restart it
    for k in range(3 * CLOCK_RESYNC):
        with pytest.raises(DatagramError):
            buf.add([0, 0, 0], yaw_q(0), t=(-1) ** k * 1e6 * (k + 1), arrival=6.0)
    assert buf.resyncs == 1 and len(buf) == 1


def test_mavlink_poses_off_the_clock_or_the_bounds_are_dropped_with_their_reason():
    common = _mav()
    from mitsonar.cli.live import _summary
    from mitsonar.live.mavlink import MavlinkReceiver

    buf = PoseBuffer()
    rx = MavlinkReceiver("udpin:127.0.0.1:0", buf, out=io.StringIO())
    try:
        enc = common.MAVLink(None, srcSystem=1, srcComponent=1)
        dec = common.MAVLink(None)
        msgs = [enc.attitude_quaternion_encode(1000, 1.0, 0.0, 0.0, 0.0, 0, 0, 0),
                enc.local_position_ned_encode(1000, 4.0, -1.0, 2.5, 0, 0, 0),            # a pose
                enc.local_position_ned_encode(4_000_000_000, 5.0, -1.0, 2.5, 0, 0, 0),   # 46 days on
                enc.local_position_ned_encode(1100, 1e6, -1.0, 2.5, 0, 0, 0),            # 1000 km north
                enc.local_position_ned_encode(1200, 6.0, -1.0, 2.5, 0, 0, 0)]            # a pose
        got = [rx.handle(dec.decode(bytearray(_encoded(enc, m))), 50.0 + 0.1 * k) for k, m in enumerate(msgs)]
        assert got == [False, True, False, False, True]
        assert rx.drops.counts == {"implausible time": 1, "out of bounds": 1} and rx.stats["poses"] == 2
        np.testing.assert_allclose(buf.at(1e9)[:3, 3], [-1.0, 6.0, -2.5])
        assert "2 MAVLink poses, 2 dropped (1 implausible time, 1 out of bounds)" in _summary(
            PingLogless(), None, rx)
        assert "dropped a MAVLink message" in rx.out.getvalue()
    finally:
        rx.stop()


class PingLogless:
    """A renderer's summary, for `_summary` without a scene."""

    def summary(self):
        return "0 pings rendered"
