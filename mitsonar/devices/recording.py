"""Recording and replaying a head's raw byte stream: `replay`, and the passive part of recording.

`mitsonar.devices.micron.driver.record` and `mitsonar.devices.ping360.driver.record` drive a head and log every byte
(`mitsonar.devices.rawlog` format; the header's ``head`` says which: ``ping360``, else a SeaNet head); a
passive recording (`record_passive`: a tap on the head's transmit line) needs no driver and
lives here. `replay` turns a log back into the scans the driver returned while recording,
with the same assembler and the same rule for usable pings (`ping_problem`: a Micron's
`ScanAssembler`, a Ping360's `Ping360Assembler`). This module does not import the drivers.
"""
from __future__ import annotations

import time
import warnings
from pathlib import Path

import numpy as np

from mitsonar.devices.micron.assembler import ScanAssembler, check_pose
from mitsonar.devices.ping360.head import LIMITS as PING360_LIMITS, Ping360Assembler, Ping360Settings
from mitsonar.devices.ping360.head import ping_problem as ping360_problem
from mitsonar.devices.ping360.protocol import StreamParser as PingStreamParser, ids as ping_ids
from mitsonar.devices.rawlog import POSE, RX, TX, LogDamageWarning, RawLogWriter, read_log
from mitsonar.scan import Scan
from mitsonar.devices.micron.seanet.constants import DEFAULT_NIBBLE_ORDER
from mitsonar.devices.micron.seanet.messages import HeadCommand, HeadData
from mitsonar.devices.micron.seanet.settings import SOUND_SPEED_ALLOWED, HeadSettings, ping_problem, sound_speed_ok
from mitsonar.devices.micron.seanet.stream import StreamParser
from mitsonar.devices.transports import SonarError, SonarTimeout, open_serial

__all__ = ["replay", "record_passive", "record_driven", "finish_recording"]


def finish_recording(log: RawLogWriter, port, started: float, packets: int,
                     error: BaseException | None = None, protocol: str = "SeaNet") -> None:
    """End a recording: rename its log into place, or remove it when no packet came from the head.

    ``log`` was opened with ``temporary=True``; ``started`` is the `time.monotonic` of the start,
    ``packets`` the number of packets (``protocol``: SeaNet, ping-protocol) received, ``error`` what
    stopped the recording (None for a normal end or Ctrl-C). A log holding a packet is kept whatever happened (a head that
    goes quiet after data arrived loses nothing); the `SonarError` that stopped it then says
    where the log is. A log without any packet is removed and the error says so in one line:
    ``no bytes from the head on PORT in N s`` (or that the bytes formed no packet).
    """
    elapsed = time.monotonic() - started
    if packets > 0:
        log.close()
        if isinstance(error, SonarError):
            raise type(error)(f"{error}; the log keeps the {log.bytes_rx} bytes received before: "
                              f"{log.path}") from None
    else:
        log.discard()
        if error is None or isinstance(error, SonarError):
            if log.bytes_rx:
                what = (f"no {protocol} packet from the head on {port} in {elapsed:.1f} s ({log.bytes_rx} "
                        f"bytes that form none: wrong baud rate?)")
            else:
                what = f"no bytes from the head on {port} in {elapsed:.1f} s"
            if error is not None:
                why = str(error)
                what += "; " + (why[len(f"{port}: "):] if why.startswith(f"{port}: ") else why)
            raise (SonarError if error is not None and not isinstance(error, SonarTimeout)
                   else SonarTimeout)(what) from None
    if error is not None:
        raise error


def record_driven(sonar, path, seconds: float | None, scans: int | None, pings: int | None,
                  start, protocol: str = "SeaNet") -> dict:
    """The recording loop both drivers' ``record`` share: log every byte while driving ``sonar``.

    ``sonar`` is a driver made with ``start=False`` (`mitsonar.devices.micron.driver.MicronSonar`,
    `mitsonar.devices.ping360.driver.Ping360Sonar`: ``_log_meta``, ``scan``, ``read_ping``, ``stats``, ``parser``,
    ``port``); ``start()`` starts the head. Stops after ``seconds``, ``scans`` scans or ``pings``
    pings (one of them, else only Ctrl-C). The log is written under a temporary name and renamed
    at the end, or removed (`finish_recording`). Returns ``{"bytes_rx", "bytes_tx", "pings",
    "scans", "bytes_dropped"}``.
    """
    out = {"bytes_rx": 0, "bytes_tx": 0, "pings": 0, "scans": 0}
    log = RawLogWriter(path, sonar._log_meta(), temporary=True)
    sonar._log = log
    started = time.monotonic()
    end = None if seconds is None else started + seconds
    error = None
    try:
        start()
        while end is None or time.monotonic() < end:
            if scans is not None:
                sonar.scan()
                out["scans"] += 1
                if out["scans"] >= scans:
                    break
            else:
                sonar.read_ping()
                out["pings"] += 1
                if pings is not None and out["pings"] >= pings:
                    break
    except KeyboardInterrupt:
        pass
    except BaseException as e:      # noqa: BLE001 - finish_recording re-raises it
        error = e
    out["pings"] = int(sonar.stats["pings"])
    out["bytes_dropped"] = int(sonar.parser.dropped)
    out["bytes_rx"], out["bytes_tx"] = log.bytes_rx, log.bytes_tx
    finish_recording(log, sonar.port, started, sonar.parser.packets, error, protocol)
    return out


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


def replay(path, *, sound_speed: float | None = None, pose=None, nibble_order: str | None = None,
           revisit: bool | None = None, max_turns: int | None = None, partial: bool = False) -> list[Scan]:
    """Scans of a raw log, assembled exactly as `MicronSonar.scan` did while recording.

    ============  ================================================================
    path          raw log (``record``)
    sound_speed   m/s; default the log's (settings), else 1500
    pose          4x4 head mounting; default the log's pose records / header
    nibble_order  default the log's
    revisit       default the log's (True)
    max_turns     default the log's (3)
    partial       also return the unfinished scan at the end of the log, zero-filled
    ============  ================================================================

    Scanlines count once an mtHeadCommand was sent and when they match the last one sent (as
    the driver does), so a log recorded with ``record(..., scans=k)`` replays into the same
    scans the driver returned. A Ping360 log (``head: ping360``; ``nibble_order``, ``revisit``
    and ``max_turns`` do not apply) counts each ``device_data`` that answers the last
    ``transducer`` sent, as `mitsonar.devices.ping360.driver.Ping360Sonar` does.
    """
    if sound_speed is not None and not sound_speed_ok(sound_speed):
        raise ValueError(f"replay: sound_speed = {sound_speed!r} is out of range: allowed {SOUND_SPEED_ALLOWED}")
    meta, records = read_log(path)
    if meta.get("head") == "ping360":
        return _replay_ping360(path, meta, records, sound_speed, pose, partial)
    c = sound_speed or meta.get("sound_speed") or 1500.0
    if not sound_speed_ok(c):
        raise ValueError(f"{path}: the log's sound_speed = {c!r} is out of range: allowed "
                         f"{SOUND_SPEED_ALLOWED} (pass sound_speed)")
    c = float(c)
    nib = nibble_order or meta.get("nibble_order") or DEFAULT_NIBBLE_ORDER
    fixed_pose = pose is not None
    T = check_pose(pose if fixed_pose else meta.get("pose"))
    settings = None
    if isinstance(meta.get("settings"), dict):
        try:
            settings = HeadSettings(**meta["settings"])
        except (TypeError, ValueError):
            settings = None
    if settings is not None and sound_speed is not None:
        settings = None    # a different sound speed changes the range window: no snapping
    asm = ScanAssembler(c, revisit=meta.get("revisit", True) if revisit is None else revisit,
                        max_turns=int(meta.get("max_turns", 3) if max_turns is None else max_turns),
                        settings=settings)
    return _assemble(path, meta, records, asm, StreamParser(nibble_order=nib), StreamParser(nibble_order=nib),
                     lambda m: isinstance(m, HeadCommand),
                     lambda m, c: isinstance(m, HeadData) and ping_problem(m, c) is None,
                     T, fixed_pose, partial, "SeaNet packet")


def _assemble(path, meta: dict, records: list, asm, rx, tx, is_command, usable, T, fixed_pose: bool,
              partial: bool, what: str, once: bool = False) -> list[Scan]:
    """The scans the driver assembled while it recorded ``records``: what the head sent (``rx``
    parser) counts when ``usable(message, command)`` holds for the last message sent to it that
    ``is_command`` (``tx`` parser); ``once``: one reply per command, as the Ping360 driver takes
    it. Poses from the log unless ``fixed_pose``; ``LogDamageWarning`` for bytes that form no
    ``what``."""
    command = None
    scans = []
    t0 = float(meta.get("start_time", 0.0))

    def take(msgs, t):
        nonlocal command
        for m in msgs:
            if command is not None and usable(m, command):
                if once:
                    command = None
                s = asm.add(m, T, t0 + t)
                if s is not None:
                    s.meta["log"] = str(path)
                    scans.append(s)

    for t, kind, data in records:
        if kind == TX:
            for m in tx.feed(data):
                if is_command(m):
                    command = m
        elif kind == POSE and not fixed_pose and len(data) == 128:
            T = np.frombuffer(data, dtype="<f8").reshape(4, 4).copy()
        elif kind == RX:
            take(rx.feed(data), t)
    take(rx.flush(), records[-1][0] if records else 0.0)
    tx.flush()
    for parser, way in ((rx, "from"), (tx, "to")):
        if parser.dropped:
            reasons = ", ".join(f"{r}: {n}" for r, n in parser.drop_reasons.most_common(3))
            warnings.warn(LogDamageWarning(
                f"{Path(path).name}: dropped {parser.dropped} bytes {way} "
                f"the head that form no whole {what} ({reasons})"), stacklevel=3)
    if partial:
        s = asm.finish()
        if s is not None:
            s.meta["log"] = str(path)
            s.meta["partial"] = True
            scans.append(s)
    return scans


def _replay_ping360(path, meta: dict, records: list, sound_speed, pose, partial: bool) -> list[Scan]:
    """`replay` of a Ping360 log: the `Ping360Sonar.scan` results, from the logged bytes."""
    lo, hi = PING360_LIMITS["sound_speed"]
    c = sound_speed or meta.get("sound_speed") or 1500.0
    if not (isinstance(c, (int, float)) and lo <= c <= hi):
        raise ValueError(f"{path}: sound_speed = {c!r} is out of range: allowed {lo:g}..{hi:g} m/s")
    try:
        settings = Ping360Settings(**{**meta.get("settings", {}), "sound_speed": float(c)})
    except (TypeError, ValueError) as e:
        raise ValueError(f"{path}: the log's Ping360 settings are unusable ({e})") from None
    fixed_pose = pose is not None
    T = check_pose(pose if fixed_pose else meta.get("pose"))
    return _assemble(path, meta, records, Ping360Assembler(settings), PingStreamParser(), PingStreamParser(),
                     lambda m: m.message_id == ping_ids["transducer"] and bool(m.transmit),
                     lambda m, c: m.message_id == ping_ids["device_data"] and ping360_problem(m, c) is None,
                     T, fixed_pose, partial, "ping-protocol message", once=True)
