"""A virtual Blue Robotics Ping360: answers ping-protocol with the pings of a given scan.

``VirtualPing360(scan)`` opens a pseudo-terminal (or a UDP port on the loopback,
``udp://127.0.0.1:PORT``, or a ``socket://`` TCP port, or any pyserial URL) and behaves like the
head on the other end, speaking what ``brping.Ping360`` speaks (`mitsonar.devices.ping360.protocol`, on
brping's own message definitions):

==================================  =====================================================
``general_request`` (6) of          ``protocol_version`` (5, 1.1.0), ``device_information``
                                    (4: type 2, a Ping360), ``device_data`` (2300, the
                                    state, no samples); any other id: ``nack``
``transducer`` (2601), transmit 0   the new settings, answered by ``device_data`` without samples
``transducer``, transmit 1          motor to ``angle``, one ping: ``device_data`` with
                                    ``number_of_samples`` samples
``auto_transmit`` (2602)            pings from ``start_angle`` to ``stop_angle`` (then from
                                    ``start_angle`` again) every ``num_steps`` gradians as
                                    ``auto_device_data`` (2301) until ``motor_off`` (2903) or
                                    any other command
``reset`` (2600)                    back to the power-on state
a field out of range                ``nack`` (2) naming the field, nothing else changes
==================================  =====================================================

The samples at angle ``a`` are the row of the scan whose bearing is nearest to
``angle_to_radians(a)`` (within half the larger of the scan's and the request's step; zeros
otherwise), resampled by range onto the request's samples (each sample takes the scan bin that
holds its centre ``(i + 1/2) * sample_period * 25 ns * c / 2``, zero outside the scan's window).

Timing (``realtime=True``): a ping's reply leaves after the request's transfer
(``(10 + 14) * 10 / baud``), the motor's move (``motor_time`` per gradian turned, the shorter
way), the transmit pulse and the listening time ``number_of_samples * sample_period * 25 ns``,
and takes ``(10 + 14 + n) * 10 / baud`` on the line (no transfer time on UDP).
``realtime=False`` answers at once, for tests.
"""
from __future__ import annotations

import math
import threading
import time
from collections import Counter, deque

import numpy as np

from mitsonar.devices.ping360.head import GRADIANS, TICK, angle_to_radians, check_setting
from mitsonar.devices.ping360.protocol import Message, StreamParser, encode, ids
from mitsonar.scan import Scan
from mitsonar.scan.model import require_bytes
from mitsonar.devices.transports import ServedHead

__all__ = ["VirtualPing360", "serve"]

_STATE = ("gain_setting", "angle", "transmit_duration", "sample_period", "transmit_frequency",
          "number_of_samples")


class VirtualPing360(ServedHead):
    """A simulated Ping360 on a pseudo-terminal, a loopback UDP port, a TCP port or a pyserial URL.

    ===============  ========================================================================
    scan             the `Scan` to serve (mechanical)
    port_url         None or ``"pty"``: a new pseudo-terminal (default); ``udp://127.0.0.1:PORT``
                     (0 picks one); ``socket://HOST:PORT``; else a pyserial URL to sit on
    baudrate         115200 (timing model on serial lines)
    realtime         True: the timing model above; False: answer at once
    sound_speed      m/s, turns sample periods into metres; default the scan's
    motor_time       s per gradian the transducer turns (default 0.0005)
    device_id        the head's ``src_device_id`` (default 2)
    corrupt_pings    indices of pings (from 0) whose reply gets one byte flipped: its
                     checksum fails (a fault for tests)
    cut_pings        indices of pings whose reply loses its second half
    ===============  ========================================================================

    `start` (or ``with``) returns the port a client opens. ``stats`` counts messages and pings,
    ``state`` holds the head's current ``device_data`` fields, ``parser`` the bytes it dropped.
    """

    def __init__(self, scan: Scan, port_url: str | None = None, *, baudrate: int = 115200,
                 realtime: bool = True, sound_speed: float | None = None, motor_time: float = 0.0005,
                 device_id: int = 2, corrupt_pings=(), cut_pings=()):
        if not isinstance(scan, Scan):
            raise TypeError(f"scan must be a Scan, got {type(scan).__name__}")
        if not scan.sonar_kind.scanlines:
            raise ValueError(f"VirtualPing360: a {scan.kind} scan has no Ping360 pings to serve "
                             f"(a Ping360 is a mechanical head)")
        require_bytes(scan, "VirtualPing360", "a Ping360 sends 8-bit samples")
        self.scan = scan
        self.port_url = port_url
        self.baudrate = int(baudrate)
        self.realtime = bool(realtime)
        self.sound_speed = float(scan.sound_speed if sound_speed is None else sound_speed)
        check_setting("sound_speed", self.sound_speed, "VirtualPing360")
        self.motor_time = float(motor_time)
        self.device_id = int(device_id)
        self.corrupt_pings = frozenset(int(i) for i in corrupt_pings)
        self.cut_pings = frozenset(int(i) for i in cut_pings)
        self.parser = StreamParser()
        self.stats: Counter = Counter()
        self.last_error: BaseException | None = None
        self._b = np.mod(np.asarray(scan.bearings, np.float64), 2 * math.pi)
        self._scan_step = float(np.median(np.abs(np.diff(scan.bearings)))) if scan.n_pings > 1 else 0.0
        self._transport = None
        self._thread = None
        self._stop = threading.Event()
        self._reset()

    def _reset(self) -> None:
        self.state = dict(mode=1, gain_setting=1, angle=0, transmit_duration=32, sample_period=80,
                          transmit_frequency=740, number_of_samples=1200)
        self._auto = None
        self._free_at = 0.0
        self._queue: deque = deque()      # (due time, bytes)
        self._out = bytearray()

    def _power_on(self) -> None:
        self._udp = self._transport.port.startswith("udp://")
        self._reset()

    # ---- the line ----
    def _tick(self) -> None:
        now = time.monotonic()
        while self._queue and self._queue[0][0] <= now:
            self._out += self._queue.popleft()[1]
        if self._auto is not None and not self._queue:
            self._auto_ping(now)
        if self._out:
            n = self._transport.write(bytes(self._out))
            del self._out[:n]
        wait = 0.02
        if self._queue:
            wait = min(wait, max(0.0, self._queue[0][0] - time.monotonic()))
        if self._out or self._auto is not None:
            wait = min(wait, 0.002)
        data = self._transport.read(wait)
        if data:
            for m in self.parser.feed(data):
                self._on_message(m, time.monotonic())

    def _wire_time(self, n_bytes: int) -> float:
        return 0.0 if (self._udp or not self.realtime) else n_bytes * 10.0 / self.baudrate

    def _send(self, msg: Message, now: float, busy: float = 0.0, ping: int | None = None) -> None:
        """Queue ``msg``: it leaves after ``busy`` s of work and its transfer, in order."""
        msg.src, msg.dst = self.device_id, 0
        data = encode(msg)
        if ping in self.corrupt_pings:
            k = len(data) // 2
            data = data[:k] + bytes([data[k] ^ 0x5A]) + data[k + 1:]
            self.stats["fault corrupted"] += 1
        if ping in self.cut_pings:
            data = data[:len(data) // 2]
            self.stats["fault cut"] += 1
        start = max(now, self._free_at) + (busy if self.realtime else 0.0)
        self._free_at = start + self._wire_time(len(data))
        self._queue.append((self._free_at, data))
        self.stats[f"sent {msg.name}"] += 1

    def _nack(self, mid: int, text: str, now: float) -> None:
        self.stats["nacks"] += 1
        self._send(Message("nack", nacked_id=mid, nack_message=text.encode("ascii", "replace")), now)

    # ---- commands ----
    def _on_message(self, m: Message, now: float) -> None:
        self.stats[f"got {m.name}"] += 1
        if m.message_id != ids["general_request"] and m.message_id != ids["auto_transmit"]:
            self._auto = None      # any command ends auto-transmit, as motor_off does
        if m.message_id == ids["general_request"]:
            self._request(m.requested_id, now)
        elif m.message_id == ids["transducer"]:
            self._transducer(m, now)
        elif m.message_id == ids["auto_transmit"]:
            self._auto_transmit(m, now)
        elif m.message_id == ids["reset"]:
            self._reset()
        elif m.message_id == ids["motor_off"]:
            self._send(Message("ack", acked_id=m.message_id), now)
        elif m.message_id not in (ids["ack"], ids["nack"]):
            self._nack(m.message_id, f"{m.name} is not supported by this head", now)

    def _request(self, mid: int, now: float) -> None:
        if mid == ids["protocol_version"]:
            self._send(Message("protocol_version", version_major=1, version_minor=1, version_patch=0), now)
        elif mid == ids["device_information"]:
            self._send(Message("device_information", device_type=2, device_revision=1,
                               firmware_version_major=3, firmware_version_minor=3, firmware_version_patch=0), now)
        elif mid == ids["device_data"]:
            self._send(Message("device_data", **self.state), now)
        else:
            self._nack(ids["general_request"], f"cannot send message {mid}", now)

    def _check(self, m: Message) -> str | None:
        for name in _STATE:
            if name in m.fields:
                try:
                    check_setting(name, getattr(m, name), m.name)
                except ValueError as e:
                    return str(e)
        return None

    def _transducer(self, m: Message, now: float) -> None:
        problem = self._check(m)
        if problem:
            self._nack(m.message_id, problem, now)
            return
        old = self.state["angle"]
        self.state.update({k: int(getattr(m, k)) for k in _STATE})
        if not m.transmit:
            self._send(Message("device_data", **self.state), now)
            return
        self._ping("device_data", self.state, old, now)

    def _ping(self, name: str, fields: dict, old_angle: int, now: float, **extra) -> None:
        moved = abs(fields["angle"] - old_angle) % GRADIANS
        moved = min(moved, GRADIANS - moved)
        n = fields["number_of_samples"]
        busy = (self._wire_time(24) + moved * self.motor_time + fields["transmit_duration"] * 1e-6
                + n * fields["sample_period"] * TICK)
        index = self.stats["pings"]
        self.stats["pings"] += 1
        row = self.row(fields["angle"], fields["sample_period"], n, extra.get("num_steps", 1))
        self._send(Message(name, **fields, **extra, data=row), now, busy, ping=index)

    def _auto_transmit(self, m: Message, now: float) -> None:
        problem = self._check(m)
        for name in ("start_angle", "stop_angle"):
            if problem is None and not 0 <= getattr(m, name) < GRADIANS:
                problem = f"auto_transmit '{name}': {getattr(m, name)} is not allowed (0..399 gradians)"
        if problem is None and not 1 <= m.num_steps <= 10:
            problem = f"auto_transmit 'num_steps': {m.num_steps} is not allowed (1..10 gradians)"
        if problem:
            self._nack(m.message_id, problem, now)
            return
        self.state.update({k: int(getattr(m, k)) for k in _STATE if k in m.fields})
        self.state["angle"] = m.start_angle
        self._auto = {k: int(getattr(m, k)) for k in ("start_angle", "stop_angle", "num_steps", "delay")}
        self._auto_next = m.start_angle

    def _auto_ping(self, now: float) -> None:
        a = self._auto
        old = self.state["angle"]
        self.state["angle"] = self._auto_next
        extra = dict(start_angle=a["start_angle"], stop_angle=a["stop_angle"], num_steps=a["num_steps"],
                     delay=a["delay"])
        self._ping("auto_device_data", self.state, old, now + a["delay"] * 1e-3, **extra)
        # start to stop, then from start again (stop == start: whole turns)
        width = (a["stop_angle"] - a["start_angle"]) % GRADIANS or GRADIANS
        off = (self._auto_next - a["start_angle"]) % GRADIANS + a["num_steps"]
        if width < GRADIANS and off > width:
            off = 0
        self._auto_next = (a["start_angle"] + off) % GRADIANS

    # ---- samples ----
    def row(self, angle: int, sample_period: int, n: int, step: int = 1) -> bytes:
        """The samples the head sends at ``angle`` (gradians) for these settings."""
        scan = self.scan
        out = np.zeros(n, np.uint8)
        if scan.n_pings:
            rad = angle_to_radians(angle) % (2 * math.pi)
            diff = np.abs(np.mod(self._b - rad + math.pi, 2 * math.pi) - math.pi)
            k = int(np.argmin(diff))
            if diff[k] <= max(self._scan_step, step * math.pi / 200) / 2 + 1e-9:
                w = sample_period * TICK * self.sound_speed / 2.0
                centres = (np.arange(n) + 0.5) * w
                idx = np.floor((centres - scan.range_min) / scan.bin_width + 1e-9).astype(np.int64)
                ok = (idx >= 0) & (idx < scan.n_bins)
                out[ok] = scan.data[k, idx[ok]]
            else:
                self.stats["pings off the scan's bearings"] += 1
        return out.tobytes()


def serve(scan: Scan, port_url: str | None = None, seconds: float | None = None, *, out=None,
          **kwargs) -> int:
    """Run a `VirtualPing360` in the foreground: print ``virtual Ping360 on PORT``, serve until
    ``seconds`` or Ctrl-C. Other keyword arguments go to `VirtualPing360`."""
    return VirtualPing360(scan, port_url, **kwargs).serve(seconds, out, "virtual Ping360")
