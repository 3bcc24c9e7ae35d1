"""Head settings in engineering units, the receiver's gain scales and the sound-speed bounds.

`HeadSettings` turns range, bins, gain, A/D window, step and sector into the wire values of an
mtHeadCommand (``reference/seanet.md`` section 3) and back; `ping_problem` says whether a
scanline was made under the parameters in force. No I/O.
"""
from __future__ import annotations

import math
import struct
from dataclasses import dataclass, fields
from typing import Any

import numpy as np

from mitsonar._checks import in_range, is_number
from mitsonar.acoustics.water import SOUND_SPEED
import mitsonar.kinds as kinds
from mitsonar.receiver.electronics import HEAD_AD_BYTES, HEAD_DB_SCALE, HEAD_LIMITS
from mitsonar.scan.electronics import ElectronicsSettings
from mitsonar.devices.micron.seanet.constants import FULL_TURN, STEP_SIZES, HdCtrl, radians_to_bearing
from mitsonar.devices.micron.seanet.messages import V3B_BLOCK, V3B_NONE, HeadCommand, HeadData

__all__ = ["HeadSettings", "ping_problem", "sound_speed_ok", "gain_db", "ad_db", "require_mechanical",
           "SOUND_SPEED_RANGE", "SOUND_SPEED_ALLOWED", "DB_FULL_SCALE", "GAIN_FULL_SCALE", "AD_FULL_SCALE"]


def _round(x: float) -> int:
    # Half up, not Python's half-to-even: ADSpan for 24 dB is 76.5 -> 77 as drivers send it.
    return int(math.floor(x + 0.5))


# The receiver's scales on the wire: IGain 0..210 and ADLow/ADSpan 0..255 both span 0..80 dB.
DB_FULL_SCALE, GAIN_FULL_SCALE, AD_FULL_SCALE = HEAD_DB_SCALE, 210, HEAD_AD_BYTES


# Sound speeds a head can be set to (m/s), and how messages word the bound: HeadSettings, the
# replay of a log and the CLI's --sound-speed all use these.
SOUND_SPEED_RANGE = (1300.0, 1800.0)
SOUND_SPEED_ALLOWED = "1300..1800 m/s"


def sound_speed_ok(value) -> bool:
    """Is ``value`` a finite number in `SOUND_SPEED_RANGE`?"""
    return in_range(value, *SOUND_SPEED_RANGE)


def gain_db(byte: int) -> float:
    """An IGain byte in dB."""
    return int(byte) * DB_FULL_SCALE / GAIN_FULL_SCALE


def ad_db(byte: int) -> float:
    """An ADLow or ADSpan byte in dB."""
    return int(byte) * DB_FULL_SCALE / AD_FULL_SCALE


def require_mechanical(scan, who: str, lacks: str) -> None:
    """SeaNet speaks for mechanically scanned heads only: refuse other scan kinds in one sentence."""
    kind = getattr(scan, "kind", kinds.DEFAULT)
    if not getattr(kinds.lookup(kind), "scanlines", False):
        raise ValueError(f"{who}: a SeaNet head is mechanically scanned; a {kind!r} scan (kind must be "
                         f"{kinds.which('scanlines')}) has {lacks}")


@dataclass
class HeadSettings:
    """Scanning parameters of a Micron-class head, in engineering units.

    ===============  ===========  ==============================================================
    name             default      meaning, allowed values
    ===============  ===========  ==============================================================
    range            12.0         range scale, m; 0.3..300
    n_bins           500          bins per scanline; 2..1500 (even in 4-bit mode)
    sound_speed      1500.0       m/s; 1300..1800 (turns range into ADInterval)
    gain             27.8         receiver initial gain, dB; 0..80 (IGain = 210 gain / 80)
    ad_low           12.5         dB mapped to level 0 (4-bit data); 0..80 (ADLow = 255 x / 80)
    ad_span          24.0         dB mapped onto the levels (4-bit data); >0..80
    step_size        32           motor step, 1/16 gradian (32 = 1.8 deg); a divisor of 6400
                                  up to 200 (4, 8, 16, 32 are the head's named resolutions)
    continuous       True         full turns; False scans the sector left_limit..right_limit
    left_limit       2400         sector start, 1/16 gradian (0..6399, 3200 ahead, 1600 left)
    right_limit      4000         sector end; the sector runs clockwise (increasing) from
                                  left to right and its width must be a multiple of step_size
    scan_right       False        step clockwise (increasing wire bearing). False steps
                                  counter-clockwise: increasing simulator bearing
    bit_depth        8            8 (adc8on) or 4 (packed nibbles, ADLow/ADSpan applied)
    invert           False        head mounted upside down (flips the bearing sign)
    frequency        675e3        transmit frequency, Hz; 100e3..2e6 (TxN/RxN words)
    channel          1            1 or 2 (chan2 bit, dual-frequency heads)
    slope            None         TVG slope, 1/255 units; None: 100 for DST, 125 otherwise
    mo_time          25           motor step delay, 10 µs units; 1..255
    lockout          100          lockout after transmit, µs; 0..65535
    max_ad_buf       500          MaxADbuf, 1..1000 (the reference's default; Rock and
                                  UxVCtrl send 1000)
    v3b              False        append the 16-byte V3B gain block (V3B byte 0x1D)
    ===============  ===========  ==============================================================

    Derived wire values: ``ad_interval`` (round(2 range / n_bins / c / 640 ns), must be 5..1500),
    ``igain``, ``ad_low_byte``, ``ad_span_byte``, ``range_scale``, ``tx_pulse_length``,
    ``hd_ctrl``, ``txn``, ``rxn``. ``bin_width`` and ``range_max`` are the actual values after
    ADInterval's rounding. Out-of-range values raise ValueError naming the field.
    """

    range: float = 12.0
    n_bins: int = 500
    sound_speed: float = SOUND_SPEED
    gain: float = 27.8
    ad_low: float = 12.5
    ad_span: float = 24.0
    step_size: int = 32
    continuous: bool = True
    left_limit: int = 2400
    right_limit: int = 4000
    scan_right: bool = False
    bit_depth: int = 8
    invert: bool = False
    frequency: float = 675e3
    channel: int = 1
    slope: int | None = None
    mo_time: int = 25
    lockout: int = 100
    max_ad_buf: int = 500
    v3b: bool = False

    def __post_init__(self) -> None:
        self.validate()

    @staticmethod
    def _need(ok: bool, name: str, value, allowed: str) -> None:
        if not ok:
            raise ValueError(f"HeadSettings.{name} = {value!r} is out of range: allowed {allowed}")

    def validate(self) -> None:
        """Raise ValueError naming the first field outside its allowed values."""
        n = self._need
        num = is_number

        def integer(v):     # an int type: the wire packs ints (is_whole would let 8.0 through)
            return isinstance(v, (int, np.integer)) and not isinstance(v, bool)

        n(num(self.range) and 0.3 <= self.range <= 300.0, "range", self.range, "0.3..300 m")
        n(integer(self.n_bins) and 2 <= self.n_bins <= 1500, "n_bins", self.n_bins, "2..1500")
        n(sound_speed_ok(self.sound_speed), "sound_speed", self.sound_speed, SOUND_SPEED_ALLOWED)
        n(num(self.gain) and in_range(self.gain, *HEAD_LIMITS["gain"]), "gain", self.gain, "0..80 dB")
        n(num(self.ad_low) and in_range(self.ad_low, *HEAD_LIMITS["ad_low"]), "ad_low", self.ad_low, "0..80 dB")
        n(num(self.ad_span) and 0.0 < self.ad_span <= HEAD_LIMITS["ad_span"][1] and self.ad_span_byte >= 1,
          "ad_span", self.ad_span, "0.16..80 dB (ADSpan 1..255)")
        n(integer(self.step_size) and self.step_size in STEP_SIZES, "step_size", self.step_size,
          "a divisor of 6400 in 1..200, 1/16 gradian (4, 8, 16, 32 = 0.225, 0.45, 0.9, 1.8 deg)")
        n(isinstance(self.continuous, (bool, np.bool_)), "continuous", self.continuous, "True or False")
        n(integer(self.left_limit) and 0 <= self.left_limit < FULL_TURN, "left_limit", self.left_limit, "0..6399")
        n(integer(self.right_limit) and 0 <= self.right_limit < FULL_TURN, "right_limit", self.right_limit, "0..6399")
        if not self.continuous:
            width = self.sector_width
            n(width > 0 and width % self.step_size == 0, "right_limit", self.right_limit,
              f"a sector (right_limit - left_limit) mod 6400 that is a positive multiple of "
              f"step_size {self.step_size} (now {width})")
        n(self.bit_depth in (8, 4) and integer(self.bit_depth), "bit_depth", self.bit_depth, "8 or 4")
        if self.bit_depth == 4:
            n(self.n_bins % 2 == 0, "n_bins", self.n_bins, "an even number with bit_depth 4")
        n(num(self.frequency) and 100e3 <= self.frequency <= 2e6, "frequency", self.frequency, "100e3..2e6 Hz")
        n(self.channel in (1, 2), "channel", self.channel, "1 or 2")
        n(self.slope is None or (integer(self.slope) and 0 <= self.slope <= 0xFFFF), "slope", self.slope,
          "None or 0..65535")
        n(integer(self.mo_time) and 1 <= self.mo_time <= 255, "mo_time", self.mo_time, "1..255 (10 µs)")
        n(integer(self.lockout) and 0 <= self.lockout <= 0xFFFF, "lockout", self.lockout, "0..65535 µs")
        n(integer(self.max_ad_buf) and 1 <= self.max_ad_buf <= 1000, "max_ad_buf", self.max_ad_buf, "1..1000")
        ad = self.ad_interval_exact
        n(5 <= _round(ad) <= 1500, "range", self.range,
          f"values giving ADInterval = 2 range / n_bins / sound_speed / 640 ns in 5..1500 "
          f"(now {ad:.1f}: change range or n_bins)")

    # ---- derived wire values ----
    @property
    def sector_width(self) -> int:
        return (self.right_limit - self.left_limit) % FULL_TURN

    @property
    def ad_interval_exact(self) -> float:
        return 2.0 * self.range / self.n_bins / self.sound_speed / 640e-9

    @property
    def ad_interval(self) -> int:
        """ADInterval (640 ns units), rounded to nearest: UxVCtrl truncates, which turns the
        49.9999... of the worked example (12 m, 500 bins) into 49."""
        return _round(self.ad_interval_exact)

    @property
    def sampling_interval(self) -> float:
        return self.ad_interval * 640e-9

    @property
    def bin_width(self) -> float:
        """Actual range per bin after ADInterval's rounding, m."""
        return self.sound_speed * self.sampling_interval / 2.0

    @property
    def range_max(self) -> float:
        """Actual end of the last bin, m (equals ``range`` up to ADInterval's rounding)."""
        return self.n_bins * self.bin_width

    @property
    def data_bytes(self) -> int:
        return self.n_bins if self.bit_depth == 8 else self.n_bins // 2

    @property
    def igain(self) -> int:
        return min(GAIN_FULL_SCALE, _round(GAIN_FULL_SCALE * self.gain / DB_FULL_SCALE))

    @property
    def ad_low_byte(self) -> int:
        return min(AD_FULL_SCALE, _round(AD_FULL_SCALE * self.ad_low / DB_FULL_SCALE))

    @property
    def ad_span_byte(self) -> int:
        return min(AD_FULL_SCALE, _round(AD_FULL_SCALE * self.ad_span / DB_FULL_SCALE))

    @property
    def range_scale(self) -> int:
        return min(0x3FFF, _round(self.range * 10.0))

    @property
    def tx_pulse_length(self) -> int:
        """Transmit pulse, µs: (range + 10) x 25 / 10 clamped to 37..350 (UxVCtrl)."""
        return int(min(350, max(37, _round((self.range + 10.0) * 25.0 / 10.0))))

    @property
    def txn(self) -> int:
        # Truncated like UxVCtrl's constants (675 kHz -> 0x05666666, RxN 0x090A3D70).
        return int(self.frequency * 2 ** 32 / 32e6) & 0xFFFFFFFF

    @property
    def rxn(self) -> int:
        return int((self.frequency + 455e3) * 2 ** 32 / 32e6) & 0xFFFFFFFF

    @property
    def hd_ctrl(self) -> int:
        """HdCtrl: raw | hasmot | ReplyASL as UxVCtrl, plus the flags of these settings."""
        h = HdCtrl.RAW | HdCtrl.HASMOT | HdCtrl.REPLYASL
        if self.bit_depth == 8:
            h |= HdCtrl.ADC8ON
        if self.continuous:
            h |= HdCtrl.CONT
        if self.scan_right:
            h |= HdCtrl.SCANRIGHT
        if self.invert:
            h |= HdCtrl.INVERT
        if self.channel == 2:
            h |= HdCtrl.CHAN2
        return int(h)

    def head_command(self, dst: bool = False) -> HeadCommand:
        """The mtHeadCommand for these settings; ``dst`` selects head type 0x11 and slope 100."""
        slope = self.slope if self.slope is not None else (100 if dst else 125)
        block = b""
        if self.v3b:
            block = struct.pack("<8B4H", self.ad_span_byte, self.ad_span_byte, self.ad_low_byte,
                                self.ad_low_byte, self.igain, self.igain, 0, 0, slope, slope, 0, 0)
        return HeadCommand(
            v3b_params=V3B_BLOCK if self.v3b else V3B_NONE, hd_ctrl=self.hd_ctrl,
            head_type=0x11 if dst else 0x02, txn_ch1=self.txn, txn_ch2=self.txn,
            rxn_ch1=self.rxn, rxn_ch2=self.rxn, tx_pulse_length=self.tx_pulse_length,
            range_scale=self.range_scale, left_lim=self.left_limit, right_lim=self.right_limit,
            ad_span=self.ad_span_byte, ad_low=self.ad_low_byte, igain_ch1=self.igain,
            igain_ch2=self.igain, slope_ch1=slope, slope_ch2=slope, mo_time=self.mo_time,
            step_size=self.step_size, ad_interval=self.ad_interval, n_bins=self.n_bins,
            max_ad_buf=self.max_ad_buf, lockout=self.lockout, v3b_block=block)

    @classmethod
    def from_command(cls, cmd: HeadCommand, sound_speed: float = SOUND_SPEED) -> "HeadSettings":
        """Settings a head would infer from ``cmd`` (the virtual sonar's view of the host).

        The range comes from ADInterval and ``sound_speed`` (RangeScale is informational).
        Raises ValueError when the command asks for something outside the allowed values.
        """
        h = HdCtrl(cmd.hd_ctrl)
        freq = cmd.txn_ch2 if h & HdCtrl.CHAN2 else cmd.txn_ch1
        freq_hz = freq * 32e6 / 2 ** 32
        slope = cmd.slope_ch2 if h & HdCtrl.CHAN2 else cmd.slope_ch1
        return cls(
            range=cmd.n_bins * cmd.ad_interval * 640e-9 * sound_speed / 2.0, n_bins=cmd.n_bins,
            sound_speed=sound_speed, gain=gain_db(cmd.igain_ch2 if h & HdCtrl.CHAN2 else cmd.igain_ch1),
            ad_low=ad_db(cmd.ad_low), ad_span=ad_db(max(cmd.ad_span, 1)),
            step_size=cmd.step_size, continuous=bool(h & HdCtrl.CONT), left_limit=cmd.left_lim,
            right_limit=cmd.right_lim, scan_right=bool(h & HdCtrl.SCANRIGHT),
            bit_depth=8 if h & HdCtrl.ADC8ON else 4, invert=bool(h & HdCtrl.INVERT),
            frequency=freq_hz if 100e3 <= freq_hz <= 2e6 else 675e3,
            channel=2 if h & HdCtrl.CHAN2 else 1, slope=slope, mo_time=max(1, cmd.mo_time),
            lockout=cmd.lockout, max_ad_buf=min(max(cmd.max_ad_buf, 1), 1000),
            v3b=cmd.v3b_params == V3B_BLOCK)

    @classmethod
    def from_scan(cls, scan, **overrides) -> "HeadSettings":
        """Settings under which a head reproduces ``scan`` (a `mitsonar.scan.Scan`) on the wire.

        Range and bins come from the scan's range window (the head's bins always start at
        0 m), the step size and direction from its bearings, a sector from its first and
        last bearing when it does not cover a full turn, the bit depth, receiver gain and A/D
        window (``bit_depth``, ``gain``, ``ad_low``, ``ad_span``) from ``scan.electronics`` where it
        records them (a rendered scan's `Electronics`, a received scan's reply headers). Keyword
        arguments override any field.
        """
        require_mechanical(scan, "HeadSettings.from_scan", "no head settings")
        bw = float(scan.range_max - scan.range_min) / scan.n_bins
        n_bins = int(round(scan.range_max / bw))
        bear = np.asarray(scan.bearings, dtype=np.float64)
        step_rad = float(np.median(np.diff(bear))) if bear.size > 1 else math.radians(1.8)
        step = int(round(abs(step_rad) * 3200.0 / math.pi)) or 32
        invert = bool(overrides.get("invert", False))
        # Simulator bearing increasing = wire bearing decreasing (for an upright head).
        scan_right = (step_rad < 0) != invert
        full = bear.size * step >= FULL_TURN
        e = ElectronicsSettings.from_dict(getattr(scan, "electronics", None) or {})
        kw: dict[str, Any] = dict(range=n_bins * bw, n_bins=n_bins, sound_speed=float(scan.sound_speed),
                                  step_size=step, scan_right=scan_right, continuous=full,
                                  bit_depth=int(8 if e.bit_depth is None else e.bit_depth))
        for name in ("gain", "ad_low", "ad_span"):
            if getattr(e, name) is not None:
                kw[name] = float(getattr(e, name))
        if not full:
            first, last = radians_to_bearing(bear[0], invert), radians_to_bearing(bear[-1], invert)
            kw["left_limit"], kw["right_limit"] = (first, last) if scan_right else (last, first)
        kw.update(overrides)
        return cls(**kw)

    def as_dict(self) -> dict:
        """JSON-friendly field values."""
        return {f.name: (getattr(self, f.name).item() if isinstance(getattr(self, f.name), np.generic)
                         else getattr(self, f.name)) for f in fields(self)}

    def expected_step_time(self, baudrate: int = 115200, motor_time: float = 0.0065) -> float:
        """Seconds per scanline: request + 2R/c + reply transfer + motor (reference timing model)."""
        return (18 * 10 / baudrate + self.n_bins * self.sampling_interval
                + (45 + self.data_bytes) * 10 / baudrate + motor_time)


def ping_problem(ping: HeadData, command: HeadCommand | None) -> str | None:
    """Why ``ping`` should not be used with ``command`` in force, or None.

    Motor error and power loss in the head status mean the parameters must be sent again;
    a scanline whose echoed settings differ from the command (ADInterval, bins, step,
    AD low/span, the cont/adc8on/invert bits, sector limits) was made under other
    parameters. Scan-right is not compared: Micron DST heads always report it set (Rock).
    """
    if ping.motor_error:
        return "head reports a motor error"
    if ping.power_loss:
        return "head reports a power loss"
    if command is None:
        return None
    mask = HdCtrl.CONT | HdCtrl.ADC8ON | HdCtrl.INVERT
    if (ping.hd_ctrl & mask) != (command.hd_ctrl & mask):
        return "HdCtrl (cont/adc8on/invert) differs from the command"
    if ping.n_bins != command.n_bins:
        return f"{ping.n_bins} bins instead of {command.n_bins}"
    if ping.ad_interval != command.ad_interval:
        return f"ADInterval {ping.ad_interval} instead of {command.ad_interval}"
    if ping.step_size != command.step_size:
        return f"step size {ping.step_size} instead of {command.step_size}"
    if ping.ad_low != command.ad_low or ping.ad_span != command.ad_span:
        return "ADLow/ADSpan differ from the command"
    if not command.continuous and (ping.left_lim, ping.right_lim) != (command.left_lim, command.right_lim):
        return "sector limits differ from the command"
    return None
