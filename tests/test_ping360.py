"""Ping360 driver against the virtual Ping360 through real pseudo-terminals and loopback UDP;
the head's settings and their ranges; brping's own client against the virtual head; logs and
replay. Every head runs with ``realtime=False`` unless a test says otherwise, every blocking call
is bounded by a timeout."""
from __future__ import annotations

import contextlib
import io
import math
import os
import warnings

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings, strategies as st

from mitsonar.devices.ping360.driver import Ping360Sonar, SonarError, SonarTimeout, record
from mitsonar.devices.ping360.head import Ping360Assembler, Ping360Settings, angle_to_radians
from mitsonar.devices.ping360.protocol import Message, ids
from mitsonar.devices.rawlog import read_log
from mitsonar.devices.recording import replay
from mitsonar.scan import Scan, bearing_rotation
from mitsonar.devices.ping360.virtual import VirtualPing360

pytestmark = pytest.mark.skipif(not hasattr(os, "openpty"), reason="needs pseudo-terminals")

FAST = dict(timeout=5.0, ping_timeout=0.3)
MOUNT = np.array([[0.0, 0.0, 1.0, 1.5], [1.0, 0.0, 0.0, -2.0], [0.0, 1.0, 0.0, 0.25], [0, 0, 0, 1]])


def synthetic_scan(n_pings=400, n_bins=200, range_max=2.4, start_deg=0.0, step_deg=-0.9, seed=1, pose=None):
    """A Scan as the renderer returns it, with random device bytes (exact test data)."""
    rng = np.random.default_rng(seed)
    b = np.radians(start_deg + np.arange(n_pings) * step_deg)
    T = np.eye(4) if pose is None else pose
    return Scan(intensity=rng.random((n_pings, n_bins)).astype(np.float32),
                data=rng.integers(0, 256, (n_pings, n_bins), dtype=np.uint8),
                ranges=(np.arange(n_bins) + 0.5) * range_max / n_bins, bearings=b,
                poses=T @ bearing_rotation(b), range_min=0.0, range_max=range_max)


SCAN = synthetic_scan(pose=MOUNT)


def assert_same_scan(got: Scan, want: Scan):
    assert (got.n_pings, got.n_bins) == (want.n_pings, want.n_bins)
    assert np.array_equal(got.data, want.data)                   # byte for byte
    np.testing.assert_allclose(got.bearings, want.bearings, rtol=0, atol=1e-12)
    np.testing.assert_allclose(got.poses, want.poses, rtol=0, atol=1e-12)
    np.testing.assert_allclose(got.ranges, want.ranges, rtol=1e-12)
    assert got.range_max == pytest.approx(want.range_max, rel=1e-12) and got.range_min == 0.0
    assert got.kind == "mechanical" and (got.beamwidth_h, got.beamwidth_v) == (2.0, 25.0)
    assert not got.intensity.any() and got.meta.missing == [] and got.meta.source == "ping360"


def run_scan(scan, url=None, n=1, vm_kw=None, **kw):
    settings = kw.pop("settings", None) or Ping360Settings.from_scan(scan)
    with VirtualPing360(scan, url, realtime=False, **(vm_kw or {})) as vm:
        with Ping360Sonar(vm.port, settings=settings, pose=MOUNT, **{**FAST, **kw}) as sonar:
            return [sonar.scan() for _ in range(n)], sonar, vm


# ---- the head's settings --------------------------------------------------------------------

def test_angles_turn_clockwise_and_bearings_counter_clockwise():
    assert angle_to_radians(0) == 0.0
    assert angle_to_radians(100) == pytest.approx(-math.pi / 2)       # right of ahead
    assert angle_to_radians(300) == pytest.approx(math.pi / 2)
    assert angle_to_radians(200) == pytest.approx(math.pi)


def test_range_from_sample_period_and_sound_speed():
    s = Ping360Settings(range=12.0, number_of_samples=500)      # the box scene's 24 mm bins
    assert s.sample_period == 1280 and s.range_max == 12.0 and s.bin_width == pytest.approx(0.024)
    s = Ping360Settings(range=2.0, number_of_samples=1200, sound_speed=1481.5)
    assert s.sample_period == round(2 * 2.0 / (1481.5 * 1200 * 25e-9))
    assert s.range_max == pytest.approx(1200 * s.sample_period * 25e-9 * 1481.5 / 2)
    # transmit duration: 8000 R / c us, at least 2.5 sample periods, within 5..500 us
    assert Ping360Settings(range=12.0).transmit_duration == 64
    assert Ping360Settings(range=0.5, number_of_samples=200).transmit_duration == 8   # 2.5 x 3.325 us
    assert Ping360Settings(range=0.3, number_of_samples=200).transmit_duration == 5
    assert Ping360Settings(range=100.0).transmit_duration == 500
    assert Ping360Settings(transmit_duration=7).transmit_duration == 7
    assert Ping360Settings().angles == list(range(400))
    assert Ping360Settings(step=10, start_angle=390, stop_angle=20).angles == [390, 0, 10, 20]
    assert Ping360Settings(step=2, clockwise=False).angles[:3] == [0, 398, 396]


@pytest.mark.parametrize("kw,match", [
    (dict(gain_setting=3), r"Ping360Settings 'gain_setting': 3 is not allowed \(a whole number 0..2 0 low, 1 normal, 2 high\)"),
    (dict(transmit_duration=2000), r"'transmit_duration': 2000 is not allowed \(a whole number 1..1000 us\)"),
    (dict(number_of_samples=100), r"'number_of_samples': 100 is not allowed"),
    (dict(transmit_frequency=1500), r"'transmit_frequency': 1500"),
    (dict(start_angle=400), r"'angle': 400 is not allowed \(a whole number 0..399 gradians\)"),
    (dict(step=3), r"'step': 3 is not allowed \(a divisor of 400"),
    (dict(range=1000.0), r"'range': 1000.0 is not allowed \(with 1200 samples at 1500 m/s: "),
    (dict(range=0.01), r"sample period 80..40000 ticks"),
    (dict(sound_speed=1000.0), r"'sound_speed': 1000.0 is not allowed"),
    (dict(step=10, stop_angle=15), r"'stop_angle': 15 is not allowed \(a whole number of 10-gradian steps"),
])
def test_settings_out_of_range_are_one_line(kw, match):
    with pytest.raises(ValueError, match=match) as e:
        Ping360Settings(**kw)
    assert "\n" not in str(e.value)


def test_settings_from_scan():
    s = Ping360Settings.from_scan(SCAN)
    assert (s.step, s.start_angle, s.stop_angle, s.clockwise, s.number_of_samples, s.sample_period) == \
        (1, 0, None, True, 200, 640)
    sector = synthetic_scan(n_pings=11, step_deg=9.0, start_deg=-45.0)
    s = Ping360Settings.from_scan(sector)
    assert (s.step, s.start_angle, s.stop_angle, s.clockwise) == (10, 50, 350, False)


# ---- driver and virtual head ------------------------------------------------------------------

def test_full_turn_through_a_pty_is_byte_exact():
    (got,), sonar, vm = run_scan(SCAN)
    assert_same_scan(got, SCAN)
    assert got.meta.angles == list(range(400)) and got.meta.sample_period == 640
    assert sonar.stats["pings"] == 400 and sonar.parser.dropped == 0
    # the autobaud 'U' the driver sends first, as brping does, is the only byte the head skips
    assert vm.parser.dropped == 1 and vm.parser.packets == 402
    assert sonar.device_information.device_type == 2 and sonar.protocol_version.version_minor == 1


def test_udp_on_the_loopback_is_byte_exact():
    (got,), sonar, vm = run_scan(SCAN, "udp://127.0.0.1:0")
    assert got.meta.port.startswith("udp://127.0.0.1:")
    assert_same_scan(got, SCAN)


def test_the_virtual_head_serves_udp_on_the_loopback_only():
    with pytest.raises(ValueError, match=r"cannot open port udp://0.0.0.0:0: serves on the loopback only"):
        VirtualPing360(SCAN, "udp://0.0.0.0:0").start()


def test_sector_counter_clockwise_and_coarser_steps():
    sector = synthetic_scan(n_pings=11, step_deg=9.0, start_deg=-45.0, pose=MOUNT, seed=4)
    scans, sonar, _ = run_scan(sector, n=2)
    for s in scans:
        assert_same_scan(s, sector)
        assert s.meta.sweep == "sector" and s.meta.angles[0] == 50


def test_a_coarser_request_serves_the_nearest_rendered_bearing():
    settings = Ping360Settings(range=2.4, number_of_samples=200, step=4)
    (got,), _, vm = run_scan(SCAN, settings=settings)
    assert np.array_equal(got.data, SCAN.data[::4])
    # twice the samples over the same range: each sample takes the scan bin holding its centre
    settings = Ping360Settings(range=2.4, number_of_samples=400, step=40)
    (got,), _, _ = run_scan(SCAN, settings=settings)
    assert np.array_equal(got.data, np.repeat(SCAN.data[::40], 2, axis=1))


def test_damaged_replies_are_skipped_counted_and_asked_again():
    (got,), sonar, vm = run_scan(SCAN, vm_kw=dict(corrupt_pings=(3, 100), cut_pings=(7, 250)))
    assert_same_scan(got, SCAN)
    assert sonar.parser.errors >= 2 and sonar.parser.dropped > 0
    assert sonar.stats["request timeouts"] == 4 and vm.stats["pings"] == 404


def test_brping_client_against_the_virtual_head():
    """Any client that speaks the protocol: brping's own, over a pty and over UDP."""
    from brping import Ping360
    for url in (None, "udp://127.0.0.1:0"):
        with VirtualPing360(SCAN, url, realtime=False) as vm:
            p = Ping360()
            with contextlib.redirect_stdout(io.StringIO()):      # brping prints as it connects
                if url is None:
                    p.connect_serial(vm.port, 115200)
                else:
                    p.connect_udp("127.0.0.1", int(vm.port.rsplit(":", 1)[1]))
            try:
                assert p.initialize()
                assert p.set_number_of_samples(200).message_id == ids["device_data"]
                assert p.set_sample_period(640).message_id == ids["device_data"]
                rows = [p.transmitAngle(a) for a in range(400)]
                assert all(bytes(r.data) == SCAN.data[a].tobytes() for a, r in enumerate(rows))
                nack = p.set_sample_period(50)
                assert nack.message_id == ids["nack"] and b"'sample_period': 50 is not allowed" in bytes(nack.nack_message)
            finally:
                p.iodev.close()


def test_auto_transmit_streams_auto_device_data():
    from mitsonar.devices.ping360.protocol import StreamParser, encode
    from mitsonar.devices.transports import open_serial, read_available, serial_fileno
    import time
    with VirtualPing360(SCAN, realtime=False) as vm:
        ser = open_serial(vm.port, 115200, timeout=0.1)
        try:
            ser.write(encode(Message("auto_transmit", mode=1, gain_setting=1, transmit_duration=10,
                                     sample_period=640, transmit_frequency=750, number_of_samples=200,
                                     start_angle=10, stop_angle=30, num_steps=10)))
            # the loop ends when 5 messages are in; the deadline only ends a broken run (it was
            # 5 s, which a loaded machine could reach)
            p, got, end = StreamParser(), [], time.monotonic() + 60
            while len(got) < 5 and time.monotonic() < end:
                got += p.feed(read_available(ser, serial_fileno(ser), 0.1, vm.port))
            ser.write(encode(Message("motor_off")))
            assert [m.angle for m in got[:5]] == [10, 20, 30, 10, 20]
            assert all(m.name == "auto_device_data" and m.num_steps == 10 for m in got[:5])
            assert bytes(got[1].data) == SCAN.data[20].tobytes()
        finally:
            ser.close()


def test_a_refused_setting_is_one_line_from_the_driver():
    with VirtualPing360(SCAN, realtime=False) as vm, Ping360Sonar(vm.port, **FAST) as sonar:
        sonar._settings.sample_period = 50          # past the checks of Ping360Settings
        with pytest.raises(SonarError, match=r"the head refused transducer: transducer 'sample_period': 50 is not allowed"):
            sonar.read_ping()


def test_silent_port_times_out_without_hanging():
    master, slave = os.openpty()
    try:
        with pytest.raises(SonarTimeout, match="no protocol_version within 0.5 s"):
            Ping360Sonar(os.ttyname(slave), timeout=0.5, ping_timeout=0.1)
    finally:
        os.close(master)
        os.close(slave)


def test_bad_port_is_one_line():
    with pytest.raises(SonarError, match="cannot open /nonexistent/tty"):
        Ping360Sonar("/nonexistent/tty")
    with pytest.raises(SonarError, match=r"cannot open udp://127.0.0.1: needs a host and a port"):
        Ping360Sonar("udp://127.0.0.1")


def test_realtime_head_gives_the_same_scan():
    sector = synthetic_scan(n_pings=5, step_deg=-9.0, pose=MOUNT, seed=2)
    with VirtualPing360(sector, realtime=True) as vm, \
            Ping360Sonar(vm.port, settings=Ping360Settings.from_scan(sector), pose=MOUNT, timeout=10) as sonar:
        assert_same_scan(sonar.scan(), sector)


def test_assembler_zero_fills_a_pass_cut_short():
    s = Ping360Settings(range=2.4, number_of_samples=200, step=100)
    asm = Ping360Assembler(s)
    def reply(a):
        return Message("device_data", **{k: v for k, v in s.transducer(a).items() if k not in ("transmit", "reserved")},
                       data=bytes([a % 256]) * 200)
    assert asm.add(reply(0)) is None and asm.add(reply(100)) is None
    cut = asm.add(reply(0))                      # a new pass before the last angle
    assert cut.meta.missing == [2, 3] and not cut.data[2:].any() and cut.data[1, 0] == 100
    assert asm.add(reply(0)) is None             # a repeat of the last ping counts once
    assert asm.finish().meta.missing == [1, 2, 3]


# ---- record and replay ------------------------------------------------------------------------

def test_record_then_replay_gives_the_same_scans(tmp_path):
    log = tmp_path / "p360.bin"
    settings = Ping360Settings.from_scan(SCAN)
    with VirtualPing360(SCAN, realtime=False, corrupt_pings=(5,), cut_pings=(420,)) as vm:
        with Ping360Sonar(vm.port, settings=settings, pose=MOUNT, **FAST) as sonar:
            live = [sonar.scan(), sonar.scan()]
        stats = record(vm.port, log, scans=2, settings=settings, pose=MOUNT, **FAST)
    assert stats["scans"] == 2 and stats["pings"] == 800 and stats["bytes_dropped"] == 0
    meta, records = read_log(log)
    assert meta["head"] == "ping360" and meta["settings"]["number_of_samples"] == 200
    with warnings.catch_warnings():
        warnings.simplefilter("error")           # a clean log: no damage to report
        scans = replay(log)
    assert len(scans) == 2
    for a, b in zip(scans, live):
        assert_same_scan(a, SCAN)
        assert np.array_equal(a.data, b.data) and np.array_equal(a.poses, b.poses)
    assert replay(log, pose=np.eye(4))[0].poses[0] == pytest.approx(bearing_rotation(SCAN.bearings[0]))
    # the rows' reception times, from the first row's: rising through the turn, within its span
    for s in scans:
        assert s.times[0] == 0 and np.all(np.diff(s.times) >= 0) and s.times[-1] > 0
        assert s.times[-1] == pytest.approx(s.meta.end_time - s.meta.start_time)


def test_replay_of_a_damaged_log_warns_and_keeps_the_rest(tmp_path):
    from mitsonar.devices.rawlog import LogDamageWarning
    log = tmp_path / "p360.bin"
    sector = synthetic_scan(n_pings=11, step_deg=9.0, start_deg=-45.0, pose=MOUNT, seed=4)
    with VirtualPing360(sector, realtime=False, corrupt_pings=(2,)) as vm:
        record(vm.port, log, scans=2, settings=Ping360Settings.from_scan(sector), pose=MOUNT, **FAST)
    with pytest.warns(LogDamageWarning, match="form no whole ping-protocol message.*bad checksum"):
        scans = replay(log)
    assert len(scans) == 2 and all(np.array_equal(s.data, sector.data) for s in scans)


def test_record_from_a_silent_port_leaves_no_file(tmp_path):
    master, slave = os.openpty()
    try:
        with pytest.raises(SonarTimeout, match="no bytes from the head on"):
            record(os.ttyname(slave), tmp_path / "x.bin", scans=1, timeout=0.3, ping_timeout=0.1)
    finally:
        os.close(master)
        os.close(slave)
    assert list(tmp_path.iterdir()) == []


def test_rendered_box_scan_survives_the_wire(mitsonar_mod):
    """The whole chain as with hardware: render, serve as a Ping360 over a pty, receive with the
    driver: the renderer's 200 pings of 1.8 deg are 2-gradian steps counter-clockwise, its 500 bins
    to 12 m a sample period of 1280 ticks."""
    box = os.path.join(os.path.dirname(os.path.dirname(os.path.abspath(__file__))), "scenes_xml", "box.xml")
    scan = mitsonar_mod.render_scan(mitsonar_mod.load_scene(box), spp=64, seed=2)
    settings = Ping360Settings.from_scan(scan)
    assert (settings.step, settings.clockwise, settings.sample_period) == (2, False, 1280)
    mount = scan.poses[0] @ np.linalg.inv(bearing_rotation(scan.bearings[0]))
    with VirtualPing360(scan, realtime=False) as vm, \
            Ping360Sonar(vm.port, settings=settings, pose=mount, timeout=30) as sonar:
        got = sonar.scan()
    assert np.array_equal(got.data, scan.data)
    np.testing.assert_allclose(got.bearings, scan.bearings, atol=1e-9)
    np.testing.assert_allclose(got.poses, scan.poses, atol=1e-9)
    np.testing.assert_allclose(got.ranges, scan.ranges, rtol=1e-6)


class _ScriptedLine:
    """A pyserial-like line whose head answers each transducer request with ``before(reply)``
    bytes and then the right reply (no file descriptor: the driver polls it)."""

    def __init__(self, before):
        from mitsonar.devices.ping360.protocol import StreamParser
        self.before, self.parser, self.buf, self.timeout, self.port = before, StreamParser(), bytearray(), 0.0, "scripted"

    def write(self, data):
        from mitsonar.devices.ping360.protocol import encode
        for m in self.parser.feed(data):
            if m.message_id == ids["general_request"]:
                name = {v: k for k, v in ids.items()}[m.requested_id]
                extra = {"device_type": 2} if name == "device_information" else {}
                self.buf += encode(Message(name, **extra))
            elif m.message_id == ids["transducer"]:
                fields = {k: getattr(m, k) for k in m.fields if k not in ("transmit", "reserved")}
                good = encode(Message("device_data", **fields, data=SCAN.data[m.angle, :m.number_of_samples].tobytes()))
                self.buf += self.before(good) + good
        return len(data)

    @property
    def in_waiting(self):
        return len(self.buf)

    def read(self, n=1):
        out = bytes(self.buf[:n])
        del self.buf[:n]
        return out

    def close(self):
        pass


@settings(max_examples=int(os.environ.get("MITSONAR_FUZZ_EXAMPLES", 40)), deadline=None, derandomize=True,
          suppress_health_check=[HealthCheck.too_slow])
@given(st.binary(max_size=120).map(lambda b: b.replace(b"B", b"b")), st.sampled_from(["cut", "flip", "none"]),
       st.floats(0.05, 0.95))
def test_driver_survives_garbage_and_damaged_replies(garbage, damage, where):
    """Before every good reply: garbage, and a copy of the reply cut short or with a flipped byte.
    The driver never fails, every ping it returns is the right one, and the skipped bytes are counted."""
    def before(good):
        k = 2 + int(where * (len(good) - 3))
        bad = {"cut": good[:k], "flip": good[:k] + bytes([good[k] ^ 0x21]) + good[k + 1:], "none": b""}[damage]
        return garbage + bad
    line = _ScriptedLine(before)
    settings_ = Ping360Settings(range=2.4, number_of_samples=200, step=100)
    with Ping360Sonar(line, settings=settings_, timeout=5.0, ping_timeout=0.5) as sonar:
        got = sonar.scan()
    assert np.array_equal(got.data, SCAN.data[::100])
    # four pings, each reply 10 + 14 + 200 bytes: all that came before each good one was skipped
    assert sonar.parser.dropped == 4 * len(before(bytes(224))) and sonar.stats["request timeouts"] == 0
