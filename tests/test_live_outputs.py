"""`mitsonar live --foxglove/--mcap`: each rendered ping reaches Foxglove (read back with a minimal
client of the published ``foxglove.websocket.v1`` protocol) and an MCAP file (read back with the
``mcap`` reader and protobuf's own decoder, neither of them foxglove-sdk): the schemas advertised,
the raw ping's bytes equal to the rendered scan's, the picture where geometry puts each bin, the
frames as given; a slow output drops the oldest pings (counted), never the head's; bad flags are
one line before any work, and no file."""
from __future__ import annotations

import base64
import contextlib
import io
import json
import math
import os
import signal
import socket
import struct
import subprocess
import sys
import threading

import numpy as np
import pytest
from conftest import subcommand_runner

from mitsonar.live.poses import PoseBuffer
from mitsonar.geometry.trajectory import quat_to_matrix

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
BOX = os.path.join(ROOT, "scenes_xml", "box.xml")


def yaw_q(deg):
    h = math.radians(deg) / 2
    return [0.0, 0.0, math.sin(h), math.cos(h)]


class Collect:
    """A `LiveOutput` keeping what it is given (``pings``: ``(t_ns, vehicle, mount, scan)``);
    ``gate``: an event it waits on before taking each ping (set: no wait)."""

    def __init__(self):
        self.pings, self.closed = [], False
        self.gate, self.taking = threading.Event(), threading.Event()
        self.gate.set()

    def publish(self, t_ns, vehicle, mount, scan):
        self.taking.set()
        assert self.gate.wait(30)
        self.pings.append((t_ns, vehicle, mount, scan))

    def close(self):
        self.closed = True


# ---------------------------------------------------------------- the fan-out

def test_a_slow_output_drops_the_oldest_pings_and_counts_them():
    from mitsonar.live.outputs import LiveOutput, LiveOutputs

    slow = Collect()
    assert isinstance(slow, LiveOutput)
    slow.gate.clear()
    outs = LiveOutputs([slow], maxsize=3, out=io.StringIO())
    outs.publish(0, None, None, "ping 0")
    assert slow.taking.wait(30)                   # ping 0 is being sent, stuck in the output
    for k in range(1, 7):                         # 6 more: 3 wait, the 3 oldest of them dropped
        outs.publish(k, None, None, f"ping {k}")
    assert outs.stats["dropped"] == 3
    slow.gate.set()
    outs.close()
    assert [p[0] for p in slow.pings] == [0, 4, 5, 6] and slow.closed
    assert outs.summary() == "4 pings published, 3 dropped"


def test_an_output_that_fails_is_said_once_and_the_others_go_on():
    from mitsonar.live.outputs import LiveOutputs

    class Broken:
        def publish(self, *ping):
            raise RuntimeError("disk full")

        def close(self):
            pass

    good, log = Collect(), io.StringIO()
    outs = LiveOutputs([Broken(), good], out=log)
    for k in range(3):
        outs.publish(k, None, None, None)
    outs.close()
    assert [p[0] for p in good.pings] == [0, 1, 2]
    assert outs.stats["errors"] == 3 and log.getvalue().count("Broken: disk full") == 1


# ---------------------------------------------------------------- the picture

def one_row(bearing, data, r_min=0.0, r_max=10.0, beamwidth=3.0):
    from mitsonar.scan.model import Scan

    data = np.asarray(data, np.uint8)[None]
    n = data.shape[1]
    ranges = r_min + (np.arange(n) + 0.5) * (r_max - r_min) / n
    return Scan(intensity=np.zeros(data.shape, np.float32), data=data, ranges=ranges, bearings=[bearing],
                poses=np.eye(4)[None], range_min=r_min, range_max=r_max, beamwidth_h=beamwidth, kind="mechanical")


def test_a_sweep_puts_each_bin_where_its_bearing_and_range_are():
    """Bearing 0 up the picture, bearing +90 deg (port) to its left (seen from above, as the bags'
    fan and `plot_fan`); a pixel at
    distance r from the centre holds bin floor(r / width); later pings keep the earlier ones."""
    from mitsonar.live.outputs.pictures import Pictures

    size, r_max, n = 200, 10.0, 50
    pictures = Pictures(size=size)
    ahead = np.arange(1, n + 1)                    # bin k holds k + 1
    right = np.arange(101, 101 + n)
    pictures.of(one_row(0.0, ahead, r_max=r_max))
    pic = pictures.of(one_row(math.pi / 2, right, r_max=r_max))
    px = 2 * r_max / size
    c = size // 2
    for i in range(0, c - 30, 7):                  # (nearer the centre, a pixel is wider than the beam)
        r = (c - i - 0.5) * px                     # pixel row i, just right of the centre column
        along = math.hypot(r, 0.5 * px)
        assert pic[i, c] == ahead[int(along / (r_max / n))], i
        assert pic[c - 1, i] == right[int(along / (r_max / n))], i
    assert pic[size - 5, c] == 0 and pic[0, 0] == 0      # behind: no ping yet; outside the circle
    # a third ping at the same bearing replaces its slots only
    pic = pictures.of(one_row(0.0, np.full(n, 7), r_max=r_max))
    assert pic[c - 40, c] == 7 and pic[c - 1, c - 41] == right[int(math.hypot(40.5, 0.5) * px / (r_max / n))]


def test_a_fan_is_drawn_from_above_port_on_the_left():
    """A two-beam fan (bearings +-30 deg; positive bearings turn the boresight towards the beam
    frame's +x, port for an upright head, `bearing_rotation`): the +30 deg beam's level lies left of
    the picture's centre column and up, the -30 deg beam's right, as `plot_fan` draws them."""
    from mitsonar.export.ros.messages import fan_pixels
    from mitsonar.scan.model import Scan

    b = math.radians(30)
    data = np.array([np.full(40, 200), np.full(40, 50)], np.uint8)      # +30 deg: 200, -30 deg: 50
    ranges = (np.arange(40) + 0.5) * 10.0 / 40
    scan = Scan(intensity=np.zeros(data.shape, np.float32), data=data, ranges=ranges, bearings=[b, -b],
                poses=np.tile(np.eye(4), (2, 1, 1)), range_min=0.0, range_max=10.0, beamwidth_h=2.0,
                kind="multibeam")
    pic = fan_pixels(scan, 200)
    h, w = pic.shape
    rows, cols = np.nonzero(pic == 200)
    assert len(cols) and cols.mean() < 0.4 * w and np.mean(cols < w / 2 + 1) == 1
    rows, cols = np.nonzero(pic == 50)
    assert len(cols) and cols.mean() > 0.6 * w and np.mean(cols > w / 2 - 2) == 1
    # at range 8 m along +30 deg: x = -8 sin 30 (left), up 8 cos 30 from the apex at the bottom
    px = (2 * 10.0 * math.sin(b)) / w
    col = int((-8 * math.sin(b) + 10.0 * math.sin(b)) / px)
    row = int((10.0 - 8 * math.cos(b)) / px)
    assert pic[row, col] == 200


# ---------------------------------------------------------------- rendered pings out

@pytest.fixture(scope="module")
def box():
    from mitsonar.live.heads import PingRenderer, live_scene
    from mitsonar.sim.render import pick_sensor

    scene = live_scene(BOX)
    return PingRenderer(scene, pick_sensor(scene), PoseBuffer(), spp=32, seed=3, out=io.StringIO())


def protobuf_class(name, descriptor_set: bytes):
    """The message class of ``name`` from a FileDescriptorSet, with protobuf's own runtime."""
    pytest.importorskip("google.protobuf")
    from google.protobuf import descriptor_pb2, descriptor_pool, message_factory

    pool = descriptor_pool.DescriptorPool()
    for f in descriptor_pb2.FileDescriptorSet.FromString(descriptor_set).file:
        pool.Add(f)
    return message_factory.GetMessageClass(pool.FindMessageTypeByName(name))


def replayed_pictures(scans):
    from mitsonar.live.outputs.pictures import Pictures

    pictures = Pictures()
    return [pictures.of(s).copy() for s in scans]


def check_messages(messages, given, before=()):
    """``messages``: {topic: [(log_time, schema name, encoding, schema bytes, payload)]} as a client
    decoded them; ``given``: the `Collect`'s pings (``before``: those earlier in the sweep). Every
    topic once per ping, in order."""
    n = len(given)
    assert sorted(messages) == ["/sonar/fan", "/sonar/ping", "/tf", "/vehicle/pose"]
    assert all(len(v) == n for v in messages.values()), {k: len(v) for k, v in messages.items()}
    pictures = replayed_pictures([g[3] for g in list(before) + list(given)])[len(before):]
    for k, (t_ns, vehicle, mount, scan) in enumerate(given):
        # the raw ping: the rendered scan's device bytes, ranges and bearing
        t, name, enc, _, payload = messages["/sonar/ping"][k]
        assert (t, name, enc) == (t_ns, "mitsonar.SonarPing", "json")
        ping = json.loads(payload)
        assert base64.b64decode(ping["intensities"]) == scan.data.tobytes()
        assert ping["bearings"] == [float(scan.bearings[0])] and ping["bin_count"] == scan.data.shape[1]
        np.testing.assert_array_equal(ping["ranges"], scan.ranges)
        assert ping["timestamp"] == {"sec": t_ns // 10**9, "nsec": t_ns % 10**9}
        # the picture: the bytes of the sweep so far
        t, name, enc, schema, payload = messages["/sonar/fan"][k]
        assert (t, name, enc) == (t_ns, "foxglove.RawImage", "protobuf")
        img = protobuf_class(name, schema).FromString(payload)
        assert (img.encoding, img.height, img.width, img.step) == ("mono8", *pictures[k].shape, pictures[k].shape[1])
        assert img.data == pictures[k].tobytes() and img.frame_id == "sonar"
        # the frames: map -> base_link the vehicle, base_link -> sonar the mount (z forward, x up)
        t, name, enc, schema, payload = messages["/tf"][k]
        assert (t, name, enc) == (t_ns, "foxglove.FrameTransforms", "protobuf")
        tfs = protobuf_class(name, schema).FromString(payload).transforms
        assert [(f.parent_frame_id, f.child_frame_id) for f in tfs] == [("map", "base_link"), ("base_link", "sonar")]
        for f, pose in zip(tfs, (vehicle, mount)):
            m = np.eye(4)
            m[:3, :3] = quat_to_matrix([f.rotation.x, f.rotation.y, f.rotation.z, f.rotation.w])
            m[:3, 3] = f.translation.x, f.translation.y, f.translation.z
            if f.child_frame_id == "sonar":     # its z is the boresight (mount z), its x the scan axis (mount y)
                np.testing.assert_allclose(m[:3, 2], pose[:3, 2], atol=1e-9)
                np.testing.assert_allclose(m[:3, 0], pose[:3, 1], atol=1e-9)
                np.testing.assert_allclose(m[:3, 3], pose[:3, 3], atol=1e-9)
            else:
                np.testing.assert_allclose(m, pose, atol=1e-9)
        t, name, enc, schema, payload = messages["/vehicle/pose"][k]
        assert (t, name, enc) == (t_ns, "foxglove.PoseInFrame", "protobuf")
        p = protobuf_class(name, schema).FromString(payload)
        assert p.frame_id == "map"
        np.testing.assert_allclose([p.pose.position.x, p.pose.position.y, p.pose.position.z], vehicle[:3, 3], atol=1e-9)
    # the rendered pose is the one given: vehicle @ mount at the ping's bearing
    from mitsonar.geometry.frames import bearing_rotation
    for _, vehicle, mount, scan in given:
        np.testing.assert_allclose(scan.poses[0], vehicle @ mount @ bearing_rotation(scan.bearings[0]), atol=1e-9)


def render_some(box, outs, n=3):
    box.poses = PoseBuffer()
    box.poses.add([1.0, 0.5, 0.0], yaw_q(20))
    box.outputs = outs
    try:
        return [box.render(b) for b in (0.0, math.pi / 2, -math.pi / 2, 0.3, 1.2)[:n]]
    finally:
        box.outputs = None


def read_mcap(path):
    from mcap.reader import make_reader

    out = {}
    with open(path, "rb") as f:
        reader = make_reader(f)
        for schema, channel, message in reader.iter_messages():
            out.setdefault(channel.topic, []).append((message.log_time, schema.name, channel.message_encoding,
                                                     schema.data, message.data))
        summary = reader.get_summary()
    return out, summary


def test_an_mcap_recording_holds_each_rendered_ping(box, tmp_path):
    pytest.importorskip("foxglove")
    pytest.importorskip("mcap")
    from mitsonar.live.outputs import LiveOutputs
    from mitsonar.live.outputs.mcapfile import McapRecording

    path = tmp_path / "live.mcap"
    seen = Collect()
    rec = McapRecording(path)
    assert not path.exists()                      # written under a temporary name until closed
    outs = LiveOutputs([rec, seen])
    scans = render_some(box, outs)
    outs.close()
    assert [g[3] for g in seen.pings] == scans
    assert sorted(os.listdir(tmp_path)) == ["live.mcap"]
    messages, summary = read_mcap(path)
    check_messages(messages, seen.pings)
    assert summary.statistics.message_count == 4 * len(scans)
    assert {s.name: s.encoding for s in summary.schemas.values()} == {
        "foxglove.RawImage": "protobuf", "mitsonar.SonarPing": "jsonschema",
        "foxglove.FrameTransforms": "protobuf", "foxglove.PoseInFrame": "protobuf"}


def test_a_multibeam_frame_is_one_message_of_its_fan(tmp_path):
    """A multibeam head publishes whole frames (all its beams at once): one picture (the bags' fan
    of that frame alone) and one raw ping holding every beam."""
    pytest.importorskip("foxglove")
    from mitsonar.live.outputs import open_outputs
    from mitsonar.export.ros.messages import fan_pixels
    from mitsonar.geometry.frames import bearing_rotation
    from mitsonar.scan.model import Scan

    rng = np.random.default_rng(5)
    bearings = np.radians(np.linspace(-60, 60, 16))
    frames = []
    for k in range(2):
        data = rng.integers(0, 256, (16, 80), dtype=np.uint8)
        frames.append(Scan(intensity=np.zeros(data.shape, np.float32), data=data, ranges=(np.arange(80) + 0.5) * 0.25,
                           bearings=bearings, poses=np.stack([bearing_rotation(b) for b in bearings]),
                           range_min=0.0, range_max=20.0, beamwidth_h=8.0, kind="multibeam"))
    outs = open_outputs(mcap=tmp_path / "mb.mcap")
    for k, frame in enumerate(frames):
        outs.publish(10**18 + k * 10**8, np.eye(4), np.eye(4), frame)
    outs.close()
    messages, _ = read_mcap(tmp_path / "mb.mcap")
    assert {t: len(v) for t, v in messages.items()} == {"/sonar/fan": 2, "/sonar/ping": 2, "/tf": 2, "/vehicle/pose": 2}
    for frame, fan, ping in zip(frames, messages["/sonar/fan"], messages["/sonar/ping"]):
        img = protobuf_class(fan[1], fan[3]).FromString(fan[4])
        assert img.data == fan_pixels(frame, 400).tobytes()
        ping = json.loads(ping[4])
        assert (ping["beam_count"], ping["bin_count"]) == (16, 80)
        assert base64.b64decode(ping["intensities"]) == frame.data.tobytes()
        np.testing.assert_array_equal(ping["bearings"], bearings)


def test_a_discarded_recording_leaves_no_file(tmp_path):
    pytest.importorskip("foxglove")
    from mitsonar.live.outputs import open_outputs

    outs = open_outputs(mcap=tmp_path / "x.mcap")
    outs.discard()
    assert os.listdir(tmp_path) == []


def test_foxglove_websocket_stream_read_by_a_minimal_protocol_client(box):
    """The client speaks the published protocol (github.com/foxglove/ws-protocol, docs/spec.md, v1):
    JSON ``advertise`` of the channels with their schemas, a ``subscribe``, then binary frames of
    opcode 0x01, subscription id (u32 LE), receive time (u64 LE), payload. foxglove-sdk names it
    ``foxglove.sdk.v1`` (the same protocol renamed; it refuses a client offering only
    ``foxglove.websocket.v1``): the client offers both, as the Foxglove app does."""
    pytest.importorskip("foxglove")
    sync = pytest.importorskip("websockets.sync.client")
    from mitsonar.live.outputs import LiveOutputs
    from mitsonar.live.outputs.foxglove import FoxgloveServer

    server = FoxgloveServer(0)
    seen = Collect()
    outs = LiveOutputs([server, seen])
    try:
        with sync.connect(server.url, subprotocols=["foxglove.sdk.v1", "foxglove.websocket.v1"], open_timeout=30) as ws:
            assert ws.subprotocol in ("foxglove.sdk.v1", "foxglove.websocket.v1")
            channels = {}
            while len(channels) < 4:
                msg = ws.recv(timeout=30)
                assert isinstance(msg, str)
                op = json.loads(msg)
                if op["op"] == "advertise":
                    channels.update({c["id"]: c for c in op["channels"]})
            by_topic = {c["topic"]: c for c in channels.values()}
            assert {t: (c["encoding"], c["schemaName"], c.get("schemaEncoding")) for t, c in by_topic.items()} == {
                "/sonar/fan": ("protobuf", "foxglove.RawImage", "protobuf"),
                "/sonar/ping": ("json", "mitsonar.SonarPing", "jsonschema"),
                "/tf": ("protobuf", "foxglove.FrameTransforms", "protobuf"),
                "/vehicle/pose": ("protobuf", "foxglove.PoseInFrame", "protobuf")}
            assert json.loads(by_topic["/sonar/ping"]["schema"])["properties"]["intensities"]["contentEncoding"] == "base64"
            subs = {100 + k: cid for k, cid in enumerate(sorted(channels))}
            ws.send(json.dumps({"op": "subscribe", "subscriptions": [{"id": s, "channelId": c} for s, c in subs.items()]}))

            def receive(timeout):
                """One message data frame as (topic, (time, schema name, encoding, schema, payload))."""
                while True:
                    msg = ws.recv(timeout=timeout)
                    if isinstance(msg, str):
                        continue
                    assert msg[0] == 0x01
                    sub, t_ns = struct.unpack_from("<IQ", msg, 1)
                    c = channels[subs[sub]]
                    schema = base64.b64decode(c["schema"]) if c["schemaEncoding"] == "protobuf" else c["schema"].encode()
                    return c["topic"], (t_ns, c["schemaName"], c["encoding"], schema, bytes(msg[13:]))

            box.poses = PoseBuffer()
            box.poses.add([1.0, 0.5, 0.0], yaw_q(20))
            box.outputs = outs
            # the server takes the subscription when it reads it: ping until a message comes
            for _ in range(100):
                box.render(0.0)
                try:
                    receive(0.5)
                    break
                except TimeoutError:
                    pass
            else:
                pytest.fail("no message reached the client")
            k0 = len(seen.pings) if outs.flush(30) else pytest.fail("outputs stuck")
            scans = [box.render(b) for b in (math.pi / 2, -math.pi / 2, 0.3)]
            assert outs.flush(30)
            mine = {p[0] for p in seen.pings[k0:]}
            assert [p[3] for p in seen.pings[k0:]] == scans
            got = {}
            while sum(len(v) for v in got.values()) < 4 * len(scans):
                topic, message = receive(30)
                if message[0] in mine:           # (the rest of the pings before)
                    got.setdefault(topic, []).append(message)
    finally:
        box.outputs = None
        outs.close()
    check_messages(got, seen.pings[k0:], before=seen.pings[:k0])


def test_outputs_import_no_optional_package_unless_asked():
    code = ("import sys, mitsonar.cli.live, mitsonar.live.heads, mitsonar.live.outputs;"
            "import mitsonar.live.outputs.base, mitsonar.live.outputs.pictures;"
            "bad = [m for m in ('foxglove', 'cyclonedds', 'websockets', 'mcap') if m in sys.modules];"
            "assert not bad, bad")
    subprocess.run([sys.executable, "-c", code], check=True, timeout=120)


# ---------------------------------------------------------------- the command

def _start_live(*extra):
    from test_live import _start_live as start
    return start(*extra)


def test_live_session_recorded_to_mcap_is_complete_after_sigint(tmp_path):
    brping = pytest.importorskip("brping")
    pytest.importorskip("foxglove")
    from mitsonar.devices.ping360.head import angle_to_radians

    path = tmp_path / "session.mcap"
    proc, text = _start_live("--head", "ping360", "--port-url", "udp://127.0.0.1:0", "--mcap", str(path),
                             "--foxglove", "0")
    try:
        assert f"recording to {path}" in text and "foxglove on ws://127.0.0.1:" in text, (text, proc.stderr)
        head = text.split("live Ping360 on udp://")[1].split()[0]
        p = brping.Ping360()
        with contextlib.redirect_stdout(io.StringIO()):
            p.connect_udp(head.rsplit(":", 1)[0], int(head.rsplit(":", 1)[1]))
        assert p.initialize()
        angles = (0, 100, 250)
        for a in angles:
            assert p.transmitAngle(a) is not None
        p.iodev.close()
        assert not path.exists()                      # being written under a temporary name
        proc.send_signal(signal.SIGINT)
        out, err = proc.communicate(timeout=60)
        assert proc.returncode == 0 and "Traceback" not in err, err
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.communicate()
    n = int(out.split(" pings rendered")[0].split()[-1])
    assert n >= len(angles) and f"{n} pings published, 0 dropped" in out, out
    assert sorted(os.listdir(tmp_path)) == ["session.mcap"]
    messages, summary = read_mcap(path)
    assert summary.statistics.message_count == 4 * n
    assert {t: len(v) for t, v in messages.items()} == {"/sonar/fan": n, "/sonar/ping": n, "/tf": n, "/vehicle/pose": n}
    pings = [json.loads(m[4]) for m in messages["/sonar/ping"]][-len(angles):]
    for a, ping in zip(angles, pings):
        assert math.isclose(math.remainder(ping["bearings"][0] - angle_to_radians(a), 2 * math.pi), 0, abs_tol=1e-9)
        assert len(base64.b64decode(ping["intensities"])) == ping["bin_count"] == len(ping["ranges"])


def test_bad_output_flags_are_one_line_before_the_scene_loads_and_leave_no_file(capsys, tmp_path):
    pytest.importorskip("foxglove")

    from mitsonar.cli import live as live_cli
    from test_serial_cli import one_error_line

    cli = subcommand_runner(live_cli)

    (tmp_path / "old.mcap").write_bytes(b"keep")
    busy = socket.socket()
    busy.bind(("127.0.0.1", 0))
    busy.listen()
    port = busy.getsockname()[1]
    try:
        for argv, words in [(("--mcap", tmp_path / "x.bag"), "must end in .mcap"),
                            (("--mcap", tmp_path / "old.mcap"), "exists; --force to overwrite"),
                            (("--mcap", tmp_path / "no" / "x.mcap"), "does not exist"),
                            (("--mcap", tmp_path), "is a folder"),
                            (("--mcap", tmp_path / "new.mcap", "--foxglove", port), f"--foxglove {port}: cannot listen")]:
            assert cli("live", BOX, "--head", "ping360", *argv) == 1
            assert words in one_error_line(capsys, "live"), argv
        assert sorted(os.listdir(tmp_path)) == ["old.mcap"] and (tmp_path / "old.mcap").read_bytes() == b"keep"
    finally:
        busy.close()
    for argv, words in [(("--foxglove", "70000"), "expected a TCP port from 0 to 65535"),
                        (("--foxglove", "x"), "expected a TCP port"), (("--dds", "300"), "expected a DDS domain id")]:
        with pytest.raises(SystemExit) as e:
            cli("live", BOX, *argv)
        assert e.value.code == 2 and words in capsys.readouterr().err


# ---------------------------------------------------------------- ROS 2 over DDS

LOOPBACK = ('<CycloneDDS><Domain id="any"><General><Interfaces><NetworkInterface name="lo"/></Interfaces>'
            '</General></Domain></CycloneDDS>')


def test_dds_topics_are_ros2_messages_a_subscriber_reads(box, monkeypatch):
    """A cyclonedds subscriber on the same host (loopback, a domain of this process's own) reads
    the four topics under ROS 2's names; each sample's CDR is byte for byte what mcap-ros2-support
    encodes from the ROS 2 ``.msg`` definitions for the same message (so ``rclcpp`` reads it)."""
    pytest.importorskip("cyclonedds")
    mcap_ros2 = pytest.importorskip("mcap_ros2._dynamic")
    monkeypatch.setenv("CYCLONEDDS_URI", LOOPBACK)
    from cyclonedds.domain import DomainParticipant
    from cyclonedds.sub import DataReader
    from cyclonedds.topic import Topic

    from mitsonar.live.outputs import LiveOutputs
    from mitsonar.live.outputs.dds import TOPICS, DdsOutput, ros_qos, ros_types
    from mitsonar.export.ros import messages as M
    from mitsonar.export.ros import msgdefs

    domain = 100 + os.getpid() % 100
    types = ros_types()
    assert {n: types[t].__idl_typename__ for n, t in TOPICS.items()} == {
        "rt/sonar/fan": "sensor_msgs::msg::dds_::Image_",
        "rt/sonar/image": "marine_acoustic_msgs::msg::dds_::ProjectedSonarImage_",
        "rt/tf": "tf2_msgs::msg::dds_::TFMessage_", "rt/vehicle/pose": "geometry_msgs::msg::dds_::PoseStamped_"}
    dds, seen = DdsOutput(domain), Collect()
    outs = LiveOutputs([dds, seen])
    participant = DomainParticipant(domain)
    readers = {n: DataReader(participant, Topic(participant, n, types[t]), qos=ros_qos()) for n, t in TOPICS.items()}
    got = {n: [] for n in TOPICS}

    def take():
        for n, r in readers.items():
            got[n] += r.take(N=100)

    try:
        box.poses = PoseBuffer()
        box.poses.add([1.0, 0.5, 0.0], yaw_q(20))
        box.outputs = outs
        for _ in range(100):                    # until the reader and the writers have met
            box.render(0.0)
            assert outs.flush(30)
            threading.Event().wait(0.1)
            take()
            if all(got.values()):
                break
        k0 = len(seen.pings)
        scans = [box.render(b) for b in (math.pi / 2, -0.4)]
        assert outs.flush(30)
        mine = {p[0] for p in seen.pings[k0:]}

        def stamp_ns(sample):
            h = sample.transforms[0].header if hasattr(sample, "transforms") else sample.header
            return h.stamp.sec * 10**9 + h.stamp.nanosec

        for _ in range(300):
            take()
            if all(sum(stamp_ns(s) in mine for s in v) == len(scans) for v in got.values()):
                break
            threading.Event().wait(0.1)
    finally:
        box.outputs = None
        outs.close()
    mine_by_topic = {n: [s for s in v if stamp_ns(s) in mine] for n, v in got.items()}
    assert {n: len(v) for n, v in mine_by_topic.items()} == {n: len(scans) for n in TOPICS}
    pictures = replayed_pictures([p[3] for p in seen.pings])[k0:]
    encoders = {t: mcap_ros2.serialize_dynamic(t, msgdefs.definition(t))[t] for t in
                ("sensor_msgs/msg/Image", "marine_acoustic_msgs/msg/ProjectedSonarImage", "tf2_msgs/msg/TFMessage")}
    for k, (t_ns, vehicle, mount, scan) in enumerate(seen.pings[k0:]):
        assert scan is scans[k]
        fan, image = mine_by_topic["rt/sonar/fan"][k], mine_by_topic["rt/sonar/image"][k]
        assert bytes(fan.data) == pictures[k].tobytes() and (fan.height, fan.width) == pictures[k].shape
        assert bytes(image.image.data) == scan.data.tobytes() and image.header.frame_id == "sonar"
        assert fan.serialize() == bytes(encoders["sensor_msgs/msg/Image"](M.mono8(t_ns, "sonar", pictures[k])))
        assert image.serialize() == bytes(encoders["marine_acoustic_msgs/msg/ProjectedSonarImage"](
            M.projected_image(scan, [0], t_ns)))
        sonar = mount @ M.SONAR_AXES                 # the mount in ROS sonar axes: where the ping was
        np.testing.assert_allclose(sonar, np.linalg.inv(vehicle) @ M.sonar_pose(scan, 0), atol=1e-12)
        assert mine_by_topic["rt/tf"][k].serialize() == bytes(encoders["tf2_msgs/msg/TFMessage"](
            {"transforms": [M.transform(vehicle, t_ns, "map", "base_link"),
                            M.transform(sonar, t_ns, "base_link", "sonar")]}))
        pose = mine_by_topic["rt/vehicle/pose"][k].pose
        np.testing.assert_allclose([pose.position.x, pose.position.y, pose.position.z], vehicle[:3, 3], atol=1e-12)
