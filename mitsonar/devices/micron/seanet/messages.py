"""SeaNet messages: one dataclass per message type, each packing and unpacking its payload.

Field layouts follow ``reference/seanet.md`` (sections 2-5, compiled from the Rock, UxVCtrl
and McGill drivers). ``encode(msg)`` (`mitsonar.devices.micron.seanet.stream`) turns any of them into a
packet; ``decode``/`StreamParser` make them from bytes. No I/O.

Commands (PC -> head): `ReBoot`, `SendVersion`, `SendBBUser`, `SendData`, `HeadCommand`,
`ScanReverse`, `GainCommand`, `StopAlives`, `ResetToDefaults`. Replies (head -> PC):
`VersionData`, `HeadData`, `Alive`, `BBUserData`, `AuxData`, `FpgaVersionData`,
`FpgaCalibrationData`; `RawMessage` for ids without a typed class.
"""
from __future__ import annotations

import struct
from dataclasses import dataclass, field
from typing import ClassVar

import numpy as np

from mitsonar.acoustics.water import SOUND_SPEED
from mitsonar.devices.micron.seanet.constants import (DEFAULT_NIBBLE_ORDER, FULL_TURN, PC_NODE, SONAR_NODE, HdCtrl, HeadInf,
                        HeadStatus, MessageId, SeaNetError, pack_bins, unpack_bins)

__all__ = [
    "Message", "ReBoot", "SendVersion", "SendBBUser", "SendData", "StopAlives", "ResetToDefaults",
    "HeadCommand", "ScanReverse", "GainCommand", "VersionData", "HeadData", "Alive", "BBUserData",
    "AuxData", "FpgaVersionData", "FpgaCalibrationData", "RawMessage", "BBUSER_LENGTHS",
    "V3B_NONE", "V3B_BLOCK", "V3B_SCAN_REVERSE", "V3B_GAIN_ONLY",
]

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

    def bin_width(self, sound_speed: float = SOUND_SPEED) -> float:
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

