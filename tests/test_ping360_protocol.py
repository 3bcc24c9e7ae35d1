"""The ping-protocol codec (mitsonar.devices.ping360.protocol) against brping's own message definitions,
packer and parser: exact bytes, round trips of every message, and a resynchronising stream parser
fuzzed with hypothesis (damaged and truncated frames are skipped and counted, every whole frame
after them is recovered)."""
from __future__ import annotations

import os
import struct

import pytest
from brping import definitions as brdefs, pingmessage
from hypothesis import HealthCheck, given, settings, strategies as st

from mitsonar.devices.ping360 import protocol as pp
from mitsonar.devices.ping360.protocol import Message, ProtocolError, StreamParser, decode, encode, ids

# MITSONAR_FUZZ_EXAMPLES=5000 for a soak run; derandomized: the same examples every run.
FUZZ = settings(max_examples=int(os.environ.get("MITSONAR_FUZZ_EXAMPLES", 60)), deadline=None,
                derandomize=True, suppress_health_check=[HealthCheck.too_slow])

_MAX = {"B": 0xFF, "H": 0xFFFF, "I": 0xFFFFFFFF}


@st.composite
def messages(draw, mid=None):
    """Any message brping defines for the Ping360 and the common set, with random fields."""
    mid = draw(st.sampled_from(sorted(pp.MESSAGES))) if mid is None else mid
    spec = pp.MESSAGES[mid]
    fmt, names = spec["format"], spec["field_names"]
    vals = {n: draw(st.integers(0, _MAX[c])) for c, n in zip(fmt, names)}
    if len(names) > len(fmt):        # the variable-length last field
        vals[names[-1]] = draw(st.binary(max_size=300))
    return Message(mid, src=draw(st.integers(0, 255)), dst=draw(st.integers(0, 255)), **vals)


def brping_bytes(m: Message) -> bytes | None:
    """The same message packed by brping.pingmessage.PingMessage (None for an empty variable part,
    which brping cannot pack: its format then lacks the field its value list still holds)."""
    if m.variable and not getattr(m, m.variable):
        return None
    if m.message_id in pingmessage.asciiMsgs:
        # brping's constructor cannot make its text messages (it sets their text to 0, then
        # takes its len): set up what pack_msg_data reads by hand.
        b = pingmessage.PingMessage.__new__(pingmessage.PingMessage)
        b.payload_dict, b.message_id, b.request_id = pingmessage.payload_dict, m.message_id, None
        b.payload_field_names = pp.MESSAGES[m.message_id]["field_names"]
    else:
        b = pingmessage.PingMessage(m.message_id)
    b.src_device_id, b.dst_device_id = m.src, m.dst
    for k, v in m.values().items():
        setattr(b, k, bytearray(v) if isinstance(v, bytes) else v)
    return bytes(b.pack_msg_data())


def brping_parse(data: bytes):
    p = pingmessage.PingParser()
    got = []
    for x in data:
        if p.parse_byte(x) == p.NEW_MESSAGE:
            got.append(p.rx_msg)
    return got, p.errors


# ---- exact bytes ------------------------------------------------------------------------------

def test_ids_are_brpings():
    assert ids["transducer"] == brdefs.PING360_TRANSDUCER == 2601
    assert ids["device_data"] == 2300 and ids["general_request"] == 6 and ids["motor_off"] == 2903
    assert pp.MESSAGES[2601] is brdefs.payload_dict_ping360[2601]


def test_general_request_bytes_by_hand():
    # 'B' 'R', payload 2, id 6, src 255, dst 0, requested_id 5, checksum = byte sum 0x01a0
    frame = encode(Message("general_request", src=255, dst=0, requested_id=5))
    assert frame == bytes([0x42, 0x52, 2, 0, 6, 0, 255, 0, 5, 0, 0xA0, 0x01])


def test_device_data_layout():
    m = Message("device_data", mode=1, gain_setting=2, angle=399, transmit_duration=500,
                sample_period=40000, transmit_frequency=1000, number_of_samples=3, data=b"\x01\x02\x03")
    f = encode(m)
    assert f[:8] == b"BR" + struct.pack("<HHBB", 14 + 3, 2300, 0, 0)
    assert struct.unpack_from("<BBHHHHHH", f, 8) == (1, 2, 399, 500, 40000, 1000, 3, 3)
    assert f[22:25] == b"\x01\x02\x03" and struct.unpack("<H", f[-2:])[0] == sum(f[:-2]) & 0xFFFF
    assert m.data_length == 3                 # filled in by encode


# ---- round trips against brping ---------------------------------------------------------------

@pytest.mark.parametrize("mid", sorted(pp.MESSAGES), ids=lambda i: pp.MESSAGES[i]["name"])
def test_every_message_matches_brping(mid):
    spec = pp.MESSAGES[mid]
    vals = {n: (k * 37 + 5) % (_MAX[c] + 1) for k, (c, n) in enumerate(zip(spec["format"], spec["field_names"]))}
    if len(spec["field_names"]) > len(spec["format"]):
        vals[spec["field_names"][-1]] = bytes(range(7))
    m = Message(mid, src=1, dst=2, **vals)
    frame = encode(m)
    assert frame == brping_bytes(m)
    assert decode(frame) == m
    got, errors = brping_parse(frame)
    assert errors == 0 and len(got) == 1 and got[0].message_id == mid


@FUZZ
@given(messages())
def test_round_trip_property_against_brping(m):
    frame = encode(m)
    assert brping_bytes(m) in (frame, None)
    back = decode(frame)
    assert back == m and encode(back) == frame
    (got,), errors = brping_parse(frame)
    assert errors == 0
    for k, v in m.values().items():
        if k in ("data_length",) or m.variable == k:
            continue
        assert getattr(got, k) == v


def test_out_of_range_fields_and_unknown_names_are_refused():
    with pytest.raises(ValueError, match=r"transducer.angle = 65536 is outside 0..65535"):
        encode(Message("transducer", angle=65536))
    with pytest.raises(ValueError, match=r"transducer.mode = -1"):
        encode(Message("transducer", mode=-1))
    with pytest.raises(ValueError, match="transducer.src"):
        encode(Message("transducer", src=256))
    with pytest.raises(ValueError, match="has no field 'range'"):
        Message("transducer", range=3)
    with pytest.raises(ValueError, match="unknown ping-protocol message 'ping'"):
        Message("ping")


@pytest.mark.parametrize("damage,match", [
    (lambda f: f[:-1] + bytes([f[-1] ^ 1]), "checksum"),
    (lambda f: f[:5], "shorter than the 10"),
    (lambda f: b"XR" + f[2:], "expected b'BR'"),
    (lambda f: f + b"\0", "payload_length says"),
])
def test_decode_refuses_damage_in_one_line(damage, match):
    frame = encode(Message("transducer", angle=3))
    with pytest.raises(ProtocolError, match=match):
        decode(damage(frame))


def test_decode_checks_lengths_per_message():
    body = b"BR" + struct.pack("<HHBB", 3, 2601, 0, 0) + b"abc"
    with pytest.raises(ProtocolError, match="impossible for transducer"):
        decode(body + struct.pack("<H", sum(body) & 0xFFFF))
    body = b"BR" + struct.pack("<HHBB", 15, 2300, 0, 0) + struct.pack("<BBHHHHHH", 1, 1, 0, 1, 80, 750, 1, 5) + b"x"
    with pytest.raises(ProtocolError, match="data_length = 5 but 1 data bytes follow"):
        decode(body + struct.pack("<H", sum(body) & 0xFFFF))


def test_unknown_ids_are_kept_as_raw_payloads():
    body = b"BR" + struct.pack("<HHBB", 2, 1300, 0, 0) + b"hi"
    m = decode(body + struct.pack("<H", sum(body) & 0xFFFF))
    assert m.name == "unknown_1300" and m.payload_bytes == b"hi"
    assert encode(m) == body + struct.pack("<H", sum(body) & 0xFFFF)


# ---- the stream parser ------------------------------------------------------------------------

def test_parser_skips_a_bad_checksum_and_counts_it():
    a, b = (encode(Message("transducer", angle=k)) for k in (1, 2))
    bad = a[:-1] + bytes([a[-1] ^ 0xFF])
    p = StreamParser()
    out = p.feed(b"U" + bad + b)
    assert [m.angle for m in out] == [2]
    assert p.errors == 1 and p.dropped == 1 + len(bad) and p.drop_reasons["bad checksum"] == 1


def test_parser_holds_a_split_frame_and_keeps_a_trailing_B():
    f = encode(Message("device_data", number_of_samples=4, data=b"abcd"))
    p = StreamParser()
    assert p.feed(b"xx" + f[:1]) == [] and p.pending == 1 and p.dropped == 2
    assert p.feed(f[1:9]) == [] and p.pending == 9
    assert [m.data for m in p.feed(f[9:])] == [b"abcd"] and p.pending == 0


def test_a_header_claiming_too_much_is_dropped_at_once():
    p = StreamParser(max_payload=100)
    good = encode(Message("ack", acked_id=2601))
    out = p.feed(b"BR" + struct.pack("<HHBB", 5000, 1, 0, 0) + good)
    assert [m.acked_id for m in out] == [2601] and p.dropped == 8
    with pytest.raises(ValueError, match="max_payload"):
        StreamParser(max_payload=-1)


@FUZZ
@given(st.binary(max_size=3000), st.integers(1, 64))
def test_parser_random_bytes_never_crash_and_account_for_every_byte(data, chunk):
    p = StreamParser()
    out = []
    for i in range(0, len(data), chunk):
        out += p.feed(data[i:i + chunk])
    out += p.flush()
    assert p.dropped + sum(len(encode(m)) for m in out) == len(data) and p.pending == 0


garbage = st.binary(max_size=40).map(lambda b: b.replace(b"B", b"b"))


@FUZZ
@given(st.lists(st.tuples(messages(), st.sampled_from(["ok", "cut", "flip", "garbage"]),
                          st.floats(0, 1), garbage), min_size=1, max_size=8),
       st.integers(1, 80))
def test_every_whole_frame_after_damage_is_recovered(items, chunk):
    """Frames cut short, frames with a flipped bit, garbage: the good frames all come out, in order."""
    stream, want = b"", []
    for m, how, where, junk in items:
        f = encode(m)
        if how == "ok":
            stream += f
            want.append(f)
        elif how == "cut":
            stream += f[:max(1, int(where * (len(f) - 1)))]
        elif how == "flip":
            k = 2 + int(where * (len(f) - 3))          # past 'BR': a flipped header byte is garbage
            stream += f[:k] + bytes([f[k] ^ 0x10]) + f[k + 1:]
        else:
            stream += junk
    p = StreamParser()
    out = []
    for i in range(0, len(stream), chunk):
        out += p.feed(stream[i:i + chunk])
    out += p.flush()
    assert [encode(m) for m in out] == want
    assert p.dropped == len(stream) - sum(map(len, want)) and p.pending == 0
