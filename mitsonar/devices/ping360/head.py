"""What a Blue Robotics Ping360 is: its settings and their ranges, its geometry, and its scans.

No I/O; shared by the driver (`mitsonar.devices.ping360.driver`), the virtual head (`mitsonar.devices.ping360.virtual`)
and `mitsonar.devices.recording.replay`. Field ranges are those of ping-protocol's ``ping360.json``
(also in ``brping/ping360.py``'s docstrings; ``reference/seanet.md`` section 6):

==================  ===========================  ==========================================
gain_setting        0 low, 1 normal, 2 high      analog receiver gain preset
transmit_duration   1..1000 us                   None: the rule below
sample_period       80..40000 ticks of 25 ns     from the range: see `Ping360Settings`
transmit_frequency  500..1000 kHz                750 (practical 650..850)
number_of_samples   200..1200                    1200
angle               0..399 gradians              400 per turn, 0.9 deg each
==================  ===========================  ==========================================

Range: a sample ``i`` of ``n`` covers ``[i, i+1) * w`` with ``w = sample_period * 25 ns * c / 2``;
``range_max = n * w``. Transmit duration when not given (Blue Robotics' Ping360 examples,
"per firmware engineer"): ``8000 * range / c`` us, at least 2.5 sample periods, within 5..500 us.

Bearing: the head's angle turns clockwise seen from above (as the Micron's wire bearing), the
simulator's bearing counter-clockwise about the beam frame's +y (`mitsonar.scan.bearing_rotation`),
so angle ``a`` is bearing ``-a * pi / 200`` (angle 0 ahead, bearing 0).
"""
from __future__ import annotations

import math
from dataclasses import asdict, dataclass, field

import numpy as np

from mitsonar._checks import in_range, is_whole, require
from mitsonar.acoustics.water import SOUND_SPEED
import mitsonar.kinds as kinds
from mitsonar.geometry.frames import bearing_rotation, check_rigid
from mitsonar.presets.ping360 import BEAMWIDTH_H, BEAMWIDTH_V  # the head's beam (published figures)
from mitsonar.scan import ElectronicsSettings, Scan, ScanMeta, reception_times

__all__ = ["Ping360Settings", "Ping360Assembler", "GRADIANS", "TICK", "LIMITS", "GAIN_PRESETS",
           "BEAMWIDTH_H", "BEAMWIDTH_V", "angle_to_radians", "ping_problem", "check_pose"]

GRADIANS = 400
TICK = 25e-9
GAIN_PRESETS = {"low": 0, "normal": 1, "high": 2}
LIMITS = {"gain_setting": (0, 2), "transmit_duration": (1, 1000), "sample_period": (80, 40000),
          "transmit_frequency": (500, 1000), "number_of_samples": (200, 1200), "angle": (0, 399),
          "step": (1, 200), "sound_speed": (1300.0, 1800.0)}
_UNITS = {"gain_setting": "0 low, 1 normal, 2 high", "transmit_duration": "us",
          "sample_period": "ticks of 25 ns", "transmit_frequency": "kHz", "number_of_samples": "samples",
          "angle": "gradians", "step": "gradians", "sound_speed": "m/s"}


def check_setting(name: str, value, where: str = "Ping360") -> None:
    """Refuse a head field outside `LIMITS` in one line (`mitsonar._checks.not_allowed`)."""
    lo, hi = LIMITS[name]
    whole = name != "sound_speed"
    ok = in_range(value, lo, hi) and (not whole or is_whole(value))
    require(ok, where, name, value, f"{'a whole number ' if whole else ''}{lo}..{hi} {_UNITS[name]}")


def angle_to_radians(angle) -> float:
    """Simulator bearing of head angle ``angle`` (gradians), wrapped to (-pi, pi]."""
    b = -(float(angle) % GRADIANS) * math.pi / 200.0
    return b + 2 * math.pi if b <= -math.pi else b


def check_pose(pose) -> np.ndarray:
    """A head mounting as a float64 4x4 (identity for None); ValueError unless rigid and finite."""
    return np.eye(4) if pose is None else check_rigid(np.array(pose, dtype=np.float64), "pose")


@dataclass
class Ping360Settings:
    """Settings of a Ping360 scan (the fields of its ``transducer`` message, plus the sweep).

    ==================  ==================================================================
    range               m, requested range; ``sample_period`` = round(2 range / (c n 25 ns))
    number_of_samples   samples per ping, 200..1200 (default 1200)
    sound_speed         m/s, 1300..1800 (default 1500)
    gain_setting        0 low, 1 normal (default), 2 high (`GAIN_PRESETS`)
    transmit_frequency  kHz, 500..1000 (default 750)
    transmit_duration   us, 1..1000; None (default): the rule of the module docstring
    step                gradians between pings, 1..200 (default 1: 400 pings a turn)
    start_angle         first angle of a scan, gradians (default 0, ahead)
    stop_angle          None (default): full turns; else the last angle of a sector scan
    clockwise           angles increase during a scan (default True)
    ==================  ==================================================================

    ``range_max`` is the range the wire values give (snapped to ``range`` when within 1e-9 of
    it), ``angles`` the angles of one scan in order.
    """

    range: float = 12.0
    number_of_samples: int = 1200
    sound_speed: float = SOUND_SPEED
    gain_setting: int = 1
    transmit_frequency: int = 750
    transmit_duration: int | None = None
    step: int = 1
    start_angle: int = 0
    stop_angle: int | None = None
    clockwise: bool = True
    sample_period: int = field(init=False)

    def __post_init__(self):
        w = "Ping360Settings"
        require(in_range(self.range, 1e-3, 1e4), w, "range", self.range, "a range in metres, 0.001..10000")
        for name in ("number_of_samples", "sound_speed", "gain_setting", "transmit_frequency", "step"):
            check_setting(name, getattr(self, name), w)
        check_setting("angle", self.start_angle, w)
        if self.stop_angle is not None:
            check_setting("angle", self.stop_angle, w)
        self.number_of_samples, self.gain_setting = int(self.number_of_samples), int(self.gain_setting)
        self.transmit_frequency, self.step = int(self.transmit_frequency), int(self.step)
        self.start_angle = int(self.start_angle)
        self.sound_speed = float(self.sound_speed)
        sp = round(2.0 * self.range / (self.sound_speed * self.number_of_samples * TICK))
        require(LIMITS["sample_period"][0] <= sp <= LIMITS["sample_period"][1], w, "range", self.range,
                f"with {self.number_of_samples} samples at {self.sound_speed:g} m/s: "
                f"{self.range_for(80):.3g}..{self.range_for(40000):.4g} m (sample period 80..40000 ticks)")
        self.sample_period = int(sp)
        if self.transmit_duration is None:
            self.transmit_duration = auto_transmit_duration(self.range_max, self.sample_period, self.sound_speed)
        check_setting("transmit_duration", self.transmit_duration, w)
        self.transmit_duration = int(self.transmit_duration)
        if self.stop_angle is None:
            require(GRADIANS % self.step == 0, w, "step", self.step,
                    "a divisor of 400 for full turns (1, 2, 4, 5, 8, 10, ...)")
        else:
            self.stop_angle = int(self.stop_angle)
            width = ((self.stop_angle - self.start_angle) * (1 if self.clockwise else -1)) % GRADIANS
            require(width % self.step == 0 and width > 0, w, "stop_angle", self.stop_angle,
                    f"a whole number of {self.step}-gradian steps from start_angle {self.start_angle}")

    def range_for(self, sample_period: int) -> float:
        return self.number_of_samples * sample_period * TICK * self.sound_speed / 2.0

    @property
    def range_max(self) -> float:
        r = self.range_for(self.sample_period)
        return float(self.range) if abs(r - self.range) <= 1e-9 * self.range else r

    @property
    def bin_width(self) -> float:
        return self.range_max / self.number_of_samples

    @property
    def angles(self) -> list[int]:
        d = 1 if self.clockwise else -1
        if self.stop_angle is None:
            n = GRADIANS // self.step
        else:
            n = ((self.stop_angle - self.start_angle) * d) % GRADIANS // self.step + 1
        return [(self.start_angle + d * k * self.step) % GRADIANS for k in range(n)]

    def ping_time(self) -> float:
        """Seconds a ping listens: ``number_of_samples * sample_period * 25 ns`` (2 R / c)."""
        return self.number_of_samples * self.sample_period * TICK

    def transducer(self, angle: int, transmit: bool = True) -> dict:
        """Fields of the ``transducer`` message asking for a ping at ``angle``."""
        check_setting("angle", angle)
        return dict(mode=1, gain_setting=self.gain_setting, angle=int(angle),
                    transmit_duration=self.transmit_duration, sample_period=self.sample_period,
                    transmit_frequency=self.transmit_frequency, number_of_samples=self.number_of_samples,
                    transmit=int(bool(transmit)), reserved=0)

    def as_dict(self) -> dict:
        d = asdict(self)
        d.pop("sample_period")
        return d

    @classmethod
    def from_scan(cls, scan, **overrides) -> "Ping360Settings":
        """Settings under which a Ping360 reproduces ``scan``: range and samples from its range
        window (starting at 0 m), step, start and direction from its bearings (a sector when they
        do not cover a full turn). Keyword arguments override any field."""
        require(scan.sonar_kind.scanlines, "Ping360Settings.from_scan", "kind", scan.kind,
                "a mechanical scan: a Ping360 has one beam")
        bw = float(scan.range_max - scan.range_min) / scan.n_bins
        n = int(round(scan.range_max / bw))
        bear = np.asarray(scan.bearings, dtype=np.float64)
        step_rad = float(np.median(np.diff(bear))) if bear.size > 1 else -math.pi / 200
        step = max(1, int(round(abs(step_rad) * 200 / math.pi)))
        start = int(round(-bear[0] * 200 / math.pi)) % GRADIANS
        kw = dict(range=n * bw, number_of_samples=n, sound_speed=float(scan.sound_speed), step=step,
                  start_angle=start, clockwise=step_rad < 0)
        if bear.size * step < GRADIANS:
            kw["stop_angle"] = (start + (1 if step_rad < 0 else -1) * step * (bear.size - 1)) % GRADIANS
        kw.update(overrides)
        return cls(**kw)


def auto_transmit_duration(range_max: float, sample_period: int, sound_speed: float) -> int:
    """The transmit duration (us) Blue Robotics' examples use for a range (module docstring)."""
    us = 8000.0 * range_max / sound_speed
    us = max(2.5 * sample_period * TICK * 1e6, us)
    return int(round(min(500.0, max(5.0, us))))


def ping_problem(reply, command) -> str | None:
    """Why ``reply`` (``device_data``) is not the ping ``command`` (``transducer``) asked for."""
    for name in ("angle", "gain_setting", "transmit_duration", "sample_period", "transmit_frequency",
                 "number_of_samples"):
        if getattr(reply, name) != getattr(command, name):
            return f"{name} {getattr(reply, name)} where {getattr(command, name)} was asked"
    if len(reply.data) != reply.number_of_samples:
        return f"{len(reply.data)} samples where number_of_samples says {reply.number_of_samples}"
    return None


class Ping360Assembler:
    """Groups ``device_data`` replies into `Scan` objects, one per pass over ``settings.angles``.

    `add` (reply, pose, time) places a reply by its angle and returns the scan when the last
    angle of the pass arrives (or a reply starts a new pass before that: then the rows not
    received are zero and listed in ``scan.meta["missing"]``). ``sound_speed`` turns the sample
    period into ranges. Rows: ``bearings[k] = angle_to_radians(angles[0]) + k * step`` (unwrapped,
    ``step = -+ settings.step * pi / 200``), ``poses[k] = pose @ bearing_rotation(bearings[k])``.
    """

    def __init__(self, settings: Ping360Settings):
        self.settings = settings
        self.angles = settings.angles
        self._index = {a: k for k, a in enumerate(self.angles)}
        self.reset()

    def reset(self) -> None:
        self._slots: dict = {}
        self._last = -1

    def add(self, reply, pose=None, t: float | None = None) -> Scan | None:
        k = self._index.get(reply.angle)
        if k is None or k == self._last:      # not in this scan, or a repeat of the last ping
            return None
        scan = None
        if k <= self._last and self._slots:
            scan = self._build()
        self._slots[k] = (bytes(reply.data), check_pose(pose), t, reply)
        self._last = k
        if k == len(self.angles) - 1 and scan is None:
            return self._build()
        return scan

    def finish(self) -> Scan | None:
        """The pass in progress, zero-filled, or None."""
        return self._build() if self._slots else None

    def _build(self) -> Scan:
        s = self.settings
        n, nb = len(self.angles), s.number_of_samples
        ref = next(iter(self._slots.values()))[3]
        c = s.sound_speed
        w = ref.sample_period * TICK * c / 2.0
        range_max = nb * w
        if abs(range_max - s.range_max) <= 1e-9 * s.range_max:
            range_max, w = s.range_max, s.range_max / nb
        d = -(1 if s.clockwise else -1) * s.step * math.pi / 200.0
        bearings = angle_to_radians(self.angles[0]) + np.arange(n) * d
        data = np.zeros((n, nb), np.uint8)
        poses = np.empty((n, 4, 4))
        first = next(self._slots[k][1] for k in range(n) if k in self._slots)
        last_T, times = first, []
        row_times = np.full(n, np.nan)
        for k in range(n):
            if k in self._slots:
                row, last_T, t, _ = self._slots[k]
                data[k, :len(row)] = np.frombuffer(row, np.uint8)[:nb]
                if t is not None:
                    times.append(t)
                    row_times[k] = t
            poses[k] = last_T
        meta = ScanMeta(source="ping360", sweep="continuous" if s.stop_angle is None else "sector",
                        angles=list(self.angles), missing=[k for k in range(n) if k not in self._slots],
                        gain_setting=int(ref.gain_setting), transmit_duration=int(ref.transmit_duration),
                        sample_period=int(ref.sample_period), transmit_frequency=int(ref.transmit_frequency))
        if times:
            meta.start_time, meta.end_time = float(min(times)), float(max(times))
        self.reset()
        return Scan(intensity=np.zeros((n, nb), np.float32), data=data, ranges=(np.arange(nb) + 0.5) * w,
                    bearings=bearings, poses=poses @ bearing_rotation(bearings), range_min=0.0,
                    range_max=float(range_max), beamwidth_h=BEAMWIDTH_H, beamwidth_v=BEAMWIDTH_V,
                    kind=kinds.MECHANICAL.name, sound_speed=c, times=reception_times(row_times),
                    electronics=ElectronicsSettings(bit_depth=8), meta=meta)
