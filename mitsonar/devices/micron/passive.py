"""Passive recording of a SeaNet head: listen on a tap of its transmit line, log every byte.

Needs no driver (nothing is sent); the log (`mitsonar.devices.rawlog` format) holds the settings
and pose given, for `mitsonar.devices.recording.replay`.
"""
from __future__ import annotations

import time

from mitsonar.devices.micron.assembler import check_pose
from mitsonar.devices.micron.seanet.constants import DEFAULT_NIBBLE_ORDER
from mitsonar.devices.micron.seanet.settings import HeadSettings
from mitsonar.devices.micron.seanet.stream import StreamParser
from mitsonar.devices.rawlog import RawLogWriter
from mitsonar.devices.recording import finish_recording
from mitsonar.devices.transports import SonarError, open_serial

__all__ = ["record_passive"]


def record_passive(port, path, seconds: float, *, baudrate: int = 115200,
                   settings: HeadSettings | None = None, pose=None) -> dict:
    """Listen on ``port`` for ``seconds`` (or until Ctrl-C) and log every byte received.

    For a tap on the head's transmit line: nothing is sent. ``settings`` and ``pose`` are
    stored in the log's header for `replay`. The log is written under a temporary name and
    renamed at the end (`finish_recording`: removed if no packet arrived). Returns
    ``{"bytes_rx", "bytes_tx", "pings", "scans"}`` (only ``bytes_rx`` counts here).
    """
    settings = settings or HeadSettings()
    out = {"bytes_rx": 0, "bytes_tx": 0, "pings": 0, "scans": 0}
    meta = {"format": "mitsonar seanet raw log", "port": str(port), "baudrate": baudrate,
            "sound_speed": settings.sound_speed, "nibble_order": DEFAULT_NIBBLE_ORDER,
            "settings": settings.as_dict(), "pose": check_pose(pose).tolist(), "passive": True}
    ser = open_serial(port, baudrate, timeout=0.1)
    parser = StreamParser()      # only counts packets: the log keeps the bytes as they came
    error = None
    try:
        log = RawLogWriter(path, meta, temporary=True)
    except BaseException:
        ser.close()
        raise
    started = time.monotonic()
    end = started + seconds
    try:
        while time.monotonic() < end:
            try:
                data = ser.read(max(1, ser.in_waiting))
            except Exception as e:
                raise SonarError(f"{port}: read failed: {e}") from None
            log.rx(data)
            parser.feed(data)
    except KeyboardInterrupt:
        pass
    except BaseException as e:      # noqa: BLE001 - finish_recording re-raises it
        error = e
    finally:
        ser.close()
    parser.flush()
    out["bytes_rx"] = log.bytes_rx
    finish_recording(log, port, started, parser.packets, error)
    return out

