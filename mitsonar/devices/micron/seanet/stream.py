"""SeaNet framing: `encode`, `decode` (one packet) and `StreamParser` (a byte stream).

Bytes in, typed messages out, and back; no I/O. Offsets count from the ``'@'`` byte
(``reference/seanet.md`` section 1)::

    0      '@'
    1..4   total length - 6, four ASCII hex digits ("003C"; either case is accepted)
    5..6   the same length, uint16 little-endian
    7      source node (PC 255, sonar 2)        8   destination node
    9      byte count after this byte, excluding LF (payload + 3); 0 in mtHeadData
    10     message id                           11  sequence, 0x80 (bit 7 = last packet)
    12     node number (destination for commands, source for replies)
    13..   payload                              n-1 LF (0x0A)

There is no checksum. `StreamParser` therefore accepts a packet only when its framing,
its per-type length rules and its field ranges hold *and* no plausible packet header starts
inside it: a packet that lost bytes is always followed by the next packet's header within its
claimed length, which is how truncated packets and wrong length fields are caught.
"""
from __future__ import annotations

import struct
from collections import Counter, deque

import numpy as np

from mitsonar.devices.micron.seanet.constants import (DEFAULT_NIBBLE_ORDER, HEADER, MAX_PACKET, MIN_PACKET, TERMINATOR, MessageId,
                        SeaNetError, _check_nibble_order)
from mitsonar.devices.micron.seanet.messages import (_GAIN_LAYOUT, _REGISTRY, BBUSER_LENGTHS, V3B_GAIN_ONLY, V3B_SCAN_REVERSE,
                       GainCommand, HeadCommand, HeadData, Message, RawMessage, ScanReverse, _fmt_size)

__all__ = ["encode", "decode", "StreamParser"]

_HEX = frozenset(b"0123456789ABCDEFabcdef")


def encode(message: Message) -> bytes:
    """The packet of ``message`` (header, payload, LF). Raises ValueError for out-of-range fields."""
    payload = message.payload()
    n = 13 + len(payload) + 1
    if n - 6 > 0xFFFF:
        raise ValueError(f"{type(message).__name__}: packet of {n} bytes is too long for SeaNet")
    if message.count is not None:
        count = message.count
    else:
        # Heads put 0 in mtHeadData ("single-packet mode"); everything else counts the bytes.
        count = 0 if message.msg_id == MessageId.mtHeadData else (n - 11) & 0xFF
    head = [message.src, message.dst, count, message.msg_id, message.sequence, message.node]
    for name, v in zip(("src", "dst", "count", "msg_id", "sequence", "node"), head):
        if not isinstance(v, (int, np.integer)) or not 0 <= int(v) <= 0xFF:
            raise ValueError(f"{type(message).__name__}.{name} = {v!r} is outside 0..255")
    return (b"@" + f"{n - 6:04X}".encode("ascii") + struct.pack("<H", n - 6)
            + bytes(int(v) for v in head) + payload + b"\n")


_FIXED_LENGTHS = {
    MessageId.mtSendData: (18,), MessageId.mtSendVersion: (14,), MessageId.mtReBoot: (14,),
    MessageId.mtSendBBUser: (14,), MessageId.mtVersionData: (25,), MessageId.mtAlive: (22,),
    MessageId.mtBBUserData: BBUSER_LENGTHS, MessageId.mtStopAlives: (14,),
    MessageId.mtResetToDefaults: (14,), MessageId.mtHeadCommand: (15, 31, 66, 82),
}


def _length_problem(buf, n: int, check_count: bool) -> str | None:
    """Why the 13+ header bytes in ``buf`` cannot start an ``n``-byte packet (None if they can)."""
    if n < MIN_PACKET:
        return "length field below the 14-byte minimum"
    if check_count and buf[9] not in (0, (n - 11) & 0xFF):
        return "byte count (byte 9) does not match the length field"
    if not buf[11] & 0x80:
        return "multi-packet sequence (not supported)"
    mid = buf[10]
    allowed = _FIXED_LENGTHS.get(mid)
    if allowed is not None and n not in allowed:
        return f"length {n} impossible for {MessageId(mid).name}"
    if mid == MessageId.mtHeadData:
        if n < 45:
            return f"length {n} too short for mtHeadData"
        if len(buf) >= 15 and buf[13] | (buf[14] << 8) != n - 14:
            return "mtHeadData byte count does not match the length field"
    if mid == MessageId.mtAuxData:
        if n < 16:
            return f"length {n} too short for mtAuxData"
        if len(buf) >= 15 and buf[13] | (buf[14] << 8) != n - 16:
            return "mtAuxData size does not match the length field"
    return None


def _decode_frame(frame: bytes, nibble_order: str) -> Message:
    """Typed message of a complete, framing-checked packet."""
    mid = frame[10]
    common = dict(src=frame[7], dst=frame[8], node=frame[12], sequence=frame[11], count=frame[9])
    payload = frame[13:-1]
    if mid == MessageId.mtHeadCommand:
        v3b = payload[0] if payload else None
        if v3b == V3B_SCAN_REVERSE and len(payload) == 1:
            return ScanReverse(**common)
        if v3b == V3B_GAIN_ONLY and len(payload) == _fmt_size(_GAIN_LAYOUT):
            return GainCommand(**GainCommand._unpack(_GAIN_LAYOUT, payload), **common)
        return HeadCommand.from_payload(payload, **common)
    cls = _REGISTRY.get(mid)
    if cls is None:
        return RawMessage(message_id=mid, payload_bytes=bytes(payload), **common)
    if cls is HeadData:
        return HeadData.from_payload(payload, nibble_order=nibble_order, **common)
    try:
        return cls.from_payload(payload, **common)
    except struct.error as e:    # pragma: no cover - lengths are checked before
        raise SeaNetError(f"{cls.__name__}: {e}") from None


def decode(packet: bytes, nibble_order: str = DEFAULT_NIBBLE_ORDER, check_count: bool = True) -> Message:
    """The message of exactly one complete packet; raises `SeaNetError` if it is not valid."""
    _check_nibble_order(nibble_order)
    # bytes(str) asks for an encoding and bytes(int) makes zeros: neither is a packet.
    if isinstance(packet, (str, int, np.integer)):
        raise TypeError(f"packet must be bytes, got {type(packet).__name__}")
    try:
        b = bytes(packet)
    except TypeError:
        raise TypeError(f"packet must be bytes, got {type(packet).__name__}") from None
    if len(b) < MIN_PACKET:
        raise SeaNetError(f"packet of {len(b)} bytes is shorter than 14")
    problem = _header_problem(b)
    if problem:
        raise SeaNetError(problem)
    n = int(b[1:5], 16) + 6
    if n != len(b):
        raise SeaNetError(f"length field says {n} bytes, packet has {len(b)}")
    problem = _length_problem(b, n, check_count)
    if problem:
        raise SeaNetError(problem)
    if b[-1] != TERMINATOR:
        raise SeaNetError(f"byte {len(b) - 1} is {b[-1]:#04x}, expected the LF terminator (0x0a)")
    return _decode_frame(b, nibble_order)


def _header_problem(b: bytes) -> str | None:
    """The first wrong framing byte of ``b`` (offset, value, what was expected), or None."""
    if b[0] != HEADER:
        return f"byte 0 is {b[0]:#04x}, expected '@' (0x40)"
    for k in range(1, 5):
        if b[k] not in _HEX:
            return f"byte {k} is {b[k]:#04x}, expected an ASCII hex digit (length field, bytes 1..4)"
    value = int(b[1:5], 16)
    if value + 6 < MIN_PACKET:
        return f"length field (bytes 1..4) is {value:#06x}, expected at least 0x0008 (a 14-byte packet)"
    for k, want in ((5, value & 0xFF), (6, value >> 8)):
        if b[k] != want:
            return (f"byte {k} is {b[k]:#04x}, expected {want:#04x} (binary copy of the length "
                    f"field {b[1:5].decode('ascii')})")
    return None


def _header_state(buf, j: int, max_len: int) -> tuple[str, int]:
    """Is there a packet header at ``buf[j]``? ('yes', total length) / ('no', 0) / ('maybe', 0).

    Checks '@', four hex digits, the binary copy of the length; 'maybe' when bytes are missing.
    """
    end = len(buf)
    if buf[j] != HEADER:
        return "no", 0
    for k in range(1, 5):
        if j + k >= end:
            return "maybe", 0
        if buf[j + k] not in _HEX:
            return "no", 0
    value = int(bytes(buf[j + 1:j + 5]), 16)
    if value + 6 < MIN_PACKET or value + 6 > max_len:
        return "no", 0
    if j + 5 >= end:
        return "maybe", 0
    if buf[j + 5] != value & 0xFF:
        return "no", 0
    if j + 6 >= end:
        return "maybe", 0
    if buf[j + 6] != value >> 8:
        return "no", 0
    return "yes", value + 6


class StreamParser:
    """Streaming SeaNet parser: ``feed(bytes) -> list`` of messages, resynchronising on damage.

    Parameters
    ----------
    ============  ==============================================================
    nibble_order  ``"low_first"`` (default) or ``"high_first"``, for 4-bit mtHeadData
    check_count   reject packets whose byte 9 is neither 0 nor payload + 3 (default True)
    max_length    longest packet accepted, bytes (default 65541, the format's limit)
    log_size      how many drop records `drops` keeps (default 1000)
    ============  ==============================================================

    Attributes
    ----------
    ``dropped`` bytes discarded so far; ``drops`` a deque of ``(reason, n_bytes)`` (latest
    ``log_size``); ``drop_reasons`` a Counter of bytes per reason; ``packets`` messages
    emitted; ``pending`` bytes held waiting for the rest of a packet.

    A candidate packet (``'@'`` + matching hex and binary lengths) is emitted when its per-type
    length rules hold, its last byte is LF, its fields decode, and no plausible header (``'@'``,
    hex length, its binary copy, byte count and sequence bytes) starts inside it. Otherwise the
    parser drops bytes up to that inner header, or the ``'@'`` alone, and searches again, so a
    truncated packet or a wrong length field costs only the damaged packet. Without a checksum
    a corruption that forges both the length structure and the LF cannot be seen; everything
    else is.
    """

    def __init__(self, nibble_order: str = DEFAULT_NIBBLE_ORDER, check_count: bool = True,
                 max_length: int = MAX_PACKET, log_size: int = 1000):
        self.nibble_order = _check_nibble_order(nibble_order)
        self.check_count = bool(check_count)
        if not MIN_PACKET <= max_length <= MAX_PACKET:
            raise ValueError(f"max_length must lie in {MIN_PACKET}..{MAX_PACKET}, got {max_length}")
        self.max_length = int(max_length)
        self.drops: deque = deque(maxlen=log_size)
        self.reset()

    def reset(self) -> None:
        """Forget buffered bytes and counters."""
        self._buf = bytearray()
        self._checked = 1         # offsets of the current candidate already cleared of inner headers
        self.dropped = 0
        self.drops.clear()
        self.drop_reasons: Counter = Counter()
        self.packets = 0

    @property
    def pending(self) -> int:
        return len(self._buf)

    def feed(self, data: bytes) -> list:
        """Add bytes; return the messages completed by them (possibly none)."""
        if data:
            self._buf += data
        return self._parse(final=False)

    def flush(self) -> list:
        """End of stream: emit what can still be decided, drop the incomplete rest."""
        out = self._parse(final=True)
        if self._buf:
            self._drop(len(self._buf), "incomplete packet at end of stream")
        return out

    def _drop(self, n: int, reason: str) -> None:
        del self._buf[:n]
        self._checked = 1
        self.dropped += n
        self.drop_reasons[reason] += n
        if self.drops and self.drops[-1][0] == reason:
            self.drops[-1] = (reason, self.drops[-1][1] + n)
        else:
            self.drops.append((reason, n))

    def _inner_header(self, n: int, final: bool) -> tuple[str, int]:
        """Look for a plausible header starting inside the candidate's first ``n`` bytes."""
        buf = self._buf
        stop = min(n, len(buf))
        j = buf.find(b"@", self._checked, stop)
        while j >= 0:
            state, m = _header_state(buf, j, self.max_length)
            if state == "yes":
                # The 13-byte header must also make sense, which makes a false alarm inside
                # genuine data (bins that happen to spell a header) vanishingly rare.
                if j + 13 > len(buf):
                    state = "maybe"
                elif _length_problem(buf[j:j + 15], m, self.check_count) is None:
                    return "yes", j
                else:
                    state = "no"
            if state == "maybe" and not final:
                self._checked = j
                return "maybe", j
            j = buf.find(b"@", j + 1, stop)
        self._checked = max(self._checked, stop)
        return "no", 0

    def _parse(self, final: bool) -> list:
        out = []
        buf = self._buf
        while buf:
            i = buf.find(b"@")
            if i < 0:
                self._drop(len(buf), "garbage between packets")
                break
            if i > 0:
                self._drop(i, "garbage between packets")
            state, n = _header_state(buf, 0, self.max_length)
            if state == "maybe":
                if final:
                    self._drop(1, "incomplete header at end of stream")
                    continue
                break
            if state == "no":
                self._drop(1, "bad header (hex and binary lengths)")
                continue
            # The next packet's header inside this one is the surest sign of a cut: test it
            # first so the drop log names the cause.
            inner, j = self._inner_header(n, final)
            if inner == "yes":
                self._drop(j, "truncated packet (next header inside it)")
                continue
            if inner == "maybe":     # only without `final`: an inner header may still complete
                break
            if len(buf) >= 13:
                problem = _length_problem(buf[:15], n, self.check_count)
                if problem:
                    self._drop(1, problem)
                    continue
            if len(buf) < n:
                if final:
                    self._drop(1, "truncated packet at end of stream")
                    continue
                break
            if buf[n - 1] != TERMINATOR:
                self._drop(1, "no LF where the length field puts the end")
                continue
            try:
                msg = _decode_frame(bytes(buf[:n]), self.nibble_order)
            except SeaNetError as e:
                self._drop(1, str(e))
                continue
            del buf[:n]
            self._checked = 1
            self.packets += 1
            out.append(msg)
        return out

