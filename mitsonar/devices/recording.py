"""Recording and replaying a head's raw byte stream: the parts every head shares.

A head's driver records (`record_driven`: log every byte while driving it; `finish_recording`:
keep or remove the log) in the `mitsonar.devices.rawlog` format, whose header's ``head`` says
which head wrote it (`mitsonar.devices.head.Head.log_tag`). `replay` turns a log back into
the scans the driver returned while recording: the head that wrote it
(`mitsonar.devices.registry.for_log`) replays its records, through `assemble_log` with its own
codec, assembler and rule for usable pings. This module knows no head and imports no driver.
"""
from __future__ import annotations

import time
import warnings
from pathlib import Path

import numpy as np

from mitsonar.devices.rawlog import POSE, RX, TX, LogDamageWarning, RawLogWriter, read_log
from mitsonar.devices.registry import for_file, for_log
from mitsonar.devices.micron.seanet.settings import SOUND_SPEED_ALLOWED, sound_speed_ok
from mitsonar.devices.transports import SonarError, SonarTimeout
from mitsonar.geometry.frames import check_rigid
from mitsonar.scan import Scan

__all__ = ["replay", "record_driven", "finish_recording", "assemble_log", "check_pose"]


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


def check_pose(pose) -> np.ndarray:
    """A head mounting as a float64 4x4 (identity for None); ValueError unless rigid and finite."""
    return np.eye(4) if pose is None else check_rigid(np.array(pose, dtype=np.float64), "pose")


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
    ``transducer`` sent, as `mitsonar.devices.ping360.driver.Ping360Sonar` does. The head is the
    one whose `mitsonar.devices.head.Head.log_tag` the header holds (ValueError naming the
    known heads if none does); its `~mitsonar.devices.head.Head.replay` does the rest.
    """
    if sound_speed is not None and not sound_speed_ok(sound_speed):
        raise ValueError(f"replay: sound_speed = {sound_speed!r} is out of range: allowed {SOUND_SPEED_ALLOWED}")
    own = for_file(path)
    if own is not None:      # a log in the head's own format (an Oculus .oculus log)
        return own.replay_file(path, pose=pose, partial=partial)
    meta, records = read_log(path)
    options = {k: v for k, v in (("nibble_order", nibble_order), ("revisit", revisit), ("max_turns", max_turns))
               if v is not None}
    return for_log(meta, path).replay(path, meta, records, sound_speed=sound_speed, pose=pose, partial=partial,
                                      **options)


def assemble_log(path, meta: dict, records: list, asm, rx, tx, is_command, usable, pose, partial: bool,
                 what: str, once: bool = False) -> list[Scan]:
    """The scans the driver assembled (``asm``) while it recorded ``records`` (`read_log` of
    ``path``, header ``meta``): what the head sent (``rx`` parser) counts when
    ``usable(message, command)`` holds for the last message sent to it that ``is_command``
    (``tx`` parser); ``once``: one reply per command, as the Ping360 driver takes it. ``pose``
    (4x4) for every ping, else the log's pose records and header; ``LogDamageWarning`` for bytes
    that form no ``what``."""
    fixed_pose = pose is not None
    T = check_pose(pose if fixed_pose else meta.get("pose"))
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
                    s.meta.log = str(path)
                    scans.append(s)

    for t, record_type, data in records:
        if record_type == TX:
            for m in tx.feed(data):
                if is_command(m):
                    command = m
        elif record_type == POSE and not fixed_pose and len(data) == 128:
            T = np.frombuffer(data, dtype="<f8").reshape(4, 4).copy()
        elif record_type == RX:
            take(rx.feed(data), t)
    take(rx.flush(), records[-1][0] if records else 0.0)
    tx.flush()
    for parser, way in ((rx, "from"), (tx, "to")):
        if parser.dropped:
            reasons = ", ".join(f"{r}: {n}" for r, n in parser.drop_reasons.most_common(3))
            warnings.warn(LogDamageWarning(
                f"{Path(path).name}: dropped {parser.dropped} bytes {way} "
                f"the head that form no whole {what} ({reasons})"), stacklevel=4)
    if partial:
        s = asm.finish()
        if s is not None:
            s.meta.log = str(path)
            s.meta.partial = True
            scans.append(s)
    return scans
