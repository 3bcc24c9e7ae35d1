"""Blue Robotics ping-protocol codec (Ping360 and the common messages): bytes in, messages out, and back.

No I/O. The message ids, field names and field widths are not written here: they are those of
the ``bluerobotics-ping`` package (``brping.definitions``: ``payload_dict_common`` and
``payload_dict_ping360``), so the codec speaks exactly what ``brping.Ping360`` speaks.
Frame (ping-protocol ``docs/index.md``; ``reference/seanet.md`` section 6), little-endian::

    0..1   'B' 'R'
    2..3   payload_length  u16
    4..5   message_id      u16
    6      src_device_id   u8
    7      dst_device_id   u8
    8..    payload         (the fields of the message's struct format, then its variable part)
    n-2..  checksum        u16 = sum of every byte before it, mod 2^16

Variable parts (the last field): ``data`` of ``device_data``/``auto_device_data`` (preceded by
the fixed u16 ``data_length``, which `encode` fills in), the text of ``nack`` and
``ascii_text``. `StreamParser` resynchronises on damage: a frame is accepted only when its
checksum holds and its length suits its message id; otherwise one byte is dropped, counted
with its reason, and the search for ``'BR'`` starts again, so every whole frame after a
damaged one is found.
"""
from __future__ import annotations

import struct
from collections import Counter

from brping import definitions as _defs

__all__ = ["Message", "ProtocolError", "encode", "decode", "StreamParser", "MESSAGES", "ids",
           "HEADER_SIZE", "CHECKSUM_SIZE", "MAX_PAYLOAD"]

HEADER = b"BR"
_HEAD = struct.Struct("<2sHHBB")
HEADER_SIZE = _HEAD.size          # 8
CHECKSUM_SIZE = 2
# device_data at its 1200 samples is 1214 bytes; other devices' longer messages are not ours.
MAX_PAYLOAD = 4096

#: message id -> brping definition (name, format, field_names, payload_length), common + Ping360
MESSAGES: dict = {**_defs.payload_dict_common, **_defs.payload_dict_ping360}
#: name -> id for the messages the driver and the virtual head use
ids = {
    "ack": _defs.COMMON_ACK, "nack": _defs.COMMON_NACK, "ascii_text": _defs.COMMON_ASCII_TEXT,
    "general_request": _defs.COMMON_GENERAL_REQUEST, "device_information": _defs.COMMON_DEVICE_INFORMATION,
    "protocol_version": _defs.COMMON_PROTOCOL_VERSION, "device_data": _defs.PING360_DEVICE_DATA,
    "auto_device_data": _defs.PING360_AUTO_DEVICE_DATA, "reset": _defs.PING360_RESET,
    "transducer": _defs.PING360_TRANSDUCER, "auto_transmit": _defs.PING360_AUTO_TRANSMIT,
    "motor_off": _defs.PING360_MOTOR_OFF, "set_device_id": _defs.PING360_SET_DEVICE_ID,
}
# Messages whose last field has a variable length (brping.pingmessage: variable_msgs, asciiMsgs).
_VARIABLE = {_defs.COMMON_NACK, _defs.COMMON_ASCII_TEXT, _defs.PING360_DEVICE_DATA,
             _defs.PING360_AUTO_DEVICE_DATA}
_LENGTH_FIELD = {_defs.PING360_DEVICE_DATA: "data_length", _defs.PING360_AUTO_DEVICE_DATA: "data_length"}
_RANGES = {"B": 0xFF, "H": 0xFFFF, "I": 0xFFFFFFFF, "b": None, "h": None, "i": None, "f": None}


class ProtocolError(ValueError):
    """A frame that is not a valid ping-protocol message (the text says which byte and why)."""


class Message:
    """One ping-protocol message: ``message_id``, ``src``, ``dst`` and its fields as attributes.

    ``Message("transducer", angle=100, ...)`` or ``Message(2601, ...)``: fields not given are 0
    (the variable part ``b""``), as in ``brping.PingMessage``. ``name`` is brping's name;
    ``fields`` the field names in wire order; ``payload_bytes`` the payload of a message whose id
    brping does not define (kept as received). ``general_request`` is answered by the message it
    names (``requested_id``).
    """

    def __init__(self, message, *, src: int = 0, dst: int = 0, payload_bytes: bytes | None = None,
                 **values):
        mid = ids.get(message, message) if isinstance(message, str) else message
        if isinstance(message, str) and message not in ids:
            raise ValueError(f"unknown ping-protocol message {message!r}: one of {sorted(ids)}")
        self.message_id = int(mid)
        self.src, self.dst = src, dst
        spec = MESSAGES.get(self.message_id)
        self.name = spec["name"] if spec else f"unknown_{self.message_id}"
        self.fields = tuple(spec["field_names"]) if spec else ()
        self.payload_bytes = None if spec else bytes(payload_bytes or b"")
        unknown = set(values) - set(self.fields)
        if unknown:
            raise ValueError(f"{self.name} has no field {sorted(unknown)[0]!r} (fields: {', '.join(self.fields)})")
        for i, f in enumerate(self.fields):
            last_var = self.message_id in _VARIABLE and i == len(self.fields) - 1
            setattr(self, f, values.get(f, b"" if last_var else 0))

    @property
    def variable(self) -> str | None:
        """Name of the variable-length last field, or None."""
        return self.fields[-1] if self.message_id in _VARIABLE else None

    def values(self) -> dict:
        return {f: getattr(self, f) for f in self.fields}

    def __eq__(self, other):
        if not isinstance(other, Message):
            return NotImplemented
        return ((self.message_id, self.src, self.dst, self.payload_bytes) ==
                (other.message_id, other.src, other.dst, other.payload_bytes)
                and {k: _norm(v) for k, v in self.values().items()} == {k: _norm(v) for k, v in other.values().items()})

    def __repr__(self):
        items = ", ".join(f"{k}={v!r}" if not isinstance(v, (bytes, bytearray)) or len(v) < 16
                          else f"{k}=<{len(v)} bytes>" for k, v in self.values().items())
        return f"Message({self.name!r}, src={self.src}, dst={self.dst}{', ' if items else ''}{items})"


def _norm(v):
    return bytes(v) if isinstance(v, (bytes, bytearray, memoryview)) else v


def _payload(m: Message) -> bytes:
    if m.payload_bytes is not None:
        return m.payload_bytes
    spec = MESSAGES[m.message_id]
    fmt = spec["format"]
    var = m.variable
    tail = b""
    if var is not None:
        v = getattr(m, var)
        tail = v.encode("ascii") if isinstance(v, str) else bytes(v)
        if m.message_id in _LENGTH_FIELD:
            setattr(m, _LENGTH_FIELD[m.message_id], len(tail))
    names = m.fields[:len(fmt)]
    vals = []
    for code, name in zip(fmt, names):
        v = getattr(m, name)
        hi = _RANGES.get(code)
        if hi is not None and not (isinstance(v, int) and not isinstance(v, bool) and 0 <= v <= hi):
            raise ValueError(f"{m.name}.{name} = {v!r} is outside 0..{hi}")
        vals.append(v)
    return struct.pack("<" + fmt, *vals) + tail


def encode(message: Message) -> bytes:
    """The frame of ``message`` (header, payload, checksum). ValueError for out-of-range fields."""
    for name in ("src", "dst"):
        v = getattr(message, name)
        if not (isinstance(v, int) and 0 <= v <= 0xFF):
            raise ValueError(f"{message.name}.{name} = {v!r} is outside 0..255")
    payload = _payload(message)
    if len(payload) > 0xFFFF:
        raise ValueError(f"{message.name}: payload of {len(payload)} bytes is too long (max 65535)")
    body = _HEAD.pack(HEADER, len(payload), message.message_id, message.src, message.dst) + payload
    return body + struct.pack("<H", sum(body) & 0xFFFF)


def _length_problem(mid: int, n: int) -> str | None:
    """Why a payload of ``n`` bytes cannot belong to message ``mid`` (None if it can)."""
    spec = MESSAGES.get(mid)
    if spec is None:
        return None
    want = spec["payload_length"]
    if mid in _VARIABLE:
        return None if n >= want else f"payload of {n} bytes too short for {spec['name']} (>= {want})"
    return None if n == want else f"payload of {n} bytes impossible for {spec['name']} ({want})"


def _decode_frame(frame: bytes) -> Message:
    _, n, mid, src, dst = _HEAD.unpack_from(frame, 0)
    payload = frame[HEADER_SIZE:HEADER_SIZE + n]
    spec = MESSAGES.get(mid)
    if spec is None:
        return Message(mid, src=src, dst=dst, payload_bytes=payload)
    fmt = spec["format"]
    fixed = struct.calcsize("<" + fmt)
    vals = dict(zip(spec["field_names"], struct.unpack_from("<" + fmt, payload, 0)))
    if mid in _VARIABLE:
        tail = payload[fixed:]
        lf = _LENGTH_FIELD.get(mid)
        if lf is not None and vals[lf] != len(tail):
            raise ProtocolError(f"{spec['name']}: {lf} = {vals[lf]} but {len(tail)} data bytes follow")
        vals[spec["field_names"][-1]] = bytes(tail)
    return Message(mid, src=src, dst=dst, **vals)


def _checksum_problem(frame) -> str | None:
    n = len(frame) - CHECKSUM_SIZE
    got = frame[n] | (frame[n + 1] << 8)
    want = sum(frame[:n]) & 0xFFFF
    return None if got == want else f"checksum {got:#06x}, bytes sum to {want:#06x}"


def decode(frame: bytes) -> Message:
    """The message of exactly one whole frame; `ProtocolError` if it is not valid."""
    if isinstance(frame, (str, int)):
        raise TypeError(f"frame must be bytes, got {type(frame).__name__}")
    b = bytes(frame)
    if len(b) < HEADER_SIZE + CHECKSUM_SIZE:
        raise ProtocolError(f"frame of {len(b)} bytes is shorter than the 10 of header and checksum")
    if b[:2] != HEADER:
        raise ProtocolError(f"bytes 0..1 are {b[:2]!r}, expected b'BR'")
    _, n, mid, _, _ = _HEAD.unpack_from(b, 0)
    if len(b) != HEADER_SIZE + n + CHECKSUM_SIZE:
        raise ProtocolError(f"payload_length says {n} bytes, the frame holds {len(b) - HEADER_SIZE - CHECKSUM_SIZE}")
    problem = _length_problem(mid, n) or _checksum_problem(b)
    if problem:
        raise ProtocolError(problem)
    return _decode_frame(b)


class StreamParser:
    """Streaming ping-protocol parser: ``feed(bytes) -> list`` of `Message`, resynchronising on damage.

    Attributes: ``dropped`` bytes discarded so far, ``drop_reasons`` a Counter of bytes per reason,
    ``packets`` messages emitted (the name the Micron's parser uses), ``errors`` frames refused
    for their checksum, ``pending`` bytes held for the rest of a frame. ``max_payload`` (default
    `MAX_PAYLOAD`) bounds the length a header may claim before it is taken for damage.
    """

    def __init__(self, max_payload: int = MAX_PAYLOAD):
        if not (isinstance(max_payload, int) and 0 <= max_payload <= 0xFFFF):
            raise ValueError(f"max_payload must be an integer in 0..65535, got {max_payload!r}")
        self.max_payload = max_payload
        self.reset()

    def reset(self) -> None:
        """Forget buffered bytes and counters."""
        self._buf = bytearray()
        self.dropped = 0
        self.drop_reasons: Counter = Counter()
        self.packets = 0
        self.errors = 0

    @property
    def pending(self) -> int:
        return len(self._buf)

    def _drop(self, n: int, reason: str) -> None:
        del self._buf[:n]
        self.dropped += n
        self.drop_reasons[reason] += n

    def feed(self, data: bytes) -> list:
        """Add bytes; return the messages completed by them (possibly none)."""
        if data:
            self._buf += data
        return self._parse()

    def flush(self) -> list:
        """End of stream: what can still be decoded, the incomplete rest dropped (counted).

        A header whose frame never completed may be damage hiding whole frames behind it: it
        loses its first byte and the search goes on, as after a bad checksum.
        """
        out = self._parse()
        while self._buf:
            self._drop(1, "incomplete frame at end of stream")
            out += self._parse()
        return out

    def _parse(self) -> list:
        out = []
        buf = self._buf
        while buf:
            i = buf.find(HEADER)
            if i < 0:
                # Keep a trailing 'B': it may start a header.
                keep = 1 if buf[-1:] == b"B" else 0
                if len(buf) - keep:
                    self._drop(len(buf) - keep, "garbage between frames")
                break
            if i > 0:
                self._drop(i, "garbage between frames")
            if len(buf) < HEADER_SIZE:
                break
            _, n, mid, _, _ = _HEAD.unpack_from(buf, 0)
            problem = (f"payload_length {n} over the {self.max_payload} accepted"
                       if n > self.max_payload else _length_problem(mid, n))
            if problem:
                self._drop(1, problem if mid in MESSAGES else "bad header")
                continue
            end = HEADER_SIZE + n + CHECKSUM_SIZE
            if len(buf) < end:
                break
            frame = bytes(buf[:end])
            if _checksum_problem(frame):
                self.errors += 1
                self._drop(1, "bad checksum")
                continue
            try:
                msg = _decode_frame(frame)
            except ProtocolError as e:
                self._drop(1, str(e).split(":")[0] + ": length field mismatch")
                continue
            del buf[:end]
            self.packets += 1
            out.append(msg)
        return out
