"""SeaNet serial protocol of Tritech heads (Micron, MiniKing, SeaKing): a pure codec.

Bytes in, typed messages out, and back; no I/O, no pyserial. The field layout follows
``reference/seanet.md`` (compiled from the Rock, UxVCtrl and McGill drivers).

Submodules (this package gathers their public names, so ``from mitsonar.devices.micron.seanet import X`` and
``mitsonar.devices.micron.seanet.X`` work for all of them):

=============  ==============================================================================
constants      node numbers, packet bounds, `MessageId`, `HdCtrl`, `HeadInf`, `HeadStatus`,
               `SweepCode`, `SeaNetError`, `bearing_to_radians`, `radians_to_bearing`,
               `pack_bins`, `unpack_bins` (4-bit nibble order: see that module)
messages       the message dataclasses: commands `ReBoot`, `SendVersion`, `SendBBUser`,
               `SendData`, `HeadCommand`, `ScanReverse`, `GainCommand`, `StopAlives`,
               `ResetToDefaults`; replies `VersionData`, `HeadData`, `Alive`, `BBUserData`,
               `AuxData`, `FpgaVersionData`, `FpgaCalibrationData`; `RawMessage`
stream         `encode`, `decode` (one whole packet), `StreamParser` (streaming, resynchronising)
settings       `HeadSettings` (builds `HeadCommand`: ADInterval, TxN, pulse length, ...),
               `ping_problem`, gain scales, sound-speed bounds
=============  ==============================================================================

The serial driver is `mitsonar.devices.micron.driver.MicronSonar` (with `SonarError`, `SonarTimeout`): the
codec imports nothing above itself, so it does not re-export the driver.
"""
from __future__ import annotations

from mitsonar.devices.micron.seanet.constants import (DEFAULT_NIBBLE_ORDER, FULL_TURN, HEADER, MAX_PACKET, MIN_PACKET,
                        NIBBLE_ORDERS, PC_NODE, SONAR_NODE, STEP_SIZES, TERMINATOR, HdCtrl, HeadInf,
                        HeadStatus, MessageId, SeaNetError, SweepCode, bearing_to_radians, pack_bins,
                        radians_to_bearing, unpack_bins)
from mitsonar.devices.micron.seanet.messages import (_HEAD_COMMAND_LAYOUT, BBUSER_LENGTHS, V3B_BLOCK, V3B_GAIN_ONLY, V3B_NONE,
                       V3B_SCAN_REVERSE, Alive, AuxData, BBUserData, FpgaCalibrationData,
                       FpgaVersionData, GainCommand, HeadCommand, HeadData, Message, RawMessage, ReBoot,
                       ResetToDefaults, ScanReverse, SendBBUser, SendData, SendVersion, StopAlives,
                       VersionData)
from mitsonar.devices.micron.seanet.settings import (AD_FULL_SCALE, DB_FULL_SCALE, GAIN_FULL_SCALE, SOUND_SPEED_ALLOWED,
                       SOUND_SPEED_RANGE, HeadSettings, ad_db, gain_db, ping_problem, require_mechanical,
                       sound_speed_ok)
from mitsonar.devices.micron.seanet.stream import StreamParser, decode, encode

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

_DRIVER_NAMES = ("MicronSonar", "SonarError", "SonarTimeout")


def __getattr__(name):
    # The driver's names used to be re-exported here, which made the codec import the driver
    # and the driver the codec. Say where they live instead of importing them.
    if name in _DRIVER_NAMES:
        raise AttributeError(f"mitsonar.devices.micron.seanet.{name} is gone: import {name} from mitsonar.devices.micron.driver "
                             f"(the codec does not import the driver)")
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
