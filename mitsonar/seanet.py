"""SeaNet serial protocol of Tritech heads (Micron, MiniKing, SeaKing): a pure codec.

Bytes in, typed messages out, and back; no I/O. The field layout follows
``reference/seanet.md`` (compiled from the Rock, UxVCtrl and McGill drivers). Offsets below
count from the ``'@'`` byte.

Framing (every message)::

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

Public names
------------
Messages (dataclasses; ``encode(msg)`` turns any of them into bytes):
    commands `ReBoot`, `SendVersion`, `SendBBUser`, `SendData`, `HeadCommand`, `ScanReverse`,
    `GainCommand`, `StopAlives`, `ResetToDefaults`; replies `VersionData`, `HeadData`, `Alive`,
    `BBUserData`, `AuxData`, `FpgaVersionData`, `FpgaCalibrationData`; `RawMessage` for ids
    without a typed class.
Parsing: `StreamParser` (streaming, resynchronising), `decode` (one whole packet).
Settings: `HeadSettings` builds `HeadCommand` (ADInterval, TxN, pulse length, ... computed).
Driver: ``mitsonar.seanet.MicronSonar`` is `mitsonar.micron.MicronSonar`, imported on first use.
Bearings: `bearing_to_radians`, `radians_to_bearing` (the simulator's convention).
Flags: `MessageId`, `HdCtrl`, `HeadInf`, `HeadStatus`.

4-bit nibble order
------------------
With ``adc8on`` clear the head packs two bins per byte. Rock takes the low nibble first,
UxVCtrl the high nibble first; no public byte log of a real head settles it. The order is a
setting (``nibble_order``: ``"low_first"`` or ``"high_first"``) of `StreamParser`, `decode`,
`HeadData` and the virtual sonar; the default is ``"low_first"`` (Rock's, whose driver was
used with Micron DST heads and scales by 17 as ``bins`` does).
"""
from __future__ import annotations

import enum
import math
import struct
from collections import Counter, deque
from dataclasses import dataclass, field, fields
from typing import Any, ClassVar

import numpy as np

__all__ = [
    "HEADER", "TERMINATOR", "PC_NODE", "SONAR_NODE", "MIN_PACKET", "MAX_PACKET", "FULL_TURN",
    "NIBBLE_ORDERS", "DEFAULT_NIBBLE_ORDER", "STEP_SIZES",
    "MessageId", "HdCtrl", "HeadInf", "HeadStatus", "SweepCode",
    "SeaNetError", "Message", "ReBoot", "SendVersion", "SendBBUser", "SendData", "StopAlives",
    "ResetToDefaults", "HeadCommand", "ScanReverse", "GainCommand", "VersionData", "HeadData",
    "Alive", "BBUserData", "AuxData", "FpgaVersionData", "FpgaCalibrationData", "RawMessage",
    "encode", "decode", "StreamParser", "HeadSettings", "ping_problem",
    "bearing_to_radians", "radians_to_bearing", "pack_bins", "unpack_bins",
]

HEADER = 0x40          # '@'
TERMINATOR = 0x0A      # LF
PC_NODE = 255
SONAR_NODE = 2
MIN_PACKET = 14        # 13-byte header + LF, no payload
MAX_PACKET = 0xFFFF + 6
FULL_TURN = 6400       # bearings count 1/16 gradian
NIBBLE_ORDERS = ("low_first", "high_first")
DEFAULT_NIBBLE_ORDER = "low_first"
# Step sizes a head can be given so that a turn closes on itself (divisors of 6400 that fit a byte).
STEP_SIZES = tuple(s for s in range(1, 256) if FULL_TURN % s == 0)

_HEX = frozenset(b"0123456789ABCDEFabcdef")


class SeaNetError(ValueError):
    """A packet that is not valid SeaNet (bad framing, length or field)."""


class MessageId(enum.IntEnum):
    """Message ids (reference section 2)."""

    mtNull = 0
    mtVersionData = 1
    mtHeadData = 2
    mtSpectData = 3
    mtAlive = 4
    mtPrgAck = 5
    mtBBUserData = 6
    mtTestData = 7
    mtAuxData = 8
    mtAdcData = 9
    mtAdcReq = 10
    mtLanStatus = 13
    mtSetTime = 14
    mtTimeout = 15
    mtReBoot = 16
    mtPerformanceData = 17
    mtHeadCommand = 19
    mtEraseSector = 20
    mtProgBlock = 21
    mtCopyBootBlk = 22
    mtSendVersion = 23
    mtSendBBUser = 24
    mtSendData = 25
    mtSendPerformanceData = 26
    mtFpgaVersionData = 57
    mtFpgaCalibrationData = 63
    mtStopAlives = 66
    mtResetToDefaults = 70


class HdCtrl(enum.IntFlag):
    """Bits of the HdCtrl word of mtHeadCommand (echoed in mtHeadData)."""

    ADC8ON = 1 << 0
    CONT = 1 << 1
    SCANRIGHT = 1 << 2
    INVERT = 1 << 3
    MOTOFF = 1 << 4
    TXOFF = 1 << 5
    SPARE = 1 << 6
    CHAN2 = 1 << 7
    RAW = 1 << 8
    HASMOT = 1 << 9
    APPLYOFFSET = 1 << 10
    PINGPONG = 1 << 11
    STARELLIM = 1 << 12
    REPLYASL = 1 << 13
    REPLYTHR = 1 << 14
    IGNORESENSOR = 1 << 15


class HeadInf(enum.IntFlag):
    """Bits of the HeadInf byte of mtAlive (LSB first, as Rock's masks and UxVCtrl read them)."""

    IN_CENTRE = 1 << 0
    CENTRED = 1 << 1
    MOTORING = 1 << 2
    MOTOR_ON = 1 << 3
    DIR = 1 << 4
    IN_SCAN = 1 << 5
    NO_PARAMS = 1 << 6
    SENT_CFG = 1 << 7


class HeadStatus(enum.IntFlag):
    """Bits of the head-status byte of mtHeadData."""

    PWR_LOSS = 1 << 0
    MOT_ERR = 1 << 1
    ADC8ON = 1 << 4
    MSG_APPENDED = 1 << 7


class SweepCode(enum.IntEnum):
    NORMAL = 0
    AT_LEFT_LIMIT = 1
    AT_RIGHT_LIMIT = 2
    AT_CENTRE = 5


# --------------------------------------------------------------------------------------------
# Bearings
# --------------------------------------------------------------------------------------------

def bearing_to_radians(bearing, invert: bool = False):
    """Simulator bearing in radians of a wire bearing (1/16 gradian, 3200 = ahead).

    ``(3200 - b) * pi / 3200``: SeaNet counts clockwise seen from above (1600 = left 90 deg),
    the simulator counter-clockwise about the beam frame's +y axis (right-handed), so left is
    positive. An inverted head (HdCtrl ``invert``) is upside down, which flips the sign.
    Returns a float for a scalar, a float64 array for an array; in (-pi, pi] for 0..6399.
    """
    b = np.asarray(bearing, dtype=np.float64)
    rad = (3200.0 - b) * (math.pi / 3200.0)
    if invert:
        rad = -rad
    return float(rad) if rad.ndim == 0 else rad


def radians_to_bearing(rad, invert: bool = False):
    """Inverse of `bearing_to_radians`: nearest wire bearing in 0..6399 (int or int64 array)."""
    r = np.asarray(rad, dtype=np.float64)
    if invert:
        r = -r
    b = np.mod(np.rint(3200.0 - r * (3200.0 / math.pi)), FULL_TURN).astype(np.int64)
    return int(b) if b.ndim == 0 else b


# --------------------------------------------------------------------------------------------
# 4-bit packing
# --------------------------------------------------------------------------------------------

def _check_nibble_order(nibble_order: str) -> str:
    if nibble_order not in NIBBLE_ORDERS:
        raise ValueError(f"nibble_order must be one of {NIBBLE_ORDERS}, got {nibble_order!r}")
    return nibble_order


def unpack_bins(data: bytes, adc8on: bool, nibble_order: str = DEFAULT_NIBBLE_ORDER) -> np.ndarray:
    """Bins of an mtHeadData payload as uint8 0..255 (4-bit nibbles scaled by 17)."""
    raw = np.frombuffer(bytes(data), dtype=np.uint8)
    if adc8on:
        return raw.copy()
    lo, hi = raw & 0x0F, raw >> 4
    first, second = (lo, hi) if _check_nibble_order(nibble_order) == "low_first" else (hi, lo)
    out = np.empty(2 * raw.size, dtype=np.uint8)
    out[0::2] = first * 17
    out[1::2] = second * 17
    return out


def pack_bins(bins, adc8on: bool, nibble_order: str = DEFAULT_NIBBLE_ORDER) -> bytes:
    """Inverse of `unpack_bins`. In 4-bit mode each level is rounded to the nearest of 0, 17, ..., 255."""
    b = np.asarray(bins)
    if b.ndim != 1:
        raise ValueError(f"bins must be one-dimensional, got shape {b.shape}")
    if b.size and (b.min() < 0 or b.max() > 255):
        raise ValueError("bins must lie in 0..255")
    b = b.astype(np.int64)
    if adc8on:
        return b.astype(np.uint8).tobytes()
    if b.size % 2:
        raise ValueError(f"4-bit data needs an even number of bins, got {b.size}")
    nib = (b + 8) // 17
    first, second = nib[0::2], nib[1::2]
    if _check_nibble_order(nibble_order) == "low_first":
        packed = first | (second << 4)
    else:
        packed = (first << 4) | second
    return packed.astype(np.uint8).tobytes()


# --------------------------------------------------------------------------------------------
# Messages
# --------------------------------------------------------------------------------------------

_REGISTRY: dict[int, type[Message]] = {}


def _fmt_size(layout) -> int:
    return struct.calcsize("<" + "".join(f for _, f in layout))


_RANGES = {"B": (0, 0xFF), "H": (0, 0xFFFF), "I": (0, 0xFFFFFFFF)}


@dataclass(kw_only=True)
class Message:
    """Common part of every SeaNet message.

    Parameters (keyword-only, all optional)
    ----------------------------------------
    ==========  =====================================================================
    src         source node; default 255 (PC) for commands, 2 (sonar) for replies
    dst         destination node; default 2 for commands, 255 for replies
    node        byte 12; default ``dst`` for commands, ``src`` for replies
    sequence    byte 11; 0x80 (single packet, last)
    count       byte 9 as on the wire; ``None`` computes it (payload + 3, 0 in mtHeadData);
                kept from decoded packets so they re-encode byte for byte; not compared
    ==========  =====================================================================
    """

    MSG_ID: ClassVar[int] = -1
    FROM_HEAD: ClassVar[bool] = False
    LAYOUT: ClassVar[tuple] = ()

    src: int | None = None
    dst: int | None = None
    node: int | None = None
    sequence: int = 0x80
    count: int | None = field(default=None, compare=False)

    def __init_subclass__(cls, **kw):
        super().__init_subclass__(**kw)
        if cls.__dict__.get("MSG_ID", -1) >= 0 and cls.__dict__.get("_PRIMARY", True):
            _REGISTRY.setdefault(cls.MSG_ID, cls)

    def __post_init__(self) -> None:
        if self.src is None:
            self.src = SONAR_NODE if self.FROM_HEAD else PC_NODE
        if self.dst is None:
            self.dst = PC_NODE if self.FROM_HEAD else SONAR_NODE
        if self.node is None:
            self.node = self.src if self.FROM_HEAD else self.dst

    @property
    def msg_id(self) -> int:
        return self.MSG_ID

    @property
    def name(self) -> str:
        try:
            return MessageId(self.msg_id).name
        except ValueError:
            return f"mt{self.msg_id}"

    def payload(self) -> bytes:
        """The bytes from offset 13 up to (not including) the LF."""
        return self._pack(self.LAYOUT)

    def _pack(self, layout) -> bytes:
        values = []
        for name, f in layout:
            v = getattr(self, name)
            lo, hi = _RANGES[f]
            if not isinstance(v, (int, np.integer)) or not lo <= int(v) <= hi:
                raise ValueError(f"{type(self).__name__}.{name} = {v!r} is outside {lo}..{hi}")
            values.append(int(v))
        return struct.pack("<" + "".join(f for _, f in layout), *values)

    @classmethod
    def _unpack(cls, layout, payload: bytes) -> dict:
        vals = struct.unpack("<" + "".join(f for _, f in layout), payload[:_fmt_size(layout)])
        return {name: v for (name, _), v in zip(layout, vals)}

    @classmethod
    def from_payload(cls, payload: bytes, **common) -> "Message":
        if len(payload) != _fmt_size(cls.LAYOUT):
            raise SeaNetError(f"{cls.__name__}: payload of {len(payload)} bytes, expected {_fmt_size(cls.LAYOUT)}")
        return cls(**cls._unpack(cls.LAYOUT, payload), **common)


# ---- commands (PC -> head) -----------------------------------------------------------------

@dataclass(kw_only=True)
class ReBoot(Message):
    """mtReBoot (16): restart the head; it re-centres and forgets its parameters."""

    MSG_ID: ClassVar[int] = MessageId.mtReBoot


@dataclass(kw_only=True)
class SendVersion(Message):
    """mtSendVersion (23): ask for mtVersionData."""

    MSG_ID: ClassVar[int] = MessageId.mtSendVersion


@dataclass(kw_only=True)
class SendBBUser(Message):
    """mtSendBBUser (24): ask for mtBBUserData (the head's stored user settings)."""

    MSG_ID: ClassVar[int] = MessageId.mtSendBBUser


@dataclass(kw_only=True)
class StopAlives(Message):
    """mtStopAlives (66, DST): stop the ~1 Hz mtAlive messages."""

    MSG_ID: ClassVar[int] = MessageId.mtStopAlives


@dataclass(kw_only=True)
class ResetToDefaults(Message):
    """mtResetToDefaults (70, DST)."""

    MSG_ID: ClassVar[int] = MessageId.mtResetToDefaults


@dataclass
class SendData(Message):
    """mtSendData (25): ask for the next scanline (one mtHeadData).

    ==========  =======================================================================
    time_ms     uint32 time sent with the request; McGill sends ms since midnight, Rock
                and UxVCtrl send 0 (the default here)
    ==========  =======================================================================
    """

    MSG_ID: ClassVar[int] = MessageId.mtSendData
    LAYOUT: ClassVar[tuple] = (("time_ms", "I"),)
    time_ms: int = 0


_HEAD_COMMAND_LAYOUT = (
    ("v3b_params", "B"), ("hd_ctrl", "H"), ("head_type", "B"),
    ("txn_ch1", "I"), ("txn_ch2", "I"), ("rxn_ch1", "I"), ("rxn_ch2", "I"),
    ("tx_pulse_length", "H"), ("range_scale", "H"), ("left_lim", "H"), ("right_lim", "H"),
    ("ad_span", "B"), ("ad_low", "B"), ("igain_ch1", "B"), ("igain_ch2", "B"),
    ("slope_ch1", "H"), ("slope_ch2", "H"), ("mo_time", "B"), ("step_size", "B"),
    ("ad_interval", "H"), ("n_bins", "H"), ("max_ad_buf", "H"), ("lockout", "H"),
    ("minor_axis", "H"), ("major_axis", "B"), ("ctl2", "B"), ("scan_z", "H"),
)
V3B_NONE = 0x01
V3B_BLOCK = 0x1D
V3B_SCAN_REVERSE = 0x0F
V3B_GAIN_ONLY = 0x1E


@dataclass
class HeadCommand(Message):
    """mtHeadCommand (19), full form: the head's scanning parameters.

    Build it with `HeadSettings.head_command` rather than by hand. Fields are the wire values
    (reference section 3): ``v3b_params`` 0x01 (no V3B block, 66-byte packet) or 0x1D (16-byte
    ``v3b_block`` appended, 82 bytes); ``hd_ctrl`` (`HdCtrl` bits); ``head_type`` 0x02 imaging,
    0x11 DST; ``txn_*``/``rxn_*`` frequency words; ``tx_pulse_length`` µs; ``range_scale``
    decimetres (+ unit bits 14-15); ``left_lim``/``right_lim`` 1/16 gradian; ``ad_span``,
    ``ad_low`` 0..255 = 0..80 dB; ``igain_*`` 0..210 = 0..80 dB; ``slope_*`` 1/255;
    ``mo_time`` 10 µs; ``step_size`` 1/16 gradian; ``ad_interval`` 640 ns; ``n_bins``;
    ``max_ad_buf``; ``lockout`` µs; ``minor_axis``, ``major_axis``, ``ctl2``, ``scan_z``.
    """

    MSG_ID: ClassVar[int] = MessageId.mtHeadCommand
    LAYOUT: ClassVar[tuple] = _HEAD_COMMAND_LAYOUT
    v3b_params: int = V3B_NONE
    hd_ctrl: int = 0
    head_type: int = 0x02
    txn_ch1: int = 0
    txn_ch2: int = 0
    rxn_ch1: int = 0
    rxn_ch2: int = 0
    tx_pulse_length: int = 0
    range_scale: int = 0
    left_lim: int = 0
    right_lim: int = 0
    ad_span: int = 0
    ad_low: int = 0
    igain_ch1: int = 0
    igain_ch2: int = 0
    slope_ch1: int = 0
    slope_ch2: int = 0
    mo_time: int = 25
    step_size: int = 32
    ad_interval: int = 0
    n_bins: int = 0
    max_ad_buf: int = 500
    lockout: int = 100
    minor_axis: int = 1600
    major_axis: int = 1
    ctl2: int = 0
    scan_z: int = 0
    v3b_block: bytes = b""

    def payload(self) -> bytes:
        if self.v3b_params == V3B_BLOCK and len(self.v3b_block) != 16:
            raise ValueError(f"HeadCommand.v3b_block must hold 16 bytes when v3b_params = 0x1D, got {len(self.v3b_block)}")
        if self.v3b_params == V3B_NONE and self.v3b_block:
            raise ValueError("HeadCommand.v3b_block must be empty when v3b_params = 0x01")
        if self.v3b_params not in (V3B_NONE, V3B_BLOCK):
            raise ValueError(f"HeadCommand.v3b_params must be 0x01 or 0x1D, got {self.v3b_params:#x} "
                             "(use ScanReverse / GainCommand for 0x0F / 0x1E)")
        return self._pack(self.LAYOUT) + bytes(self.v3b_block)

    @classmethod
    def from_payload(cls, payload: bytes, **common) -> "HeadCommand":
        n = _fmt_size(cls.LAYOUT)
        v3b = payload[0] if payload else None
        if not ((v3b == V3B_NONE and len(payload) == n) or (v3b == V3B_BLOCK and len(payload) == n + 16)):
            raise SeaNetError(f"HeadCommand: V3B byte {v3b!r} with a {len(payload)}-byte payload")
        return cls(**cls._unpack(cls.LAYOUT, payload), v3b_block=bytes(payload[n:]), **common)

    @property
    def adc8on(self) -> bool:
        return bool(self.hd_ctrl & HdCtrl.ADC8ON)

    @property
    def continuous(self) -> bool:
        return bool(self.hd_ctrl & HdCtrl.CONT)

    @property
    def invert(self) -> bool:
        return bool(self.hd_ctrl & HdCtrl.INVERT)

    @property
    def scan_right(self) -> bool:
        return bool(self.hd_ctrl & HdCtrl.SCANRIGHT)

    @property
    def data_bytes(self) -> int:
        """Dbytes the head will send per scanline with these parameters."""
        return self.n_bins if self.adc8on else self.n_bins // 2


@dataclass
class ScanReverse(Message):
    """mtHeadCommand with V3B byte 0x0F: reverse the scan direction without re-configuring."""

    MSG_ID: ClassVar[int] = MessageId.mtHeadCommand
    _PRIMARY: ClassVar[bool] = False
    LAYOUT: ClassVar[tuple] = (("v3b_params", "B"),)
    v3b_params: int = V3B_SCAN_REVERSE


_GAIN_LAYOUT = (
    ("v3b_params", "B"), ("ad_span_ch1", "B"), ("ad_span_ch2", "B"), ("ad_low_ch1", "B"),
    ("ad_low_ch2", "B"), ("igain_ch1", "B"), ("igain_ch2", "B"), ("spare", "H"),
    ("slope_ch1", "H"), ("slope_ch2", "H"), ("slope_delay_ch1", "H"), ("slope_delay_ch2", "H"),
)


@dataclass
class GainCommand(Message):
    """mtHeadCommand with V3B byte 0x1E: reduced command with gain parameters only (UxVCtrl)."""

    MSG_ID: ClassVar[int] = MessageId.mtHeadCommand
    _PRIMARY: ClassVar[bool] = False
    LAYOUT: ClassVar[tuple] = _GAIN_LAYOUT
    v3b_params: int = V3B_GAIN_ONLY
    ad_span_ch1: int = 77
    ad_span_ch2: int = 77
    ad_low_ch1: int = 40
    ad_low_ch2: int = 40
    igain_ch1: int = 73
    igain_ch2: int = 73
    spare: int = 0
    slope_ch1: int = 125
    slope_ch2: int = 125
    slope_delay_ch1: int = 0
    slope_delay_ch2: int = 0


# ---- replies (head -> PC) ------------------------------------------------------------------

@dataclass
class VersionData(Message):
    """mtVersionData (1), 25 bytes: software version, info bits, serial number, program
    length and checksum, node id (Rock's decodeVersionData)."""

    MSG_ID: ClassVar[int] = MessageId.mtVersionData
    FROM_HEAD: ClassVar[bool] = True
    LAYOUT: ClassVar[tuple] = (("software_version", "B"), ("info_bits", "B"), ("serial", "H"),
                               ("program_length", "I"), ("checksum", "H"), ("node_id", "B"))
    software_version: int = 0
    info_bits: int = 0
    serial: int = 0
    program_length: int = 0
    checksum: int = 0
    node_id: int = SONAR_NODE


@dataclass
class Alive(Message):
    """mtAlive (4), 22 bytes, about 1 Hz.

    ==========  ==================================================================
    spare       byte 13 (meaning not documented publicly)
    clock_ms    head clock, ms since boot
    heading     current transducer bearing, 1/16 gradian
    head_inf    `HeadInf` bits; also exposed as the boolean properties below
    ==========  ==================================================================
    """

    MSG_ID: ClassVar[int] = MessageId.mtAlive
    FROM_HEAD: ClassVar[bool] = True
    LAYOUT: ClassVar[tuple] = (("spare", "B"), ("clock_ms", "I"), ("heading", "H"), ("head_inf", "B"))
    spare: int = 0
    clock_ms: int = 0
    heading: int = 3200
    head_inf: int = 0

    def _bit(self, flag) -> bool:
        return bool(self.head_inf & flag)

    in_centre = property(lambda self: self._bit(HeadInf.IN_CENTRE))
    centred = property(lambda self: self._bit(HeadInf.CENTRED))
    motoring = property(lambda self: self._bit(HeadInf.MOTORING))
    motor_on = property(lambda self: self._bit(HeadInf.MOTOR_ON))
    direction = property(lambda self: self._bit(HeadInf.DIR))
    in_scan = property(lambda self: self._bit(HeadInf.IN_SCAN))
    no_params = property(lambda self: self._bit(HeadInf.NO_PARAMS))
    sent_cfg = property(lambda self: self._bit(HeadInf.SENT_CFG))


@dataclass
class _Opaque(Message):
    """A reply whose payload is kept as bytes."""

    payload_bytes: bytes = b""

    def payload(self) -> bytes:
        return bytes(self.payload_bytes)

    @classmethod
    def from_payload(cls, payload: bytes, **common):
        return cls(payload_bytes=bytes(payload), **common)


BBUSER_LENGTHS = (175, 264)   # total packet lengths: original heads, DST heads


@dataclass
class BBUserData(_Opaque):
    """mtBBUserData (6): the head's stored user settings, kept opaque (175 bytes, 264 for DST).

    ``is_dst`` reads byte 19 (15 = DST, UxVCtrl); ``half_duplex`` byte 146 (DST) or 99.
    `make` builds a plausible one for the virtual sonar.
    """

    MSG_ID: ClassVar[int] = MessageId.mtBBUserData
    FROM_HEAD: ClassVar[bool] = True

    def _byte(self, offset: int) -> int:
        i = offset - 13
        return self.payload_bytes[i] if 0 <= i < len(self.payload_bytes) else 0

    @property
    def is_dst(self) -> bool:
        return self._byte(19) == 15

    @property
    def half_duplex(self) -> bool:
        return self._byte(146 if self.is_dst else 99) == 1

    @classmethod
    def make(cls, dst: bool = True, half_duplex: bool = False) -> "BBUserData":
        n = (264 if dst else 175) - 14
        p = bytearray(n)
        if dst:
            p[19 - 13] = 15
        p[(146 if dst else 99) - 13] = 1 if half_duplex else 0
        return cls(payload_bytes=bytes(p))


@dataclass
class AuxData(Message):
    """mtAuxData (8): data of an auxiliary device chained through the head (size + bytes)."""

    MSG_ID: ClassVar[int] = MessageId.mtAuxData
    FROM_HEAD: ClassVar[bool] = True
    data: bytes = b""

    def payload(self) -> bytes:
        if len(self.data) > 0xFFFF:
            raise ValueError("AuxData.data is longer than 65535 bytes")
        return struct.pack("<H", len(self.data)) + bytes(self.data)

    @classmethod
    def from_payload(cls, payload: bytes, **common):
        if len(payload) < 2 or struct.unpack_from("<H", payload)[0] != len(payload) - 2:
            raise SeaNetError("AuxData: size field does not match the packet length")
        return cls(data=bytes(payload[2:]), **common)


@dataclass
class FpgaVersionData(_Opaque):
    """mtFpgaVersionData (57, DST, follows mtBBUserData), kept opaque."""

    MSG_ID: ClassVar[int] = MessageId.mtFpgaVersionData
    FROM_HEAD: ClassVar[bool] = True


@dataclass
class FpgaCalibrationData(_Opaque):
    """mtFpgaCalibrationData (63, DST, follows mtBBUserData), kept opaque."""

    MSG_ID: ClassVar[int] = MessageId.mtFpgaCalibrationData
    FROM_HEAD: ClassVar[bool] = True


@dataclass
class RawMessage(_Opaque):
    """A well-framed message of an id without a typed class here (payload kept as bytes)."""

    _PRIMARY: ClassVar[bool] = False
    message_id: int = 0

    @property
    def msg_id(self) -> int:
        return self.message_id


_HEAD_DATA_LAYOUT = (
    ("device_type", "B"), ("head_status", "B"), ("sweep_code", "B"), ("hd_ctrl", "H"),
    ("range_scale", "H"), ("txn", "I"), ("gain", "B"), ("slope", "H"), ("ad_span", "B"),
    ("ad_low", "B"), ("heading_offset", "H"), ("ad_interval", "H"), ("left_lim", "H"),
    ("right_lim", "H"), ("step_size", "B"), ("bearing", "H"),
)
_HEAD_DATA_FIXED = 2 + _fmt_size(_HEAD_DATA_LAYOUT) + 2     # count + fields + Dbytes = 31


@dataclass
class HeadData(Message):
    """mtHeadData (2): one scanline of an imaging head (reference section 4).

    ================  ==============================================================
    bearing           transducer bearing, 1/16 gradian, 0..6399, 3200 = ahead
    data              the Dbytes data bytes as on the wire (packed nibbles in 4-bit)
    device_type       byte 15 (0x11 DST, 0x02 imaging)
    head_status       `HeadStatus` bits (motor error, power loss, adc8on)
    sweep_code        0 normal, 1 at left limit, 2 at right limit, 5 at centre
    hd_ctrl           HdCtrl echo (``adc8on`` decides 8- or 4-bit data)
    range_scale       decimetres (+ unit bits), informational
    txn, gain, slope  transmitter word, receiver gain 0..210, slope
    ad_span, ad_low   0..255 = 0..80 dB
    heading_offset    1/16 gradian
    ad_interval       sample interval in 640 ns units (bin range = c * interval / 2)
    left_lim,         sector limits, 1/16 gradian
    right_lim
    step_size         motor step, 1/16 gradian
    nibble_order      how ``bins`` unpacks 4-bit data (not on the wire)
    ================  ==============================================================

    ``bins`` (uint8 0..255, 4-bit levels scaled by 17) and ``n_bins`` are derived from
    ``data``; `from_bins` packs bins into a message.
    """

    MSG_ID: ClassVar[int] = MessageId.mtHeadData
    FROM_HEAD: ClassVar[bool] = True
    LAYOUT: ClassVar[tuple] = _HEAD_DATA_LAYOUT
    bearing: int = 3200
    data: bytes = b""
    device_type: int = 0x11
    head_status: int = 0
    sweep_code: int = 0
    hd_ctrl: int = int(HdCtrl.ADC8ON | HdCtrl.CONT | HdCtrl.RAW | HdCtrl.HASMOT | HdCtrl.REPLYASL)
    range_scale: int = 0
    txn: int = 0
    gain: int = 0
    slope: int = 0
    ad_span: int = 0
    ad_low: int = 0
    heading_offset: int = 0
    ad_interval: int = 0
    left_lim: int = 0
    right_lim: int = 0
    step_size: int = 32
    nibble_order: str = field(default=DEFAULT_NIBBLE_ORDER, compare=False)

    def payload(self) -> bytes:
        if not 0 <= self.bearing < FULL_TURN:
            raise ValueError(f"HeadData.bearing = {self.bearing} is outside 0..6399")
        d = bytes(self.data)
        if len(d) + _HEAD_DATA_FIXED > 0xFFFF:
            raise ValueError("HeadData.data is too long")
        return (struct.pack("<H", len(d) + _HEAD_DATA_FIXED) + self._pack(self.LAYOUT)
                + struct.pack("<H", len(d)) + d)

    @classmethod
    def from_payload(cls, payload: bytes, nibble_order: str = DEFAULT_NIBBLE_ORDER, **common):
        if len(payload) < _HEAD_DATA_FIXED:
            raise SeaNetError("HeadData: packet too short for the imaging-head layout")
        total, = struct.unpack_from("<H", payload, 0)
        dbytes, = struct.unpack_from("<H", payload, _HEAD_DATA_FIXED - 2)
        if total != len(payload) or dbytes != len(payload) - _HEAD_DATA_FIXED:
            raise SeaNetError(f"HeadData: byte count {total} / Dbytes {dbytes} do not match a "
                              f"{len(payload) + 14}-byte packet")
        vals = cls._unpack(cls.LAYOUT, payload[2:])
        if vals["bearing"] >= FULL_TURN:
            raise SeaNetError(f"HeadData: bearing {vals['bearing']} is outside 0..6399")
        return cls(**vals, data=bytes(payload[_HEAD_DATA_FIXED:]), nibble_order=nibble_order, **common)

    @property
    def adc8on(self) -> bool:
        return bool(self.hd_ctrl & HdCtrl.ADC8ON)

    @property
    def n_bins(self) -> int:
        return len(self.data) if self.adc8on else 2 * len(self.data)

    @property
    def bins(self) -> np.ndarray:
        return unpack_bins(self.data, self.adc8on, self.nibble_order)

    @property
    def sampling_interval(self) -> float:
        """Seconds between bins (ADInterval x 640 ns)."""
        return self.ad_interval * 640e-9

    def bin_width(self, sound_speed: float = 1500.0) -> float:
        """Range covered by one bin in metres."""
        return sound_speed * self.sampling_interval / 2.0

    @property
    def motor_error(self) -> bool:
        return bool(self.head_status & HeadStatus.MOT_ERR)

    @property
    def power_loss(self) -> bool:
        return bool(self.head_status & HeadStatus.PWR_LOSS)

    @classmethod
    def from_bins(cls, bins, *, adc8on: bool = True, nibble_order: str = DEFAULT_NIBBLE_ORDER, **fields_):
        """HeadData carrying ``bins`` (uint8 0..255), packed as the head would."""
        hd = int(fields_.pop("hd_ctrl", cls.hd_ctrl))
        hd = (hd | HdCtrl.ADC8ON) if adc8on else (hd & ~HdCtrl.ADC8ON)
        return cls(data=pack_bins(bins, adc8on, nibble_order), hd_ctrl=int(hd),
                   nibble_order=nibble_order, **fields_)


# --------------------------------------------------------------------------------------------
# encode / decode
# --------------------------------------------------------------------------------------------

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


# --------------------------------------------------------------------------------------------
# Settings -> mtHeadCommand
# --------------------------------------------------------------------------------------------

def _round(x: float) -> int:
    # Half up, not Python's half-to-even: ADSpan for 24 dB is 76.5 -> 77 as drivers send it.
    return int(math.floor(x + 0.5))


# The receiver's scales on the wire: IGain 0..210 and ADLow/ADSpan 0..255 both span 0..80 dB.
DB_FULL_SCALE, GAIN_FULL_SCALE, AD_FULL_SCALE = 80.0, 210, 255


# Sound speeds a head can be set to (m/s), and how messages word the bound: HeadSettings, the
# replay of a log and the CLI's --sound-speed all use these.
SOUND_SPEED_RANGE = (1300.0, 1800.0)
SOUND_SPEED_ALLOWED = "1300..1800 m/s"


def sound_speed_ok(value) -> bool:
    """Is ``value`` a finite number in `SOUND_SPEED_RANGE`?"""
    lo, hi = SOUND_SPEED_RANGE
    return (isinstance(value, (int, float, np.integer, np.floating)) and not isinstance(value, bool)
            and math.isfinite(value) and lo <= value <= hi)


def gain_db(byte: int) -> float:
    """An IGain byte in dB."""
    return int(byte) * DB_FULL_SCALE / GAIN_FULL_SCALE


def ad_db(byte: int) -> float:
    """An ADLow or ADSpan byte in dB."""
    return int(byte) * DB_FULL_SCALE / AD_FULL_SCALE


def require_mechanical(scan, who: str, lacks: str) -> None:
    """SeaNet speaks for mechanically scanned heads only: refuse other scan kinds in one sentence."""
    kind = getattr(scan, "kind", "mechanical")
    if kind != "mechanical":
        raise ValueError(f"{who}: a SeaNet head is mechanically scanned; a {kind!r} scan (kind must be "
                         f"'mechanical') has {lacks}")


@dataclass
class HeadSettings:
    """Scanning parameters of a Micron-class head, in engineering units.

    Parameters
    ----------
    ===============  ===========  ==============================================================
    name             default      meaning, allowed values
    ===============  ===========  ==============================================================
    range            12.0         range scale, m; 0.3..300
    n_bins           500          bins per scanline; 2..1500 (even in 4-bit mode)
    sound_speed      1500.0       m/s; 1300..1800 (turns range into ADInterval)
    gain             27.8         receiver initial gain, dB; 0..80 (IGain = 210 gain / 80)
    ad_low           12.5         dB mapped to level 0 (4-bit data); 0..80 (ADLow = 255 x / 80)
    ad_span          24.0         dB mapped onto the levels (4-bit data); >0..80
    step_size        32           motor step, 1/16 gradian (32 = 1.8 deg); a divisor of 6400
                                  up to 200 (4, 8, 16, 32 are the head's named resolutions)
    continuous       True         full turns; False scans the sector left_limit..right_limit
    left_limit       2400         sector start, 1/16 gradian (0..6399, 3200 ahead, 1600 left)
    right_limit      4000         sector end; the sector runs clockwise (increasing) from
                                  left to right and its width must be a multiple of step_size
    scan_right       False        step clockwise (increasing wire bearing). False steps
                                  counter-clockwise: increasing simulator bearing
    bit_depth        8            8 (adc8on) or 4 (packed nibbles, ADLow/ADSpan applied)
    invert           False        head mounted upside down (flips the bearing sign)
    frequency        675e3        transmit frequency, Hz; 100e3..2e6 (TxN/RxN words)
    channel          1            1 or 2 (chan2 bit, dual-frequency heads)
    slope            None         TVG slope, 1/255 units; None: 100 for DST, 125 otherwise
    mo_time          25           motor step delay, 10 µs units; 1..255
    lockout          100          lockout after transmit, µs; 0..65535
    max_ad_buf       500          MaxADbuf, 1..1000 (the reference's default; Rock and
                                  UxVCtrl send 1000)
    v3b              False        append the 16-byte V3B gain block (V3B byte 0x1D)
    ===============  ===========  ==============================================================

    Derived wire values: ``ad_interval`` (round(2 range / n_bins / c / 640 ns), must be 5..1500),
    ``igain``, ``ad_low_byte``, ``ad_span_byte``, ``range_scale``, ``tx_pulse_length``,
    ``hd_ctrl``, ``txn``, ``rxn``. ``bin_width`` and ``range_max`` are the actual values after
    ADInterval's rounding. Out-of-range values raise ValueError naming the field.
    """

    range: float = 12.0
    n_bins: int = 500
    sound_speed: float = 1500.0
    gain: float = 27.8
    ad_low: float = 12.5
    ad_span: float = 24.0
    step_size: int = 32
    continuous: bool = True
    left_limit: int = 2400
    right_limit: int = 4000
    scan_right: bool = False
    bit_depth: int = 8
    invert: bool = False
    frequency: float = 675e3
    channel: int = 1
    slope: int | None = None
    mo_time: int = 25
    lockout: int = 100
    max_ad_buf: int = 500
    v3b: bool = False

    def __post_init__(self) -> None:
        self.validate()

    @staticmethod
    def _need(ok: bool, name: str, value, allowed: str) -> None:
        if not ok:
            raise ValueError(f"HeadSettings.{name} = {value!r} is out of range: allowed {allowed}")

    def validate(self) -> None:
        """Raise ValueError naming the first field outside its allowed values."""
        n = self._need

        def num(v):
            return isinstance(v, (int, float, np.integer, np.floating)) and not isinstance(v, bool) and math.isfinite(v)

        def integer(v):
            return isinstance(v, (int, np.integer)) and not isinstance(v, bool)

        n(num(self.range) and 0.3 <= self.range <= 300.0, "range", self.range, "0.3..300 m")
        n(integer(self.n_bins) and 2 <= self.n_bins <= 1500, "n_bins", self.n_bins, "2..1500")
        n(sound_speed_ok(self.sound_speed), "sound_speed", self.sound_speed, SOUND_SPEED_ALLOWED)
        n(num(self.gain) and 0.0 <= self.gain <= 80.0, "gain", self.gain, "0..80 dB")
        n(num(self.ad_low) and 0.0 <= self.ad_low <= 80.0, "ad_low", self.ad_low, "0..80 dB")
        n(num(self.ad_span) and 0.0 < self.ad_span <= 80.0 and self.ad_span_byte >= 1,
          "ad_span", self.ad_span, "0.16..80 dB (ADSpan 1..255)")
        n(integer(self.step_size) and self.step_size in STEP_SIZES, "step_size", self.step_size,
          "a divisor of 6400 in 1..200, 1/16 gradian (4, 8, 16, 32 = 0.225, 0.45, 0.9, 1.8 deg)")
        n(isinstance(self.continuous, (bool, np.bool_)), "continuous", self.continuous, "True or False")
        n(integer(self.left_limit) and 0 <= self.left_limit < FULL_TURN, "left_limit", self.left_limit, "0..6399")
        n(integer(self.right_limit) and 0 <= self.right_limit < FULL_TURN, "right_limit", self.right_limit, "0..6399")
        if not self.continuous:
            width = self.sector_width
            n(width > 0 and width % self.step_size == 0, "right_limit", self.right_limit,
              f"a sector (right_limit - left_limit) mod 6400 that is a positive multiple of "
              f"step_size {self.step_size} (now {width})")
        n(self.bit_depth in (8, 4) and integer(self.bit_depth), "bit_depth", self.bit_depth, "8 or 4")
        if self.bit_depth == 4:
            n(self.n_bins % 2 == 0, "n_bins", self.n_bins, "an even number with bit_depth 4")
        n(num(self.frequency) and 100e3 <= self.frequency <= 2e6, "frequency", self.frequency, "100e3..2e6 Hz")
        n(self.channel in (1, 2), "channel", self.channel, "1 or 2")
        n(self.slope is None or (integer(self.slope) and 0 <= self.slope <= 0xFFFF), "slope", self.slope,
          "None or 0..65535")
        n(integer(self.mo_time) and 1 <= self.mo_time <= 255, "mo_time", self.mo_time, "1..255 (10 µs)")
        n(integer(self.lockout) and 0 <= self.lockout <= 0xFFFF, "lockout", self.lockout, "0..65535 µs")
        n(integer(self.max_ad_buf) and 1 <= self.max_ad_buf <= 1000, "max_ad_buf", self.max_ad_buf, "1..1000")
        ad = self.ad_interval_exact
        n(5 <= _round(ad) <= 1500, "range", self.range,
          f"values giving ADInterval = 2 range / n_bins / sound_speed / 640 ns in 5..1500 "
          f"(now {ad:.1f}: change range or n_bins)")

    # ---- derived wire values ----
    @property
    def sector_width(self) -> int:
        return (self.right_limit - self.left_limit) % FULL_TURN

    @property
    def ad_interval_exact(self) -> float:
        return 2.0 * self.range / self.n_bins / self.sound_speed / 640e-9

    @property
    def ad_interval(self) -> int:
        """ADInterval (640 ns units), rounded to nearest: UxVCtrl truncates, which turns the
        49.9999... of the worked example (12 m, 500 bins) into 49."""
        return _round(self.ad_interval_exact)

    @property
    def sampling_interval(self) -> float:
        return self.ad_interval * 640e-9

    @property
    def bin_width(self) -> float:
        """Actual range per bin after ADInterval's rounding, m."""
        return self.sound_speed * self.sampling_interval / 2.0

    @property
    def range_max(self) -> float:
        """Actual end of the last bin, m (equals ``range`` up to ADInterval's rounding)."""
        return self.n_bins * self.bin_width

    @property
    def data_bytes(self) -> int:
        return self.n_bins if self.bit_depth == 8 else self.n_bins // 2

    @property
    def igain(self) -> int:
        return min(GAIN_FULL_SCALE, _round(GAIN_FULL_SCALE * self.gain / DB_FULL_SCALE))

    @property
    def ad_low_byte(self) -> int:
        return min(AD_FULL_SCALE, _round(AD_FULL_SCALE * self.ad_low / DB_FULL_SCALE))

    @property
    def ad_span_byte(self) -> int:
        return min(AD_FULL_SCALE, _round(AD_FULL_SCALE * self.ad_span / DB_FULL_SCALE))

    @property
    def range_scale(self) -> int:
        return min(0x3FFF, _round(self.range * 10.0))

    @property
    def tx_pulse_length(self) -> int:
        """Transmit pulse, µs: (range + 10) x 25 / 10 clamped to 37..350 (UxVCtrl)."""
        return int(min(350, max(37, _round((self.range + 10.0) * 25.0 / 10.0))))

    @property
    def txn(self) -> int:
        # Truncated like UxVCtrl's constants (675 kHz -> 0x05666666, RxN 0x090A3D70).
        return int(self.frequency * 2 ** 32 / 32e6) & 0xFFFFFFFF

    @property
    def rxn(self) -> int:
        return int((self.frequency + 455e3) * 2 ** 32 / 32e6) & 0xFFFFFFFF

    @property
    def hd_ctrl(self) -> int:
        """HdCtrl: raw | hasmot | ReplyASL as UxVCtrl, plus the flags of these settings."""
        h = HdCtrl.RAW | HdCtrl.HASMOT | HdCtrl.REPLYASL
        if self.bit_depth == 8:
            h |= HdCtrl.ADC8ON
        if self.continuous:
            h |= HdCtrl.CONT
        if self.scan_right:
            h |= HdCtrl.SCANRIGHT
        if self.invert:
            h |= HdCtrl.INVERT
        if self.channel == 2:
            h |= HdCtrl.CHAN2
        return int(h)

    def head_command(self, dst: bool = False) -> HeadCommand:
        """The mtHeadCommand for these settings; ``dst`` selects head type 0x11 and slope 100."""
        slope = self.slope if self.slope is not None else (100 if dst else 125)
        block = b""
        if self.v3b:
            block = struct.pack("<8B4H", self.ad_span_byte, self.ad_span_byte, self.ad_low_byte,
                                self.ad_low_byte, self.igain, self.igain, 0, 0, slope, slope, 0, 0)
        return HeadCommand(
            v3b_params=V3B_BLOCK if self.v3b else V3B_NONE, hd_ctrl=self.hd_ctrl,
            head_type=0x11 if dst else 0x02, txn_ch1=self.txn, txn_ch2=self.txn,
            rxn_ch1=self.rxn, rxn_ch2=self.rxn, tx_pulse_length=self.tx_pulse_length,
            range_scale=self.range_scale, left_lim=self.left_limit, right_lim=self.right_limit,
            ad_span=self.ad_span_byte, ad_low=self.ad_low_byte, igain_ch1=self.igain,
            igain_ch2=self.igain, slope_ch1=slope, slope_ch2=slope, mo_time=self.mo_time,
            step_size=self.step_size, ad_interval=self.ad_interval, n_bins=self.n_bins,
            max_ad_buf=self.max_ad_buf, lockout=self.lockout, v3b_block=block)

    @classmethod
    def from_command(cls, cmd: HeadCommand, sound_speed: float = 1500.0) -> "HeadSettings":
        """Settings a head would infer from ``cmd`` (the virtual sonar's view of the host).

        The range comes from ADInterval and ``sound_speed`` (RangeScale is informational).
        Raises ValueError when the command asks for something outside the allowed values.
        """
        h = HdCtrl(cmd.hd_ctrl)
        freq = cmd.txn_ch2 if h & HdCtrl.CHAN2 else cmd.txn_ch1
        freq_hz = freq * 32e6 / 2 ** 32
        slope = cmd.slope_ch2 if h & HdCtrl.CHAN2 else cmd.slope_ch1
        return cls(
            range=cmd.n_bins * cmd.ad_interval * 640e-9 * sound_speed / 2.0, n_bins=cmd.n_bins,
            sound_speed=sound_speed, gain=gain_db(cmd.igain_ch2 if h & HdCtrl.CHAN2 else cmd.igain_ch1),
            ad_low=ad_db(cmd.ad_low), ad_span=ad_db(max(cmd.ad_span, 1)),
            step_size=cmd.step_size, continuous=bool(h & HdCtrl.CONT), left_limit=cmd.left_lim,
            right_limit=cmd.right_lim, scan_right=bool(h & HdCtrl.SCANRIGHT),
            bit_depth=8 if h & HdCtrl.ADC8ON else 4, invert=bool(h & HdCtrl.INVERT),
            frequency=freq_hz if 100e3 <= freq_hz <= 2e6 else 675e3,
            channel=2 if h & HdCtrl.CHAN2 else 1, slope=slope, mo_time=max(1, cmd.mo_time),
            lockout=cmd.lockout, max_ad_buf=min(max(cmd.max_ad_buf, 1), 1000),
            v3b=cmd.v3b_params == V3B_BLOCK)

    @classmethod
    def from_scan(cls, scan, **overrides) -> "HeadSettings":
        """Settings under which a head reproduces ``scan`` (a `mitsonar.scan.Scan`) on the wire.

        Range and bins come from the scan's range window (the head's bins always start at
        0 m), the step size and direction from its bearings, a sector from its first and
        last bearing when it does not cover a full turn, the bit depth, receiver gain and A/D
        window (``bit_depth``, ``gain``, ``ad_low``, ``ad_span``) from ``scan.electronics`` where it
        records them (a rendered scan's `Electronics`, a received scan's reply headers). Keyword
        arguments override any field.
        """
        require_mechanical(scan, "HeadSettings.from_scan", "no head settings")
        bw = float(scan.range_max - scan.range_min) / scan.n_bins
        n_bins = int(round(scan.range_max / bw))
        bear = np.asarray(scan.bearings, dtype=np.float64)
        step_rad = float(np.median(np.diff(bear))) if bear.size > 1 else math.radians(1.8)
        step = int(round(abs(step_rad) * 3200.0 / math.pi)) or 32
        invert = bool(overrides.get("invert", False))
        # Simulator bearing increasing = wire bearing decreasing (for an upright head).
        scan_right = (step_rad < 0) != invert
        full = bear.size * step >= FULL_TURN
        kw: dict[str, Any] = dict(range=n_bins * bw, n_bins=n_bins, sound_speed=float(scan.sound_speed),
                                  step_size=step, scan_right=scan_right, continuous=full,
                                  bit_depth=int(scan.electronics.get("bit_depth", 8)) if scan.electronics else 8)
        for name in ("gain", "ad_low", "ad_span"):
            if scan.electronics and scan.electronics.get(name) is not None:
                kw[name] = float(scan.electronics[name])
        if not full:
            first, last = radians_to_bearing(bear[0], invert), radians_to_bearing(bear[-1], invert)
            kw["left_limit"], kw["right_limit"] = (first, last) if scan_right else (last, first)
        kw.update(overrides)
        return cls(**kw)

    def as_dict(self) -> dict:
        """JSON-friendly field values."""
        return {f.name: (getattr(self, f.name).item() if isinstance(getattr(self, f.name), np.generic)
                         else getattr(self, f.name)) for f in fields(self)}

    def expected_step_time(self, baudrate: int = 115200, motor_time: float = 0.0065) -> float:
        """Seconds per scanline: request + 2R/c + reply transfer + motor (reference timing model)."""
        return (18 * 10 / baudrate + self.n_bins * self.sampling_interval
                + (45 + self.data_bytes) * 10 / baudrate + motor_time)


def ping_problem(ping: HeadData, command: HeadCommand | None) -> str | None:
    """Why ``ping`` should not be used with ``command`` in force, or None.

    Motor error and power loss in the head status mean the parameters must be sent again;
    a scanline whose echoed settings differ from the command (ADInterval, bins, step,
    AD low/span, the cont/adc8on/invert bits, sector limits) was made under other
    parameters. Scan-right is not compared: Micron DST heads always report it set (Rock).
    """
    if ping.motor_error:
        return "head reports a motor error"
    if ping.power_loss:
        return "head reports a power loss"
    if command is None:
        return None
    mask = HdCtrl.CONT | HdCtrl.ADC8ON | HdCtrl.INVERT
    if (ping.hd_ctrl & mask) != (command.hd_ctrl & mask):
        return "HdCtrl (cont/adc8on/invert) differs from the command"
    if ping.n_bins != command.n_bins:
        return f"{ping.n_bins} bins instead of {command.n_bins}"
    if ping.ad_interval != command.ad_interval:
        return f"ADInterval {ping.ad_interval} instead of {command.ad_interval}"
    if ping.step_size != command.step_size:
        return f"step size {ping.step_size} instead of {command.step_size}"
    if ping.ad_low != command.ad_low or ping.ad_span != command.ad_span:
        return "ADLow/ADSpan differ from the command"
    if not command.continuous and (ping.left_lim, ping.right_lim) != (command.left_lim, command.right_lim):
        return "sector limits differ from the command"
    return None


def __getattr__(name):
    # The issue lists the driver with the codec's names; import it lazily so the codec stays
    # pure (no pyserial, no I/O) for everyone who does not ask for it.
    if name in ("MicronSonar", "SonarError", "SonarTimeout"):
        from . import micron
        return getattr(micron, name)
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
