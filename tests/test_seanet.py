"""SeaNet codec: byte layouts from the reference, round trips, settings, and the stream parser."""
from __future__ import annotations

import math
import os

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings, strategies as st

from mitsonar.devices.micron import seanet as sn
from mitsonar.devices.micron.seanet import (Alive, AuxData, BBUserData, FpgaCalibrationData, FpgaVersionData,
                             GainCommand, HdCtrl, HeadCommand, HeadData, HeadSettings, RawMessage,
                             ReBoot, ResetToDefaults, ScanReverse, SendBBUser, SendData,
                             SendVersion, StopAlives, StreamParser, VersionData, decode, encode)

# MITSONAR_FUZZ_EXAMPLES=5000 for a soak run; the default keeps the suite fast.
FUZZ = settings(max_examples=int(os.environ.get("MITSONAR_FUZZ_EXAMPLES", 60)), deadline=None,
                suppress_health_check=[HealthCheck.too_slow])


# ---- byte layouts of the reference -----------------------------------------------------------

def test_fixed_commands_match_reference_bytes():
    # reference section 2 (UxVCtrl): 40 30 30 30 38 08 00 FF 02 03 <id> 80 02 0A
    for msg, mid in ((ReBoot(), 0x10), (SendVersion(), 0x17), (SendBBUser(), 0x18)):
        assert encode(msg) == bytes([0x40, 0x30, 0x30, 0x30, 0x38, 0x08, 0x00, 0xFF, 0x02, 0x03,
                                     mid, 0x80, 0x02, 0x0A])
    assert encode(SendData()) == bytes.fromhex("40 30 30 30 43 0C 00 FF 02 07 19 80 02 00 00 00 00 0A")


def test_head_command_for_worked_example_matches_uxvctrl_layout():
    s = HeadSettings()          # 12 m, 500 bins, c = 1500, 1.8 deg steps
    assert s.ad_interval == 50 and s.step_size == 32
    assert s.bin_width == pytest.approx(0.024)
    assert FULL_TURN_STEPS(s) == 200
    b = encode(s.head_command())
    assert len(b) == 66
    assert b[:14] == bytes.fromhex("40 30 30 33 43 3C 00 FF 02 37 13 80 02 01")
    assert b[14:17] == bytes([0x03, 0x23, 0x02])                          # adc8on|cont|raw|hasmot|ReplyASL
    assert b[17:25] == bytes.fromhex("66666605 66666605")                 # TxN 675 kHz
    assert b[25:33] == bytes.fromhex("703D0A09 703D0A09")                 # RxN
    assert b[33:37] == bytes([55, 0, 120, 0])                             # pulse (12+10)*2.5, range dm
    assert b[41:45] == bytes([77, 40, 0x49, 0x49])                        # ADSpan 24 dB, ADLow 12.5 dB
    assert b[49:51] == bytes([25, 32])                                    # MoTime, StepSize
    assert int.from_bytes(b[51:53], "little") == 50
    assert int.from_bytes(b[53:55], "little") == 500
    assert b[59:62] == bytes([0x40, 0x06, 0x01]) and b[-1] == 0x0A
    dst = encode(s.head_command(dst=True))
    assert dst[16] == 0x11 and dst[45] == 100
    v3b = encode(HeadSettings(v3b=True).head_command())
    assert len(v3b) == 82 and v3b[13] == 0x1D


def FULL_TURN_STEPS(s):
    return sn.FULL_TURN // s.step_size


def test_head_data_offsets():
    hd = HeadData.from_bins(np.arange(10, dtype=np.uint8), bearing=0x1234, ad_interval=0x0102,
                            step_size=32, left_lim=7, right_lim=9)
    b = encode(hd)
    assert len(b) == 10 + 45 and b[9] == 0                 # single-packet mode
    assert int.from_bytes(b[13:15], "little") == 10 + 31
    assert int.from_bytes(b[33:35], "little") == 0x0102
    assert int.from_bytes(b[40:42], "little") == 0x1234
    assert int.from_bytes(b[42:44], "little") == 10
    assert b[44:54] == bytes(range(10)) and b[54] == 0x0A


# ---- round trips ---------------------------------------------------------------------------

ALL_MESSAGES = [
    ReBoot(), SendVersion(), SendBBUser(), SendData(time_ms=123456), StopAlives(), ResetToDefaults(),
    HeadSettings().head_command(), HeadSettings(v3b=True, bit_depth=4).head_command(dst=True),
    ScanReverse(), GainCommand(ad_span_ch1=10, igain_ch2=200),
    VersionData(software_version=0x19, info_bits=1, serial=4321, program_length=99999, checksum=7),
    HeadData.from_bins(np.arange(500) % 256, ad_interval=50, bearing=6399),
    HeadData.from_bins(np.arange(0, 256, 17).repeat(2), adc8on=False, bearing=0),
    HeadData.from_bins(np.arange(0, 256, 17).repeat(2), adc8on=False, nibble_order="high_first"),
    Alive(clock_ms=5000, heading=3200, head_inf=0b11000010),
    BBUserData.make(dst=True), BBUserData.make(dst=False, half_duplex=True),
    AuxData(data=b"aux\x00\xff"), FpgaVersionData(payload_bytes=bytes(16)),
    FpgaCalibrationData(payload_bytes=bytes(range(24))),
    RawMessage(message_id=sn.MessageId.mtPerformanceData, payload_bytes=b"\x01\x02"),
]


@pytest.mark.parametrize("msg", ALL_MESSAGES, ids=lambda m: type(m).__name__)
def test_round_trip_every_type(msg):
    b = encode(msg)
    back = decode(b, nibble_order=getattr(msg, "nibble_order", sn.DEFAULT_NIBBLE_ORDER))
    assert type(back) is type(msg)
    assert back == msg
    assert encode(back) == b
    if isinstance(msg, HeadData):
        assert np.array_equal(back.bins, msg.bins)


def test_bbuser_flags_and_lengths():
    assert BBUserData.make(dst=True).is_dst and len(encode(BBUserData.make(dst=True))) == 264
    nd = BBUserData.make(dst=False, half_duplex=True)
    assert not nd.is_dst and nd.half_duplex and len(encode(nd)) == 175


def test_alive_flags():
    a = Alive(head_inf=int(sn.HeadInf.CENTRED | sn.HeadInf.NO_PARAMS | sn.HeadInf.SENT_CFG))
    assert a.centred and a.no_params and a.sent_cfg and not a.motoring and not a.in_centre
    assert decode(encode(a)).sent_cfg


u8, u16, u32 = (st.integers(0, 2 ** k - 1) for k in (8, 16, 32))


@FUZZ
@given(bins=st.binary(min_size=0, max_size=600), bearing=st.integers(0, 6399), adint=u16,
       status=u8, sweep=u8, hd=u16, txn=u32, gain=u8, slope=u16, node=u8)
def test_head_data_round_trip_property(bins, bearing, adint, status, sweep, hd, txn, gain, slope, node):
    msg = HeadData(bearing=bearing, data=bins, ad_interval=adint, head_status=status, sweep_code=sweep,
                   hd_ctrl=hd, txn=txn, gain=gain, slope=slope, src=node)
    b = encode(msg)
    assert decode(b) == msg and encode(decode(b)) == b


@FUZZ
@given(st.lists(u32, min_size=27, max_size=27))
def test_head_command_round_trip_property(vals):
    names = [n for n, _ in sn._HEAD_COMMAND_LAYOUT][1:]
    fmt = dict(sn._HEAD_COMMAND_LAYOUT)
    kw = {n: v % (256 if fmt[n] == "B" else 65536 if fmt[n] == "H" else 2 ** 32) for n, v in zip(names, vals)}
    msg = HeadCommand(**kw)
    assert decode(encode(msg)) == msg


def test_encode_rejects_out_of_range_fields_naming_them():
    with pytest.raises(ValueError, match="HeadData.bearing"):
        encode(HeadData(bearing=6400))
    with pytest.raises(ValueError, match="HeadCommand.step_size"):
        encode(HeadCommand(step_size=300))
    with pytest.raises(ValueError, match="Alive.heading"):
        encode(Alive(heading=-1))
    with pytest.raises(ValueError, match="SendData.time_ms"):
        encode(SendData(time_ms=2 ** 32))


# ---- nibbles and bearings ------------------------------------------------------------------

def test_nibble_orders():
    raw = bytes([0x1F, 0xA0])
    lo = sn.unpack_bins(raw, adc8on=False, nibble_order="low_first")
    hi = sn.unpack_bins(raw, adc8on=False, nibble_order="high_first")
    assert lo.tolist() == [15 * 17, 1 * 17, 0, 10 * 17]
    assert hi.tolist() == [1 * 17, 15 * 17, 10 * 17, 0]
    for order in sn.NIBBLE_ORDERS:
        levels = np.arange(16, dtype=np.uint8).repeat(2) * 17
        assert np.array_equal(sn.unpack_bins(sn.pack_bins(levels, False, order), False, order), levels)
    # levels between multiples of 17 round to the nearest nibble
    assert sn.unpack_bins(sn.pack_bins([8, 9], False), False).tolist() == [0, 17]
    with pytest.raises(ValueError, match="nibble_order"):
        sn.unpack_bins(raw, False, "middle")
    with pytest.raises(ValueError, match="even"):
        sn.pack_bins([1, 2, 3], False)


def test_bearing_convention():
    assert sn.bearing_to_radians(3200) == 0.0
    assert sn.bearing_to_radians(1600) == pytest.approx(math.pi / 2)        # left is positive
    assert sn.bearing_to_radians(4800) == pytest.approx(-math.pi / 2)
    assert sn.bearing_to_radians(1600, invert=True) == pytest.approx(-math.pi / 2)
    b = np.arange(6400)
    for inv in (False, True):
        assert np.array_equal(sn.radians_to_bearing(sn.bearing_to_radians(b, inv), inv), b)
        assert np.array_equal(sn.radians_to_bearing(sn.bearing_to_radians(b, inv) + 4 * math.pi, inv), b)


# ---- settings ------------------------------------------------------------------------------

@pytest.mark.parametrize("field,value,pattern", [
    ("range", 0.1, r"range = 0\.1 .*0\.3\.\.300"),
    ("n_bins", 2000, r"n_bins = 2000 .*2\.\.1500"),
    ("n_bins", 2.5, "n_bins"),
    ("sound_speed", 900.0, "sound_speed.*1300..1800"),
    ("gain", 81.0, "gain.*0..80 dB"),
    ("ad_low", -1.0, "ad_low.*0..80 dB"),
    ("ad_span", 0.0, "ad_span"),
    ("step_size", 33, "step_size = 33 .*divisor of 6400"),
    ("step_size", 0, "step_size"),
    ("left_limit", 6400, "left_limit.*0..6399"),
    ("bit_depth", 6, "bit_depth.*8 or 4"),
    ("frequency", 10.0, "frequency"),
    ("channel", 3, "channel"),
    ("mo_time", 0, "mo_time"),
    ("max_ad_buf", 1001, "max_ad_buf.*1..1000"),
    ("lockout", -1, "lockout"),
])
def test_settings_ranges_name_the_field(field, value, pattern):
    with pytest.raises(ValueError, match=pattern):
        HeadSettings(**{field: value})


def test_settings_ad_interval_and_sector_rules():
    with pytest.raises(ValueError, match="ADInterval.*5..1500"):
        HeadSettings(range=0.3, n_bins=1500)             # ADInterval 0.4
    with pytest.raises(ValueError, match="ADInterval"):
        HeadSettings(range=300, n_bins=10)               # ADInterval 62500
    with pytest.raises(ValueError, match="even number"):
        HeadSettings(n_bins=501, bit_depth=4)
    with pytest.raises(ValueError, match="multiple of step_size"):
        HeadSettings(continuous=False, left_limit=2400, right_limit=4001)
    s = HeadSettings(continuous=False, left_limit=5600, right_limit=800)    # sector across astern
    assert s.sector_width == 1600
    assert HeadSettings(range=10, n_bins=200).ad_interval == 104           # 104.17, rounded
    assert HeadSettings(range=10, n_bins=200).range_max == pytest.approx(9.984)


def test_settings_command_round_trip():
    s = HeadSettings(range=20, n_bins=400, gain=40, ad_low=10, ad_span=30, step_size=16,
                     continuous=False, left_limit=1600, right_limit=4800, scan_right=True,
                     bit_depth=4, invert=True, channel=2)
    back = HeadSettings.from_command(decode(encode(s.head_command())), s.sound_speed)
    assert back.head_command() == s.head_command()
    assert back.ad_interval == s.ad_interval and back.n_bins == 400 and back.bit_depth == 4
    h = HdCtrl(s.hd_ctrl)
    assert h & HdCtrl.INVERT and h & HdCtrl.SCANRIGHT and h & HdCtrl.CHAN2 and not h & HdCtrl.CONT


def test_ping_problem():
    cmd = HeadSettings().head_command()
    ok = HeadData.from_bins(np.zeros(500, np.uint8), ad_interval=50, hd_ctrl=cmd.hd_ctrl, step_size=32,
                            ad_low=cmd.ad_low, ad_span=cmd.ad_span)
    assert sn.ping_problem(ok, cmd) is None
    assert "motor" in sn.ping_problem(HeadData(**{**ok.__dict__, "head_status": 2}), cmd)
    assert "ADInterval" in sn.ping_problem(HeadData(**{**ok.__dict__, "ad_interval": 51}), cmd)
    assert "bins" in sn.ping_problem(HeadData(**{**ok.__dict__, "data": bytes(400)}), cmd)


# ---- stream parser: resynchronisation ------------------------------------------------------

ALIVE = encode(Alive(clock_ms=1, heading=3200, head_inf=2))
VERSION = encode(VersionData(serial=7))


def _feed_all(parser, data, chunk=7):
    out = []
    for i in range(0, len(data), chunk):
        out += parser.feed(data[i:i + chunk])
    return out + parser.flush()


@pytest.mark.parametrize("damage,reason", [
    (lambda b: b[:3] + b"Z" + b[4:], "bad header"),                             # not hex
    (lambda b: b[:5] + bytes([b[5] + 1]) + b[6:], "bad header"),                # hex != binary
    (lambda b: b[:-1] + b"X", "no LF"),                                         # terminator
    (lambda b: b"@000F\x0f\x00" + b[7:9] + b"\x0a" + b[10:], "impossible for mtAlive"),  # length
    (lambda b: b[:9] + b"\x05" + b[10:], "byte count"),                         # byte 9
    (lambda b: b[:11] + b"\x01" + b[12:], "multi-packet"),                      # sequence
    (lambda b: b[:10], "truncated"),                                            # cut short
])
def test_parser_drops_damaged_packet_and_recovers(damage, reason):
    p = StreamParser()
    bad = damage(ALIVE)
    out = _feed_all(p, b"junk" + bad + VERSION + ALIVE)
    assert [type(m) for m in out] == [VersionData, Alive]
    assert p.dropped == 4 + len(bad)
    assert any(reason in r for r, _ in p.drops), list(p.drops)


def test_parser_accepts_lowercase_hex_and_wrong_long_length_field():
    lower = ALIVE[:1] + ALIVE[1:5].lower() + ALIVE[5:]
    p = StreamParser()
    assert p.feed(lower.replace(b"0010", b"0010")) == [decode(ALIVE)]
    # A length field claiming far more than is there: the next header inside ends it at once.
    hd = bytearray(encode(HeadData.from_bins(np.zeros(50, np.uint8))))
    hd[1:5], hd[5:7] = b"0400", (0x400).to_bytes(2, "little")
    p = StreamParser()
    assert p.feed(bytes(hd) + ALIVE) == [decode(ALIVE)] and p.pending == 0


def test_parser_waits_for_split_packets():
    p = StreamParser()
    b = encode(HeadData.from_bins(np.arange(300) % 256))
    for i in range(len(b) - 1):
        assert p.feed(b[i:i + 1]) == []
    assert len(p.feed(b[-1:])) == 1 and p.dropped == 0


@pytest.mark.parametrize("damage,message", [
    (lambda b: b"#" + b[1:], r"^byte 0 is 0x23, expected '@' \(0x40\)$"),
    (lambda b: b[:3] + b"Z" + b[4:], r"^byte 3 is 0x5a, expected an ASCII hex digit \(length field, bytes 1\.\.4\)$"),
    (lambda b: b"@0002" + b[5:], r"^length field \(bytes 1\.\.4\) is 0x0002, expected at least 0x0008"),
    (lambda b: b[:5] + bytes([b[5] + 1]) + b[6:], r"^byte 5 is 0x11, expected 0x10 \(binary copy of the length field 0010\)$"),
    (lambda b: b[:6] + b"\x01" + b[7:], r"^byte 6 is 0x01, expected 0x00 \(binary copy"),
    (lambda b: b[:-1] + b"X", r"^byte 21 is 0x58, expected the LF terminator \(0x0a\)$"),
], ids=["at", "hex-digit", "short-length", "binary-low", "binary-high", "terminator"])
def test_decode_names_the_first_wrong_header_byte(damage, message):
    # Each framing field on its own, in order: offset, value found, value expected.
    with pytest.raises(sn.SeaNetError, match=message):
        decode(damage(ALIVE))
    # '#' and a bad hex digit together: the first one is reported.
    with pytest.raises(sn.SeaNetError, match="^byte 0 is 0x23"):
        decode(b"#" + ALIVE[1:3] + b"Z" + ALIVE[4:])


@pytest.mark.parametrize("packet,name", [(ALIVE.decode("latin-1"), "str"), (22, "int"), (None, "NoneType")],
                         ids=["str", "int", "None"])
def test_decode_wants_bytes(packet, name):
    with pytest.raises(TypeError, match=f"^packet must be bytes, got {name}$"):
        decode(packet)
    assert decode(bytearray(ALIVE)) == decode(memoryview(ALIVE)) == decode(ALIVE)


def test_sound_speed_bound_lives_in_one_place():
    assert sn.SOUND_SPEED_RANGE == (1300.0, 1800.0) and sn.SOUND_SPEED_ALLOWED == "1300..1800 m/s"
    assert sn.sound_speed_ok(1300) and sn.sound_speed_ok(np.float32(1500)) and sn.sound_speed_ok(1800.0)
    for v in (1299.9, 1e9, 100, float("nan"), float("inf"), True, "1500", None):
        assert not sn.sound_speed_ok(v), v
    with pytest.raises(ValueError, match=r"^HeadSettings.sound_speed = 1000000000.0 is out of range: allowed 1300\.\.1800 m/s$"):
        HeadSettings(sound_speed=1e9)


# ---- stream parser: property-based fuzzing --------------------------------------------------

def _message_strategy():
    bins = st.binary(max_size=120)
    return st.one_of(
        st.builds(lambda d, b, a: HeadData(data=d, bearing=b, ad_interval=a), bins, st.integers(0, 6399), u16),
        st.builds(lambda c, h, i: Alive(clock_ms=c, heading=h, head_inf=i), u32, st.integers(0, 6399), u8),
        st.builds(lambda s: VersionData(serial=s), u16),
        st.builds(lambda t: SendData(time_ms=t), u32),
        st.sampled_from([ReBoot(), SendVersion(), SendBBUser(), BBUserData.make(), ScanReverse(),
                         HeadSettings().head_command(), GainCommand()]),
        st.builds(lambda d: AuxData(data=d), st.binary(max_size=40)),
    )


# Garbage between packets may hold anything but LF: with no checksum, an LF in garbage right
# where a cut packet's length field puts its end is indistinguishable from a real packet.
garbage = st.binary(max_size=30).map(lambda g: g.replace(b"\n", b"\x0b"))


@FUZZ
@given(st.binary(max_size=2000), st.integers(1, 64))
def test_parser_random_bytes_never_crash_and_account_for_every_byte(data, chunk):
    p = StreamParser()
    out = _feed_all(p, data, chunk)
    assert sum(len(encode(m)) for m in out) + p.dropped == len(data)
    assert p.pending == 0


@FUZZ
@given(st.lists(st.tuples(_message_strategy(), garbage), min_size=1, max_size=8),
       garbage, st.integers(1, 50))
def test_parser_recovers_every_packet_embedded_in_garbage(items, lead, chunk):
    stream = lead + b"".join(encode(m) + g for m, g in items)
    p = StreamParser()
    out = _feed_all(p, stream, chunk)
    assert [encode(m) for m in out] == [encode(m) for m, _ in items]


@FUZZ
@given(st.lists(st.tuples(_message_strategy(), _message_strategy(), st.floats(0, 1), st.booleans(), garbage),
                min_size=1, max_size=6),
       st.integers(1, 50), st.data())
def test_parser_cut_and_spliced_packets_never_yield_corrupt_messages(items, chunk, data):
    """A packet cut anywhere and spliced to the next is dropped; the intact ones all come out."""
    stream, expected = b"", []
    for cut_msg, msg, frac, has_cut, junk in items:
        if has_cut:
            frag = encode(cut_msg)
            stream += frag[:max(1, int(frac * (len(frag) - 1)))]     # a strict prefix
        stream += junk + encode(msg)
        expected.append(encode(msg))
    if data.draw(st.booleans()):
        tail = encode(data.draw(_message_strategy()))
        stream += tail[:data.draw(st.integers(1, len(tail) - 1))]  # cut at the very end
    p = StreamParser()
    out = _feed_all(p, stream, chunk)
    assert [encode(m) for m in out] == expected
    assert p.dropped == len(stream) - sum(map(len, expected))


@FUZZ
@given(st.lists(_message_strategy(), min_size=1, max_size=6), st.data())
def test_parser_survives_arbitrary_cuts_and_byte_drops(msgs, data):
    """Any damage at all: no exception, every byte accounted, every output re-encodes."""
    stream = bytearray(b"".join(encode(m) for m in msgs))
    for _ in range(data.draw(st.integers(0, 5))):
        if not stream:
            break
        i = data.draw(st.integers(0, len(stream) - 1))
        n = data.draw(st.integers(1, 20))
        del stream[i:i + n]
    p = StreamParser()
    out = _feed_all(p, bytes(stream), data.draw(st.integers(1, 40)))
    assert sum(len(encode(m)) for m in out) + p.dropped == len(stream)
    for m in out:
        encode(m)
