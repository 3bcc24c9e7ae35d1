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
    assert set(by_topic) == set(TOPICS)
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
    assert err == f"mitsonar: error: {out}: exists; refusing to overwrite it (use --force)"
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
    want = [round((s.meta["start_time"] + t) * 1e9) for s in scans for t in np.unique(s.times)]
    assert [_ns(m.header.stamp) for m in images] == want
    tfs = [d for t, _, _, d in msgs if t == "/tf"]

    def matrix(tr):
        m = np.eye(4)
        r = tr.transform.rotation
        m[:3, :3] = quat_to_matrix([r.x, r.y, r.z, r.w])
        m[:3, 3] = [tr.transform.translation.x, tr.transform.translation.y, tr.transform.translation.z]
        return m

    first = tfs[0].transforms
    assert [(t.header.frame_id, t.child_frame_id) for t in first] == [("map", "base_link"), ("base_link", "sonar")]
    np.testing.assert_allclose(matrix(first[0]) @ matrix(first[1]), sonar_pose(scans[0], 0), atol=1e-9)
    # the twist is the vehicle's velocity in base_link: forward at the lawnmower's 0.2 m/s on a line
    odoms = [d for t, _, _, d in msgs if t == "/odom"]
    assert odoms[0].child_frame_id == "base_link"
    lin = odoms[0].twist.twist.linear
    assert math.isclose(math.hypot(lin.x, lin.y, lin.z), 0.2, rel_tol=1e-6) and lin.x > 0.19
    # a second run onto the same bag is refused before any render
    assert main(["survey", os.path.join(SCENES, "box.xml"), "--lawnmower", "-1", "1", "-1", "1", "--depth", "0",
                 "-q", "-o", str(tmp_path / "other"), "--mcap", str(bag)]) == 1
    assert "exists" in capsys.readouterr().err and not (tmp_path / "other").exists()


def test_sidescan_channels_each_in_their_own_frame(tmp_path):
    """A side-scan ping is two groups, one per channel, each in its own sonar frame whose z axis is
    that channel's boresight (port looks +y, starboard -y): the starboard rows are not drawn in
    the port channel's frame. One odometry per ping, no fan picture (a line has no fan)."""
    from mitsonar.geometry.frames import sidescan_rotation

    n, bins = 3, 16
    channel = np.repeat([0, 1], n)
    poses = sidescan_rotation(channel, math.radians(15.0))
    scan = Scan(intensity=np.zeros((2 * n, bins), np.float32), data=np.full((2 * n, bins), 7, np.uint8),
                ranges=np.linspace(0.5, 20, bins), bearings=np.zeros(2 * n), poses=poses, range_min=0.0,
                range_max=20.5, kind="sidescan", beamwidth_h=1.0, beamwidth_v=50.0,
                times=np.tile(np.arange(n) * 0.1, 2), meta={"side": "both"})
    path = tmp_path / "ss.mcap"
    counts = write_mcap(path, [scan])
    msgs = _read(path)
    images = [d for topic, _, _, d in msgs if topic == "/sonar/image"]
    assert len(images) == 2 * n and counts.get("/sonar/fan", 0) == 0 and counts["/odom"] == n
    assert [im.header.frame_id for im in images] == ["sonar_port", "sonar_starboard"] * n
    tfs = {t.child_frame_id: t for topic, _, _, d in msgs if topic == "/tf" for t in d.transforms}
    for frame, sign in (("sonar_port", 1.0), ("sonar_starboard", -1.0)):
        q = tfs[frame].transform.rotation
        from mitsonar.geometry.trajectory import quat_to_matrix
        rot = quat_to_matrix(np.array([q.x, q.y, q.z, q.w]))
        assert np.sign(rot[1, 2]) == sign                 # the frame's z (boresight) looks to its side
    for im in images:                                     # every beam on its own frame's boresight
        d = im.beam_directions[0]
        assert np.allclose([d.x, d.y, d.z], [0.0, 0.0, 1.0], atol=1e-9)
