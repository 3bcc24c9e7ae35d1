"""The Oculus head over 127.0.0.1: the virtual head (mitsonar.devices.oculus.virtual) against a small
client written here from the published layout (struct formats of Oculus.h, not mitsonar's codec)
and against bps_oculus (oculus-python); its status broadcast; refusals; the driver (discovery,
raw log, replay, reconnect, a malformed message); .oculus logs written by mitsonar read by
bps_oculus, and one built here from the layout replayed by `mitsonar replay`; the command line
(`virtual-sonar SCENE --head oculus`, `--log`) with the wall of a test scene at its range."""
from __future__ import annotations

import io
import math
import os
import socket
import struct
import subprocess
import sys
import threading
import time
from pathlib import Path

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings, strategies as st

from mitsonar.cli.main import main
import mitsonar.presets.oculus as presets
from mitsonar.geometry.frames import bearing_rotation
from mitsonar import load_scan
from mitsonar.scan import Scan

WALL = """<scene version="3.0.0">
  <integrator type="sonar_tof"><integer name="max_depth" value="1"/></integrator>
  <sensor type="sonar">
    <string name="kind" value="multibeam"/>
    <transform name="to_world"><lookat origin="0,0,0" target="1,0,0" up="0,0,1"/></transform>
    <float name="range_min" value="0"/><float name="range_max" value="10"/><integer name="n_bins" value="100"/>
    <float name="bearing_start" value="-65"/><float name="bearing_step" value="2.0"/><integer name="n_pings" value="66"/>
    <string name="beam_pattern" value="gaussian"/><float name="beamwidth_h" value="2"/><float name="beamwidth_v" value="20"/>
  </sensor>
  <bsdf type="acoustic" id="c"><float name="diffuse" value="0.6"/><float name="specular" value="0.0"/></bsdf>
  <shape type="rectangle"><transform name="to_world"><scale value="30"/>
    <lookat origin="6,0,0" target="0,0,0" up="0,0,1"/></transform><ref id="c"/></shape>
</scene>
"""
WALL_RANGE = 6.0

# ---- a client from the published layout (Oculus.h, liboculus; independent of mitsonar's codec) ----
HEADER = "<5HIH"                       # oculusId, src, dst, msgId, msgVersion, payloadSize, spare2
FIRE1, FIRE2 = "<5B4d", "<5B4d9I"      # masterMode, pingRate, networkSpeed, gamma, flags, range, gain, c, S
PING1, PING2 = "<2I4dIBd2H3I", "<2I8dBd2H7I"


def fire_bytes(version=2, mode=1, rate=2, gamma=255, flags=0x0D, rng=10.0, gain=100.0, c=1500.0, salinity=35.0,
               ext=0) -> bytes:
    body = struct.pack(FIRE2, mode, rate, 255, gamma, flags, rng, gain, c, salinity, ext, *([0] * 8)) \
        if version == 2 else struct.pack(FIRE1, mode, rate, 255, gamma, flags, rng, gain, c, salinity)
    return struct.pack(HEADER, 0x4F53, 0, 0, 0x15, version, len(body), 0) + body


class LayoutClient:
    """Connects, fires, and reads simple ping results by the published offsets."""

    def __init__(self, port, host="127.0.0.1"):
        self.sock = socket.create_connection((host, port), timeout=10)
        self.buf = b""

    def close(self):
        self.sock.close()

    def fire(self, **kw):
        self.sock.sendall(fire_bytes(**kw))

    def _read(self, n):
        while len(self.buf) < n:
            data = self.sock.recv(1 << 20)
            if not data:
                raise ConnectionError("closed")
            self.buf += data
        out, self.buf = self.buf[:n], self.buf[n:]
        return out

    def message(self) -> bytes:
        head = self._read(16)
        oid, _src, _dst, mid, ver, size, _ = struct.unpack(HEADER, head)
        assert oid == 0x4F53
        return head + self._read(size)

    def ping(self, want_range=None) -> dict:
        """The next ping result (skipping those of an earlier fire message whose range differs)."""
        while True:
            m = self.message()
            p = parse_ping(m)
            if want_range is None or p["range"] == want_range:
                return p

    def drain(self, quiet=0.3) -> int:
        """Read until nothing comes for ``quiet`` s; the bytes read."""
        self.sock.settimeout(quiet)
        n = 0
        try:
            while True:
                data = self.sock.recv(1 << 20)
                if not data:
                    break
                n += len(data)
        except socket.timeout:
            pass
        self.sock.settimeout(10)
        self.buf = b""
        return n


def parse_ping(m: bytes) -> dict:
    mid, ver = struct.unpack_from("<2H", m, 6)
    assert mid == 0x23
    v = 2 if ver == 2 else 1
    fire = struct.unpack_from(FIRE2 if v == 2 else FIRE1, m, 16)
    at = 89 if v == 2 else 53
    f = struct.unpack_from(PING2 if v == 2 else PING1, m, at)
    if v == 2:
        pid, _st, freq, temp, pres, heading, pitch, roll, c, t0, dsize, res, n_r, n_b = f[:14]
        off, isize, total = f[18:21]
    else:
        pid, _st, freq, temp, pres, c, t0, dsize, res, n_r, n_b, off, isize, total = f
    head = at + struct.calcsize(PING2 if v == 2 else PING1)
    nb = {0: 1, 1: 2, 3: 4}[dsize]
    bearings = np.frombuffer(m, "<i2", n_b, head)
    gain = bool(fire[4] & 0x04)
    stride = n_b * nb + (4 if gain else 0)
    assert isize == stride * n_r and total == len(m) == off + isize
    rows = np.frombuffer(m, np.uint8, isize, off).reshape(n_r, stride)
    gains = rows[:, :4].copy().view("<f4")[:, 0] if gain else None
    img = np.ascontiguousarray(rows[:, 4:] if gain else rows).view({1: "<u1", 2: "<u2", 4: "<u4"}[nb])
    return {"version": v, "id": pid, "frequency": freq, "c": c, "res": res, "n_r": n_r, "n_b": n_b,
            "bearings": bearings, "image": img, "gains": gains, "range": fire[5], "temperature": temp, "pressure": pres,
            "heading": heading if v == 2 else None, "pitch": pitch if v == 2 else None,
            "roll": roll if v == 2 else None, "raw": m}


def free_udp_port() -> int:
    s = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    s.bind(("127.0.0.1", 0))
    port = s.getsockname()[1]
    s.close()
    return port


def fan_scan(aperture=130.0, n_b=256, n_r=100, bin_width=0.1, seed=0, pose=None):
    """A multibeam scan whose rows lie at the head's own bearing table (so beam k is row k), of a
    head at ``pose`` (default identity)."""
    b = np.radians(presets.bearing_table(aperture, n_b) / 100.0)
    data = np.random.default_rng(seed).integers(0, 256, (n_b, n_r), dtype=np.uint8)
    pose = np.eye(4) if pose is None else pose
    return Scan(intensity=np.zeros((n_b, n_r), np.float32), data=data, ranges=(np.arange(n_r) + 0.5) * bin_width,
                bearings=b, poses=pose @ bearing_rotation(b), range_min=0.0, range_max=n_r * bin_width,
                kind="multibeam", sound_speed=1500.0)


@pytest.fixture
def head():
    from mitsonar.devices.oculus.virtual import VirtualOculus
    h = VirtualOculus(fan_scan(), tcp_port=0, udp_port=None)
    h.start()
    yield h
    h.stop()


@pytest.fixture(scope="module")
def wall(tmp_path_factory):
    import mitsonar
    path = tmp_path_factory.mktemp("oculus") / "wall.xml"
    path.write_text(WALL)
    return path, mitsonar.render_scan(mitsonar.load_scene(str(path)), spp=16, seed=0)


# ---- the virtual head ----

def test_a_layout_client_fires_with_several_settings(head):
    data = head.scan.data.T.astype(np.int64)           # (range lines, beams) at the head's own bearings
    c = LayoutClient(head.tcp_port)
    try:
        c.fire(version=1, flags=0x09, rng=10.0)        # metres, 8-bit, no gains, 256 beams
        p = c.ping(10.0)
        assert p["version"] == 1 and (p["n_r"], p["n_b"]) == (100, 256) and p["res"] == pytest.approx(0.1)
        np.testing.assert_array_equal(p["image"], data)
        np.testing.assert_array_equal(p["bearings"], presets.bearing_table(130.0, 256))
        assert p["frequency"] == 1.2e6 and p["gains"] is None
        c.fire(version=2, flags=0x0F, rng=9.0)         # 16-bit, gains
        p = c.ping(9.0)
        np.testing.assert_array_equal(p["image"], data[:90] * 257)
        np.testing.assert_array_equal(p["gains"], np.ones(90, np.float32))
        c.fire(version=2, flags=0x0D, rng=8.0, ext=0x200)       # 32-bit (extFlags)
        np.testing.assert_array_equal(c.ping(8.0)["image"], data[:80] * 16843009)
        c.fire(version=2, flags=0x0D, rng=7.0, gain=50.0)       # gain 50 %: -6 dB on the A/D scale
        p = c.ping(7.0)
        from mitsonar.receiver.electronics import Electronics
        shift = 20 * math.log10(0.5) * 255 / Electronics.from_dict({}).ad_span
        np.testing.assert_array_equal(p["image"], np.clip(np.floor(data[:70] + shift + 0.5), 0, 255))
        np.testing.assert_array_equal(p["gains"], np.full(70, 0.5, np.float32))
        c.fire(version=2, flags=0x0D, rng=6.0, gamma=127)       # gamma 0.5
        np.testing.assert_array_equal(c.ping(6.0)["image"], np.round(255 * (data[:60] / 255) ** (127 / 255)))
        c.fire(version=2, flags=0x4D, rng=5.0, mode=2)          # high frequency, 512 beams
        p = c.ping(5.0)
        assert p["n_b"] == 512 and p["frequency"] == 2.1e6
        assert p["bearings"][0] / 100 == pytest.approx(-30, abs=0.2) and p["bearings"][-1] / 100 == pytest.approx(30, abs=0.2)
        c.fire(version=2, flags=0x0C, rng=25.0)                 # range in percent of the mode's 40 m
        p = c.ping(25.0)
        assert p["n_r"] * p["res"] == pytest.approx(10.0)
        c.fire(version=2, flags=0x0D, rng=4.0, c=0.0, salinity=30.0)   # the head's own speed of sound
        from mitsonar.acoustics.seawater import sound_speed
        p = c.ping(4.0)
        assert p["c"] == pytest.approx(float(sound_speed(10.0, 30.0, 0.0)))
        assert p["res"] == pytest.approx(0.1 * p["c"] / 1500.0) and p["temperature"] == 10.0
        c.fire(version=2, flags=0x0D, rng=3.5, c=0.0, salinity=0.0)    # fresh water (liboculus's default)
        p = c.ping(3.5)
        # Mackenzie (1981) is linear in salinity: 1.340 - 1.025e-2 T m/s per ppt, continued to 0 ppt
        assert p["c"] == pytest.approx(float(sound_speed(10.0, 35.0, 0.0)) - 35 * (1.340 - 1.025e-2 * 10))
    finally:
        c.close()
    assert head.stats["refused"] == 0 and head.last_error is None


def test_one_fire_message_streams_at_its_rate_until_standby(head):
    c = LayoutClient(head.tcp_port)
    try:
        c.fire(rate=2, rng=3.0)                        # 40 Hz
        ids = [c.ping()["id"] for _ in range(4)]
        assert ids == sorted(ids) and len(set(ids)) == 4
        c.fire(rate=5, rng=3.0)                        # standby
        c.drain()
        n = head.stats["pings"]
        time.sleep(0.3)
        assert head.stats["pings"] == n
    finally:
        c.close()


def test_period_follows_the_rate_and_the_listening_time(head):
    from mitsonar.devices.oculus.protocol import FireMessage
    assert head.period(FireMessage(ping_rate=4, range=5.0, speed_of_sound=1500)) == pytest.approx(0.5)   # 2 Hz
    assert head.period(FireMessage(ping_rate=2, range=30.0, speed_of_sound=1500)) == pytest.approx(0.04)  # 40 m/s^-1
    assert head.period(FireMessage(ping_rate=2, range=40.0, speed_of_sound=1000 * 1.5)) == pytest.approx(80 / 1500)
    assert head.period(FireMessage(ping_rate=5)) == math.inf


class _FakeClock:
    """The head's clock in a test: time passes only when the test (or the fake selector) says."""

    def __init__(self):
        self.t = 0.0

    def __call__(self):
        return self.t


class _FakeSelector:
    """The head's selector on the fake clock: a wait of ``timeout`` s passes at once, no events."""

    def __init__(self, clock):
        self.clock = clock

    def select(self, timeout):
        self.clock.t += max(timeout, 1e-6)
        return []

    def register(self, *a):
        pass

    modify = unregister = register


class _FakeSock:
    """A client socket that takes every byte (``full``: none)."""

    def __init__(self, full=False, chunk=None):
        self.full, self.chunk, self.sent = full, chunk, 0

    def send(self, data):
        if self.full:
            raise BlockingIOError
        n = len(data) if self.chunk is None else min(len(data), self.chunk)
        self.sent += n
        return n

    def fileno(self):
        return 99

    def close(self):
        pass


def _scheduled_head(render_s, full=False, chunk=None, rate=10):
    """A virtual head on a fake clock with one client fired at ``rate`` Hz (a 2 m range: 20 lines),
    each ping taking ``render_s`` s of that clock to make."""
    from mitsonar.devices.oculus.driver import fire_message
    from mitsonar.devices.oculus.virtual import VirtualOculus, _Client
    clock = _FakeClock()
    h = VirtualOculus(fan_scan(n_r=20), tcp_port=0, udp_port=None, clock=clock)
    h._sel, h._udp = _FakeSelector(clock), None        # what start() would open, without sockets
    made = h.ping

    def slow_ping(*a, **kw):
        clock.t += render_s
        return made(*a, **kw)

    h.ping = slow_ping
    c = _Client(_FakeSock(full, chunk), ("127.0.0.1", 1))
    h._clients[99] = c
    h._on_message(c, fire_message(rate=rate, range=2.0, gain=100, beams=256))
    return h, clock, c


@pytest.mark.parametrize("hz, code", [(10, 0), (15, 1), (40, 2), (5, 3), (2, 4), (0, 5)])
def test_each_ping_rate_streams_at_its_rate_from_one_fire_message(hz, code):
    # pingRate (Oculus.h PingRateType): 0 10 Hz, 1 15 Hz, 2 40 Hz, 3 5 Hz, 4 2 Hz, 5 standby. One fire
    # message, then a ping every 1/rate s of the head's clock (2 s: 2 x rate pings); standby: none
    from mitsonar.devices.oculus.driver import fire_message
    fire = fire_message(rate=hz, range=2.0)
    assert fire.ping_rate == code and fire.encode()[17] == code          # pingRate at byte 17
    h, clock, _ = _scheduled_head(0.0, rate=hz)
    sent = []
    send = h._send_ping
    h._send_ping = lambda c, now: (sent.append(now), send(c, now))
    while clock.t < (2.0 - 0.5 / hz if hz else 2.0):     # half a period after the last slot before 2 s
        h._tick()
    assert h.stats["fire messages"] == 1 and h.stats["pings"] == len(sent) == 2 * hz
    if hz:
        np.testing.assert_allclose(sent, np.arange(2 * hz) / hz, atol=1e-6)
    assert h.stats["pings skipped (late)"] == 0 and h.last_error is None


def test_the_head_keeps_its_rate_when_each_ping_takes_most_of_the_period():
    # 60 ms to make each ping at 10 Hz: slots 0, 0.1, ..., 9.9 s of the head's clock all ping.
    # Scheduling the next ping a period after the tick that sent it (and waiting a period from the
    # tick's start) added each ping's making time to the period: 9 pings a second, not 10.
    h, clock, _ = _scheduled_head(0.06)
    while clock.t < 9.95:                 # half a period after the last slot (9.9 s)
        h._tick()
    assert h.stats["pings"] == 100
    assert h.stats["pings skipped (late)"] == 0 and h.last_error is None


def test_slots_missed_by_a_whole_period_are_skipped_and_counted_not_burst():
    # 250 ms a ping at 10 Hz: the head pings at the next slot it can and counts the ones it missed;
    # every slot is either pinged or skipped, and no two pings are closer than a ping's making.
    h, clock, _ = _scheduled_head(0.25)
    sent = []
    send = h._send_ping
    h._send_ping = lambda c, now: (sent.append(now), send(c, now))
    while clock.t < 9.95:
        h._tick()
    slots = round(h._clients[99].due / 0.1)
    assert h.stats["pings"] == len(sent) == 40
    assert h.stats["pings"] + h.stats["pings skipped (late)"] == slots
    assert min(np.diff(sent)) >= 0.25 - 1e-9


def test_slots_of_a_client_behind_are_skipped_on_the_heads_schedule(monkeypatch):
    import mitsonar.devices.oculus.virtual as virtual
    monkeypatch.setattr(virtual, "MAX_BACKLOG", 1)          # the first ping fills what the client may have waiting
    h, clock, c = _scheduled_head(0.0, full=True)
    while clock.t < 1.95:
        h._tick()
    assert h.stats["pings"] == 1 and h.stats["pings skipped (client behind)"] == 19
    assert c.due == pytest.approx(2.0)


def test_the_heads_summary_and_the_live_summary_say_its_skipped_slots(monkeypatch):
    # a head that cannot keep its rate (250 ms a ping at 10 Hz), and one whose client reads nothing:
    # virtual-sonar's last line and `mitsonar live`'s summary say how many slots each skipped
    import mitsonar.devices.oculus.virtual as virtual
    from mitsonar.cli.live import _summary

    class Renderer:
        def summary(self):
            return "9 pings rendered"

    slow, clock, _ = _scheduled_head(0.25)
    while clock.t < 1.95:
        slow._tick()
    monkeypatch.setattr(virtual, "MAX_BACKLOG", 1)
    behind, clock, _ = _scheduled_head(0.0, full=True)
    while clock.t < 1.95:
        behind._tick()
    for h, late, slow_client in ((slow, slow.stats["pings skipped (late)"], 0), (behind, 0, 19)):
        assert h.stats["pings skipped (late)"] == late and h.stats["pings skipped (client behind)"] == slow_client
        said = (f"{h.stats['pings']} pings to 0 client(s), 0 message(s) refused, {late} pings skipped (late), "
                f"{slow_client} pings skipped (client behind)")
        assert h.summary() == said
        assert _summary(Renderer(), None, None, None, h) == f"9 pings rendered; head: {said}"
    assert slow.stats["pings skipped (late)"] > 0
    out = io.StringIO()
    monkeypatch.setattr("mitsonar.devices.transports.serve_in_foreground", lambda *a: None)
    slow.serve(0, out)
    assert out.getvalue() == f"virtual Oculus: {slow.summary()}\n"


_NUMBERS = st.one_of(st.floats(allow_nan=True, allow_infinity=True), st.sampled_from([0.0, 5.0, 40.0, 100.0]))


@settings(max_examples=int(os.environ.get("MITSONAR_FUZZ_EXAMPLES", 60)), deadline=None, derandomize=True, suppress_health_check=[HealthCheck.too_slow])
@given(st.integers(0, 255), st.integers(0, 255), st.integers(0, 255), st.integers(0, 255), _NUMBERS, _NUMBERS,
       _NUMBERS, _NUMBERS, st.integers(0, 2 ** 32 - 1), st.sampled_from([1, 2]))
def test_any_fire_message_is_answered_or_refused_and_the_head_stays_up(mode, rate, gamma, flags, rng, gain, c,
                                                                        salinity, ext, version):
    # every field of a fire message that decodes, at any value: the head pings with it, or refuses it
    # naming the field (counted); it never fails inside
    from mitsonar.devices.oculus.protocol import FireMessage, decode
    fire = decode(FireMessage(mode, rate, 0, gamma, flags, rng, gain, c, salinity, ext_flags=ext,
                              version=version).encode())
    h, clock, client = _scheduled_head(0.0)
    h._on_message(client, fire)
    for _ in range(3):
        h._tick()
    assert h.last_error is None and h.stats["internal errors"] == 0
    if h.stats["refused"] == 1:
        assert h.last_problem.startswith("simple fire '") and "is not allowed" in h.last_problem
    else:
        assert h.stats["refused"] == 0 and client.fire is fire
        assert h.stats["pings"] >= 1 or math.isinf(h.period(fire))


def test_a_ping_is_delivered_when_its_last_byte_is_written():
    # the live head's latency runs to the ping result's last byte (LiveOculus.delivered): a client
    # taking 1000 bytes a write has the ping only after several writes, not when it was made
    h, clock, c = _scheduled_head(0.0, chunk=1000)
    got = []
    h.delivered = lambda pid, t: got.append((pid, t, c.sock.sent))
    h._tick()                               # the first ping made at t = 0, its first 1000 bytes out
    size = len(c.out) + c.sock.sent
    assert got == [] and size > 3000
    start, writes = clock.t, 0
    while not got and writes < 100:
        clock.t += 0.001
        h._flush(c)
        writes += 1
    assert got == [(0, pytest.approx(start + writes * 0.001), size)] and writes == -(-size // 1000) - 1


def test_gain_percent_is_the_receiver_gain_of_a_rendered_scan(wall):
    from mitsonar.devices.oculus.virtual import VirtualOculus
    from mitsonar.receiver.electronics import apply_to_scan
    _, rendered = wall
    head = VirtualOculus(rendered, tcp_port=0)
    assert head.received(rendered, 100.0) is rendered.data
    g = rendered.electronics.gain
    for percent, db in ((50.0, 20 * math.log10(0.5)), (10.0, -20.0), (0.0, -g)):
        expected = apply_to_scan(rendered, {**rendered.electronics, "gain": g + db}).data
        np.testing.assert_array_equal(head.received(rendered, percent), expected)
    assert head.received(rendered, 10.0).astype(int).sum() < rendered.data.astype(int).sum()


def test_status_broadcast_carries_the_head_and_its_address():
    from mitsonar.devices.oculus.virtual import VirtualOculus
    port = free_udp_port()
    rx = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    rx.bind(("127.0.0.1", port))
    rx.settimeout(5)
    try:
        with VirtualOculus(fan_scan(n_r=10), model="M3000d", tcp_port=0, udp_port=port, status_period=0.1):
            data, _ = rx.recvfrom(4096)
    finally:
        rx.close()
    assert len(data) == 142 and struct.unpack_from("<H", data, 0)[0] == 0x4F53
    _dev, dtype, part, status = struct.unpack_from("<IHHI", data, 16)
    assert (dtype, part, status & 7) == (1, 2203, 3)
    assert data[52:56] == socket.inet_aton("127.0.0.1")


@pytest.mark.parametrize("name", ["M750d", "M1200d", "M3000d"])
def test_each_models_frequency_mode_selects_its_frequency_aperture_beams_and_range(name):
    # masterMode 1 (low) / 2 (high frequency): the model's frequency, aperture (the bearing table
    # spans it), beam widths (the driver's scan) and largest range; 256 or 512 beams by flag bit 6
    from mitsonar.devices.oculus.driver import fire_message
    from mitsonar.devices.oculus.head import ping_to_scan
    from mitsonar.devices.oculus.virtual import VirtualOculus, check_fire
    model = presets.model(name)
    h = VirtualOculus(fan_scan(n_r=50), model=name, tcp_port=0, udp_port=None)
    assert h.status().part_number == model.part_number
    for number, mode in model.modes.items():
        for beams in (256, 512):
            p = h.ping(fire_message(mode=number, range=5.0, beams=beams, speed_of_sound=1500.0))
            assert (p.frequency, p.n_beams) == (mode.frequency, beams)
            np.testing.assert_array_equal(p.bearings, presets.bearing_table(mode.aperture, beams))
            assert -p.bearings[0] / 100 == p.bearings[-1] / 100 == pytest.approx(mode.aperture / 2, abs=0.6)
            s = ping_to_scan(p)
            assert (s.beamwidth_h, s.beamwidth_v, s.meta.frequency) == (mode.beamwidth_h, mode.beamwidth_v,
                                                                        mode.frequency)
        assert check_fire(fire_message(mode=number, range=mode.max_range), model) is None
        assert (f"'range': {mode.max_range + 1!r} m is not allowed (0.1..{mode.max_range:g} m for the {name} in "
                f"mode {number})") in check_fire(fire_message(mode=number, range=mode.max_range + 1), model)


def test_heading_pitch_roll_depth_and_temperature_come_from_the_heads_pose_and_water():
    # a head looking east (x), its vehicle yawed 30 deg left, pitched 10 deg nose down, rolled 5 deg
    # to starboard, 3 m below the surface: heading 60, pitch -10, roll 5, pressure of 3 m of sea water
    from scipy.spatial.transform import Rotation
    from mitsonar.devices.oculus.driver import fire_message
    from mitsonar.devices.oculus.virtual import VirtualOculus
    mount = np.eye(4)
    mount[:3, :3] = np.array([[0, 1, 0], [0, 0, 1], [1, 0, 0]]).T      # lookat +x, up +z: z boresight, y up
    vehicle = np.eye(4)
    vehicle[:3, :3] = Rotation.from_euler("ZYX", [30, 10, 5], degrees=True).as_matrix()
    vehicle[:3, 3] = [4.0, -2.0, -1.0]
    h = VirtualOculus(fan_scan(n_r=20, pose=vehicle @ mount), tcp_port=0, udp_port=None, water={"temperature": 14.0, "surface_z": 2.0})
    p = h.ping(fire_message(range=2.0, speed_of_sound=1500.0))
    assert (p.heading, p.pitch, p.roll) == (pytest.approx(60.0), pytest.approx(-10.0), pytest.approx(5.0))
    assert p.temperature == 14.0 and p.pressure == pytest.approx(3.0 * 1025.0 * 9.80665 / 1e5)


def test_the_ports_default_to_what_the_open_clients_hard_wire_and_are_configurable(tmp_path, monkeypatch):
    # liboculus: StatusRx binds UDP 52102, DataRx connects to TCP 52100 of the status's address
    from mitsonar.devices.oculus.driver import OculusSonar
    from mitsonar.devices.oculus.logfile import write_log
    from mitsonar.devices.oculus.registration import OculusHead
    from mitsonar.devices.oculus.virtual import VirtualOculus
    h = VirtualOculus(fan_scan(n_r=10))                       # not started: nothing bound
    assert (h.host, h.tcp_port, h.udp_port, h.status().ip) == ("127.0.0.1", 52100, 52102, "127.0.0.1")
    sonar = OculusSonar(start=False)
    assert (sonar.host, sonar.tcp_port, sonar.udp_port) == (None, 52100, 52102)     # None: discovered
    served = []
    monkeypatch.setattr(OculusHead, "check_serve", lambda self, args: None)          # binds nothing here
    monkeypatch.setattr(VirtualOculus, "serve", lambda self, *a: served.append((self.host, self.tcp_port,
                                                                              self.udp_port)) or 0)
    log = write_log(tmp_path / "p.oculus", [fan_scan(n_r=10)])
    assert main(["virtual-sonar", "--log", str(log), "--head", "oculus"]) == 0
    assert main(["virtual-sonar", "--log", str(log), "--head", "oculus", "--port-url", "tcp://127.0.0.1:5100",
                 "--status-port", "5102"]) == 0
    assert served == [("127.0.0.1", 52100, 52102), ("127.0.0.1", 5100, 5102)]


def test_malformed_oversized_and_refused_messages_are_counted_and_the_head_stays_up(head):
    a, b = LayoutClient(head.tcp_port), LayoutClient(head.tcp_port)
    try:
        b.fire(rng=2.0)
        a.sock.sendall(b"junk that is no message")
        a.sock.sendall(struct.pack(HEADER, 0x4F53, 0, 0, 0x15, 2, 10 ** 6, 0))             # oversized
        a.sock.sendall(struct.pack(HEADER, 0x4F53, 0, 0, 0x15, 2, 8, 0) + b"\0" * 8)      # a cut fire message
        a.fire(rng=999.0)                                                                  # out of range
        a.fire(rng=3.0)
        assert a.ping()["range"] == 3.0
        assert b.ping()["range"] == 2.0
        assert head.stats["refused"] == 3 and head.stats["clients"] == 2
        assert "'range': 999.0 m is not allowed (0.1..40 m for the M1200d in mode 1)" in head.last_problem
        assert head.last_error is None
    finally:
        a.close()
        b.close()


def test_bps_oculus_parses_the_virtual_heads_ping_results(head):
    core = pytest.importorskip("bps_oculus.core")
    from mitsonar.devices.oculus.protocol import FireMessage
    c = LayoutClient(head.tcp_port)
    try:
        c.fire(version=2, flags=0x0D, rng=6.0)         # 8-bit with gains (bps_oculus needs them under numpy 2)
        raw = c.ping()["raw"]
    finally:
        c.close()
    res = core.process_raw(raw)
    img = core.parse_polar_image(raw, res)
    expected = head.ping(FireMessage(flags=0x0D, range=6.0, gain=100.0, speed_of_sound=1500.0))
    np.testing.assert_array_equal(img.polar_image, expected.image)
    np.testing.assert_array_equal(img.polar_image, head.scan.data.T[:60])
    np.testing.assert_allclose(img.bearing_table, np.radians(presets.bearing_table(130, 256) / 100))
    np.testing.assert_allclose(img.ranging_table, np.arange(1, 61) * 0.1)


# ---- the driver ----

def test_driver_discovers_records_a_raw_log_that_replays(tmp_path):
    from mitsonar.devices.oculus.driver import fire_message, record
    from mitsonar.devices.oculus.virtual import VirtualOculus
    from mitsonar.devices.recording import replay
    port = free_udp_port()
    scan = fan_scan(n_r=40)
    with VirtualOculus(scan, tcp_port=0, udp_port=port, status_period=0.05) as h:
        got = record(None, tmp_path / "o.bin", pings=3, tcp_port=h.tcp_port, udp_port=port,
                     fire=fire_message(rate=40, range=4.0, gain=100, speed_of_sound=1500))
    assert got["pings"] == 3
    scans = replay(tmp_path / "o.bin")
    assert len(scans) >= 3
    for s in scans:
        assert s.kind == "multibeam" and s.meta.source == "oculus"
        np.testing.assert_array_equal(s.data, scan.data)
        np.testing.assert_allclose(s.bearings, scan.bearings, atol=1e-9)
        np.testing.assert_allclose(s.ranges, scan.ranges)


@pytest.fixture(scope="module")
def head_frame(wall):
    """The wall scene rendered at the head's own geometry (M1200d low frequency, 256 beams at its
    bearing table, 0..10 m in 0.1 m bins): beam k is row k, range line i is bin i."""
    from mitsonar.devices.oculus.scenes import SceneFrames
    path, rendered = wall
    return SceneFrames(path, bin_width=rendered.bin_width, spp=4, seed=0)(presets.model("M1200d").mode(1), 256, 10.0)


@pytest.mark.parametrize("bits", [8, 16, 32])
def test_the_drivers_scans_keep_the_rendered_codes_of_each_data_size(head_frame, bits, tmp_path):
    # the virtual head fires 8-, 16- and 32-bit samples of the rendered scan's receiver chain; the
    # driver's scans, a raw log's replay and a .oculus log's carry those codes, bit for bit, in
    # uint8/16/32 with electronics bit_depth 8/16/32 (it kept the top eight bits of each)
    from mitsonar.devices.oculus.driver import OculusSonar, fire_message, record, record_oculus
    from mitsonar.devices.oculus.logfile import read_scans
    from mitsonar.devices.oculus.virtual import VirtualOculus
    from mitsonar.devices.recording import replay
    from mitsonar.receiver.electronics import apply_to_scan
    frame = head_frame
    codes = frame.data if bits == 8 else apply_to_scan(frame, frame.electronics.replace(bit_depth=bits)).data
    dtype = {8: np.uint8, 16: np.uint16, 32: np.uint32}[bits]
    assert codes.dtype == dtype and codes.shape == (256, 100) and codes.any()
    fire = fire_message(rate=40, range=10.0, gain=100, speed_of_sound=frame.sound_speed, data_bits=bits)
    with VirtualOculus(frame, tcp_port=0, udp_port=None) as h:
        with OculusSonar("127.0.0.1", h.tcp_port, fire) as sonar:
            scans = [sonar.scan()]
        record("127.0.0.1", tmp_path / "o.bin", pings=2, tcp_port=h.tcp_port, fire=fire)
        record_oculus("127.0.0.1", tmp_path / "o.oculus", pings=2, tcp_port=h.tcp_port, fire=fire)
    scans += replay(tmp_path / "o.bin") + read_scans(tmp_path / "o.oculus")
    assert len(scans) >= 5
    for s in scans:
        assert s.data.dtype == dtype and s.electronics.bit_depth == bits
        np.testing.assert_array_equal(s.data, codes)


def test_driver_reconnects_after_a_dropped_connection(head):
    from mitsonar.devices.oculus.driver import OculusSonar, fire_message
    out = io.StringIO()
    with OculusSonar("127.0.0.1", head.tcp_port, fire_message(rate=40, range=3.0, gain=100, speed_of_sound=1500),
                     out=out) as sonar:
        first = sonar.scan()
        head.drop_clients()
        for _ in range(3):
            s = sonar.scan()
    assert sonar.stats["reconnects"] == 1 and sonar.stats["fire messages"] == 2
    assert "the head closed the connection; reconnecting (1 of 3)" in out.getvalue()
    np.testing.assert_array_equal(s.data, first.data)


def test_driver_says_a_malformed_message_in_one_line_and_goes_on():
    from mitsonar.devices.oculus.driver import OculusSonar
    from mitsonar.devices.oculus.protocol import FireMessage, PingResult
    good = PingResult(FireMessage(flags=0x0D), np.ones((3, 4), np.uint8), np.arange(4, dtype=np.int16), 0.5,
                      gains=np.ones(3, np.float32)).encode()
    bad = bytearray(good)
    bad[161] = 7                                    # dataSize
    srv = socket.socket()
    srv.bind(("127.0.0.1", 0))
    srv.listen(1)

    def serve():
        conn, _ = srv.accept()
        conn.recv(1024)
        conn.sendall(bytes(bad) + good)
        time.sleep(0.5)
        conn.close()

    t = threading.Thread(target=serve, daemon=True)
    t.start()
    out = io.StringIO()
    with OculusSonar("127.0.0.1", srv.getsockname()[1], out=out, reconnects=0) as sonar:
        p = sonar.read_ping()
    srv.close()
    np.testing.assert_array_equal(p.image, np.ones((3, 4)))
    assert "dropped a malformed message (message 0x23: simple ping result 'dataSize': 7 is not allowed (0..3))" \
        in out.getvalue()


# ---- .oculus logs ----

def test_a_log_written_by_mitsonar_opens_in_bps_oculus_with_every_ping(tmp_path, wall):
    bio = pytest.importorskip("bps_oculus.io")
    from mitsonar.devices.oculus.logfile import read_scans, write_log
    _path, rendered = wall
    scans = [rendered, fan_scan(n_r=30, seed=1), rendered]
    log = write_log(tmp_path / "m.oculus", scans)
    assert bio.logger.check_oculus_log_version(log) == bio.logger.LoggerVersion.BPSv1
    items = list(bio.ImporterV1(log).generate())
    assert len(items) == 3
    for (info, msg, img, _), s in zip(items, scans):
        np.testing.assert_array_equal(img.polar_image, s.data.T)
        np.testing.assert_allclose(img.bearing_table, s.bearings, atol=np.radians(0.005))
        np.testing.assert_allclose(img.ranging_table, (np.arange(s.n_bins) + 1) * s.bin_width)
    back = read_scans(log)
    for b, s in zip(back, scans):
        np.testing.assert_array_equal(b.data, s.data)
        np.testing.assert_allclose(b.ranges, s.ranges)


def _foreign_log(path, pings):
    """A .oculus log built from the layout alone: file header, one item of another record type,
    then the pings (hand-packed version 1 and 2 simple ping results; ``(version, image, bearings,
    res[, bytes per sample])``: 1, 2, 3 or 4, dataSize 0..3, little-endian samples)."""
    out = struct.pack("<2I16s2H4xqd", 0x11223344, 48, b"Oculus", 1, 0, 0, 1.7e9)
    out += struct.pack("<2I2H4xdH2x2I4x", 0xAABBCCDD, 40, 2, 1, 1.7e9, 0, 3, 3) + b"abc"   # rt_serialPort
    for k, (version, image, bearings, res, *nb) in enumerate(pings):
        nb = nb[0] if nb else 1
        n_r, n_b = image.shape
        samples = np.asarray(image, "<u4").view(np.uint8).reshape(n_r, n_b, 4)[..., :nb].tobytes()
        flags, ext = 0x09 | (0x02 if nb == 2 else 0), 0x200 if nb == 4 else 0
        fire = struct.pack(FIRE2 if version == 2 else FIRE1, 1, 0, 255, 255, flags, n_r * res, 100.0, 1500.0, 35.0,
                           *(([ext] + [0] * 8) if version == 2 else []))
        head_size = (202 if version == 2 else 122)
        off = head_size + 2 * n_b
        total = off + len(samples)
        if version == 2:
            tail = struct.pack(PING2, k, 0, 1.2e6, 10.0, 0.0, 0, 0, 0, 1500.0, 0.0, nb - 1, res, n_r, n_b, 0, 0, 0, 0,
                               off, len(samples), total)
        else:
            tail = struct.pack(PING1, k, 0, 1.2e6, 10.0, 0.0, 1500.0, 0, nb - 1, res, n_r, n_b, off, len(samples),
                               total)
        msg = (struct.pack(HEADER, 0x4F53, 1, 0, 0x23, version, total - 16, 0) + fire + tail
               + np.asarray(bearings, "<i2").tobytes() + samples)
        out += struct.pack("<2I2H4xdH2x2I4x", 0xAABBCCDD, 40, 10, 1, 1.7e9 + k, 0, len(msg), len(msg)) + msg
    path.write_bytes(out)


def test_a_log_mitsonar_did_not_write_replays(tmp_path):
    rng = np.random.default_rng(3)
    pings = [(v, rng.integers(0, 256, (20, 8)), np.arange(-4, 4) * 500, 0.05) for v in (1, 2)]
    log = tmp_path / "foreign.oculus"
    _foreign_log(log, pings)
    assert main(["replay", str(log), "-o", str(tmp_path / "f.npz"), "--all"]) == 0
    for k, (_v, image, bearings, res) in enumerate(pings):
        s = load_scan(tmp_path / f"f_{k:03d}.npz")
        assert s.kind == "multibeam"
        np.testing.assert_array_equal(s.data, image.T)
        np.testing.assert_allclose(np.degrees(s.bearings), bearings / 100.0)
        np.testing.assert_allclose(s.ranges, (np.arange(20) + 0.5) * res)


def test_a_foreign_log_of_wide_samples_replays_with_its_codes(tmp_path):
    # 16- and 32-bit samples keep their codes (uint16, uint32; bit_depth 16, 32); 24-bit ones, which
    # no fire message asks for, go on the 32-bit scale: round(code (2^32 - 1) / (2^24 - 1))
    rng = np.random.default_rng(4)
    tops = {2: 65535, 3: (1 << 24) - 1, 4: (1 << 32) - 1}
    images = {nb: rng.integers(0, top, (12, 6), dtype=np.uint64, endpoint=True) for nb, top in tops.items()}
    images[3][0, :3] = [0, 1, (1 << 24) - 1]
    log = tmp_path / "wide.oculus"
    _foreign_log(log, [(2, images[nb], np.arange(-3, 3) * 700, 0.05, nb) for nb in (2, 3, 4)] +
                 [(1, images[2], np.arange(-3, 3) * 700, 0.05, 2)])
    assert main(["replay", str(log), "-o", str(tmp_path / "w.npz"), "--all"]) == 0
    got = [load_scan(tmp_path / f"w_{k:03d}.npz") for k in range(4)]
    expected = [images[2].astype(np.uint16), (images[3] * (2 ** 32 - 1) + (2 ** 24 - 1) // 2) // (2 ** 24 - 1),
                images[4].astype(np.uint32), images[2].astype(np.uint16)]
    for s, e, bits in zip(got, expected, (16, 32, 32, 16)):
        assert s.data.dtype == np.dtype(f"uint{bits}") and s.electronics.bit_depth == bits
        np.testing.assert_array_equal(s.data, e.T)
    assert list(got[1].data[:3, 0]) == [0, 256, 2 ** 32 - 1]


def test_a_cut_or_foreign_file_is_refused_naming_the_field(tmp_path):
    from mitsonar.devices.oculus.logfile import read_log, write_log
    log = write_log(tmp_path / "c.oculus", [fan_scan(n_r=5)])
    raw = log.read_bytes()
    (tmp_path / "cut.oculus").write_bytes(raw[:-10])
    with pytest.raises(ValueError, match=r"cut\.oculus: byte 48: payloadSize \d+ runs past the end"):
        read_log(tmp_path / "cut.oculus")
    (tmp_path / "other.oculus").write_bytes(b"\0" * 60)
    with pytest.raises(ValueError, match="fileHeader 0x00000000 is not 0x11223344"):
        read_log(tmp_path / "other.oculus")


# ---- the command line ----

def _serve(args):
    proc = subprocess.Popen([sys.executable, "-m", "mitsonar", "virtual-sonar", *args], stdout=subprocess.PIPE,
                            stderr=subprocess.STDOUT, text=True)
    lines = []
    for line in proc.stdout:
        lines.append(line)
        if line.startswith("virtual Oculus"):
            return proc, int(line.split("tcp://127.0.0.1:")[1].split()[0])
    proc.wait()
    raise AssertionError("".join(lines))


def test_virtual_sonar_serves_a_scene_with_the_wall_at_its_range(wall):
    from mitsonar.devices.oculus.protocol import FireMessage
    from mitsonar.devices.oculus.virtual import VirtualOculus
    path, rendered = wall
    proc, port = _serve([str(path), "--head", "oculus", "--spp", "16", "--port-url", "tcp://127.0.0.1:0",
                         "--status-port", str(free_udp_port()), "--seconds", "60"])
    try:
        c = LayoutClient(port)
        c.fire(version=2, rate=2, flags=0x0D, rng=10.0, gain=100.0, c=1500.0)
        got = [c.ping() for _ in range(3)]
        c.close()
    finally:
        proc.terminate()
        proc.wait(10)
    # each fire message's geometry (M1200d low frequency: 256 beams over 130 deg, 0.6 x 20 deg beams,
    # 1.2 MHz, 0..10 m) rendered from the scene, as the served head does
    from mitsonar.devices.oculus.scenes import SceneFrames
    frames = SceneFrames(path, bin_width=rendered.bin_width, spp=16, seed=0)
    fire = FireMessage(flags=0x0D, range=10.0, gain=100.0, speed_of_sound=1500.0)
    frame = frames(presets.model("M1200d").mode(1), 256, 10.0)
    assert frame.n_pings == 256 and frame.beamwidth_h == pytest.approx(0.6) and frame.meta["frequency"] == 1.2e6
    # rendered at the head's own (sine-spaced) bearing table: row k is beam k
    np.testing.assert_allclose(np.degrees(frame.bearings), presets.bearing_table(130, 256) / 100.0, atol=1e-9)
    expected = VirtualOculus(rendered, tcp_port=0, frames=frames).ping(fire)
    for p in got:
        np.testing.assert_array_equal(p["image"], expected.image)       # mitsonar's rendered bytes
        assert p["heading"] == pytest.approx(90.0)                      # looking along +x: east
        np.testing.assert_array_equal(p["bearings"], presets.bearing_table(130, 256))
    centre = np.abs(got[0]["bearings"] / 100.0) < 15
    profile = got[0]["image"][:, centre].mean(axis=1)
    line = 10 + int(np.argmax(profile[10:]))                            # past the ring-down
    assert (line + 0.5) * got[0]["res"] == pytest.approx(WALL_RANGE, abs=2 * got[0]["res"])


def test_a_client_fired_once_receives_200_pings_of_the_rendered_bytes(wall):
    # the target: as liboculus does, find the head by its status broadcast (the address it carries),
    # connect over TCP, fire once with a ping rate; the head streams: 200 ping results, each decoded
    # (the layout client, and bps_oculus where installed) equal to mitsonar's rendered bytes, the
    # wall at its range
    from mitsonar.devices.oculus.protocol import FireMessage
    from mitsonar.devices.oculus.scenes import SceneFrames
    from mitsonar.devices.oculus.virtual import VirtualOculus
    try:
        import bps_oculus.core as core
    except ImportError:
        core = None
    path, rendered = wall
    status_port = free_udp_port()
    rx = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    rx.bind(("127.0.0.1", status_port))
    rx.settimeout(30)
    proc, port = _serve([str(path), "--head", "oculus", "--spp", "16", "--port-url", "tcp://127.0.0.1:0",
                         "--status-port", str(status_port), "--seconds", "120"])
    try:
        status = rx.recv(4096)
        assert len(status) == 142
        c = LayoutClient(port, host=socket.inet_ntoa(status[52:56]))
        c.fire(version=2, rate=2, flags=0x0D, rng=10.0, gain=100.0, c=1500.0)      # once, 40 Hz
        got = [c.ping() for _ in range(200)]
        c.close()
    finally:
        rx.close()
        proc.terminate()
        proc.wait(10)
    frames = SceneFrames(path, bin_width=rendered.bin_width, spp=16, seed=0)
    expected = VirtualOculus(rendered, tcp_port=0, frames=frames).ping(
        FireMessage(flags=0x0D, range=10.0, gain=100.0, speed_of_sound=1500.0))
    assert [p["id"] for p in got] == list(range(200))
    for p in got:
        np.testing.assert_array_equal(p["image"], expected.image)
        np.testing.assert_array_equal(p["bearings"], expected.bearings)
        if core is not None:
            img = core.parse_polar_image(p["raw"], core.process_raw(p["raw"]))
            np.testing.assert_array_equal(img.polar_image, expected.image)
    profile = got[-1]["image"][:, np.abs(got[-1]["bearings"] / 100.0) < 15].mean(axis=1)
    line = 10 + int(np.argmax(profile[10:]))                            # past the ring-down
    assert (line + 0.5) * got[-1]["res"] == pytest.approx(WALL_RANGE, abs=2 * got[-1]["res"])


def test_virtual_sonar_takes_the_scenes_water_temperature_and_surface(tmp_path):
    from mitsonar.acoustics.seawater import sound_speed
    path = tmp_path / "warm.xml"
    path.write_text(WALL.replace('<string name="beam_pattern"', '<string name="sound_speed" value="auto"/>'
                                 '<float name="temperature" value="20"/><float name="surface_z" value="5"/>'
                                 '<string name="beam_pattern"'))
    proc, port = _serve([str(path), "--head", "oculus", "--spp", "4", "--port-url", "tcp://127.0.0.1:0",
                         "--status-port", str(free_udp_port()), "--seconds", "60"])
    try:
        c = LayoutClient(port)
        c.fire(version=2, rate=2, flags=0x0D, rng=10.0, gain=100.0, c=0.0, salinity=35.0)   # the head's own c
        p = c.ping()
        c.close()
    finally:
        proc.terminate()
        proc.wait(10)
    # the head at z = 0 is 5 m below a surface at z = 5, in water at 20 deg C
    assert p["temperature"] == pytest.approx(20.0)
    assert p["pressure"] == pytest.approx(5.0 * 1025.0 * 9.80665 / 1e5)
    assert p["c"] == pytest.approx(float(sound_speed(20.0, 35.0, 5.0)))


def test_virtual_sonar_serves_a_log(tmp_path):
    from mitsonar.devices.oculus.logfile import write_log
    scans = [fan_scan(n_r=20, seed=k) for k in range(2)]
    log = write_log(tmp_path / "l.oculus", scans)
    proc, port = _serve(["--log", str(log), "--head", "oculus", "--port-url", "tcp://127.0.0.1:0",
                         "--status-port", str(free_udp_port()), "--seconds", "60"])
    try:
        c = LayoutClient(port)
        c.fire(version=2, rate=2, flags=0x0D, rng=2.0, gain=100.0, c=1500.0)
        got = [c.ping() for _ in range(3)]
        c.close()
    finally:
        proc.terminate()
        proc.wait(10)
    for p in got:
        np.testing.assert_array_equal(p["image"], scans[p["id"] % 2].data.T)
    last = proc.stdout.read().splitlines()[-1]          # what it served, and the slots it skipped
    assert last.startswith("virtual Oculus: ") and "pings to 1 client(s), 0 message(s) refused" in last
    assert "pings skipped (late)" in last and "pings skipped (client behind)" in last


def test_virtual_sonar_refusals_name_the_flag(tmp_path, capsys, wall):
    path, _ = wall
    assert main(["virtual-sonar", "--log", str(tmp_path / "none.oculus"), "--head", "ping360"]) == 1
    assert capsys.readouterr().err.strip() == "mitsonar virtual-sonar: error: --log is for --head oculus, not ping360"
    assert main(["virtual-sonar", str(path), "--head", "oculus", "--port-url", "tcp://127.0.0.1:x"]) == 1
    assert "--port-url 'tcp://127.0.0.1:x' is not allowed for an Oculus (tcp://HOST:PORT" in capsys.readouterr().err
    mech = tmp_path / "mech.xml"
    mech.write_text(WALL.replace('value="multibeam"', 'value="mechanical"'))
    assert main(["virtual-sonar", str(mech), "--head", "oculus", "--port-url", "tcp://127.0.0.1:0"]) == 1
    assert "a 'mechanical' sonar (kind must be 'multibeam') has no Oculus pings to serve" in capsys.readouterr().err


def start_live_oculus(path, spp=4, poses=True, fire=True):
    """``mitsonar live SCENE --head oculus`` on loopback ports of its own (``spp``, 60 s at most;
    poses over UDP if ``poses``) and a layout client connected to it, which fires at 2 Hz (10 m) if
    ``fire``: the process, its pose port (None without poses) and the client."""
    cmd = [sys.executable, "-m", "mitsonar", "live", str(path), "--head", "oculus", "--spp", str(spp),
           "--port-url", "tcp://127.0.0.1:0", "--status-port", str(free_udp_port()), "--seconds", "60"]
    proc = subprocess.Popen(cmd + (["--pose-url", "udp://127.0.0.1:0"] if poses else []),
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    lines = []
    for line in proc.stdout:
        lines.append(line)
        if line.startswith("live "):
            break
    text = "".join(lines)
    try:
        assert "live Oculus on tcp://127.0.0.1:" in text, text
        pose_port = int(text.split("poses on udp://127.0.0.1:")[1].split()[0]) if poses else None
        c = LayoutClient(int(text.split("tcp://127.0.0.1:")[1].split()[0]))
        if fire:
            c.fire(version=2, rate=2, flags=0x0D, rng=10.0, gain=100.0, c=1500.0)
    except BaseException:
        proc.kill()
        proc.communicate(timeout=60)
        raise
    return proc, pose_port, c


def test_live_oculus_renders_each_ping_from_the_pose_then(wall):
    import json
    path, _ = wall
    proc, pose_port, c = start_live_oculus(path)
    tx = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    try:

        def wall_range():
            p = c.ping()
            profile = p["image"][:, np.abs(p["bearings"] / 100.0) < 15].mean(axis=1)
            return (10 + int(np.argmax(profile[10:])) + 0.5) * p["res"], p["res"]

        r, res = wall_range()
        assert r == pytest.approx(WALL_RANGE, abs=2 * res)
        tx.sendto(json.dumps({"t": 50.0, "position": [2, 0, 0], "orientation": [0, 0, 0, 1]}).encode(),
                  ("127.0.0.1", pose_port))
        got = [wall_range()[0]]
        for _ in range(50):                 # the pose is applied by another thread: ping until it shows
            if abs(got[-1] - (WALL_RANGE - 2)) <= 2 * res:
                break
            got.append(wall_range()[0])
        assert got[-1] == pytest.approx(WALL_RANGE - 2, abs=2 * res), got
        c.close()
    finally:
        tx.close()
        proc.terminate()
        out, err = proc.communicate(timeout=60)
    assert "Traceback" not in err and "1 poses applied" in out, (out, err)
    # the summary says what the head served and the ping slots it skipped (it could not keep its rate)
    import re
    served = re.search(r"; head: (\d+) pings to 1 client\(s\), 0 message\(s\) refused, (\d+) pings skipped "
                       r"\(late\), (\d+) pings skipped \(client behind\)", out)
    assert served and int(served[1]) >= len(got) + 1, out


def test_live_oculus_fills_heading_pitch_roll_and_depth_from_the_pose_then(wall):
    import json
    from scipy.spatial.transform import Rotation
    path, _ = wall
    proc, pose_port, c = start_live_oculus(path)
    tx = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    try:
        p = c.ping()
        assert (p["heading"], p["pitch"], p["roll"], p["pressure"]) == (pytest.approx(90.0), 0.0, 0.0, 0.0)
        # the vehicle (x forward, y port, z up) yawed 30 deg left, pitched 10 deg nose down, rolled 5 deg
        # to starboard, 3 m below the scene's surface (z = 0)
        q = Rotation.from_euler("ZYX", [30, 10, 5], degrees=True).as_quat()          # x, y, z, w
        tx.sendto(json.dumps({"t": 50.0, "position": [0, 0, -3], "orientation": list(q)}).encode(),
                  ("127.0.0.1", pose_port))
        for _ in range(50):                 # the pose is applied by another thread: ping until it shows
            p = c.ping()
            if abs(p["heading"] - 90.0) > 1e-6:
                break
        c.close()
    finally:
        tx.close()
        proc.terminate()
        proc.communicate(timeout=60)
    assert (p["heading"], p["pitch"], p["roll"]) == (pytest.approx(60.0), pytest.approx(-10.0), pytest.approx(5.0))
    assert p["pressure"] == pytest.approx(3.0 * 1025.0 * 9.80665 / 1e5) and p["temperature"] == 10.0


def test_live_oculus_renders_each_fire_messages_geometry(wall):
    path, _ = wall
    proc, _, c = start_live_oculus(path, spp=16, poses=False, fire=False)
    try:
        got = {}
        for mode, flags, rng in ((1, 0x4D, 8.0), (2, 0x0D, 7.0)):     # 512 beams over 130 deg; 256 over 60 deg
            c.fire(version=2, mode=mode, rate=2, flags=flags, rng=rng, gain=100.0, c=1500.0)
            for _ in range(3):                     # a ping of the earlier settings may be in flight
                p = c.ping()
                if p["n_b"] == (512 if flags & 0x40 else 256) and p["range"] == rng:
                    break
            got[mode] = p
        c.close()
    finally:
        proc.terminate()
        proc.communicate(timeout=60)
    for mode, p in got.items():
        aperture = presets.model("M1200d").mode(mode).aperture
        np.testing.assert_array_equal(p["bearings"], presets.bearing_table(aperture, p["n_b"]))
        assert p["n_r"] == round(p["range"] / 0.1)          # lines as wide as the scene sensor's bins
        img = p["image"][:, np.abs(p["bearings"] / 100.0) < 25].astype(np.int64)
        lit = img[10:].any(axis=0)
        # every beam its own rendered row: neighbours differ (the scene's own 2 deg fan served
        # beam by nearest row repeats each row over several beams)
        same = np.all(img[:, 1:] == img[:, :-1], axis=0)[lit[1:] & lit[:-1]]
        assert lit.sum() > 20 and same.mean() < 0.2, same.mean()


def test_the_scene_sensor_at_a_fire_geometry_takes_the_scenes_defaults(tmp_path):
    from mitsonar.devices.oculus.scenes import SceneFrames
    path = tmp_path / "defaults.xml"
    path.write_text(WALL.replace('<scene version="3.0.0">', '<scene version="3.0.0"><default name="bw" value="20"/>')
                    .replace('name="beamwidth_v" value="20"', 'name="beamwidth_v" value="$bw"'))
    mode = presets.model("M1200d").mode(1)
    sensor = SceneFrames(path, bin_width=0.1).sensor_at(mode, 512, 8.0)
    assert (sensor.n_pings, sensor.n_bins, sensor.range_max) == (512, 80, 8.0)
    np.testing.assert_allclose(sensor.bearings_deg(), presets.bearing_table(mode.aperture, 512) / 100.0)


def test_record_writes_a_raw_log_or_an_oculus_log_that_replay_reads(tmp_path, head, capsys):
    url = f"tcp://127.0.0.1:{head.tcp_port}"
    assert main(["record", url, "--head", "oculus", "-o", str(tmp_path / "r.bin"), "--pings", "2",
                 "--range", "3"]) == 0
    assert main(["record", url, "--head", "oculus", "-o", str(tmp_path / "r.oculus"), "--pings", "2",
                 "--range", "3"]) == 0
    assert "(2 pings) to" in capsys.readouterr().out
    from mitsonar.devices.recording import replay
    for name in ("r.bin", "r.oculus"):
        scans = replay(tmp_path / name)
        assert len(scans) >= 2
        for s in scans:                 # the default fire message: gain 50 % of the scan's bytes
            np.testing.assert_array_equal(s.data, head.received(head.scan, 50.0)[:, :30])
    assert main(["record", url, "--head", "oculus", "-o", str(tmp_path / "x.bin"), "--gain", "high"]) == 1
    assert capsys.readouterr().err.strip() == "mitsonar record: error: --gain is for --head ping360, not oculus"
