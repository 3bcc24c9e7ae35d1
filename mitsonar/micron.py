"""Tritech Micron driver on pyserial, scan assembly, raw byte logs and their replay.

``MicronSonar(port_or_url)`` opens the port (``serial.serial_for_url``: a device path,
``socket://host:port``, ``rfc2217://``, ``loop://`` ...), runs the SeaNet start-up sequence
and then serves scanlines (`MicronSonar.pings`) and whole scans (`MicronSonar.scan`) as
`mitsonar.scan.Scan` objects.

Start-up (reference section 5): mtReBoot -> wait for mtAlive "centred, not motoring, no
config sent" -> mtSendVersion / mtVersionData -> mtSendBBUser / mtBBUserData (DST heads then
send FPGA messages) -> wait for mtAlive "config sent" -> mtHeadCommand -> wait for mtAlive
with NoParams clear. Then one mtSendData per mtHeadData.

Bearings and poses in a `Scan` (contract shared with the renderer): wire bearing ``b`` maps to
``(3200 - b) * pi / 3200`` rad (sign flipped for an inverted head); bearings are unwrapped
``bearing_start + k * bearing_step``; ``poses[k] = pose @ R_y(bearings[k])`` where ``pose`` is
the head's mounting (world from beam frame at bearing 0: +z boresight, +y scan axis) at the
time the ping arrived.

Raw log format (``record`` writes it, ``replay`` and `read_log` read it; little-endian)::

    file header   8s  magic b"MSNRLOG1"
                  H   format version (1)
                  H   reserved (0)
                  d   start time, Unix seconds
                  I   n, length of the metadata
                  n   metadata, UTF-8 JSON: port, baudrate, sound_speed, nibble_order,
                      settings (HeadSettings fields), pose (4x4), revisit, max_turns, passive
    records       d   time since the start, s
                  B   kind: 0 bytes received from the head, 1 bytes sent to it,
                      2 head pose (16 float64, row-major 4x4)
                  I   m, payload length
                  m   payload

A record cut short at the end (recorder killed) is not read; neither is a damaged stretch,
after which reading picks up where whole records follow each other again. Both are reported
(`read_log`: ``meta["skipped"]`` and a `LogDamageWarning`), as are bytes that `replay` finds
to be no SeaNet packet.
"""
from __future__ import annotations

import json
import math
import os
import select
import struct
import time
import warnings
from collections import Counter, deque
from pathlib import Path
from typing import Iterator

import numpy as np

from .scan import Scan, bearing_rotation, check_rigid
from .seanet import (DEFAULT_NIBBLE_ORDER, FULL_TURN, Alive, BBUserData, HdCtrl, HeadCommand,
                     HeadData, HeadSettings, ReBoot, SendBBUser, SendData, SendVersion,
                     SOUND_SPEED_ALLOWED, StreamParser, VersionData, ad_db, bearing_to_radians, encode,
                     gain_db, ping_problem, sound_speed_ok)

__all__ = ["SonarError", "SonarTimeout", "MicronSonar", "ScanAssembler", "beam_rotation",
           "RawLogWriter", "read_log", "record", "replay", "LOG_MAGIC", "LogDamageWarning",
           "RX", "TX", "POSE"]

LOG_MAGIC = b"MSNRLOG1"
RX, TX, POSE = 0, 1, 2
_LOG_HEADER = struct.Struct("<8sHHdI")
_LOG_RECORD = struct.Struct("<dBI")


class LogDamageWarning(UserWarning):
    """`read_log` or `replay` skipped damaged bytes of a raw log (the message says where)."""


class SonarError(RuntimeError):
    """The head or the port misbehaved beyond what the driver can recover from."""


class SonarTimeout(SonarError, TimeoutError):
    """The head did not answer in time."""


# The bearing convention lives with the Scan; kept under this name for the driver's users.
beam_rotation = bearing_rotation


def _check_pose(pose) -> np.ndarray:
    # Rigid here, where a navigation pose comes in, not only when its scan is put together.
    return np.eye(4) if pose is None else check_rigid(np.array(pose, dtype=np.float64), "pose")


# --------------------------------------------------------------------------------------------
# Scan assembly
# --------------------------------------------------------------------------------------------

class ScanAssembler:
    """Groups scanlines (`HeadData`) into scans: full turns, or sector sweeps limit to limit.

    Parameters
    ----------
    ============  ==============================================================
    sound_speed   m/s, turns ADInterval into ranges (default 1500)
    revisit       full turns only: a bearing whose ping was lost is taken from a later
                  turn, so the scan is complete (default True). False: one sweep, lost
                  bearings zero-filled
    max_turns     give up revisiting after this many turns' worth of pings and zero-fill
                  (default 3)
    settings      `HeadSettings` in force (optional): snaps the range window to the
                  requested range when ADInterval's rounding changes it by < 1e-9
    ============  ==============================================================

    `add` returns a `Scan` when one completes, else None. Continuous scans start at the first
    ping and run in the head's direction of rotation (found from consecutive bearings);
    sector scans start at a ping on a limit (sweep code or bearing) and end on the other,
    whose ping also starts the next sweep. A ping whose settings differ from the scan in
    progress (ADInterval, bins, step, mode, limits) discards it and starts anew; pings with
    motor error or power loss are skipped. Missing bearings are listed in
    ``scan.meta["missing"]`` (row indices) and left zero.
    """

    def __init__(self, sound_speed: float = 1500.0, *, revisit: bool = True, max_turns: int = 3,
                 settings: HeadSettings | None = None):
        if not (isinstance(max_turns, int) and max_turns >= 1):
            raise ValueError(f"max_turns must be an integer >= 1, got {max_turns!r}")
        self.sound_speed = float(sound_speed)
        self.revisit = bool(revisit)
        self.max_turns = max_turns
        self.settings = settings
        self.discarded = 0
        self.reset()

    def reset(self) -> None:
        self._key = None
        self._slots: dict[int, tuple] = {}
        self._pending: list = []     # continuous: pings before the direction is known
        self._origin = None
        self._dir = None
        self._seen = 0
        self._progress = 0
        self._prev = None
        self._ref: HeadData | None = None

    @staticmethod
    def _key_of(p: HeadData):
        mode = p.hd_ctrl & (HdCtrl.CONT | HdCtrl.ADC8ON | HdCtrl.INVERT)
        lims = None if p.hd_ctrl & HdCtrl.CONT else (p.left_lim, p.right_lim)
        return (p.ad_interval, p.n_bins, p.step_size, int(mode), lims)

    def add(self, ping: HeadData, pose=None, t: float | None = None) -> Scan | None:
        """Feed one scanline (with the head pose and time it arrived); a `Scan` when one completes."""
        if ping.motor_error or ping.power_loss or ping.step_size == 0 or ping.n_bins == 0:
            return None
        T = _check_pose(pose)
        key = self._key_of(ping)
        if self._key is not None and key != self._key:
            if self._slots or self._pending:
                self.discarded += 1
            self.reset()
        if self._key is None or self._ref is None:
            self._key, self._ref = key, ping
        item = (ping, T, t)
        if ping.hd_ctrl & HdCtrl.CONT:
            return self._add_continuous(item)
        return self._add_sector(item)

    # ---- continuous ----
    def _n(self) -> int:
        return FULL_TURN // self._ref.step_size

    def _place(self, item) -> None:
        step, n = self._ref.step_size, self._n()
        off = ((item[0].bearing - self._origin) * self._dir) % FULL_TURN
        k = int(round(off / step)) % n
        self._slots.setdefault(k, item)

    def _add_continuous(self, item) -> Scan | None:
        ping = item[0]
        step, n = self._ref.step_size, self._n()
        if self._origin is None:
            self._origin, self._prev, self._seen, self._progress = ping.bearing, ping.bearing, 1, 0
            self._pending = [item]
            return self._emit_continuous() if n == 1 else None
        self._seen += 1
        if self._dir is None:
            self._pending.append(item)
            d = (ping.bearing - self._prev) % FULL_TURN
            if d in (step, FULL_TURN - step) and step != FULL_TURN // 2:
                self._dir = 1 if d == step else -1
            elif len(self._pending) > self.max_turns * n:
                # No two consecutive bearings one step apart: trust the HdCtrl echo.
                right = bool(self._ref.hd_ctrl & HdCtrl.SCANRIGHT)
                self._dir = 1 if right else -1
            if self._dir is not None:
                pend, self._pending = self._pending, []
                prev = self._origin
                for it in pend:
                    if not self.revisit:
                        self._progress += ((it[0].bearing - prev) * self._dir) % FULL_TURN
                        prev = it[0].bearing
                    self._place(it)
            self._prev = ping.bearing
        else:
            if not self.revisit:
                fwd = ((ping.bearing - self._prev) * self._dir) % FULL_TURN
                if self._progress + fwd >= n * step:
                    # Back at (or past) the first bearing: this ping opens the next scan.
                    scan = self._emit_continuous()
                    self._restart(item)
                    return scan
                self._progress += fwd
            self._prev = ping.bearing
            self._place(item)
        if self._dir is None:
            return None
        if len(self._slots) == n:
            return self._emit_continuous()
        if self.revisit and self._seen >= self.max_turns * n:
            return self._emit_continuous()
        if not self.revisit and self._progress >= (n - 1) * step:
            return self._emit_continuous()
        return None

    def _restart(self, item):
        key, ref = self._key, item[0]
        self.reset()
        self._key, self._ref = key, ref
        return self._add_continuous(item)

    def _emit_continuous(self) -> Scan:
        if self._dir is None:
            self._dir = 1 if self._ref.hd_ctrl & HdCtrl.SCANRIGHT else -1
            for it in self._pending:
                self._place(it)
        scan = self._build(self._origin, self._dir, self._n(), "continuous")
        key = self._key
        self.reset()
        self._key = key
        return scan

    # ---- sector ----
    def _add_sector(self, item) -> Scan | None:
        ping = item[0]
        L, R, step = ping.left_lim, ping.right_lim, ping.step_size
        width = (R - L) % FULL_TURN
        n = width // step + 1
        at_left = ping.sweep_code == 1 or ping.bearing == L
        at_right = ping.sweep_code == 2 or ping.bearing == R
        if self._origin is None:
            if at_left or at_right:
                self._start_sweep(item, at_left)
            return None
        self._seen += 1
        off = ((ping.bearing - self._origin) * self._dir) % FULL_TURN
        if off <= width:
            self._slots.setdefault(int(round(off / step)), item)
        if (at_right if self._dir > 0 else at_left) and off == width:
            scan = self._build(self._origin, self._dir, n, "sector")
            back_from_right = self._dir > 0
            key = self._key
            self.reset()
            self._key, self._ref = key, ping
            # The turning ping is shared: it ends this sweep and starts the next.
            self._start_sweep(item, at_left=not back_from_right)
            return scan
        if self._seen > 2 * n + 2:
            # Never reached the far limit (the head restarted elsewhere?): give this sweep up.
            self.discarded += 1
            key = self._key
            self.reset()
            self._key = key
        return None

    def _start_sweep(self, item, at_left: bool) -> None:
        ping = item[0]
        self._origin, self._dir = (ping.left_lim, 1) if at_left else (ping.right_lim, -1)
        self._slots = {0: item}
        self._seen = 1

    # ---- building ----
    def _build(self, origin: int, direction: int, n: int, sweep: str) -> Scan:
        ref = self._ref
        invert = bool(ref.hd_ctrl & HdCtrl.INVERT)
        nb = ref.n_bins
        c = self.sound_speed
        width = c * (ref.ad_interval * 640e-9) / 2.0
        range_max = nb * width
        s = self.settings
        if s is not None and abs(range_max - s.range) <= 1e-9 * s.range:
            range_max = float(s.range)
            width = range_max / nb
        step_rad = ref.step_size * math.pi / 3200.0
        # Wire bearing and simulator bearing turn opposite ways unless the head is inverted.
        d_theta = step_rad * direction * (1.0 if invert else -1.0)
        theta0 = bearing_to_radians(origin, invert)
        bearings = theta0 + np.arange(n) * d_theta
        data = np.zeros((n, nb), dtype=np.uint8)
        poses = np.empty((n, 4, 4))
        wire = [int((origin + direction * k * ref.step_size) % FULL_TURN) for k in range(n)]
        missing = [k for k in range(n) if k not in self._slots]
        last_T = np.eye(4)
        times = []
        for k in range(n):
            it = self._slots.get(k)
            if it is not None:
                p, T, t = it
                data[k] = p.bins
                last_T = T
                if t is not None:
                    times.append(t)
            poses[k] = last_T
        # Missing rows before the first received one take the first pose seen.
        first = next((self._slots[k][1] for k in range(n) if k in self._slots), np.eye(4))
        for k in range(n):
            if k in self._slots:
                break
            poses[k] = first
        poses = poses @ beam_rotation(bearings)
        meta = {
            "source": "seanet", "sweep": sweep, "wire_bearings": wire, "missing": missing,
            "ad_interval": int(ref.ad_interval), "step_size": int(ref.step_size),
            "hd_ctrl": int(ref.hd_ctrl), "device_type": int(ref.device_type),
            "gain_byte": int(ref.gain), "ad_low_byte": int(ref.ad_low),
            "ad_span_byte": int(ref.ad_span), "nibble_order": ref.nibble_order,
        }
        if sweep == "sector":
            meta["left_lim"], meta["right_lim"] = int(ref.left_lim), int(ref.right_lim)
        if times:
            meta["time_start"], meta["time_end"] = float(min(times)), float(max(times))
        return Scan(intensity=np.zeros((n, nb), np.float32), data=data,
                    ranges=(np.arange(nb) + 0.5) * width, bearings=bearings, poses=poses,
                    range_min=0.0, range_max=float(range_max), beamwidth_h=3.0, beamwidth_v=35.0,
                    kind="mechanical", sound_speed=c,
                    electronics=_wire_electronics(ref), meta=meta)

    def finish(self) -> Scan | None:
        """The scan in progress, zero-filled, or None if there is none (end of a replay)."""
        if self._ref is None or not (self._slots or self._pending):
            return None
        if self._ref.hd_ctrl & HdCtrl.CONT:
            return self._emit_continuous()
        if self._origin is None:
            return None
        L, R, step = self._ref.left_lim, self._ref.right_lim, self._ref.step_size
        n = ((R - L) % FULL_TURN) // step + 1
        scan = self._build(self._origin, self._dir, n, "sector")
        self.reset()
        return scan


# --------------------------------------------------------------------------------------------
# Raw byte logs
# --------------------------------------------------------------------------------------------

class RawLogWriter:
    """Writes the raw-log format of this module (see the module docstring).

    Parameters
    ----------
    ====  ==============================================================
    path  file to create (overwritten)
    meta  JSON-serialisable dict stored in the header
    ====  ==============================================================
    """

    def __init__(self, path, meta: dict | None = None):
        self.path = Path(path)
        self._t0 = time.time()
        self._m0 = time.monotonic()
        blob = json.dumps(meta or {}, sort_keys=True).encode("utf-8")
        self._f = open(self.path, "wb")
        self._f.write(_LOG_HEADER.pack(LOG_MAGIC, 1, 0, self._t0, len(blob)) + blob)
        self.bytes_rx = 0
        self.bytes_tx = 0

    def write(self, kind: int, data: bytes) -> None:
        if kind not in (RX, TX, POSE):
            # read_log finds its way through damage by what the writer can write.
            raise ValueError(f"RawLogWriter.write: kind must be RX (0), TX (1) or POSE (2), got {kind!r}")
        if self._f is None or not data:
            return
        t = time.monotonic() - self._m0
        self._f.write(_LOG_RECORD.pack(t, kind, len(data)) + bytes(data))
        if kind == RX:
            self.bytes_rx += len(data)
        elif kind == TX:
            self.bytes_tx += len(data)

    def rx(self, data: bytes) -> None:
        self.write(RX, data)

    def tx(self, data: bytes) -> None:
        self.write(TX, data)

    def pose(self, T) -> None:
        self.write(POSE, np.asarray(T, dtype="<f8").reshape(16).tobytes())

    def close(self) -> None:
        if self._f is not None:
            self._f.close()
            self._f = None

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        self.close()


def _record_at(raw: bytes, pos: int, t_prev: float, strict: bool = False):
    """``(t, kind, m)`` if a record header that `RawLogWriter` could have written starts at
    ``pos`` (``m`` may run past the end of the file), else None. ``strict`` for offsets not
    known to start a record (after damage), where bytes of the serial stream can look like a
    header: a time stamp within an hour of the last good record's."""
    if pos + _LOG_RECORD.size > len(raw):
        return None
    t, kind, m = _LOG_RECORD.unpack_from(raw, pos)
    # The writer stamps records with a monotonic clock, never writes an empty record, and a
    # pose is 16 float64. A little slack on the time: the pose may be set from another thread.
    if kind not in (RX, TX, POSE) or m == 0 or (kind == POSE and m != 128):
        return None
    if not (math.isfinite(t) and t >= 0.0 and t >= t_prev - 1.0):
        return None
    if strict and not 1e-9 <= t <= t_prev + 3600.0:
        return None
    return t, kind, m


def _chain_at(raw: bytes, pos: int, t_prev: float, depth: int, strict: bool = False) -> bool:
    """Do ``depth`` plausible records follow each other from ``pos`` (fewer where the file ends)?

    A record cut short by the end of the file counts after a whole one, or first unless
    ``strict``: else any header-like bytes with a large length would do.
    """
    for i in range(depth):
        if pos > len(raw) - _LOG_RECORD.size:
            # The file ends here, exactly or inside a header.
            return i > 0 or pos == len(raw) or not strict
        rec = _record_at(raw, pos, t_prev, strict)
        if rec is None:
            return False
        t_prev, pos = rec[0], pos + _LOG_RECORD.size + rec[2]
        if pos > len(raw):
            return i > 0 or not strict
    return True


def _resync(raw: bytes, pos: int, t_prev: float) -> int | None:
    """The first offset from ``pos`` where whole records start again, or None."""
    b = np.frombuffer(raw, dtype=np.uint8)
    last = len(raw) - _LOG_RECORD.size      # last offset a header fits at
    block = 1 << 16
    for lo in range(pos, last + 1, block):
        hi = min(lo + block, last + 1)
        # A kind byte and a nonzero length rule out most offsets before the slower checks.
        ok = (b[lo + 8:hi + 8] <= POSE) & ((b[lo + 9:hi + 9] | b[lo + 10:hi + 10]
                                            | b[lo + 11:hi + 11] | b[lo + 12:hi + 12]) != 0)
        for q in np.flatnonzero(ok) + lo:
            if _chain_at(raw, int(q), t_prev, 3, strict=True):
                return int(q)
    return None


def read_log(path) -> tuple[dict, list[tuple[float, int, bytes]]]:
    """``(meta, records)`` of a raw log; ``meta["start_time"]`` holds the header's start time.

    Raises ValueError with a one-line reason if the file is not such a log. A damaged stretch
    (a record header that the writer cannot have written) is skipped up to the next offset
    where whole records follow each other again, so what comes after the damage is kept;
    ``meta["skipped"]`` then lists ``[offset, n_bytes, reason]`` of every stretch not read
    (reason ``"damaged"``, or ``"record cut short at the end"``; ``"overlap"``: a record
    whose damaged header begins ``n_bytes`` before the end of the one before it), and a
    `LogDamageWarning` says so in one line.

    Without a checksum, damage that leaves a record length pointing exactly at a later record
    cannot be seen here: that record's payload then holds the damage (for the SeaNet parser
    of `replay` to find) and the records in between are lost.
    """
    raw = Path(path).read_bytes()
    if not raw:
        raise ValueError(f"{path}: empty file, not a mitsonar raw log")
    if raw[:len(LOG_MAGIC)] != LOG_MAGIC:
        raise ValueError(f"{path}: not a mitsonar raw log (missing {LOG_MAGIC!r} header)")
    if len(raw) < _LOG_HEADER.size:
        raise ValueError(f"{path}: truncated log: {len(raw)} bytes, less than the "
                         f"{_LOG_HEADER.size}-byte file header; no records")
    magic, version, _, t0, n = _LOG_HEADER.unpack_from(raw, 0)
    if version != 1:
        raise ValueError(f"{path}: raw log format version {version} is not supported (only 1)")
    pos = _LOG_HEADER.size
    if pos + n > len(raw):
        raise ValueError(f"{path}: truncated log: the metadata at bytes {pos}..{pos + n} ends "
                         f"after the file ({len(raw)} bytes)")
    try:
        meta = json.loads(raw[pos:pos + n].decode("utf-8")) if n else {}
    except (UnicodeDecodeError, json.JSONDecodeError) as e:
        raise ValueError(f"{path}: corrupt log metadata at bytes {pos}..{pos + n} ({e})") from None
    if not isinstance(meta, dict):
        raise ValueError(f"{path}: corrupt log metadata (not an object)")
    meta["start_time"] = t0
    pos += n
    records = []
    skipped = []
    t_prev = 0.0
    while pos < len(raw):
        rec = _record_at(raw, pos, t_prev)
        end = pos + _LOG_RECORD.size + rec[2] if rec else None
        if rec and end <= len(raw) and _chain_at(raw, end, rec[0], 2, strict=True):
            records.append((rec[0], rec[1], raw[pos + _LOG_RECORD.size:end]))
            t_prev, pos = rec[0], end
            continue
        q = _resync(raw, pos + 1, t_prev)
        if rec and end <= len(raw) and (q is None or q > end - _LOG_RECORD.size):
            # This record is whole and no record starts inside it: the damage lies further on.
            # A chain starting in its last bytes is the next record with the front of its
            # header lost (bytes cut out there): keep both.
            records.append((rec[0], rec[1], raw[pos + _LOG_RECORD.size:end]))
            t_prev, pos = rec[0], end
            if q is not None and q < end:
                skipped.append([q, end - q, "overlap"])
                pos = q
            continue
        if q is None:
            cut = (rec is not None and end > len(raw)) or pos > len(raw) - _LOG_RECORD.size
            why = "record cut short at the end" if cut else "damaged"
            skipped.append([pos, len(raw) - pos, why])
            break
        skipped.append([pos, q - pos, "damaged"])
        pos = q
    if skipped:
        meta["skipped"] = skipped
        warnings.warn(LogDamageWarning(_skipped_line(path, skipped)), stacklevel=2)
    return meta, records


def _skipped_line(path, skipped) -> str:
    def one(pos, n, why):
        if why == "overlap":
            return f"damaged record header at {pos} (its first {n} bytes lie in the record before)"
        if why == "damaged":
            return f"skipped {n} damaged bytes at {pos}..{pos + n}"
        return f"{why}: {n} bytes at {pos}..{pos + n} not read"
    if len(skipped) <= 2:
        return f"{Path(path).name}: " + "; ".join(one(*s) for s in skipped)
    total = sum(n for _, n, why in skipped if why != "overlap")
    where = ", ".join(f"{p}..{p + n}" for p, n, _ in skipped[:3]) + ", ..."
    return f"{Path(path).name}: skipped {total} damaged bytes in {len(skipped)} places ({where})"


# --------------------------------------------------------------------------------------------
# The driver
# --------------------------------------------------------------------------------------------

class MicronSonar:
    """A Tritech Micron (or other SeaNet imaging head) on a serial port.

    Parameters
    ----------
    ==============  ==========================================================================
    port_or_url     device path or pyserial URL (``socket://host:port``, ``loop://``, ...), or an
                    already open pyserial-like object (read/write/in_waiting/timeout)
    baudrate        115200 (the Micron's default)
    settings        `HeadSettings` (default: 12 m, 500 bins, 1.8 deg steps, continuous, 8-bit)
    pose            4x4 world-from-head mounting (beam frame at bearing 0); can be reassigned
                    while running, each ping takes the pose current when it arrives
    timeout         s: longest the head may go without a usable scanline (or a start-up step
                    without its answer) before `SonarTimeout`; covers recovery (default 30)
    ping_timeout    s to wait for each reply before asking again (default: 2x the expected
                    step time + 0.5 s)
    retries         re-sends of a request before the driver re-configures the head (default 3)
    reboot          send mtReBoot first (default True); False attaches to a running head
    boot_timeout    s to wait for the head to come back after mtReBoot (default 30)
    nibble_order    4-bit order, ``"low_first"`` (default) or ``"high_first"``
    revisit         complete full turns from later turns when pings are lost (default True)
    max_turns       bound on that revisiting (default 3)
    log             path or `RawLogWriter`: every byte in and out is logged (``record``)
    start           run the start-up sequence now (default True)
    ==============  ==========================================================================

    Use as a context manager, or call `close`. ``stats`` counts requests, timeouts, re-sent
    parameters and recoveries; ``parser`` (a `StreamParser`) counts dropped bytes;
    ``version``, ``bbuser``, ``dst``, ``last_alive`` hold what the head reported.
    """

    def __init__(self, port_or_url, baudrate: int = 115200, settings: HeadSettings | None = None,
                 pose=None, timeout: float = 30.0, *, ping_timeout: float | None = None,
                 retries: int = 3, reboot: bool = True, boot_timeout: float = 30.0,
                 nibble_order: str = DEFAULT_NIBBLE_ORDER, revisit: bool = True,
                 max_turns: int = 3, log=None, start: bool = True):
        if settings is None:
            settings = HeadSettings()
        if not isinstance(settings, HeadSettings):
            raise TypeError(f"settings must be a HeadSettings, got {type(settings).__name__}")
        for name, v in (("timeout", timeout), ("boot_timeout", boot_timeout)):
            if not (isinstance(v, (int, float)) and v > 0):
                raise ValueError(f"{name} must be a positive number of seconds, got {v!r}")
        if ping_timeout is not None and not (isinstance(ping_timeout, (int, float)) and ping_timeout > 0):
            raise ValueError(f"ping_timeout must be a positive number of seconds, got {ping_timeout!r}")
        if not (isinstance(retries, int) and retries >= 0):
            raise ValueError(f"retries must be an integer >= 0, got {retries!r}")
        self._settings = settings
        self.baudrate = int(baudrate)
        self._pose = _check_pose(pose)
        self.timeout = float(timeout)
        self._ping_timeout = ping_timeout
        self.retries = retries
        self.boot_timeout = float(boot_timeout)
        self.revisit = revisit
        self.max_turns = max_turns
        self.parser = StreamParser(nibble_order=nibble_order)
        self.stats: Counter = Counter()
        self.version: VersionData | None = None
        self.bbuser: BBUserData | None = None
        self.dst = False
        self.last_alive: Alive | None = None
        self.last_ping_time: float | None = None
        self._inbox: deque = deque()
        self._stash: deque = deque()
        self._command: HeadCommand | None = None
        self._configured = False
        self._outstanding = 0
        self._sent_at = 0.0
        self._params_sent_at = -1e9
        self._dropped_at_send = 0
        self._assembler: ScanAssembler | None = None
        self._own_log = False
        self._log = None
        self._ser = None
        self._fd = None
        self.port = port_or_url if isinstance(port_or_url, str) else getattr(port_or_url, "port", repr(port_or_url))
        if log is not None:
            if isinstance(log, RawLogWriter):
                self._log = log
            else:
                self._log = RawLogWriter(log, self._log_meta())
                self._own_log = True
        try:
            self._ser = self._open(port_or_url)
            self._fd = self._fileno(self._ser)
            if start:
                self.start(reboot=reboot)
        except BaseException:
            self.close()
            raise

    # ---- properties ----
    @property
    def settings(self) -> HeadSettings:
        return self._settings

    @property
    def ping_timeout(self) -> float:
        if self._ping_timeout is not None:
            return float(self._ping_timeout)
        return 2.0 * self._settings.expected_step_time(self.baudrate) + 0.5

    @property
    def pose(self) -> np.ndarray:
        return self._pose

    @pose.setter
    def pose(self, T) -> None:
        self._pose = _check_pose(T)
        if self._log is not None:
            self._log.pose(self._pose)

    def _log_meta(self) -> dict:
        return {"format": "mitsonar seanet raw log", "port": str(self.port),
                "baudrate": self.baudrate, "sound_speed": self._settings.sound_speed,
                "nibble_order": self.parser.nibble_order, "settings": self._settings.as_dict(),
                "pose": self._pose.tolist(), "revisit": self.revisit, "max_turns": self.max_turns,
                "passive": False}

    # ---- port ----
    def _open(self, port_or_url):
        if not isinstance(port_or_url, (str, os.PathLike)):
            return port_or_url
        import serial
        try:
            return serial.serial_for_url(os.fspath(port_or_url), baudrate=self.baudrate, timeout=0.05,
                                         write_timeout=max(1.0, self.timeout))
        except (serial.SerialException, OSError, ValueError) as e:
            raise SonarError(f"cannot open {port_or_url}: {e}") from None

    @staticmethod
    def _fileno(ser):
        if getattr(ser, "_socket", None) is not None:
            return None
        try:
            fd = ser.fileno()
            select.select([fd], [], [], 0)
            return fd
        except Exception:        # loop://, rfc2217:// and friends have no file descriptor
            return None

    def close(self) -> None:
        """Close the port (and the log if the driver opened it). Safe to call twice."""
        ser, self._ser = self._ser, None
        if ser is not None:
            try:
                ser.close()
            except Exception:      # closing a vanished device must not mask the real error
                pass
        if self._own_log and self._log is not None:
            self._log.close()
        self._log = None

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        self.close()

    def __del__(self):
        try:
            self.close()
        except Exception:
            pass

    def _write(self, msg) -> None:
        if self._ser is None:
            raise SonarError("the sonar is closed")
        data = encode(msg)
        try:
            self._ser.write(data)
        except Exception as e:
            raise SonarError(f"{self.port}: write failed: {e}") from None
        if self._log is not None:
            self._log.tx(data)
        self.stats[f"sent {msg.name}"] += 1

    def _read_some(self, wait: float) -> bytes:
        ser = self._ser
        if ser is None:
            raise SonarError("the sonar is closed")
        wait = max(0.0, wait)
        try:
            sock = getattr(ser, "_socket", None)
            if sock is not None:
                # pyserial's socket:// reports in_waiting as 0 or 1, which would mean one
                # read call per byte: wait on the socket and take all it has.
                r, _, _ = select.select([sock], [], [], wait)
                data = sock.recv(65536) if r else b""
                if r and not data:
                    raise SonarError(f"{self.port}: connection closed by the other end")
            elif self._fd is not None:
                # Waiting in select leaves the port's timeout alone: setting it costs a
                # tcsetattr on every poll.
                r, _, _ = select.select([self._fd], [], [], wait)
                data = ser.read(max(1, ser.in_waiting)) if r else b""
            else:
                if ser.timeout != wait:
                    ser.timeout = wait
                n = ser.in_waiting
                data = ser.read(n if n > 0 else 1)
        except SonarError:
            raise
        except Exception as e:
            raise SonarError(f"{self.port}: read failed: {e}") from None
        if data and self._log is not None:
            self._log.rx(data)
        return data

    def _poll(self, deadline: float):
        """Next message, or None once ``deadline`` (monotonic) passes."""
        while True:
            if self._inbox:
                return self._inbox.popleft()
            now = time.monotonic()
            if now >= deadline:
                return None
            data = self._read_some(min(deadline - now, 0.1))
            if data:
                msgs = self.parser.feed(data)
                for m in msgs:
                    if isinstance(m, Alive):
                        self.last_alive = m
                self._inbox.extend(msgs)

    def _aside(self, m) -> None:
        """A message nobody waits for now: keep usable scanlines, for replay's sake too."""
        if isinstance(m, HeadData):
            self._outstanding = max(0, self._outstanding - 1)
            # Same rule as replay: usable once parameters were sent and the line matches them.
            if self._command is not None and ping_problem(m, self._command) is None:
                self._stash.append(m)

    def _wait(self, pred, timeout: float, what: str, deadline: float | None = None):
        end = time.monotonic() + timeout
        if deadline is not None:
            end = min(end, deadline)
        while True:
            m = self._poll(end)
            if m is None:
                raise SonarTimeout(f"{self.port}: no {what} within {timeout:g} s")
            if pred(m):
                return m
            self._aside(m)

    def _request(self, msg, reply_type, what: str, deadline: float | None = None):
        last = None
        for _ in range(self.retries + 1):
            self._write(msg)
            try:
                return self._wait(lambda m: isinstance(m, reply_type), self.ping_timeout, what, deadline)
            except SonarTimeout as e:
                last = e
                self.stats["request timeouts"] += 1
                if deadline is not None and time.monotonic() >= deadline:
                    break
        raise SonarTimeout(f"{last} ({self.retries + 1} requests)")

    # ---- start-up ----
    def start(self, reboot: bool = True) -> None:
        """Run the start-up sequence (reboot, alive, version, BB user, parameters)."""
        self._configured = False
        if reboot:
            try:
                self._ser.reset_input_buffer()
            except Exception:
                pass
            self.parser.reset()
            self._inbox.clear()
            self._write(ReBoot())
            self._wait(lambda m: isinstance(m, Alive) and m.centred and not m.motoring and not m.sent_cfg,
                       self.boot_timeout, "mtAlive of a centred, idle head after mtReBoot")
        self._configure(time.monotonic() + self.timeout)

    def _configure(self, deadline: float) -> None:
        self._configured = False
        self._outstanding = 0
        self.version = self._request(SendVersion(), VersionData, "mtVersionData", deadline)
        self.bbuser = self._request(SendBBUser(), BBUserData, "mtBBUserData", deadline)
        self.dst = self.bbuser.is_dst
        try:
            # Heads send mtAlive about once a second; a head that never sets SentCfg only
            # costs this short wait.
            self._wait(lambda m: isinstance(m, Alive) and m.sent_cfg, min(self.timeout, 5.0),
                       "mtAlive with SentCfg", deadline)
        except SonarTimeout:
            self.stats["no SentCfg alive"] += 1     # send the parameters anyway
        last = None
        for _ in range(self.retries + 1):
            self._send_params()
            try:
                self._wait(lambda m: isinstance(m, Alive) and not m.no_params, self.timeout,
                           "mtAlive accepting the parameters", deadline)
                self._configured = True
                return
            except SonarTimeout as e:
                last = e
                if time.monotonic() >= deadline:
                    break
        raise SonarTimeout(f"{self.port}: the head did not accept the parameters ({last})")

    def _send_params(self) -> None:
        self._command = self._settings.head_command(dst=self.dst)
        self._write(self._command)
        self._params_sent_at = time.monotonic()
        self._outstanding = 0

    def reconfigure(self, settings: HeadSettings) -> None:
        """Send new settings to the running head; scans in progress are dropped."""
        if not isinstance(settings, HeadSettings):
            raise TypeError(f"settings must be a HeadSettings, got {type(settings).__name__}")
        self._settings = settings
        self._assembler = None
        self._stash.clear()
        self._configure(time.monotonic() + self.timeout)

    def _recover(self, reason: str, deadline: float) -> None:
        self.stats["recoveries"] += 1
        last = None
        while time.monotonic() < deadline:
            try:
                self._configure(deadline)
                return
            except SonarTimeout as e:
                last = e
        raise SonarTimeout(f"{self.port}: {reason}; could not re-configure the head within "
                           f"{self.timeout:g} s ({last})")

    # ---- data ----
    def read_ping(self) -> HeadData:
        """The next usable scanline (requests it, retries, recovers as needed)."""
        if not self._configured:
            raise SonarError("the head is not configured: call start()")
        deadline = time.monotonic() + self.timeout
        failures = 0
        last_problem = None
        while True:
            if self._stash:
                return self._got(self._stash.popleft())
            now = time.monotonic()
            if now >= deadline:
                why = f" (last scanline: {last_problem})" if last_problem else ""
                raise SonarTimeout(f"{self.port}: no usable mtHeadData for {self.timeout:g} s{why}")
            if self._outstanding <= 0:
                self._write(SendData())
                self._outstanding, self._sent_at = 1, now
                self._dropped_at_send = self.parser.dropped
            m = self._poll(min(self._sent_at + self.ping_timeout, deadline))
            if m is None:
                self.stats["ping timeouts"] += 1
                self._outstanding = 0
                failures += 1
                if failures > self.retries:
                    failures = 0
                    self._recover(f"no mtHeadData after {self.retries + 1} requests", deadline)
                continue
            if not isinstance(m, HeadData) and self._outstanding > 0 and self.parser.dropped > self._dropped_at_send:
                # A damaged packet went by and something else followed it: the reply we wait
                # for was most likely the damaged one, so ask again without waiting it out.
                self.stats["early re-requests"] += 1
                self._outstanding = 0
            if isinstance(m, Alive):
                if m.no_params:
                    # Only a reset head forgets its parameters: start it again.
                    self._recover("the head lost its parameters (reset?)", deadline)
                continue
            if not isinstance(m, HeadData):
                continue
            self._outstanding = max(0, self._outstanding - 1)
            problem = ping_problem(m, self._command)
            if problem is None:
                return self._got(m)
            self.stats["bad pings"] += 1
            last_problem = problem
            if self._params_sent_at <= self._sent_at:
                # The head had our parameters when it made this line and still complains
                # (motor lost sync, reset, other settings): send them again. Lines already
                # in flight after a re-send are only skipped.
                self.stats["parameters re-sent"] += 1
                self._send_params()

    def _got(self, m: HeadData) -> HeadData:
        self.stats["pings"] += 1
        self.last_ping_time = time.time()
        return m

    def pings(self, count: int | None = None) -> Iterator[HeadData]:
        """Iterator over scanlines (`HeadData`), forever or ``count`` of them."""
        k = 0
        while count is None or k < count:
            yield self.read_ping()
            k += 1

    def scan(self) -> Scan:
        """One full turn (continuous) or one sector sweep as a `Scan` (see `ScanAssembler`)."""
        if self._assembler is None:
            self._assembler = ScanAssembler(self._settings.sound_speed, revisit=self.revisit,
                                            max_turns=self.max_turns, settings=self._settings)
        while True:
            ping = self.read_ping()
            scan = self._assembler.add(ping, self._pose, self.last_ping_time)
            if scan is not None:
                scan.meta["port"] = str(self.port)
                scan.meta["settings"] = self._settings.as_dict()
                if self.version is not None:
                    scan.meta["head_serial"] = int(self.version.serial)
                    scan.meta["head_software"] = int(self.version.software_version)
                scan.meta["dst"] = bool(self.dst)
                return scan


# --------------------------------------------------------------------------------------------
# record / replay
# --------------------------------------------------------------------------------------------

def record(port, path, seconds: float | None = None, *, scans: int | None = None,
           pings: int | None = None, baudrate: int = 115200, settings: HeadSettings | None = None,
           passive: bool = False, pose=None, **sonar_kwargs) -> dict:
    """Record the raw byte stream of a head into a raw log (format in the module docstring).

    Parameters
    ----------
    ========  =================================================================
    port      device path or pyserial URL
    path      log file to write
    seconds   stop after this long (None: until scans/pings or Ctrl-C)
    scans     drive the head and stop after this many `MicronSonar.scan` results
    pings     drive the head and stop after this many scanlines
    baudrate  115200
    settings  `HeadSettings` for the head (driven mode)
    passive   only listen (a tap on the head's transmit line); needs ``seconds``
    pose      head mounting stored in the log
    ========  =================================================================

    Extra keyword arguments go to `MicronSonar`. Returns counts (bytes in/out, pings, scans;
    driven: ``bytes_dropped``, received bytes that formed no whole packet).
    """
    if passive and seconds is None:
        raise ValueError("record: passive recording needs seconds")
    for name, v in (("seconds", seconds), ("scans", scans), ("pings", pings)):
        if v is not None and not (isinstance(v, (int, float)) and v > 0):
            raise ValueError(f"record: {name} must be positive, got {v!r}")
    settings = settings or HeadSettings()
    out = {"bytes_rx": 0, "bytes_tx": 0, "pings": 0, "scans": 0}
    if passive:
        import serial
        meta = {"format": "mitsonar seanet raw log", "port": str(port), "baudrate": baudrate,
                "sound_speed": settings.sound_speed, "nibble_order": DEFAULT_NIBBLE_ORDER,
                "settings": settings.as_dict(), "pose": _check_pose(pose).tolist(), "passive": True}
        try:
            ser = serial.serial_for_url(str(port), baudrate=baudrate, timeout=0.1)
        except (serial.SerialException, OSError, ValueError) as e:
            raise SonarError(f"cannot open {port}: {e}") from None
        with RawLogWriter(path, meta) as log:
            end = time.monotonic() + seconds
            try:
                while time.monotonic() < end:
                    try:
                        data = ser.read(max(1, ser.in_waiting))
                    except Exception as e:
                        raise SonarError(f"{port}: read failed: {e}") from None
                    log.rx(data)
            except KeyboardInterrupt:
                pass
            finally:
                ser.close()
            out["bytes_rx"] = log.bytes_rx
        return out
    end = None if seconds is None else time.monotonic() + seconds
    log = None
    reboot = sonar_kwargs.pop("reboot", True)
    try:
        with MicronSonar(port, baudrate, settings, pose, start=False, **sonar_kwargs) as sonar:
            log = RawLogWriter(path, sonar._log_meta())
            sonar._log = log
            try:
                sonar.start(reboot=reboot)
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
            out["pings"] = int(sonar.stats["pings"])
            out["bytes_dropped"] = int(sonar.parser.dropped)
    finally:
        if log is not None:
            log.close()
            out["bytes_rx"], out["bytes_tx"] = log.bytes_rx, log.bytes_tx
    return out


def replay(path, *, sound_speed: float | None = None, pose=None, nibble_order: str | None = None,
           revisit: bool | None = None, max_turns: int | None = None, partial: bool = False) -> list[Scan]:
    """Scans of a raw log, assembled exactly as `MicronSonar.scan` did while recording.

    Parameters
    ----------
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
    scans the driver returned.
    """
    if sound_speed is not None and not sound_speed_ok(sound_speed):
        raise ValueError(f"replay: sound_speed = {sound_speed!r} is out of range: allowed {SOUND_SPEED_ALLOWED}")
    meta, records = read_log(path)
    c = sound_speed or meta.get("sound_speed") or 1500.0
    if not sound_speed_ok(c):
        raise ValueError(f"{path}: the log's sound_speed = {c!r} is out of range: allowed "
                         f"{SOUND_SPEED_ALLOWED} (pass sound_speed)")
    c = float(c)
    nib = nibble_order or meta.get("nibble_order") or DEFAULT_NIBBLE_ORDER
    fixed_pose = pose is not None
    T = _check_pose(pose if fixed_pose else meta.get("pose"))
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
    rx, tx = StreamParser(nibble_order=nib), StreamParser(nibble_order=nib)
    command = None
    scans = []
    t0 = float(meta.get("start_time", 0.0))

    def take(msgs, t):
        for m in msgs:
            if isinstance(m, HeadData) and command is not None and ping_problem(m, command) is None:
                s = asm.add(m, T, t0 + t)
                if s is not None:
                    s.meta["log"] = str(path)
                    scans.append(s)

    for t, kind, data in records:
        if kind == TX:
            for m in tx.feed(data):
                if isinstance(m, HeadCommand):
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
                f"the head that form no whole SeaNet packet ({reasons})"), stacklevel=2)
    if partial:
        s = asm.finish()
        if s is not None:
            s.meta["log"] = str(path)
            s.meta["partial"] = True
            scans.append(s)
    return scans


def _wire_electronics(ref) -> dict:
    """What a reply's header says of the receiver, in `Electronics`' names and units (dB), so that
    ``HeadSettings.from_scan`` of a received scan asks the head for the same gain and A/D window."""
    out = {"bit_depth": 8 if ref.adc8on else 4, "gain": gain_db(ref.gain), "ad_low": ad_db(ref.ad_low)}
    if int(ref.ad_span) > 0:  # a zero span is no window: leave the default
        out["ad_span"] = ad_db(ref.ad_span)
    return out
