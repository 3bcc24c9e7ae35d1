"""SeaNet constants, flags, bearings and 4-bit packing: the lowest layer of the codec.

Node numbers, packet bounds, the 1/16-gradian bearing unit (``reference/seanet.md`` sections
1-5), the message ids and flag words, the wire-bearing <-> simulator-bearing conversion and the
packing of 4-bit bins. No I/O, nothing of mitsonar imported.

4-bit nibble order: with ``adc8on`` clear the head packs two bins per byte. Rock takes the low
nibble first, UxVCtrl the high nibble first; no public byte log of a real head settles it. The
order is a setting (``nibble_order``: ``"low_first"`` or ``"high_first"``) of `StreamParser`,
`decode`, `HeadData` and the virtual sonar; the default is ``"low_first"`` (Rock's, whose driver
was used with Micron DST heads and scales by 17 as ``bins`` does).
"""
from __future__ import annotations

import enum
import math

import numpy as np

__all__ = [
    "HEADER", "TERMINATOR", "PC_NODE", "SONAR_NODE", "MIN_PACKET", "MAX_PACKET", "FULL_TURN",
    "NIBBLE_ORDERS", "DEFAULT_NIBBLE_ORDER", "STEP_SIZES",
    "MessageId", "HdCtrl", "HeadInf", "HeadStatus", "SweepCode", "SeaNetError",
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
