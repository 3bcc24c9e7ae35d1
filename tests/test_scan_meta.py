"""`ScanMeta`, the typed metadata of a `Scan`: one name for the scan's start (``start_time``, s),
kept by scans from real heads (SeaNet raw-log replay, Ping360 replay) through bathymetry and ROS 2
export, through EXR/NPZ files, and read from files written before it existed (``time_start``)."""
import dataclasses
import json
import os
import struct
import warnings

import numpy as np
import pytest

from mitsonar.devices.recording import replay
from mitsonar.products.bathymetry import soundings
from mitsonar import load_scan
from mitsonar.scan import Scan, ScanFieldError
from mitsonar.scan.meta import ScanMeta

DATA = os.path.join(os.path.dirname(__file__), "data")
T0 = 5000.0          # the log's start on the wall clock (s)
DT = 0.002           # between records (s)


def with_an_echo(scan):
    """``scan`` with an echo mid-range in every row as its intensity (a real head sends only
    levels), for bottom detection."""
    j = np.arange(scan.n_bins)
    row = np.exp(-0.5 * ((j - scan.n_bins / 2) / 1.5) ** 2).astype(np.float32)
    return dataclasses.replace(scan, intensity=np.tile(row, (scan.n_pings, 1)))


def _log(path, head, messages):
    """A raw log as the drivers write it, started at ``T0``, one record every ``DT`` seconds:
    ``messages`` are ``(kind, bytes)``, kind 0 from the head, 1 to it (the same bytes every run)."""
    blob = json.dumps(head).encode()
    out = bytearray(struct.pack("<8sHHdI", b"MSNRLOG1", 1, 0, T0, len(blob)) + blob)
    for k, (kind, data) in enumerate(messages):
        out += struct.pack("<dBI", DT * (k + 1), kind, len(data)) + data
    path.write_bytes(bytes(out))
    return path


def micron_log(path, n_pings=201, n_bins=40):
    from mitsonar.devices.micron.seanet import HeadData, HeadSettings, SendData, encode
    settings = HeadSettings(range=2.4, n_bins=n_bins)
    cmd = settings.head_command()
    rng = np.random.default_rng(3)
    msgs = [(1, encode(cmd))]
    for k in range(n_pings):
        bins = rng.integers(0, 256, n_bins, dtype=np.uint8)
        msgs += [(1, encode(SendData())),
                 (0, encode(HeadData.from_bins(bins, bearing=(3200 - 32 * k) % 6400, ad_interval=cmd.ad_interval,
                                               step_size=32, hd_ctrl=cmd.hd_ctrl, ad_low=cmd.ad_low,
                                               ad_span=cmd.ad_span)))]
    return _log(path, {"settings": settings.as_dict()}, msgs)


def ping360_log(path, step=100, n=200):
    from mitsonar.devices.ping360.head import Ping360Settings
    from mitsonar.devices.ping360.protocol import Message, encode
    s = Ping360Settings(range=2.4, number_of_samples=n, step=step)
    rng = np.random.default_rng(4)
    msgs = []
    for a in list(s.angles) + [s.angles[0]]:
        t = s.transducer(a)
        msgs.append((1, encode(Message("transducer", **t))))
        fields = {k: v for k, v in t.items() if k not in ("transmit", "reserved")}
        msgs.append((0, encode(Message("device_data", **fields, data=rng.integers(0, 256, n, dtype=np.uint8).tobytes()))))
    return _log(path, {"head": "ping360", "settings": s.as_dict()}, msgs)


@pytest.fixture(params=["micron", "ping360"])
def real_scan(request, tmp_path):
    """The first scan replayed from a real head's log."""
    make = micron_log if request.param == "micron" else ping360_log
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        scans = replay(make(tmp_path / "head.bin"))
    assert scans
    return scans[0]


def test_a_replayed_real_head_scan_starts_on_the_logs_clock(real_scan):
    # the first reply is the log's second record: T0 + 2 DT (+ a TX record for the Micron's SendData)
    assert T0 < real_scan.meta.start_time < T0 + 10 * DT
    assert real_scan.meta["start_time"] == real_scan.meta.start_time          # the mapping reading
    assert real_scan.meta.end_time == pytest.approx(real_scan.meta.start_time + real_scan.times[-1])
    assert "time_start" not in real_scan.meta and "time_end" not in real_scan.meta


def test_bathymetry_of_a_real_head_scan_keeps_its_start_time(real_scan):
    scan = with_an_echo(real_scan)
    out = soundings(scan)
    assert len(out) == scan.n_pings
    np.testing.assert_allclose(out["time"], real_scan.meta.start_time + real_scan.times[out["beam"]], rtol=0, atol=1e-9)
    assert out["time"].min() > T0


def test_ros_export_of_a_real_head_scan_is_stamped_on_its_clock(real_scan, tmp_path):
    pytest.importorskip("mcap_ros2")
    from mcap.reader import make_reader
    from mcap_ros2.decoder import DecoderFactory

    from mitsonar.export.ros import write_mcap

    write_mcap(tmp_path / "x.mcap", real_scan)
    with open(tmp_path / "x.mcap", "rb") as fh:
        stamps = [d.header.stamp.sec * 10**9 + d.header.stamp.nanosec
                  for _, ch, _, d in make_reader(fh, decoder_factories=[DecoderFactory()]).iter_decoded_messages()
                  if ch.topic == "/sonar/image"]
    want = [round((real_scan.meta.start_time + t) * 1e9) for t in np.unique(real_scan.times)]
    assert stamps == want and stamps[0] > T0 * 1e9


@pytest.mark.parametrize("ext", [".exr", ".npz"])
def test_real_head_metadata_round_trips_through_files(real_scan, tmp_path, ext):
    real_scan.meta["operator"] = "ünïcode"                      # unknown: kept apart, kept
    real_scan.save(tmp_path / f"s{ext}")
    back = load_scan(tmp_path / f"s{ext}")
    assert isinstance(back.meta, ScanMeta) and back.meta == real_scan.meta
    assert back.meta.start_time == real_scan.meta.start_time and back.meta.extra == {"operator": "ünïcode"}
    assert back.meta.source == real_scan.meta.source and back.meta.missing == []


def test_a_file_written_before_scan_meta_loads_with_start_time():
    """tests/data/real_head_v1.npz: a Micron replay saved by mitsonar before `ScanMeta`
    (meta ``time_start``/``time_end``, the name the heads wrote)."""
    old = load_scan(os.path.join(DATA, "real_head_v1.npz"))
    assert old.meta.start_time == pytest.approx(5000.006) and old.meta.end_time > old.meta.start_time
    assert "time_start" not in old.meta and old.meta.extra == {}
    assert old.meta.source == "seanet" and old.meta.log.endswith("head.bin")
    with pytest.warns(DeprecationWarning, match="'time_start' is now 'start_time'"):
        assert old.meta["time_start"] == old.meta.start_time
    t = soundings(with_an_echo(old))["time"]
    assert t.min() == pytest.approx(old.meta.start_time)


def test_meta_is_typed_and_mapping_compatible():
    m = ScanMeta.from_dict({"scene": "box.xml", "seed": 3, "spp": 16, "start_time": 2.5, "mine": [1, 2]})
    assert (m.scene, m.seed, m.spp, m.start_time, m.extra) == ("box.xml", 3, 16, 2.5, {"mine": [1, 2]})
    assert dict(m) == {"scene": "box.xml", "seed": 3, "spp": 16, "start_time": 2.5, "mine": [1, 2]}
    assert m == {"scene": "box.xml", "seed": 3, "spp": 16, "start_time": 2.5, "mine": [1, 2]}
    assert m.get("preset") is None and "preset" not in m and m.get("mine") == [1, 2] and len(m) == 5
    m["preset"] = "starfish_450"
    del m["seed"]
    assert m.preset == "starfish_450" and m.seed is None and "seed" not in m
    with pytest.raises(KeyError):
        m["seed"]
    m.update(side="port", survey_index=np.int64(2))
    assert {**m}["side"] == "port" and m.survey_index == 2
    for key, bad, allowed in (("start_time", "noon", "a finite number, seconds"), ("spp", 2.5, "a whole number"),
                              ("seed", True, "a whole number"), ("scene", 3, "a string"),
                              ("start_time", float("nan"), "a finite number, seconds")):
        with pytest.raises(ScanFieldError, match=rf"Scan 'meta': '{key}': .* is not allowed \({allowed}"):
            m[key] = bad
        with pytest.raises(ScanFieldError, match=rf"'{key}'"):
            ScanMeta.from_dict({key: bad})


def test_a_scan_takes_a_dict_and_keeps_a_scan_meta():
    kw = dict(intensity=np.zeros((2, 3), np.float32), data=np.zeros((2, 3), np.uint8), ranges=[0.5, 1.5, 2.5],
              bearings=[0.0, 0.1], poses=np.tile(np.eye(4), (2, 1, 1)), range_min=0.0, range_max=3.0)
    s = Scan(**kw, meta={"time_start": 7.0, "note": "x"})
    assert isinstance(s.meta, ScanMeta) and s.meta.start_time == 7.0 and s.meta.extra == {"note": "x"}
    s.meta = {"seed": 1}
    assert isinstance(s.meta, ScanMeta) and s.meta.seed == 1
    with pytest.raises(ScanFieldError, match=r"Scan 'meta': 'ping_period': -1 is not allowed"):
        Scan(**kw, meta={"ping_period": -1})
    with pytest.raises(ScanFieldError, match="Scan 'meta': a list is not a dict"):
        Scan(**kw, meta=[1])
