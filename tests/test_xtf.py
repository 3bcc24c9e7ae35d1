"""XTF export of side-scan scans (`mitsonar.export.xtf`), read back by pyxtf (the maintained reader)
and by a small independent parser of the Triton XTF structures (XTFFILEHEADER, CHANINFO,
XTFPINGHEADER, XTFPINGCHANHEADER; field offsets from the format document rev 35+)."""
from __future__ import annotations

import math
import struct

import numpy as np
import pytest

pyproj = pytest.importorskip("pyproj", reason="georeferencing needs pyproj (the geo extra)")

from mitsonar.geometry.frames import sidescan_rotation  # noqa: E402
from mitsonar.geometry.geodesy import GeoFrame  # noqa: E402
from mitsonar.scan.model import Scan  # noqa: E402

ORIGIN = (52.0, 4.5, 0.0)       # off the Dutch coast, UTM 31N


def sidescan(n=5, bins=40, yaw_deg=30.0, speed=1.5, t0=100.0, seed=0, x0=(10.0, -20.0, -8.0), kind="sidescan"):
    """A side-scan scan of ``n`` pings per channel: the head moving at ``speed`` along the grid
    direction ``yaw_deg`` (counter-clockwise from grid east), seeded random bytes."""
    rng = np.random.default_rng(seed)
    channel = np.repeat([0, 1], n)
    t = np.tile(np.arange(n) * 0.2, 2)
    yaw = math.radians(yaw_deg)
    rot = np.eye(4)
    rot[:2, :2] = [[math.cos(yaw), -math.sin(yaw)], [math.sin(yaw), math.cos(yaw)]]
    poses = rot @ sidescan_rotation(channel, math.radians(10.0))
    poses[:, :3, 3] = np.asarray(x0) + speed * t[:, None] * np.array([math.cos(yaw), math.sin(yaw), 0.0])
    data = rng.integers(0, 256, (2 * n, bins), dtype=np.uint8)
    intensity = np.zeros((2 * n, bins), np.float32)
    intensity[:, 8:] = 1.0                      # the first bottom return at bin 8
    ranges = 1.0 + (np.arange(bins) + 0.5) * 0.5
    return Scan(intensity=intensity, data=data, ranges=ranges, bearings=np.zeros(2 * n), poses=poses,
                range_min=1.0, range_max=21.0, kind=kind, beamwidth_h=1.0, beamwidth_v=50.0, times=t,
                meta={"side": "both", "start_time": t0, "frequency": 450e3, "ping_period": 0.2,
                      "depression": 10.0})


# ---- an independent reader: the structures' fields at their offsets in the XTF document ----------

def parse_xtf(path, attitudes=None):
    """(file header dict, [(ping header dict, [(chan header dict, samples)])]) by plain offsets;
    the attitude packets (XTFATTITUDEDATA, HeaderType 3) go into the list ``attitudes`` as dicts."""
    raw = open(path, "rb").read()
    fh = dict(zip(("FileFormat", "SystemType"), raw[0:2]))
    fh["NavUnits"], fh["NumberOfSonarChannels"] = struct.unpack_from("<HH", raw, 164)
    chans = []
    for i in range(6):                          # CHANINFO[6] at 256, 128 bytes each
        o = 256 + 128 * i
        chans.append(dict(TypeOfChannel=raw[o], BytesPerSample=struct.unpack_from("<H", raw, o + 6)[0],
                          SampleFormat=raw[o + 74]))
    fh["ChanInfo"] = chans
    pings, pos = [], 1024
    while pos < len(raw):
        magic, htype, _, nchan = struct.unpack_from("<HBBH", raw, pos)
        assert magic == 0xFACE
        nbytes = struct.unpack_from("<I", raw, pos + 10)[0]
        assert nbytes % 64 == 0
        if htype == 3:                           # XTFATTITUDEDATA: 64 bytes
            assert nbytes == 64
            micro, epoch = struct.unpack_from("<II", raw, pos + 22)
            tag, heading = struct.unpack_from("<If", raw, pos + 46)
            ms, = struct.unpack_from("<H", raw, pos + 61)
            if attitudes is not None:
                attitudes.append(dict(EpochMicroseconds=micro, SourceEpoch=epoch, TimeTag=tag, Heading=heading,
                                      Second=raw[pos + 60], Millisecond=ms))
            pos += nbytes
            continue
        ph = dict(HeaderType=htype, NumChansToFollow=nchan, NumBytesThisRecord=nbytes)
        ph["SoundVelocity"] = struct.unpack_from("<f", raw, pos + 32)[0]
        ph["SensorYcoordinate"], ph["SensorXcoordinate"] = struct.unpack_from("<dd", raw, pos + 160)
        ph["SensorHeading"] = struct.unpack_from("<f", raw, pos + 212)[0]
        ph["AttitudeTimeTag"], _, ph["NavFixMilliseconds"] = struct.unpack_from("<IfI", raw, pos + 224)
        c, cs = pos + 256, []
        for _ in range(nchan):
            number, = struct.unpack_from("<H", raw, c)
            slant, = struct.unpack_from("<f", raw, c + 4)
            n, = struct.unpack_from("<I", raw, c + 42)
            cs.append((dict(ChannelNumber=number, SlantRange=slant, NumSamples=n),
                       np.frombuffer(raw, np.uint8, n, c + 64)))
            c += 64 + n
        pings.append((ph, cs))
        pos += nbytes
    return fh, pings


def test_independent_offsets_match_the_maintained_reader():
    """The offsets the parser above uses are those of pyxtf's ctypes structures (both from the
    XTF document): a check of the parser, not of the writer."""
    pyxtf = pytest.importorskip("pyxtf", reason="pyxtf (the test extra) reads XTF")
    c = pyxtf.xtf_ctypes
    assert c.XTFFileHeader.NavUnits.offset == 164 and c.XTFChanInfo.SampleFormat.offset == 74
    assert c.XTFPingHeader.SensorYcoordinate.offset == 160 and c.XTFPingHeader.SensorHeading.offset == 212
    assert c.XTFPingHeader.SoundVelocity.offset == 32 and c.XTFPingChanHeader.NumSamples.offset == 42
    assert c.XTFPingHeader.AttitudeTimeTag.offset == 224 and c.XTFPingHeader.NavFixMilliseconds.offset == 232
    a = c.XTFAttitudeData
    assert (a.EpochMicroseconds.offset, a.SourceEpoch.offset, a.TimeTag.offset, a.Heading.offset, a.Second.offset,
            a.Millisecond.offset, c.ctypes.sizeof(a)) == (22, 26, 46, 50, 60, 61, 64)


def test_writer_layouts_match_pyxtf_field_by_field():
    """Every field of the writer's structures sits at the offset pyxtf's ctypes structure gives it."""
    pyxtf = pytest.importorskip("pyxtf", reason="pyxtf (the test extra) reads XTF")
    from mitsonar.export import xtf as X

    c = pyxtf.xtf_ctypes
    for (st, names), ref in ((X.CHANINFO, c.XTFChanInfo), (X.FILEHEADER, c.XTFFileHeader),
                             (X.PINGHEADER, c.XTFPingHeader), (X.PINGCHANHEADER, c.XTFPingChanHeader),
                             (X.ATTITUDEDATA, c.XTFAttitudeData)):
        off = 0
        for name, code in zip(names, X._codes(st.format)):
            assert getattr(ref, name).offset == off, (ref.__name__, name)
            off += struct.calcsize("<" + code)


def _trajectory_nav(frame, scans):
    x = np.concatenate([s.poses[s.channel == 0, 0, 3] for s in scans])
    y = np.concatenate([s.poses[s.channel == 0, 1, 3] for s in scans])
    e, n = x + frame.e0, y + frame.n0
    lon, lat = pyproj.Transformer.from_crs(frame.crs, "EPSG:4326", always_xy=True).transform(e, n)
    return lon, lat


def test_xtf_read_back_by_pyxtf_byte_equal_with_nav(tmp_path):
    pyxtf = pytest.importorskip("pyxtf", reason="pyxtf (the test extra) reads XTF")
    from mitsonar.export.xtf import write_xtf

    frame = GeoFrame.make(ORIGIN)
    scans = [sidescan(seed=0), sidescan(seed=1, t0=101.0, x0=(10.0 + 1.5 * math.cos(math.radians(30)),
                                                              -20.0 + 1.5 * math.sin(math.radians(30)), -8.0))]
    path = tmp_path / "s.xtf"
    start = 1.7e9
    assert write_xtf(path, scans, frame, start=start) == 10
    fh, packets = pyxtf.xtf_read(str(path))
    assert fh.NavUnits == 3 and fh.NumberOfSonarChannels == 2
    assert [ci.TypeOfChannel for ci in fh.ChanInfo[:2]] == [1, 2]
    sonar = packets[pyxtf.XTFHeaderType.sonar]
    assert len(sonar) == 10
    lon, lat = _trajectory_nav(frame, scans)
    k = 0
    for scan in scans:
        for i in range(5):
            p = sonar[k]
            assert np.array_equal(p.data[0], scan.data[i]) and np.array_equal(p.data[1], scan.data[5 + i])
            assert p.data[0].dtype == np.uint8
            assert abs(p.SensorXcoordinate - lon[k]) < 1e-9 and abs(p.SensorYcoordinate - lat[k]) < 1e-9
            assert p.ping_chan_headers[0].NumSamples == 40 and p.ping_chan_headers[1].ChannelNumber == 1
            assert p.ping_chan_headers[0].SlantRange == pytest.approx(21.0)
            assert p.ping_chan_headers[0].TimeDelay == pytest.approx(2 * 1.0 / 1500.0)
            assert p.SoundVelocity == pytest.approx(1500.0)
            assert p.SensorSpeed == pytest.approx(1.5 * 3600 / 1852, rel=1e-5)   # knots
            assert p.SensorPrimaryAltitude == pytest.approx(scan.ranges[8])
            assert p.SensorDepth == pytest.approx(8.0)
            t = start + scan.meta.start_time + scan.times[i]
            got = p.get_time().astype("datetime64[ms]").astype(np.int64) / 1000.0
            assert abs(got - t) <= 0.005 + 1e-6       # HSeconds: the nearest hundredth of a second
            k += 1
    # the heading is the head's grid direction turned to true north: 90 - 30 deg in the grid, minus
    # the meridian convergence at the point (pyproj's); not the grid's 60 deg
    conv = pyproj.Proj(frame.crs).get_factors(lon[0], lat[0]).meridian_convergence
    assert sonar[0].SensorHeading == pytest.approx(60.0 + conv, abs=1e-3)
    assert abs(conv) > 0.5                             # 4.5 E in zone 31 (3 E central): it matters


def test_xtf_independent_parser(tmp_path):
    from mitsonar.export.xtf import write_xtf

    frame = GeoFrame.make(ORIGIN)
    scan = sidescan(n=3, bins=33)                      # 256 + 2 (64 + 33) bytes: padded to 512
    write_xtf(tmp_path / "s.xtf", [scan], frame)
    attitudes = []
    fh, pings = parse_xtf(tmp_path / "s.xtf", attitudes)
    assert fh["FileFormat"] == 0x7B and fh["NavUnits"] == 3 and fh["NumberOfSonarChannels"] == 2
    assert [(c["TypeOfChannel"], c["BytesPerSample"], c["SampleFormat"]) for c in fh["ChanInfo"][:2]] == \
        [(1, 1, 8), (2, 1, 8)]
    assert len(pings) == 3 and all(p["NumBytesThisRecord"] == 512 for p, _ in pings)
    lon, lat = _trajectory_nav(frame, [scan])
    for k, (ph, chans) in enumerate(pings):
        assert ph["HeaderType"] == 0 and ph["NumChansToFollow"] == 2
        assert [c["ChannelNumber"] for c, _ in chans] == [0, 1]
        assert np.array_equal(chans[0][1], scan.data[k]) and np.array_equal(chans[1][1], scan.data[3 + k])
        assert abs(ph["SensorXcoordinate"] - lon[k]) < 1e-9 and abs(ph["SensorYcoordinate"] - lat[k]) < 1e-9
        # each ping's attitude packet: its millisecond tag, its time to the microsecond (start 0: the
        # scan's start_time 100 s + 0.2 k s after the epoch)
        att = attitudes[k]
        assert att["TimeTag"] == ph["AttitudeTimeTag"] == ph["NavFixMilliseconds"] == 200 * k
        assert att["SourceEpoch"] + att["EpochMicroseconds"] * 1e-6 == pytest.approx(100.0 + 0.2 * k, abs=1e-6)
        assert att["Heading"] == pytest.approx(ph["SensorHeading"])


def test_xtf_refuses_a_scan_that_is_not_sidescan_and_leaves_nothing(tmp_path):
    from mitsonar.export.xtf import XTFError, write_xtf

    frame = GeoFrame.make(ORIGIN)
    fan = sidescan()
    fan.kind = "multibeam"
    path = tmp_path / "s.xtf"
    with pytest.raises(XTFError, match=r"^b.npz: 'kind' 'multibeam' is not allowed in an XTF export"):
        write_xtf(path, [sidescan(), fan], frame, names=["a.npz", "b.npz"])
    assert list(tmp_path.iterdir()) == []


# ---- the command line: survey --xtf, export --xtf, refusals ---------------------------------------

def _sidescan_scene(tmp_path):
    from conftest import acoustic_xml, rectangle_xml, scene_xml, sonar_xml

    m = np.diag([200.0, 200.0, 1.0, 1.0])
    m[2, 3] = -4.0
    scene = tmp_path / "ss.xml"
    scene.write_text(scene_xml(sonar_xml(kind="sidescan", n_pings=10, n_bins=60, range_max=12.0),
                               rectangle_xml(m, acoustic_xml(diffuse=0.5)),
                               integrator='<integrator type="sonar_tof"><integer name="max_depth" value="1"/>'
                                          '</integrator>'))
    return scene


def test_survey_xtf_and_export_xtf_agree_with_the_scans(tmp_path, capsys):
    """``survey --xtf --origin``: the scans carry the origin and CRS, the XTF holds every ping's
    bytes with the transducer's lat/lon; ``export SCANS --xtf`` (origin from the scans' metadata)
    writes the same pings."""
    pyxtf = pytest.importorskip("pyxtf", reason="pyxtf (the test extra) reads XTF")
    from mitsonar.cli import main
    from mitsonar.scan.io import load_scan

    scene, out = _sidescan_scene(tmp_path), tmp_path / "out"
    xtf = tmp_path / "s.xtf"
    rc = main(["survey", str(scene), "--lawnmower", "0", "3", "0", "0", "--speed", "1.5", "--depth", "0",
               "--spp", "4", "--max-scans", "2", "-q", "-o", str(out), "--xtf", str(xtf),
               "--origin", "52.0", "4.5", "--start", "1700000000"])
    assert rc == 0, capsys.readouterr().err
    scans = [load_scan(out / f"scan_0000{i}.npz") for i in range(2)]
    assert all(s.meta.origin == [52.0, 4.5, 0.0] and s.meta.crs == "EPSG:32631" for s in scans)
    frame = GeoFrame.make(ORIGIN)
    lon, lat = _trajectory_nav(frame, scans)
    _, packets = pyxtf.xtf_read(str(xtf))
    sonar = packets[pyxtf.XTFHeaderType.sonar]
    assert len(sonar) == 20
    rows = [(s, i) for s in scans for i in range(10)]
    for k, (p, (s, i)) in enumerate(zip(sonar, rows)):
        assert np.array_equal(p.data[0], s.data[i]) and np.array_equal(p.data[1], s.data[10 + i])
        assert abs(p.SensorXcoordinate - lon[k]) < 1e-7 and abs(p.SensorYcoordinate - lat[k]) < 1e-7
    assert sonar[0].Year == 2023 and sonar[0].Month == 11
    rasterio = pytest.importorskip("rasterio", reason="the mosaic GeoTIFF needs rasterio")
    with rasterio.open(out / "mosaic.tif") as src:          # the survey's mosaic, in the CRS
        assert src.crs.to_epsg() == 32631 and src.transform.c > 600000
    again = tmp_path / "again.xtf"
    assert main(["export", str(out / "scan_00000.npz"), str(out / "scan_00001.npz"), "--xtf", str(again),
                 "--trajectory", str(out / "trajectory.tum"), "--start", "1700000000"]) == 0
    _, packets2 = pyxtf.xtf_read(str(again))
    assert all(np.array_equal(a.data[0], b.data[0]) and a.SensorXcoordinate == b.SensorXcoordinate
               for a, b in zip(sonar, packets2[pyxtf.XTFHeaderType.sonar]))


@pytest.mark.parametrize("extra, message", [
    (["--xtf", "{t}/s.xtf"], "survey --xtf: give --origin LAT LON"),
    (["--xtf", "{t}/s.xtf", "--origin", "95", "4"], "--origin 95 4: off the Earth"),
    (["--xtf", "{t}/s.xtf", "--origin", "52", "4", "--crs", "EPSG:4326"], "--crs EPSG:4326: WGS 84 is geographic"),
    (["--xtf", "{t}/s.xtf", "--origin", "52", "4", "--crs", "EPSG:1"], "--crs EPSG:1: unknown EPSG code"),
    (["--origin", "52", "4.5", "--crs", "EPSG:32601"], "--crs EPSG:32601: the origin 52 N 4.5 E is outside"),
    (["--origin", "52", "4.5", "--crs", "EPSG:3857"], "--crs EPSG:3857: WGS 84 / Pseudo-Mercator has a scale error"),
    (["--xtf", "{t}/s.xyz", "--origin", "52", "4"], "the file name must end in .xtf"),
    (["--crs", "EPSG:32631"], "--crs EPSG:32631: needs --origin"),
])
def test_survey_refuses_bad_geo_flags_before_any_render(tmp_path, capsys, extra, message):
    from mitsonar.cli import main

    scene, out = _sidescan_scene(tmp_path), tmp_path / "out"
    rc = main(["survey", str(scene), "--lawnmower", "0", "3", "0", "0", "--speed", "1.5", "--depth", "0",
               "--spp", "4", "--max-scans", "1", "-q", "-o", str(out)] + [a.format(t=tmp_path) for a in extra])
    err = capsys.readouterr().err.strip()
    assert rc == 1 and err.count("\n") == 0 and message in err, err
    assert not out.exists() and not list(tmp_path.glob("s.*"))


def test_export_xtf_refuses_a_mechanical_scan(tmp_path, capsys):
    from mitsonar.cli import main

    fan = sidescan()
    fan.kind = "mechanical"
    fan.meta.side = None
    fan.times = np.arange(10) * 0.1
    fan.save(tmp_path / "m.npz")
    rc = main(["export", str(tmp_path / "m.npz"), "--xtf", str(tmp_path / "m.xtf"), "--origin", "52", "4.5"])
    err = capsys.readouterr().err.strip()
    assert rc == 1 and f"{tmp_path / 'm.npz'}: 'kind' 'mechanical' is not allowed in an XTF export" in err, err
    assert not (tmp_path / "m.xtf").exists()


def test_survey_along_a_lat_lon_csv_track(tmp_path, capsys):
    """``--trajectory track.csv`` (lat/lon) with ``--origin``: the survey's trajectory.tum holds the
    fixes in the grid; without ``--origin`` one line asks for it, nothing written."""
    from mitsonar.cli import main
    from mitsonar.geometry.trajectory import Trajectory

    scene, frame = _sidescan_scene(tmp_path), GeoFrame.make(ORIGIN)
    lon, lat = frame.to_lonlat(np.array([0.0, 15.0]), np.array([0.0, 0.0]))
    csv = tmp_path / "track.csv"
    csv.write_text(f"time,lat,lon,depth\n0,{lat[0]:.10f},{lon[0]:.10f},0\n10,{lat[1]:.10f},{lon[1]:.10f},0\n")
    base = ["survey", str(scene), "--trajectory", str(csv), "--spp", "4", "--max-scans", "1", "-q"]
    assert main(base + ["-o", str(tmp_path / "no")]) == 1
    err = capsys.readouterr().err.strip()
    assert err.count("\n") == 0 and "a lat/lon trajectory needs --origin" in err and not (tmp_path / "no").exists()
    assert main(base + ["-o", str(tmp_path / "out"), "--origin", "52", "4.5"]) == 0, capsys.readouterr().err
    track = Trajectory.from_tum(tmp_path / "out" / "trajectory.tum")
    assert np.allclose(track.positions[:, :2], [[0.0, 0.0], [15.0, 0.0]], atol=1e-4)


@pytest.mark.parametrize("output", ["--xtf", "--mcap"])
@pytest.mark.parametrize("flags, message", [
    (["--origin", "95", "4"], "--origin 95 4: off the Earth"),
    (["--origin", "52", "4", "--crs", "EPSG:1"], "--crs EPSG:1: unknown EPSG code"),
    (["--origin", "52", "4", "--crs", "EPSG:4326"], "--crs EPSG:4326: WGS 84 is geographic"),
    (["--origin", "52", "4.5", "--crs", "EPSG:32601"], "--crs EPSG:32601: the origin 52 N 4.5 E is outside"),
    (["--origin", "52", "4.5", "--crs", "EPSG:3857"], "--crs EPSG:3857: WGS 84 / Pseudo-Mercator has a scale error"),
    (["--crs", "EPSG:32631"], "--crs EPSG:32631: needs --origin"),
])
def test_export_refuses_bad_geo_flags_in_one_line_and_writes_nothing(tmp_path, capsys, output, flags, message):
    """`mitsonar export` with --xtf or --mcap (whose /fix uses the origin): a bad --origin/--crs
    is one line naming the flag, exit 1, no file."""
    pytest.importorskip("mcap_ros2", reason="MCAP needs mcap-ros2-support (the ros extra)")
    from mitsonar.cli import main

    sidescan().save(tmp_path / "s.npz")
    target = tmp_path / ("o.xtf" if output == "--xtf" else "o.mcap")
    rc = main(["export", str(tmp_path / "s.npz"), output, str(target)] + flags)
    err = capsys.readouterr().err.strip()
    assert rc == 1 and err.count("\n") == 0 and message in err, err
    assert sorted(p.name for p in tmp_path.iterdir()) == ["s.npz"]


def test_xtf_times_round_trip_to_the_millisecond(tmp_path):
    """The sonar packet holds its time to the hundredth of a second (HSeconds, rounded to the
    nearest); the attitude packet before each ping, paired with it by TimeTag = AttitudeTimeTag,
    holds it to the microsecond (SourceEpoch + EpochMicroseconds), so pyxtf gives back every
    ping's time within a millisecond."""
    pyxtf = pytest.importorskip("pyxtf", reason="pyxtf (the test extra) reads XTF")
    from mitsonar.export.xtf import write_xtf

    scan = sidescan(n=6, t0=100.0)
    scan.times = np.tile(np.array([0.0, 0.2137, 0.4004, 0.6291, 0.8555, 1.0678]), 2)   # not whole hundredths
    start = 1_700_000_000.0 + 0.0123
    write_xtf(tmp_path / "t.xtf", [scan], GeoFrame.make(ORIGIN), start=start)
    _, packets = pyxtf.xtf_read(str(tmp_path / "t.xtf"))
    sonar, attitude = packets[pyxtf.XTFHeaderType.sonar], packets[pyxtf.XTFHeaderType.attitude]
    assert len(sonar) == len(attitude) == 6
    by_tag = {a.TimeTag: a for a in attitude}
    for k, p in enumerate(sonar):
        want = start + 100.0 + scan.times[k]
        a = by_tag[p.AttitudeTimeTag]
        got = a.get_time().astype("datetime64[us]").astype(np.int64) * 1e-6
        assert abs(got - want) < 1e-3, (k, got - want)
        coarse = p.get_time().astype("datetime64[ms]").astype(np.int64) * 1e-3
        assert abs(coarse - want) <= 0.005 + 1e-6
        assert a.Heading == pytest.approx(p.SensorHeading)
