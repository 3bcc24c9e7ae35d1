"""The Oculus codec (mitsonar.devices.oculus.protocol) and presets: field offsets of the published
layout read back with hand-written struct formats, round trips of every message version and data
size, bps_oculus (oculus-python, an independent parser) reading mitsonar's ping results, and
byte fuzzing (hypothesis): decoding never raises anything but the codec's own ValueError, and the
stream parser recovers every whole message around damage."""
from __future__ import annotations

import os
import struct

import numpy as np
import pytest
from hypothesis import HealthCheck, example, given, settings, strategies as st

import mitsonar.presets.oculus as presets
from mitsonar.devices.oculus import protocol as op
from mitsonar.devices.oculus.protocol import (FLAG, FireMessage, OculusError, PingResult, StatusMessage,
                                              StreamParser, UserConfig, decode)

FUZZ = settings(max_examples=int(os.environ.get("MITSONAR_FUZZ_EXAMPLES", 60)), deadline=None,
                derandomize=True, suppress_health_check=[HealthCheck.too_slow])


def ping(version=2, nbytes=1, gain=True, n_r=5, n_b=4, seed=0):
    rng = np.random.default_rng(seed)
    flags = FLAG["range_as_meters"] | FLAG["simple_return"] | (FLAG["send_gain"] if gain else 0)
    ext = 0
    if nbytes == 2:
        flags |= FLAG["data_16bit"]
    if nbytes == 4:
        ext = op.EXT_32BIT
    fire = FireMessage(master_mode=2, ping_rate=2, gamma=127, flags=flags, range=7.5, gain=42.0,
                       speed_of_sound=0.0, salinity=35.0, ext_flags=ext, version=version)
    dtype = {1: np.uint8, 2: np.uint16, 4: np.uint32}[nbytes]
    image = rng.integers(0, np.iinfo(dtype).max, (n_r, n_b), dtype=dtype, endpoint=True)
    return PingResult(fire, image, presets.bearing_table(60.0, n_b), 7.5 / n_r,
                      gains=rng.random(n_r).astype(np.float32) if gain else None, ping_id=17, frequency=2.1e6,
                      temperature=11.5, pressure=2.5, heading=33.0, pitch=-2.0, roll=1.5,
                      speed_of_sound_used=1498.25, ping_start_time=12.5)


def test_sizes_and_offsets_follow_the_published_layout():
    # sizeof() of the packed structures in Oculus.h
    assert (op.HEADER.size, op.FIRE_SIZE[1], op.FIRE_SIZE[2]) == (16, 53, 89)
    assert (op.PING_SIZE[1], op.PING_SIZE[2], op.STATUS_SIZE, op.USER_CONFIG_SIZE) == (122, 202, 142, 28)
    b = ping(version=2).encode()
    assert struct.unpack_from("<H", b, 0)[0] == 0x4F53 and struct.unpack_from("<H", b, 6)[0] == 0x23
    assert struct.unpack_from("<I", b, 10)[0] == len(b) - 16               # payloadSize
    assert struct.unpack_from("<d", b, 21)[0] == 7.5                       # rangePercent
    assert struct.unpack_from("<d", b, 29)[0] == 42.0                      # gainPercent
    assert struct.unpack_from("<I", b, 89)[0] == 17                        # pingId
    assert struct.unpack_from("<d", b, 97)[0] == 2.1e6                     # frequency
    assert struct.unpack_from("<d", b, 121)[0] == 33.0                     # heading
    assert struct.unpack_from("<d", b, 145)[0] == 1498.25                  # speedOfSoundUsed
    assert struct.unpack_from("<2H", b, 170) == (5, 4)                     # nRanges, nBeams
    off, size, total = struct.unpack_from("<3I", b, 190)
    assert (off, size, total) == (202 + 8, 5 * (4 + 4), len(b))
    b1 = ping(version=1).encode()
    assert struct.unpack_from("<I", b1, 53)[0] == 17 and struct.unpack_from("<2H", b1, 106) == (5, 4)
    assert struct.unpack_from("<3I", b1, 110) == (122 + 8, 40, len(b1))
    s = StatusMessage(part_number=1042, ip="127.0.0.1", device_id=7).encode()
    assert len(s) == 142 and struct.unpack_from("<IHH", s, 16) == (7, 1, 1042)
    assert s[52:56] == bytes([127, 0, 0, 1])       # network byte order (liboculus: ntohl)


@pytest.mark.parametrize("version", [1, 2])
@pytest.mark.parametrize("nbytes", [1, 2, 4])
@pytest.mark.parametrize("gain", [False, True])
def test_ping_result_round_trip(version, nbytes, gain):
    p = ping(version, nbytes, gain)
    d = decode(p.encode())
    assert isinstance(d, PingResult) and d.version == version
    np.testing.assert_array_equal(d.image, p.image)
    assert d.image.dtype.itemsize == nbytes
    np.testing.assert_array_equal(d.bearings, p.bearings)
    assert d.range_resolution == p.range_resolution and d.ping_id == 17
    assert (d.gains is None) == (not gain)
    if gain:
        np.testing.assert_array_equal(d.gains, p.gains)
    assert d.fire.range == 7.5
    # a version 1 fire message has no extFlags: 32-bit samples are the version 2 message's
    assert d.fire.data_bytes == (1 if (version, nbytes) == (1, 4) else nbytes)
    assert d.heading == (33.0 if version == 2 else 0.0)


def test_fire_status_user_config_round_trip():
    for v in (1, 2):
        f = FireMessage(master_mode=1, ping_rate=4, gamma=200, flags=0x45, range=30.0, gain=80.0,
                        speed_of_sound=1480.0, salinity=0.0, version=v, ext_flags=op.EXT_32BIT if v == 2 else 0)
        assert decode(f.encode()) == f
    s = StatusMessage(part_number=2203, ip="10.0.0.5", connected_ip="10.0.0.1", temperatures=(1.0,) * 8)
    assert StatusMessage.decode(s.encode()) == s
    u = UserConfig("192.168.2.4", "255.255.255.0", 1)
    assert decode(u.encode()) == u


def test_refused_fields_name_themselves():
    b = bytearray(ping().encode())
    b[161] = 9                                     # dataSize
    with pytest.raises(OculusError, match="dataSize"):
        decode(bytes(b))
    b = bytearray(ping().encode())
    struct.pack_into("<I", b, 194, 3)              # imageSize
    with pytest.raises(OculusError, match="imageSize"):
        decode(bytes(b))
    with pytest.raises(OculusError, match="oculusId"):
        decode(b"\0" * 16)


def test_presets_and_bearing_table():
    assert {m.part_number for m in presets.MODELS.values()} == {1032, 1042, 2203}
    m = presets.model("M1200d")
    assert presets.model(1042) is m and m.mode(2).frequency == 2.1e6 and m.mode(1).aperture == 130
    with pytest.raises(ValueError, match="M750d"):
        presets.model("M9")
    t = presets.bearing_table(130.0, 256) / 100.0
    assert len(t) == 256 and np.all(np.diff(t) > 0)
    assert t[0] == pytest.approx(-65, abs=0.5) and t[-1] == pytest.approx(65, abs=0.5)
    steps = np.diff(t)
    assert steps[128] < steps[1]                   # crowded at the centre: no start + k * step table


# ---- bps_oculus, an independent parser ----

def test_bps_oculus_parses_mitsonar_ping_results():
    core = pytest.importorskip("bps_oculus.core")
    # version 2 only: bps_oculus 0.0.2a1 cannot build a version 1 result (its
    # OculusSimpleFireMessage lacks the abstract pack); nor one without gains under numpy 2 (np.NAN)
    for version in (2,):
        p = ping(version, 1, True, n_r=6, n_b=8, seed=version)
        b = p.encode()
        res = core.process_raw(b)
        img = core.parse_polar_image(b, res)
        np.testing.assert_array_equal(img.polar_image, p.image)
        np.testing.assert_allclose(img.bearing_table, np.radians(p.bearings / 100.0))
        assert res.rangeResolution == p.range_resolution and res.nBeams == 8 and res.pingId == 17
        np.testing.assert_array_equal(img.gain_table.view(np.float32), p.gains)


# ---- fuzzing ----

@FUZZ
@given(st.binary(max_size=400))
def test_decode_random_bytes_only_raises_oculus_error(data):
    try:
        decode(data)
    except OculusError:
        pass


@FUZZ
@given(st.integers(0, 3), st.integers(0, 10 ** 6), st.binary(min_size=1, max_size=8))
def test_damaged_ping_results_are_refused_not_crashing(version_pick, pos, junk):
    b = bytearray(ping(version=1 + version_pick % 2, nbytes=(1, 2, 4, 1)[version_pick]).encode())
    k = pos % len(b)
    b[k:k + len(junk)] = junk
    try:
        decode(bytes(b))
    except OculusError:
        pass


@FUZZ
@given(st.lists(st.tuples(st.binary(max_size=40), st.integers(0, 2)), min_size=1, max_size=6),
       st.integers(1, 64))
def test_stream_parser_recovers_whole_messages(parts, chunk):
    msgs = [ping(seed=1).encode(), FireMessage().encode(), UserConfig().encode()]
    stream, sent = b"", []
    for junk, k in parts:
        junk = junk.replace(b"\x53\x4f", b"")       # junk that holds no message id
        if junk.endswith(b"\x53"):
            junk = junk[:-1]
        stream += junk + msgs[k]
        sent.append(msgs[k])
    p = StreamParser()
    got = []
    for i in range(0, len(stream), chunk):
        got += p.feed(stream[i:i + chunk])
    assert [m.encode() for m in got] == sent        # every message, byte for byte
    assert p.refused == 0


def test_stream_parser_refuses_oversized_and_malformed_and_goes_on():
    p = StreamParser(max_payload=1000)
    big = op.Header(op.MSG["simple_ping_result"], 2, 5000).encode()
    bad = bytearray(ping().encode())
    bad[161] = 7
    good = FireMessage(range=3.0).encode()
    got = p.feed(big + bytes(bad) + good)
    assert got == [FireMessage(range=3.0)]
    assert p.refused == 2 and "payloadSize 5000" in next(iter(p.drop_reasons))


@FUZZ
@given(st.integers(0, 10 ** 6), st.binary(min_size=1, max_size=8), st.integers(0, 400))
@example(pos=48 + 40 + 98, junk=b"\0" * 8, cut=0)        # the first ping's rangeResolution 0: no scan
def test_damaged_oculus_logs_are_refused_naming_the_file_not_crashing(tmp_path_factory, pos, junk, cut):
    # a .oculus log with bytes overwritten and cut short: read into scans, or one ValueError naming it
    from mitsonar.devices.oculus.logfile import read_scans, write_log
    path = tmp_path_factory.mktemp("fuzz") / "d.oculus"
    write_log(path, [ping(version=1 + k % 2, nbytes=(1, 2, 4)[k % 3], seed=k) for k in range(3)])
    b = bytearray(path.read_bytes())
    k = pos % len(b)
    b[k:k + len(junk)] = junk
    path.write_bytes(bytes(b[:len(b) - cut]))
    try:
        read_scans(path)
    except ValueError as e:
        assert str(e).startswith(f"{path}: "), e
