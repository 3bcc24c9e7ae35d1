"""Scan assembly: scanlines (`HeadData`) of a mechanically scanned head grouped into `Scan` objects.

Bearings and poses in a `Scan` (contract shared with the renderer): wire bearing ``b`` maps to
``(3200 - b) * pi / 3200`` rad (sign flipped for an inverted head); bearings are unwrapped
``bearing_start + k * bearing_step``; ``poses[k] = pose @ R_y(bearings[k])`` where ``pose`` is
the head's mounting (world from beam frame at bearing 0: +z boresight, +y scan axis) at the
time the ping arrived. Used by the driver (`mitsonar.devices.micron.driver`) and by `mitsonar.devices.recording.replay`,
so a log replays into the scans the driver returned. No I/O.
"""
from __future__ import annotations

import math

import numpy as np

from mitsonar.acoustics.water import SOUND_SPEED
import mitsonar.kinds as kinds
from mitsonar.geometry.frames import bearing_rotation, check_rigid
import mitsonar.presets.micron as micron
from mitsonar.scan import ElectronicsSettings, Scan, ScanMeta, reception_times
from mitsonar.devices.micron.seanet.constants import FULL_TURN, HdCtrl, bearing_to_radians
from mitsonar.devices.micron.seanet.messages import HeadData
from mitsonar.devices.micron.seanet.settings import HeadSettings, ad_db, gain_db

__all__ = ["ScanAssembler", "beam_rotation", "check_pose"]

# The bearing convention lives with the Scan; kept under this name for the driver's users.
beam_rotation = bearing_rotation


def check_pose(pose) -> np.ndarray:
    """A head mounting as a float64 4x4 (identity for None); ValueError unless rigid and finite.

    Checked where a navigation pose comes in, not only when its scan is put together.
    """
    return np.eye(4) if pose is None else check_rigid(np.array(pose, dtype=np.float64), "pose")


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

    def __init__(self, sound_speed: float = SOUND_SPEED, *, revisit: bool = True, max_turns: int = 3,
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
        T = check_pose(pose)
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
        row_times = np.full(n, np.nan)
        for k in range(n):
            it = self._slots.get(k)
            if it is not None:
                p, T, t = it
                data[k] = p.bins
                last_T = T
                if t is not None:
                    times.append(t)
                    row_times[k] = t
            poses[k] = last_T
        # Missing rows before the first received one take the first pose seen.
        first = next((self._slots[k][1] for k in range(n) if k in self._slots), np.eye(4))
        for k in range(n):
            if k in self._slots:
                break
            poses[k] = first
        poses = poses @ beam_rotation(bearings)
        meta = ScanMeta(
            source="seanet", sweep=sweep, wire_bearings=wire, missing=missing,
            ad_interval=int(ref.ad_interval), step_size=int(ref.step_size),
            hd_ctrl=int(ref.hd_ctrl), device_type=int(ref.device_type),
            gain_byte=int(ref.gain), ad_low_byte=int(ref.ad_low),
            ad_span_byte=int(ref.ad_span), nibble_order=ref.nibble_order,
        )
        if sweep == "sector":
            meta.left_lim, meta.right_lim = int(ref.left_lim), int(ref.right_lim)
        if times:
            meta.start_time, meta.end_time = float(min(times)), float(max(times))
        return Scan(intensity=np.zeros((n, nb), np.float32), data=data,
                    ranges=(np.arange(nb) + 0.5) * width, bearings=bearings, poses=poses,
                    range_min=0.0, range_max=float(range_max), beamwidth_h=micron.BEAMWIDTH_H,
                    beamwidth_v=micron.BEAMWIDTH_V,
                    kind=kinds.MECHANICAL.name, sound_speed=c, times=reception_times(row_times),
                    electronics=ElectronicsSettings.from_dict(_wire_electronics(ref)), meta=meta)

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



def _wire_electronics(ref) -> dict:
    """What a reply's header says of the receiver, in `Electronics`' names and units (dB), so that
    ``HeadSettings.from_scan`` of a received scan asks the head for the same gain and A/D window."""
    out = {"bit_depth": 8 if ref.adc8on else 4, "gain": gain_db(ref.gain), "ad_low": ad_db(ref.ad_low)}
    if int(ref.ad_span) > 0:  # a zero span is no window: leave the default
        out["ad_span"] = ad_db(ref.ad_span)
    return out
