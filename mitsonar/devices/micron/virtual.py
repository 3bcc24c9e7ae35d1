"""A virtual Tritech Micron: answers the SeaNet protocol with the scanlines of given scans.

``VirtualMicron(scan_or_source)`` opens a pseudo-terminal (or serves a TCP port for
``socket://`` clients, or sits on any pyserial URL) and behaves like a head on the other end:
boot and re-centre, mtAlive about once a second, mtVersionData, mtBBUserData (plus the FPGA
messages of a DST), parameters through mtHeadCommand, and one mtHeadData per mtSendData at the
current motor position, which then steps (continuous turns or sector sweeps).

The scanline sent at wire bearing ``b`` is the row of the scan whose bearing matches
``(3200 - b) * pi / 3200`` (sign flipped for an inverted head) within half a step, resampled
by range onto the head's bins (ADInterval and sound speed: each head bin takes the scan bin
that holds its centre, zero outside the scan's range window); bearings the scan does not cover
send zeros. Together with `mitsonar.devices.micron.driver.MicronSonar`, which maps the other way, a scan
survives the wire unchanged when the driver uses ``HeadSettings.from_scan(scan)``.

Timing model (``realtime=True``): each scanline takes ``18*10/baud`` (the request) +
``2R/c`` (listening; R = n_bins x bin width) + ``motor_time`` (6.5 ms default: what the timing
of a real head in ``reference/seanet.md``, 42.9 ms per line at 10 m, 200 bins, 115200 Bd,
leaves after the other terms), and its ``(45 + Dbytes) * 10 / baud`` transfer delays the next
output, as on a real line. ``realtime=False`` sends
everything at once and shortens boot and alive periods, for tests.

Faults for tests (`Faults`): drop a byte from chosen or random scanlines, inject garbage,
stall (silent, input discarded), reboot mid-scan, report a motor error.
"""
from __future__ import annotations

import heapq
import itertools
import math
import queue
import threading
import time
from collections import Counter
from dataclasses import dataclass

import numpy as np

from mitsonar._checks import in_range
from mitsonar.acoustics.water import SOUND_SPEED
from mitsonar.scan import Scan
from mitsonar.scan.model import require_bytes
from mitsonar.devices.transports import ServedHead, check_port
from mitsonar.devices.micron.seanet import (DEFAULT_NIBBLE_ORDER, FULL_TURN, Alive, BBUserData, FpgaCalibrationData,
                     FpgaVersionData, GainCommand, HeadCommand, HeadData, HeadInf, HeadSettings,
                     HeadStatus, HdCtrl, ReBoot, ScanReverse, SendBBUser, SendData, SendVersion,
                     StopAlives, StreamParser, VersionData, bearing_to_radians, encode, require_mechanical)

__all__ = ["Faults", "VirtualMicron", "serve", "check_port"]

#: what a Micron sends, in the refusal of a scan of wider codes (`mitsonar.scan.model.require_bytes`)
MICRON_SENDS = "a Micron sends 8- or 4-bit samples"


@dataclass
class Faults:
    """Faults the virtual head injects (reply indices count mtHeadData sent, from 0).

    ===================  ==============================================================
    drop_pings           indices of scanlines that lose one byte (at a random offset)
    drop_probability     chance that any scanline loses one byte
    garbage_probability  chance of 1..24 random bytes before any scanline
    stall_at             instead of scanline ``stall_at``, go silent for ``stall_seconds``
                         (no output, input discarded); once
    stall_seconds        1.0
    reboot_at            instead of scanline ``reboot_at``, reset (re-centre, forget the
                         parameters, boot again); once
    motor_error_at       from scanline ``motor_error_at`` on, report MotErr in the head
                         status until the parameters are sent again; once
    ===================  ==============================================================
    """

    drop_pings: tuple = ()
    drop_probability: float = 0.0
    garbage_probability: float = 0.0
    stall_at: int | None = None
    stall_seconds: float = 1.0
    reboot_at: int | None = None
    motor_error_at: int | None = None

    def __post_init__(self):
        for name in ("drop_probability", "garbage_probability"):
            v = getattr(self, name)
            if not in_range(v, 0.0, 1.0):
                raise ValueError(f"Faults.{name} = {v!r} is outside 0..1")
        if self.stall_seconds < 0:
            raise ValueError(f"Faults.stall_seconds = {self.stall_seconds!r} must be >= 0")
        self.drop_pings = tuple(int(i) for i in self.drop_pings)



# --------------------------------------------------------------------------------------------
# The head
# --------------------------------------------------------------------------------------------

class VirtualMicron(ServedHead):
    """A simulated Micron on a pseudo-terminal, a TCP port or a pyserial URL.

    =================  =========================================================================
    scan_source        a `Scan`, or a callable ``scan_source(settings: HeadSettings) -> Scan``
                       called each time the host sends parameters (e.g.
                       ``lambda s: mitsonar.render_scan(scene, ...)``)
    port_url           None or ``"pty"``: a new pseudo-terminal (default); ``socket://HOST:PORT``:
                       listen there (port 0 picks one); anything else: open that pyserial URL
                       (e.g. one end of a null-modem pair) and be the head on it
    baudrate           115200 (timing model only on a pty)
    realtime           True: the timing model above; False: as fast as possible
    dst                behave as a Micron DST (BBUser byte 19 = 15, FPGA messages, type 0x11)
    sound_speed        m/s, turns ADInterval into metres; default the scan's, else 1500
    boot_time          s from reset to "centred" (default 2.0 realtime, 0.02 otherwise)
    alive_interval     s between mtAlive (default 1.0 realtime, 0.05 otherwise)
    motor_time         s per step added to a scanline (default 0.0065)
    faults             `Faults` to inject (default none)
    seed               seed of the fault generator
    nibble_order       4-bit packing, ``"low_first"`` (default) or ``"high_first"``
    serial_number      reported in mtVersionData
    =================  =========================================================================

    `start` (or ``with``) returns the port a driver opens: the slave device path of the pty, or
    ``socket://host:port``. ``stats`` counts what happened; ``settings`` is the `HeadSettings`
    in force (None before parameters); ``bearing`` the motor position; ``last_error`` the last
    exception of the scan source or transport.
    """

    def __init__(self, scan_source, port_url: str | None = None, *, baudrate: int = 115200,
                 realtime: bool = True, dst: bool = True, sound_speed: float | None = None,
                 boot_time: float | None = None, alive_interval: float | None = None,
                 motor_time: float = 0.0065, faults: Faults | None = None, seed: int = 0,
                 nibble_order: str = DEFAULT_NIBBLE_ORDER, serial_number: int = 0x4D53):
        if not (isinstance(scan_source, Scan) or callable(scan_source)):
            raise TypeError("scan_source must be a Scan or a callable settings -> Scan")
        if isinstance(scan_source, Scan):
            require_mechanical(scan_source, "VirtualMicron", "no SeaNet scanlines to serve")
            require_bytes(scan_source, "VirtualMicron", MICRON_SENDS)
        self._source = scan_source
        self.port_url = port_url
        self.baudrate = int(baudrate)
        self.realtime = bool(realtime)
        self.dst = bool(dst)
        if sound_speed is None:
            sound_speed = float(scan_source.sound_speed) if isinstance(scan_source, Scan) else SOUND_SPEED
        self.sound_speed = float(sound_speed)
        self.boot_time = float(boot_time if boot_time is not None else (2.0 if realtime else 0.02))
        self.alive_interval = float(alive_interval if alive_interval is not None else (1.0 if realtime else 0.05))
        if self.alive_interval <= 0 or self.boot_time < 0:
            raise ValueError("alive_interval must be > 0 and boot_time >= 0")
        self.motor_time = float(motor_time)
        self.faults = faults or Faults()
        self._rng = np.random.default_rng(seed)
        self.nibble_order = nibble_order
        self.serial_number = int(serial_number)
        self.parser = StreamParser(nibble_order=nibble_order)
        self.stats: Counter = Counter()
        self.last_error: BaseException | None = None
        self.settings: HeadSettings | None = None
        self.command: HeadCommand | None = None
        self.scan: Scan | None = scan_source if isinstance(scan_source, Scan) else None
        self.bearing = 3200
        self._transport = None
        self._thread = None
        self._stop = threading.Event()
        self._actions: queue.SimpleQueue = queue.SimpleQueue()
        self._events: list = []
        self._seq = itertools.count()
        self._out = bytearray()
        self._tx_free = 0.0
        self._gen = 0
        self._fired: set = set()
        self._reset_state(time.monotonic())

    # ---- lifecycle ----
    def _power_on(self) -> None:
        now = time.monotonic()
        self._reset_state(now)
        self._boot(now)
        self._schedule(now + self.alive_interval, self._alive_tick, gen=None)

    def reboot(self) -> None:
        """Reset the head now (as a power glitch would)."""
        self._actions.put(("reboot", None))

    def stall(self, seconds: float) -> None:
        """Go silent for ``seconds`` (input discarded)."""
        self._actions.put(("stall", float(seconds)))

    # ---- state ----
    def _reset_state(self, now: float) -> None:
        self._booting = True
        self._boot_t0 = now
        self._sent_cfg = False
        self.settings = None
        self.command = None
        self._rows = {}
        self._bearing_dir = 1
        self.bearing = 3200
        self._busy = False
        self._queued = 0
        self._motor_error = False
        self._stalled_until = 0.0
        self._alives = True

    def _schedule(self, t: float, fn, *args, gen=-1) -> None:
        heapq.heappush(self._events, (t, next(self._seq), self._gen if gen == -1 else gen, fn, args))

    def _boot(self, now: float) -> None:
        self._gen += 1          # drops every reply still scheduled from before the reset
        self._out.clear()
        self._reset_state(now)
        self.stats["boots"] += 1
        self._schedule(now + self.boot_time, self._booted)

    def _booted(self, now: float) -> None:
        self._booting = False
        self._send_alive(now)

    # ---- main loop ----
    def _tick(self) -> None:
        now = time.monotonic()
        self._do_actions(now)
        self._due(now)
        self._flush()
        wait = 0.02
        if self._events:
            wait = min(wait, max(0.0, self._events[0][0] - time.monotonic()))
        if self._out:
            wait = min(wait, 0.002)
        data = self._transport.read(wait)
        if data:
            self._on_bytes(data, time.monotonic())

    def _do_actions(self, now: float) -> None:
        while True:
            try:
                action, arg = self._actions.get_nowait()
            except queue.Empty:
                return
            if action == "reboot":
                self._boot(now)
            elif action == "stall":
                self._start_stall(now, arg)

    def _due(self, now: float) -> None:
        while self._events and self._events[0][0] <= now:
            t, _, gen, fn, args = heapq.heappop(self._events)
            if gen is not None and gen != self._gen:
                continue
            fn(now, *args)

    def _flush(self) -> None:
        if not self._out:
            return
        n = self._transport.write(bytes(self._out[:65536]))
        del self._out[:n]
        if len(self._out) > (1 << 20):
            # Nobody reads the line: a real head keeps sending, the bytes are lost.
            self.stats["bytes lost (nobody reading)"] += len(self._out)
            self._out.clear()

    def _emit(self, now: float, data: bytes) -> None:
        """Put bytes on the line; in realtime they arrive after their transfer time."""
        if now < self._stalled_until:
            return
        if not self.realtime:
            self._out += data
            return
        start = max(now, self._tx_free)
        self._tx_free = start + len(data) * 10.0 / self.baudrate
        # Bytes already on the line arrive whatever the head does next (gen=None); only a
        # stall swallows them.
        self._schedule(self._tx_free, self._deliver, data, gen=None)

    def _deliver(self, now: float, data: bytes) -> None:
        if now >= self._stalled_until:
            self._out += data

    def _send(self, now: float, msg) -> None:
        self._emit(now, encode(msg))
        self.stats[f"sent {msg.name}"] += 1

    # ---- alive ----
    def _head_inf(self) -> int:
        if self._booting:
            return int(HeadInf.IN_CENTRE | HeadInf.MOTORING | HeadInf.NO_PARAMS)
        f = HeadInf(0)
        if self._sent_cfg:
            f |= HeadInf.SENT_CFG
        if self.command is None:
            return int(f | HeadInf.CENTRED | HeadInf.NO_PARAMS)
        f |= HeadInf.MOTOR_ON | HeadInf.IN_SCAN
        if self._bearing_dir > 0:
            f |= HeadInf.DIR
        if self.bearing == 3200:
            f |= HeadInf.CENTRED
        return int(f)

    def _send_alive(self, now: float) -> None:
        if not self._alives:
            return
        clock = int((now - self._boot_t0) * 1000) & 0xFFFFFFFF
        self._send(now, Alive(clock_ms=clock, heading=self.bearing, head_inf=self._head_inf()))

    def _alive_tick(self, now: float) -> None:
        self._send_alive(now)
        self._schedule(now + self.alive_interval, self._alive_tick, gen=None)

    def _changed(self, now: float) -> None:
        # A real head reports state changes with its next ~1 Hz alive; tests need not wait.
        if not self.realtime:
            self._send_alive(now)

    # ---- commands ----
    def _on_bytes(self, data: bytes, now: float) -> None:
        if now < self._stalled_until:
            self.stats["bytes ignored while stalled"] += len(data)
            return
        for m in self.parser.feed(data):
            self.stats[f"got {m.name}"] += 1
            if isinstance(m, ReBoot):
                self._boot(now)
            elif self._booting:
                self.stats["ignored while booting"] += 1
            elif isinstance(m, SendVersion):
                self._send(now, VersionData(software_version=0x19, info_bits=0x01,
                                            serial=self.serial_number & 0xFFFF,
                                            program_length=0x0001F2A0, checksum=0x5A5A))
            elif isinstance(m, SendBBUser):
                self._send(now, BBUserData.make(dst=self.dst))
                if self.dst:
                    self._send(now, FpgaCalibrationData(payload_bytes=bytes(24)))
                    self._send(now, FpgaVersionData(payload_bytes=bytes(16)))
                self._sent_cfg = True
                self._changed(now)
            elif isinstance(m, HeadCommand):
                self._accept(now, m)
            elif isinstance(m, ScanReverse):
                self._bearing_dir = -self._bearing_dir
            elif isinstance(m, GainCommand) and self.command is not None:
                c = self.command
                c.ad_span, c.ad_low = m.ad_span_ch1, m.ad_low_ch1
                c.igain_ch1, c.igain_ch2 = m.igain_ch1, m.igain_ch2
            elif isinstance(m, SendData):
                self._request(now)
            elif isinstance(m, StopAlives):
                self._alives = False

    def _accept(self, now: float, cmd: HeadCommand) -> None:
        try:
            settings = HeadSettings.from_command(cmd, self.sound_speed)
        except ValueError as e:
            self.last_error = e
            self.stats["parameters rejected"] += 1
            return
        scan = self._source if isinstance(self._source, Scan) else None
        if scan is None:
            try:
                scan = self._source(settings)
                if not isinstance(scan, Scan):
                    raise TypeError(f"scan_source returned {type(scan).__name__}, not a Scan")
                require_bytes(scan, "VirtualMicron", MICRON_SENDS)
            except Exception as e:
                self.last_error = e
                self.stats["scan source errors"] += 1
                scan = self.scan       # keep serving the previous scan, if any
        self.settings, self.command, self.scan = settings, cmd, scan
        self._prepare_rows()
        self._motor_error = False
        self._gen += 1          # scanlines in flight belong to the old parameters
        self._busy, self._queued = False, 0
        s = settings
        if s.continuous:
            self.bearing = 3200
            self._bearing_dir = 1 if s.scan_right else -1
        else:
            # Start on the limit the scan direction leaves from, so the first sweep runs the
            # way the settings ask.
            self.bearing = s.left_limit if s.scan_right else s.right_limit
            self._bearing_dir = 1 if s.scan_right else -1
        self.stats["parameters accepted"] += 1
        self._changed(now)

    def _prepare_rows(self) -> None:
        self._rows = {}
        s, scan = self.settings, self.scan
        if scan is None:
            self._bin_index = None
            return
        centres = (np.arange(s.n_bins) + 0.5) * s.bin_width
        # The scan bin holding the head bin's centre; a centre on a boundary (head bins an exact
        # multiple of the scan's) takes the upper bin whatever the rounding of the division.
        idx = np.floor((centres - scan.range_min) / scan.bin_width + 1e-9).astype(np.int64)
        self._bin_valid = (idx >= 0) & (idx < scan.n_bins)
        self._bin_index = np.where(self._bin_valid, idx, 0)
        b = np.asarray(scan.bearings, dtype=np.float64)
        self._scan_bearings = np.mod(b, 2 * math.pi)
        scan_step = float(np.median(np.abs(np.diff(b)))) if b.size > 1 else 0.0
        self._tol = max(scan_step, s.step_size * math.pi / 3200.0) / 2.0 + 1e-9

    def row(self, bearing: int) -> np.ndarray:
        """The uint8 bins the head sends at wire ``bearing`` under the current settings."""
        r = self._rows.get(bearing)
        if r is not None:
            return r
        s = self.settings
        out = np.zeros(s.n_bins, dtype=np.uint8)
        if self.scan is not None and self._bin_index is not None and self.scan.n_pings:
            rad = bearing_to_radians(bearing, s.invert)
            diff = np.abs(np.mod(self._scan_bearings - rad + math.pi, 2 * math.pi) - math.pi)
            k = int(np.argmin(diff))
            if diff[k] <= self._tol:
                out[self._bin_valid] = self.scan.data[k, self._bin_index[self._bin_valid]]
        self._rows[bearing] = out
        return out

    # ---- scanlines ----
    def _request(self, now: float) -> None:
        if self.command is None:
            self.stats["requests without parameters"] += 1
            return
        if self._busy:
            self._queued = min(self._queued + 1, 8)
            return
        self._busy = True
        delay = 0.0
        if self.realtime:
            delay = 18 * 10.0 / self.baudrate + self.settings.n_bins * self.settings.sampling_interval + self.motor_time
        self._schedule(now + delay, self._ping)

    def _once(self, name: str, index) -> bool:
        if index is not None and index == self.stats["scanlines"] and name not in self._fired:
            self._fired.add(name)
            return True
        return False

    def _ping(self, now: float) -> None:
        f = self.faults
        if self._once("reboot", f.reboot_at):
            self.stats["fault reboots"] += 1
            self._boot(now)
            return
        if self._once("stall", f.stall_at):
            self.stats["fault stalls"] += 1
            self._busy, self._queued = False, 0
            self._start_stall(now, f.stall_seconds)
            return
        if self._once("motor", f.motor_error_at):
            self._motor_error = True
        s, c = self.settings, self.command
        b = self.bearing
        at = (b - s.left_limit) % FULL_TURN
        sweep = 0
        if not s.continuous:
            sweep = 1 if at == 0 else (2 if at == s.sector_width else 0)
        status = HeadStatus.ADC8ON if s.bit_depth == 8 else HeadStatus(0)
        if self._motor_error:
            status |= HeadStatus.MOT_ERR
        chan2 = bool(c.hd_ctrl & HdCtrl.CHAN2)
        msg = HeadData.from_bins(
            self.row(b), adc8on=s.bit_depth == 8, nibble_order=self.nibble_order,
            bearing=b, device_type=0x11 if self.dst else 0x02, head_status=int(status),
            sweep_code=sweep, hd_ctrl=c.hd_ctrl, range_scale=c.range_scale,
            txn=c.txn_ch2 if chan2 else c.txn_ch1, gain=c.igain_ch2 if chan2 else c.igain_ch1,
            slope=c.slope_ch2 if chan2 else c.slope_ch1, ad_span=c.ad_span, ad_low=c.ad_low,
            ad_interval=c.ad_interval, left_lim=c.left_lim, right_lim=c.right_lim,
            step_size=c.step_size)
        data = encode(msg)
        index = self.stats["scanlines"]
        self.stats["scanlines"] += 1
        if index in f.drop_pings or (f.drop_probability and self._rng.random() < f.drop_probability):
            cut = int(self._rng.integers(0, len(data)))
            data = data[:cut] + data[cut + 1:]
            self.stats["fault bytes dropped"] += 1
        if f.garbage_probability and self._rng.random() < f.garbage_probability:
            junk = self._rng.integers(0, 256, int(self._rng.integers(1, 25)), dtype=np.uint8).tobytes()
            data = junk + data
            self.stats["fault garbage"] += 1
        self._emit(now, data)
        self._step()
        self._busy = False
        if self._queued:
            self._queued -= 1
            self._request(now)

    def _step(self) -> None:
        s = self.settings
        step = s.step_size
        if s.continuous:
            self.bearing = (self.bearing + self._bearing_dir * step) % FULL_TURN
            return
        width = s.sector_width
        off = (self.bearing - s.left_limit) % FULL_TURN
        if off > width:          # outside the sector (just configured): go to the start limit
            off = 0 if self._bearing_dir > 0 else width
        elif self._bearing_dir > 0:
            if off >= width:
                self._bearing_dir, off = -1, max(0, width - step)
            else:
                off = min(width, off + step)
        else:
            if off <= 0:
                self._bearing_dir, off = 1, min(width, step)
            else:
                off = max(0, off - step)
        self.bearing = (s.left_limit + off) % FULL_TURN

    def _start_stall(self, now: float, seconds: float) -> None:
        self._gen += 1
        self._out.clear()
        self._busy, self._queued = False, 0
        self._stalled_until = now + seconds
        self.stats["stalls"] += 1


def serve(scan_source, port_url: str | None = None, seconds: float | None = None, *,
          out=None, **kwargs) -> int:
    """Run a `VirtualMicron` in the foreground: print its port, serve until ``seconds`` or Ctrl-C.

    ``out`` (default ``sys.stdout``) receives the line ``virtual Micron on PORT``; other keyword
    arguments go to `VirtualMicron`.
    """
    return VirtualMicron(scan_source, port_url, **kwargs).serve(seconds, out, "virtual Micron")
