"""ROS 2 bags (issue 28): scans written as MCAP read back with the `mcap` reader and decode with
the ROS 2 decoder of `mcap-ros2-support` (no ROS install): topics, counts, stamps, bytes, frames."""
import math
import os

import numpy as np
import pytest

from mitsonar import Scan
from mitsonar.geometry.frames import bearing_rotation
from mitsonar.export.ros import TOPICS, ExportError, write_mcap
from mitsonar.export.ros import msgdefs

pytest.importorskip("mcap_ros2")
from mcap.reader import make_reader  # noqa: E402
from mcap_ros2.decoder import DecoderFactory  # noqa: E402


def _scan(kind, rows=7, bins=32, start=None, seed=0, head=None, **tx):
    rng = np.random.default_rng(seed)
    data = rng.integers(0, 256, size=(rows, bins), dtype=np.uint8)
    bearings = np.radians(np.linspace(-30, 30, rows)) if kind == "multibeam" else np.radians(np.arange(rows) * 1.8)
    head = np.eye(4) if head is None else head
    poses = head @ bearing_rotation(bearings)
    times = np.zeros(rows) if kind == "multibeam" else np.arange(rows) * 0.05
    meta = {} if start is None else {"start_time": start}
    meta.update(tx)
    return Scan(intensity=np.zeros((rows, bins), np.float32), data=data, ranges=np.linspace(0.1, 10, bins),
                bearings=bearings, poses=poses, range_min=0.0, range_max=10.1, kind=kind, beamwidth_h=2.0,
                beamwidth_v=20.0, sound_speed=1480.0, times=times, meta=meta)


def _read(path):
    out = []
    with open(path, "rb") as fh:
        reader = make_reader(fh, decoder_factories=[DecoderFactory()])
        for schema, channel, message, decoded in reader.iter_decoded_messages():
            out.append((channel.topic, schema.name, message.log_time, decoded))
    return out


def _ns(stamp):
    return stamp.sec * 1_000_000_000 + stamp.nanosec


def test_definitions_are_the_upstream_ros2_ones():
    text = msgdefs.definition("marine_acoustic_msgs/msg/ProjectedSonarImage")
    assert "geometry_msgs/Vector3[] beam_directions" in text and "float32[] ranges" in text
    assert "MSG: marine_acoustic_msgs/PingInfo\n" in text and "float32[] rx_beamwidths" in text
    assert "MSG: marine_acoustic_msgs/SonarImageData\n" in text and "uint32 beam_count" in text
    assert "MSG: std_msgs/Header\n" in text and "MSG: builtin_interfaces/Time\n" in text
    assert text.count("=" * 80 + "\n") == 5


def test_multibeam_and_mechanical_round_trip(tmp_path):
    fls = _scan("multibeam", start=2.5)
    mech = _scan("mechanical", rows=5, start=3.0, seed=1, tx_beamwidth_v=40.0)
    path = tmp_path / "out.mcap"
    counts = write_mcap(path, [fls, mech], start=100.0)
    msgs = _read(path)
    by_topic = {}
    for topic, schema, log_time, decoded in msgs:
        by_topic.setdefault(topic, []).append((schema, log_time, decoded))
    assert set(by_topic) == set(TOPICS) - {"/tf_static", "/fix", "/sonar/points"}    # no trajectory, side-scan, origin, 3D cloud
    assert {t: len(v) for t, v in by_topic.items()} == counts
    for topic, items in by_topic.items():
        assert {s for s, _, _ in items} == {TOPICS[topic]}
    images = by_topic["/sonar/image"]
    assert len(images) == 1 + 5                       # one per ping: the frame, then each mechanical ping
    first = images[0][2]
    assert _ns(first.header.stamp) == images[0][1] == 102_500_000_000
    assert first.header.frame_id == "sonar"
    assert first.image.beam_count == 7 and first.image.dtype == 0 and not first.image.is_bigendian
    assert bytes(first.image.data) == fls.data.T.tobytes()  # range-major: range * beam_count + beam
    assert np.allclose(first.ranges, fls.ranges.astype(np.float32))
    assert math.isclose(first.ping_info.sound_speed, 1480.0)
    assert np.allclose(first.ping_info.rx_beamwidths, math.radians(2.0))
    assert np.allclose(first.ping_info.tx_beamwidths, math.radians(20.0))
    # beams in the sonar frame's y-z plane at azimuth = bearing: (0, -sin a, cos a)
    dirs = np.array([[d.x, d.y, d.z] for d in first.beam_directions])
    assert np.allclose(dirs, np.stack([0 * fls.bearings, -np.sin(fls.bearings), np.cos(fls.bearings)], 1))
    for k, (_, log_time, msg) in enumerate(images[1:]):
        assert _ns(msg.header.stamp) == log_time == round((103.0 + 0.05 * k) * 1e9)
        assert bytes(msg.image.data) == mech.data[k].tobytes() and msg.image.beam_count == 1  # one beam
        assert np.allclose(msg.ping_info.tx_beamwidths, [math.radians(40.0)])
    waterfalls = [m for _, _, m in by_topic["/sonar/waterfall"]]
    assert [bytes(m.data) for m in waterfalls] == [fls.data.tobytes(), mech.data.tobytes()]
    assert (waterfalls[0].height, waterfalls[0].width, waterfalls[0].encoding) == (7, 32, "mono8")
    fan = by_topic["/sonar/fan"][0][2]
    assert fan.height * fan.step == len(fan.data) and fan.encoding == "mono8"
    assert {int(v) for v in np.frombuffer(bytes(fan.data), np.uint8)} - set(fls.data.ravel().tolist()) <= {0}
    tf_stamps = [lt for _, lt, _ in by_topic["/tf"]]
    assert tf_stamps == [lt for _, lt, _ in images] == [lt for _, lt, _ in by_topic["/odom"]]


def test_frames_and_detections(tmp_path):
    head = np.eye(4)
    head[:3, 3] = (1.0, 2.0, -3.0)
    scan = _scan("multibeam", head=head)
    scan.data[:] = 0
    scan.data[3, 10] = 200                               # one return on the boresight beam
    path = tmp_path / "d.mcap"
    write_mcap(path, scan)
    msgs = {t: d for t, _, _, d in _read(path)}
    tf = msgs["/tf"].transforms[0]
    assert (tf.header.frame_id, tf.child_frame_id) == ("map", "sonar")
    assert (tf.transform.translation.x, tf.transform.translation.y, tf.transform.translation.z) == (1.0, 2.0, -3.0)
    # sonar x = beam +y, so the rotation maps (1, 0, 0) to (0, 1, 0): a quarter turn about z
    q = tf.transform.rotation
    assert np.allclose([q.x, q.y, q.z, q.w], [0, 0, math.sqrt(0.5), math.sqrt(0.5)])
    cloud = msgs["/sonar/detections"]
    assert cloud.width == 1 and cloud.header.frame_id == "map"
    pts = np.frombuffer(bytes(cloud.data), dtype="<f4").reshape(-1, 4)
    assert np.allclose(pts[0], [1.0, 2.0, -3.0 + scan.ranges[10], 200.0], atol=1e-5)
    odom = msgs["/odom"]
    assert odom.child_frame_id == "sonar" and odom.pose.pose.position.x == 1.0


def test_refusals(tmp_path):
    path = tmp_path / "x.mcap"
    path.write_bytes(b"keep")
    with pytest.raises(ExportError, match="exists.*--force"):
        write_mcap(path, _scan("multibeam"))
    assert path.read_bytes() == b"keep"
    write_mcap(path, _scan("multibeam"), force=True)
    assert path.read_bytes()[:5] == b"\x89MCAP"

    class NoPoses:
        data = np.zeros((2, 3), np.uint8)
        poses = None

    with pytest.raises(ExportError, match=r"^bad\.npz: the scan has no 'ranges'"):
        write_mcap(tmp_path / "y.mcap", [NoPoses()], names=["bad.npz"])
    assert sorted(os.listdir(tmp_path)) == ["x.mcap"]       # nothing written, no temporary left


def test_a_bag_that_cannot_be_finished_leaves_no_file(tmp_path, monkeypatch):
    """The MCAP writer failing at its last step (the summary, e.g. a full disk): the error comes
    through and neither the bag nor its temporary file is left."""
    from mcap_ros2.writer import Writer

    def full(self, *a, **k):
        raise OSError(28, "No space left on device")

    monkeypatch.setattr(Writer, "finish", full)
    with pytest.raises(OSError, match="No space left"):
        write_mcap(tmp_path / "z.mcap", _scan("multibeam"))
    assert os.listdir(tmp_path) == []


def test_cli_export_round_trip_and_refusals(tmp_path, capsys):
    from mitsonar.cli import main

    files = []
    for i, kind in enumerate(("mechanical", "multibeam")):
        f = tmp_path / f"s{i}.npz"
        _scan(kind, start=float(i), seed=i).save(f)
        files.append(str(f))
    out = tmp_path / "out.mcap"
    assert main(["export", *files, "--mcap", str(out), "--start", "10"]) == 0
    assert f"wrote {out}" in capsys.readouterr().out
    msgs = _read(out)
    images = [(lt, d) for t, _, lt, d in msgs if t == "/sonar/image"]
    assert [lt for lt, _ in images] == [round((10 + 0.05 * k) * 1e9) for k in range(7)] + [11_000_000_000]
    from mitsonar import load_scan
    assert bytes(images[-1][1].image.data) == load_scan(files[1]).data.T.tobytes()
    assert np.allclose(images[0][1].ping_info.tx_beamwidths, math.radians(20.0))
    # an existing output: one line, untouched; --force overwrites
    before = out.read_bytes()
    assert main(["export", files[0], "--mcap", str(out)]) == 1
    err = capsys.readouterr().err.strip()
    assert err == f"mitsonar: error: --mcap {out}: exists; --force to overwrite"
    assert out.read_bytes() == before
    assert main(["export", files[0], "--mcap", str(out), "--force"]) == 0
    # a bad scan among good ones: one line naming the file, nothing written
    bad = tmp_path / "bad.npz"
    bad.write_bytes(b"not a scan")
    assert main(["export", files[0], str(bad), "--mcap", str(tmp_path / "new.mcap")]) == 1
    err = capsys.readouterr().err.strip()
    assert "\n" not in err and str(bad) in err
    assert not (tmp_path / "new.mcap").exists()


def test_survey_mcap_has_the_vehicle_frames(tmp_path, capsys):
    from conftest import SCENES

    import mitsonar
    from mitsonar.cli import main
    from mitsonar.export.ros.messages import sonar_pose
    from mitsonar.geometry.trajectory import quat_to_matrix

    out = tmp_path / "survey"
    bag = out / "survey.mcap"
    rc = main(["survey", os.path.join(SCENES, "box.xml"), "--lawnmower", "-1", "1", "-1", "1", "--spacing", "1",
               "--speed", "0.2", "--depth", "0", "--spp", "4", "--max-scans", "2", "-q", "-o", str(out),
               "--mcap", str(bag)])
    assert rc == 0 and f"and {bag}" in capsys.readouterr().out
    scans = [mitsonar.load_scan(f) for f in mitsonar.sim.survey.survey_files(out)]
    msgs = _read(bag)
    images = [d for t, _, _, d in msgs if t == "/sonar/image"]
    assert len(images) == sum(len(np.unique(s.times)) for s in scans)
    assert b"".join(bytes(m.image.data) for m in images) == b"".join(s.data.tobytes() for s in scans)
    want = [round((s.meta.start_time + t) * 1e9) for s in scans for t in np.unique(s.times)]
    assert [_ns(m.header.stamp) for m in images] == want
    tfs = [d for t, _, _, d in msgs if t == "/tf"]

    def matrix(tr):
        m = np.eye(4)
        r = tr.transform.rotation
        m[:3, :3] = quat_to_matrix([r.x, r.y, r.z, r.w])
        m[:3, 3] = [tr.transform.translation.x, tr.transform.translation.y, tr.transform.translation.z]
        return m

    first = tfs[0].transforms
    assert [(t.header.frame_id, t.child_frame_id) for t in first] == [("map", "base_link")]
    # the sonar's mount is fixed on the vehicle: one static transform, base_link -> sonar
    statics = [d for t, _, _, d in msgs if t == "/tf_static"]
    assert len(statics) == 1 and [(t.header.frame_id, t.child_frame_id) for t in statics[0].transforms] == \
        [("base_link", "sonar")]
    np.testing.assert_allclose(matrix(first[0]) @ matrix(statics[0].transforms[0]), sonar_pose(scans[0], 0),
                               atol=1e-9)
    # the twist is the vehicle's velocity in base_link: forward at the lawnmower's 0.2 m/s on a line
    odoms = [d for t, _, _, d in msgs if t == "/odom"]
    assert odoms[0].child_frame_id == "base_link"
    lin = odoms[0].twist.twist.linear
    assert math.isclose(math.hypot(lin.x, lin.y, lin.z), 0.2, rel_tol=1e-6) and lin.x > 0.19
    # a second run onto the same bag is refused before any render
    assert main(["survey", os.path.join(SCENES, "box.xml"), "--lawnmower", "-1", "1", "-1", "1", "--depth", "0",
                 "-q", "-o", str(tmp_path / "other"), "--mcap", str(bag)]) == 1
    assert "exists" in capsys.readouterr().err and not (tmp_path / "other").exists()


def _matrix(tr):
    from mitsonar.geometry.trajectory import quat_to_matrix

    m = np.eye(4)
    r = tr.transform.rotation
    m[:3, :3] = quat_to_matrix(np.array([r.x, r.y, r.z, r.w]))
    m[:3, 3] = [tr.transform.translation.x, tr.transform.translation.y, tr.transform.translation.z]
    return m


def _sidescan(n=3, bins=16, depression=15.0, yaw=0.0, meta=None):
    """A two-sided side-scan scan whose head is level, turned ``yaw`` deg about z and moving along +x."""
    from mitsonar.geometry.frames import sidescan_rotation

    channel = np.repeat([0, 1], n)
    head = np.tile(np.eye(4), (2 * n, 1, 1))
    c, s = math.cos(math.radians(yaw)), math.sin(math.radians(yaw))
    head[:, :2, :2] = [[c, -s], [s, c]]
    head[:, :3, 3] = np.stack([np.tile(np.arange(n) * 0.5, 2) + 3.0, np.full(2 * n, -2.0), np.full(2 * n, -5.0)], 1)
    poses = head @ sidescan_rotation(channel, math.radians(depression))
    return Scan(intensity=np.zeros((2 * n, bins), np.float32), data=np.full((2 * n, bins), 7, np.uint8),
                ranges=np.linspace(0.5, 20, bins), bearings=np.zeros(2 * n), poses=poses, range_min=0.0,
                range_max=20.5, kind="sidescan", beamwidth_h=1.0, beamwidth_v=50.0,
                times=np.tile(np.arange(n) * 0.1, 2), meta={"side": "both", **(meta or {})}), head


def _tf_tree(msgs):
    """``{child: (parent, 4x4)}`` of the first /tf message and every /tf_static transform."""
    tree = {}
    for topic, _, _, d in msgs:
        if topic == "/tf_static":
            tree.update({t.child_frame_id: (t.header.frame_id, _matrix(t)) for t in d.transforms})
    first = next(d for topic, _, _, d in msgs if topic == "/tf")
    tree.update({t.child_frame_id: (t.header.frame_id, _matrix(t)) for t in first.transforms})
    return tree


def _in_map(tree, frame):
    pose = np.eye(4)
    while frame != "map":
        assert frame in tree, f"frame {frame!r} is not in TF (frames: {sorted(tree)})"
        parent, m = tree[frame]
        pose, frame = m @ pose, parent
    return pose


@pytest.mark.parametrize("meta", [{}, {"depression": 15.0}])
def test_sidescan_channel_frames_have_x_up_and_every_stamped_frame_is_in_tf(tmp_path, meta):
    """marine_acoustic_msgs' ProjectedSonarImage: "The Z-axis is centered in the plane of the fan
    ('forward'), with X up". Each side-scan channel's frame has z its boresight and x up (a level
    head: +z of the world), right-handed; the channel frames hang off the head frame ``sonar`` on
    /tf_static (transient-local, as rosbag2 records a latched topic), and every frame an image is
    stamped with (the waterfall's included) reaches ``map`` through TF. The depression comes from
    ``meta`` or, without it, from the angle between the two boresights."""
    scan, head = _sidescan(yaw=30.0, meta=meta)
    path = tmp_path / "ss.mcap"
    counts = write_mcap(path, [scan])
    msgs = _read(path)
    images = [d for topic, _, _, d in msgs if topic == "/sonar/image"]
    assert len(images) == 6 and counts.get("/sonar/fan", 0) == 0 and counts["/odom"] == counts["/tf"] == 3
    assert [im.header.frame_id for im in images] == ["sonar_port", "sonar_starboard"] * 3
    tree = _tf_tree(msgs)
    stamped = {d.header.frame_id for topic, _, _, d in msgs if topic.startswith("/sonar/")}
    assert stamped == {"sonar", "sonar_port", "sonar_starboard", "map"}
    for frame in stamped:
        _in_map(tree, frame)
    assert tree["sonar_port"][0] == tree["sonar_starboard"][0] == "sonar"
    np.testing.assert_allclose(_in_map(tree, "sonar"), head[0], atol=1e-9)      # the head itself
    for row, frame in ((0, "sonar_port"), (3, "sonar_starboard")):
        world = _in_map(tree, frame)
        rot = world[:3, :3]
        assert np.isclose(np.linalg.det(rot), 1.0)
        np.testing.assert_allclose(rot[:, 2], scan.poses[row][:3, 2], atol=1e-9)   # z: the boresight
        assert rot[2, 0] > 0.9                                                     # x: up (cos 15 deg)
        np.testing.assert_allclose(rot[:, 0], -scan.poses[row][:3, 1], atol=1e-9)
    for im in images:                                     # every beam on its own frame's boresight
        d = im.beam_directions[0]
        assert np.allclose([d.x, d.y, d.z], [0.0, 0.0, 1.0], atol=1e-9)
    with open(path, "rb") as fh:
        channels = {c.topic: c for c in make_reader(fh).get_summary().channels.values()}
    qos = channels["/tf_static"].metadata["offered_qos_profiles"]
    assert "durability: 1" in qos and "reliability: 1" in qos and "history: 1" in qos and "depth: 1" in qos


def test_navsatfix_on_fix_with_an_origin(tmp_path):
    """With an origin (the scans' metadata, or ``frame=``) the bag holds sensor_msgs/NavSatFix on
    /fix, one per ping: the latitude and longitude of the vehicle (with a trajectory) or of the
    sonar, within 1e-7 deg of pyproj's transform of its grid coordinates, and height the origin's
    + z. Without an origin there is no /fix."""
    pyproj = pytest.importorskip("pyproj", reason="georeferencing needs pyproj (the geo extra)")
    from mitsonar.geometry.geodesy import GeoFrame
    from mitsonar.geometry.trajectory import Trajectory

    geo = GeoFrame.make((52.0, 4.5, 12.0))
    scan, head = _sidescan(meta=geo.meta())
    to_ll = pyproj.Transformer.from_crs(geo.crs, "EPSG:4326", always_xy=True)
    write_mcap(tmp_path / "a.mcap", [scan])
    fixes = [(lt, d) for topic, _, lt, d in _read(tmp_path / "a.mcap") if topic == "/fix"]
    assert len(fixes) == 3
    for k, (lt, fix) in enumerate(fixes):
        lon, lat = to_ll.transform(head[k, 0, 3] + geo.e0, head[k, 1, 3] + geo.n0)
        assert abs(fix.latitude - lat) < 1e-7 and abs(fix.longitude - lon) < 1e-7
        assert fix.altitude == pytest.approx(12.0 - 5.0) and fix.header.frame_id == "sonar"
        assert _ns(fix.header.stamp) == lt == round(0.1 * k * 1e9)
        assert fix.status.status == 0 and fix.position_covariance_type == 0
    # a trajectory: the vehicle's position, frame base_link; the frame given outright
    times = np.array([-1.0, 1.0])
    poses = np.tile(np.eye(4), (2, 1, 1))
    poses[:, :3, 3] = [[100.0, 200.0, -1.0], [120.0, 200.0, -1.0]]
    bare, _ = _sidescan()
    write_mcap(tmp_path / "b.mcap", [bare], trajectory=Trajectory(times, poses), frame=geo)
    fixes = [d for topic, _, _, d in _read(tmp_path / "b.mcap") if topic == "/fix"]
    for k, fix in enumerate(fixes):
        lon, lat = to_ll.transform(110.0 + 10.0 * 0.1 * k + geo.e0, 200.0 + geo.n0)
        assert abs(fix.latitude - lat) < 1e-7 and abs(fix.longitude - lon) < 1e-7
        assert fix.header.frame_id == "base_link" and fix.altitude == pytest.approx(11.0)
    write_mcap(tmp_path / "c.mcap", [bare])
    assert not [1 for topic, *_ in _read(tmp_path / "c.mcap") if topic == "/fix"]
