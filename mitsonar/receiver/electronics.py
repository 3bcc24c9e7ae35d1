"""Sonar head electronics: turns the noise-free ``Scan.intensity`` into device bytes ``Scan.data``.

The chain follows thesis sections 2.1.2 and 2.4.1 and the Tritech Micron's conventions
(``reference/seanet.md``), in this order, vectorised over ``(n_pings, n_bins)``:

1. **Pulse and jitter.** The binned echo energy is convolved along range with the transmit pulse
   (a boxcar ``c * pulse_length / 2`` long that starts at the echo's range: the leading edge of an
   echo marks the true range, the pulse trails behind it) and a Gaussian range jitter of standard
   deviation ``range_jitter``. The kernel sums to one, so energy is conserved except what is
   pushed past ``range_max`` (dropped, like any echo outside the window).
2. **Level.** ``level_db = 10 log10(I) + source_level + receiver_sensitivity + gain + TVG(r)``
   (``source_level`` in dB re 1 uPa at 1 m, ``receiver_sensitivity`` the receiver's response
   referred to the A/D's dB scale; ``I`` the pulse-spread intensity of step 1), with
   ``TVG(r) = min(n log10 r + 2 absorption r, tvg_cap)`` for the ``20log``/``30log``/``40log``
   laws and 0 for ``off``.
3. **Speckle.** The echo's amplitude is multiplied by the scene's complex speckle ``g`` (mean
   power 1): fully developed speckle (``rayleigh``: exponential intensity) or its modulus
   reshaped to a Weibull intensity of shape ``speckle_shape`` (``weibull``), or 1 (``off``).
   Speckle belongs to the scene, not to the receiver: ``g`` is a function of where each bin's
   echo comes from and of the head's pose (`mitsonar.receiver.speckle`, seeded by ``speckle_seed``), so a
   still head sees the same pattern ping after ping and a moving one sees it change at the
   physical rate. Without echo points (an intensity from elsewhere) it is drawn from the seed.
4. **Background.** The transducer's near-field ring-down (a deterministic ringing, decaying
   exponentially in time) and the receiver's noise (a circular complex Gaussian of power
   ``noise_floor``, seeded by the electronics seed, correlated over the pulse) are added to the
   echo as amplitudes, and the power of the sum is taken: ``|sqrt(I) g + sqrt(R) + sqrt(N) n|^2``.
   Both are pinned to the A/D converter's level scale (the scale of ``ad_low``) and pass neither
   the gain nor the TVG: the TVG would lift the background by 20 dB across a 12 m window and
   swamp the far field, while the thesis figures and Micron displays show open water alike at
   all ranges.
5. **Quantisation.** ``data = round(255 clip((level_db - ad_low) / ad_span, 0, 1))`` (halves
   round up), or at 4 bits ``17 round(15 clip(...))`` (0..15 onto 0..255, as the SeaNet driver
   reports packed 4-bit bins); 16, 32 bits (a wider A/D): ``round((2^bits - 1) clip(...))``.

With ``speckle='off'``, ``noise_floor=-inf``, ``ringdown=0``, ``pulse_length=0`` and
``range_jitter=0`` the level is the formula of step 2 (its logarithm computed as ``log2(I) log10(2)``:
a byte can differ from NumPy's ``log10`` only where a level lies within a few units in the last
place of a quantisation step's half).

All randomness comes from a counter-based generator (Philox4x32) keyed by the seed and counted
by bin (`mitsonar.receiver.devicechain`): the same seed gives the same bytes for any thread
count. The chain runs as Dr.Jit kernels of the active variant (on the GPU for ``cuda``): NumPy
intensities are uploaded (`Electronics.apply`), a render's stay on the device
(`Electronics.device_bytes`, `mitsonar.sim.render.render_frame`). Before version 0.3 the noise
was NumPy's PCG64 normals and the chain NumPy's: the same laws and statistics, other bytes.
The input intensity is never modified.

Default settings (Micron-like). The A/D window ``ad_low = 12.5 dB``, ``ad_span = 24 dB`` and
``gain = 28 dB`` are the SeaNet typical values (ADLow byte 40, ADSpan byte 77, IGain 0x49 on the
0..80 dB scale); TVG ``20log`` capped at 40 dB is the thesis's law (2.1.2) and compensates the
1/r^2 of an extended echo; ``source_level + receiver_sensitivity`` (200 - 148 = 52 dB; before
version 0.3 the sum was one calibration constant called ``source_level``) puts a diffuse
concrete wall at 4 m (about 1e-5 per bin, 42 dB) above the top of the window and grazing floor
echoes (1e-7..1e-6, 22..32 dB at 4 m) inside it (`mitsonar.sonar_equation.levels` says where
200 and -148 come from: the Micron's source level is not published; ``noise_level`` and
``receiver_bandwidth`` are the receiver's acoustic noise, which `Scan.snr` compares echoes with, not the
bytes' ``noise_floor`` below); a 100 us pulse (the Micron's short-range setting: 7.5 cm) and 2 cm jitter blur echoes over a few bins. The receiver's noise floor
(15.5 dB, 3 dB above ``ad_low``) and the ring-down (40 dB at the transducer, fading to ``ad_low``
at 0.55 m: an amplitude decay time ``tau = 2 x 0.55 m / c x 8.69 / 27.5 dB = 0.23 ms``) are fitted
to the byte statistics of public recordings of a real Micron (200 bins, 10-20 m, harbour and tank scenes):
beyond 1.6 m, 14-51 % zero bytes and a Weibull shape of 1.05-1.54 for the non-zero ones; from 0.1 to 1.0 m a
mean byte of 60-96 (`mitsonar.receiver.realism`, ``benchmarks/realism.py``). The previous defaults (noise
floor 1.5 dB below ``ad_low``, a 50 dB ring-down to 1.3 m) gave 67 %, 0.88 and 184 on the default box scan.
"""
from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass
from typing import Any

import numpy as np

from mitsonar._checks import is_number, not_a, not_allowed
from mitsonar.acoustics.water import SOUND_SPEED
import mitsonar.receiver.devicechain as devicechain
from mitsonar.acoustics.levels import (DEFAULT_NOISE_LEVEL, DEFAULT_RECEIVER_SENSITIVITY, DEFAULT_SOURCE_LEVEL,
                                       SOURCE_LEVELS, echo_level, source_level_error)
from mitsonar.scan.electronics import ElectronicsSettings
from mitsonar.scan.migrations import rename_settings

TVG_LAWS = {"off": 0, "20log": 20, "30log": 30, "40log": 40}
SPECKLE_MODELS = ("off", "rayleigh", "weibull")
BIT_DEPTHS = tuple(devicechain.AD_CODES)   # 8, 4, 16, 32

#: What a real head accepts for the settings a user gives it: the Micron's gain and A/D window on
#: its 0..80 dB scale, ADSpan at least one byte (80 / 255 dB, rounded). A sonar's XML electronics
#: fields, the command line's ``--set`` and `render_scan`'s ``electronics`` overrides are held to
#: these (`check_head_settings`); the `Electronics` class itself takes the wider simulator ranges
#: of `Electronics.validate` (a negative ``ad_low`` or a 255 dB span, for studies and tests).
HEAD_DB_SCALE = 80.0      # dB of the head's full gain and A/D scale (SeaNet: 0..80 dB)
HEAD_AD_BYTES = 255       # the A/D window's bytes (ADLow, ADSpan) span that scale
HEAD_LIMITS = {"gain": (0.0, HEAD_DB_SCALE), "ad_low": (0.0, HEAD_DB_SCALE),
               # ADSpan must round to at least one byte
               "ad_span": (0.5 * HEAD_DB_SCALE / HEAD_AD_BYTES, HEAD_DB_SCALE)}

#: Ranges below this are clamped in the TVG so that a bin centre at r = 0 stays finite.
MIN_TVG_RANGE = 1e-3


@dataclass
class Electronics:
    """Device-electronics settings of a sonar head (the ``sonar`` sensor's electronics fields).

    ==================== ========= ====================================================================
    field                default   meaning
    ==================== ========= ====================================================================
    source_level         200.0     dB re 1 uPa at 1 m: the head's on-axis source level (real heads
                                   180..230; ``intensity`` is normalised to this source, 1 W/sr on
                                   axis); 150..260 allowed
    receiver_sensitivity -148.0    dB: the receiver's response referred to the A/D's dB scale
                                   (``SL + receiver_sensitivity`` = 52 dB, the calibration constant
                                   called ``source_level`` up to version 0.2.0)
    noise_level          42.0      dB re 1 uPa^2/Hz: ambient plus self noise at the receiver
                                   (thermal noise at 700 kHz: `sonar_equation.ambient_noise_level`)
    receiver_bandwidth   0.0       Hz, the receiver's noise bandwidth; 0 means ``1 / pulse_length``
                                   (not the sensor's ``bandwidth``, the transducer's band; saved
                                   before the rename as ``bandwidth``, still read as this)
    tvg                  ``20log`` time-varying gain law: ``off``, ``20log``, ``30log``, ``40log``
                                   (each plus ``2 absorption r``)
    tvg_cap              40.0      dB, the TVG saturates here (thesis 2.1.2: "around 40 dB")
    gain                 28.0      dB, receiver gain (SeaNet IGain 0x49)
    ad_low               12.5      dB mapped to byte 0 (SeaNet ADLow)
    ad_span              24.0      dB mapped onto 0..255 above ``ad_low`` (SeaNet ADSpan), > 0
    bit_depth            8         8, or 4 (values 0..15 reported as multiples of 17), or 16 or 32
                                   (a wider A/D: the same levels on uint16 or uint32 codes)
    pulse_length         100e-6    s, transmit pulse; spreads echoes over ``c pulse_length / 2`` in range
    range_jitter         0.02      m, standard deviation of the Gaussian range jitter
    speckle              rayleigh  ``off``, ``rayleigh`` (exponential intensity), ``weibull``
    speckle_shape        1.2       Weibull shape k of the intensity speckle (``weibull`` only)
    speckle_seed         0         the scene's speckle: which scatterers its surfaces hold
                                   (`mitsonar.receiver.speckle`); the same seed, pose and scene give the same
                                   pattern whatever the render's path and electronics seeds
    noise_floor          15.5      dB on the A/D level scale (the scale of ``ad_low``): the receiver's
                                   noise power, stationary in range, not moved by ``gain`` or TVG;
                                   ``-inf`` for none
    ringdown             0.55      m, range at which the transducer's ring-down fades to ``ad_low``;
                                   0 for none
    ringdown_level       40.0      dB on the A/D level scale at range 0; falls linearly in dB (an
                                   exponentially damped ringing) to ``ad_low`` at ``ringdown``;
                                   must exceed ``ad_low`` when ``ringdown > 0``
    ==================== ========= ====================================================================

    Invalid settings raise ``ValueError`` naming the field, the value and what is allowed. These are
    the simulator's ranges; what a user gives a head (XML, ``--set``, `render_scan` overrides) is
    also held to the head's own (`HEAD_LIMITS`: gain and A/D window within 0..80 dB).
    """

    source_level: float = DEFAULT_SOURCE_LEVEL
    receiver_sensitivity: float = DEFAULT_RECEIVER_SENSITIVITY
    noise_level: float = DEFAULT_NOISE_LEVEL
    receiver_bandwidth: float = 0.0
    tvg: str = "20log"
    tvg_cap: float = 40.0
    gain: float = 28.0
    ad_low: float = 12.5
    ad_span: float = 24.0
    bit_depth: int = 8
    pulse_length: float = 100e-6
    range_jitter: float = 0.02
    speckle: str = "rayleigh"
    speckle_shape: float = 1.2
    speckle_seed: int = 0
    noise_floor: float = 15.5
    ringdown: float = 0.55
    ringdown_level: float = 40.0

    def __post_init__(self) -> None:
        self.validate()

    # ------------------------------------------------------------------------------------------
    # settings

    def validate(self, source: str = "sonar") -> None:
        """Coerce the fields to their declared types and check their values.

        Parameters
        ----------
        source : str
            Prefix of the error message (the plugin or file the settings came from).

        Raises
        ------
        ValueError
            ``"<source> '<field>': <value> is not ..."`` for the first bad field.
        """
        def bad(name, value, allowed):
            raise not_a(source, name, value, allowed)

        types = {"float": float, "int": int, "str": str}
        for f in dataclasses.fields(self):
            value = getattr(self, f.name)
            field_type = types[f.type if isinstance(f.type, str) else f.type.__name__]
            if field_type is str:
                if not isinstance(value, str):
                    bad(f.name, value, "a string")
                continue
            # XML and JSON hand over ints for floats and floats for ints; accept lossless ones.
            if isinstance(value, (bool, np.bool_)) or not isinstance(value, (int, float, np.integer, np.floating)):
                bad(f.name, value, "a number")
            if field_type is int:
                if not (math.isfinite(value) and float(value).is_integer()):
                    bad(f.name, value, "an integer")
                value = int(value)
            else:
                value = float(value)
            setattr(self, f.name, value)

        def finite(name):
            if not math.isfinite(getattr(self, name)):
                bad(name, getattr(self, name), "a finite number")

        for name in ("source_level", "receiver_sensitivity", "noise_level", "tvg_cap", "gain", "ad_low",
                     "ringdown_level"):
            finite(name)
        if not SOURCE_LEVELS[0] <= self.source_level <= SOURCE_LEVELS[1]:
            raise ValueError(source_level_error(source, self.source_level))
        if not (math.isfinite(self.receiver_bandwidth) and self.receiver_bandwidth >= 0):
            bad("receiver_bandwidth", self.receiver_bandwidth, "a bandwidth >= 0 Hz (0: 1 / pulse_length)")
        if self.tvg not in TVG_LAWS:
            bad("tvg", self.tvg, "one of " + ", ".join(TVG_LAWS))
        if not (math.isfinite(self.ad_span) and self.ad_span > 0):
            bad("ad_span", self.ad_span, "a span > 0 dB")
        if self.bit_depth not in BIT_DEPTHS:
            bad("bit_depth", self.bit_depth, "one of 8, 4, 16, 32")
        if not (math.isfinite(self.pulse_length) and 0 <= self.pulse_length <= 0.1):
            bad("pulse_length", self.pulse_length, "a duration in [0, 0.1] s")
        if not (math.isfinite(self.range_jitter) and self.range_jitter >= 0):
            bad("range_jitter", self.range_jitter, "a standard deviation >= 0 m")
        if self.speckle not in SPECKLE_MODELS:
            bad("speckle", self.speckle, "one of " + ", ".join(SPECKLE_MODELS))
        if not 0 <= self.speckle_seed <= 2 ** 32 - 1:
            bad("speckle_seed", self.speckle_seed, "a whole number from 0 to 4294967295")
        if not (math.isfinite(self.speckle_shape) and 0.1 <= self.speckle_shape <= 100):
            bad("speckle_shape", self.speckle_shape, "a Weibull shape in [0.1, 100]")
        if math.isnan(self.noise_floor) or self.noise_floor == math.inf:
            bad("noise_floor", self.noise_floor, "a finite level in dB or -inf (no noise)")
        if not (math.isfinite(self.ringdown) and self.ringdown >= 0):
            bad("ringdown", self.ringdown, "a range >= 0 m")
        if self.ringdown > 0 and not self.ringdown_level > self.ad_low:
            bad("ringdown_level", self.ringdown_level, f"above ad_low = {self.ad_low:g} dB (the ring-down must fade out)")

    def to_dict(self) -> dict[str, Any]:
        """The settings as a plain dict (what ``Scan.electronics`` records)."""
        return dataclasses.asdict(self)

    @classmethod
    def from_dict(cls, settings: dict[str, Any] | None, source: str = "sonar") -> "Electronics":
        """Build from a dict such as ``Scan.electronics``; missing fields take their defaults.

        Parameters
        ----------
        settings : dict or None
            Field values. The key ``seed`` (recorded by `apply_to_scan`) is ignored; ``bandwidth`` (the
            name before ``receiver_bandwidth``) is read as ``receiver_bandwidth``.
        source : str
            Prefix of error messages.

        Raises
        ------
        ValueError
            On an unknown key or a bad value.
        """
        settings = rename_settings(dict(settings or {}))     # fields saved under an earlier name
        settings.pop("seed", None)
        names = [f.name for f in dataclasses.fields(cls)]
        for key in settings:
            if key not in names:
                raise ValueError(f"{source} {key!r} is not an electronics setting (known: {', '.join(names)})")
        obj = cls.__new__(cls)
        for f in dataclasses.fields(cls):
            setattr(obj, f.name, settings.get(f.name, f.default))
        obj.validate(source)
        return obj

    # ------------------------------------------------------------------------------------------
    # the chain, step by step (public so that tests and users can check each law)

    def tvg_db(self, ranges, absorption: float = 0.0) -> np.ndarray:
        """Time-varying gain in dB at each range.

        Parameters
        ----------
        ranges : array_like
            Ranges in metres (clamped to at least ``MIN_TVG_RANGE``).
        absorption : float
            dB/m; the law adds ``2 absorption r`` (two-way absorption).

        Returns
        -------
        ndarray float64
            ``min(n log10 r + 2 absorption r, tvg_cap)``, or zeros for ``tvg='off'``.
        """
        r = np.maximum(np.asarray(ranges, dtype=np.float64), MIN_TVG_RANGE)
        n = TVG_LAWS[self.tvg]
        if n == 0:
            return np.zeros_like(r)
        return np.minimum(n * np.log10(r) + 2.0 * absorption * r, self.tvg_cap)

    def quantise(self, level_db) -> np.ndarray:
        """Map levels in dB onto device bytes.

        Parameters
        ----------
        level_db : array_like
            Levels on the A/D scale (``-inf`` allowed).

        Returns
        -------
        ndarray uint8 (uint16, uint32 at 16, 32 bits)
            ``round(255 x)`` with ``x = clip((level_db - ad_low) / ad_span, 0, 1)``, halves
            rounded up; at ``bit_depth=4``, ``17 round(15 x)``; at 16, 32: ``round((2^bits - 1) x)``.
        """
        level = np.asarray(level_db, dtype=np.float64)
        x = np.clip((level - self.ad_low) / self.ad_span, 0.0, 1.0)
        # NaN would become byte 0 silently; apply() never produces one, callers must not either.
        x = np.where(np.isnan(x), 0.0, x)
        top, step, dtype = devicechain.AD_CODES[self.bit_depth]
        return (_round_half_up(float(top) * x) * float(step)).astype(dtype)

    def range_kernel(self, bin_width: float, sound_speed: float = SOUND_SPEED) -> np.ndarray:
        """Weights that spread one bin's echo energy over bins 0, 1, ... (offsets ``-m .. +m``).

        The continuous spread is a boxcar ``[0, c pulse_length / 2)`` (the pulse trails the echo)
        convolved with ``N(0, range_jitter^2)``; the weight of offset k is its probability mass in
        ``[(k - 1/2) bin_width, (k + 1/2) bin_width)``, the echo sitting at its bin's centre.

        Parameters
        ----------
        bin_width : float
            Metres per bin.
        sound_speed : float
            m/s, turns the pulse length into range.

        Returns
        -------
        ndarray float64 (2 m + 1,)
            Weights summing to 1 (to rounding); index ``m`` is offset 0.
        """
        return np.array(devicechain.spread_kernel(sound_speed * self.pulse_length / 2.0, self.range_jitter, bin_width))

    def spread(self, intensity, ranges, sound_speed: float = SOUND_SPEED) -> np.ndarray:
        """Spread echo energy along range by the pulse and the range jitter (step 1 of the chain).

        Parameters
        ----------
        intensity : array_like (..., n_bins)
            Energy per bin.
        ranges : array_like (n_bins,)
            Evenly spaced bin centres in metres.
        sound_speed : float
            m/s.

        Returns
        -------
        ndarray float64, the shape of ``intensity``
            The convolution with `range_kernel`; energy pushed past either end is dropped.
        """
        inten = np.array(intensity, dtype=np.float64)
        bin_width = _bin_width(ranges)
        if bin_width == 0.0 or inten.size == 0:
            return inten
        kernel = self.range_kernel(bin_width, sound_speed)
        if kernel.size == 1:
            return inten
        import mitsuba as mi

        devicechain.check_variant()
        rows = inten.reshape(-1, inten.shape[-1])
        out = devicechain.spread(mi.Float64(rows.reshape(-1)), rows.shape[0], rows.shape[1], kernel)
        return out.numpy().reshape(inten.shape)

    def echo_level(self, intensity, ranges, sound_speed: float = SOUND_SPEED) -> np.ndarray:
        """The noise-free echo level at the receiver, dB re 1 uPa, per bin (``Scan.echo_level``):
        `mitsonar.sonar_equation.echo_level` with this head's ``source_level`` and
        ``pulse_length`` (float32, ``-inf`` where no echo)."""
        _bin_width(ranges)   # evenly spaced, or a clear error
        return echo_level(intensity, ranges, self.source_level, self.pulse_length, sound_speed)

    def noise_bandwidth(self, bin_width: float = 0.0, sound_speed: float = SOUND_SPEED) -> float:
        """Hz: ``receiver_bandwidth``, else ``1 / pulse_length`` (a matched CW pulse), else (no pulse) the
        bandwidth ``c / (2 bin_width)`` of one range bin."""
        if self.receiver_bandwidth > 0:
            return self.receiver_bandwidth
        if self.pulse_length > 0:
            return 1.0 / self.pulse_length
        if bin_width > 0:
            return sound_speed / (2.0 * bin_width)
        raise ValueError("electronics: no bandwidth (receiver_bandwidth 0, pulse_length 0 and no range bins)")

    def speckle_factors(self, shape, seed, corr_bins: np.ndarray | None = None) -> np.ndarray:
        """Mean-one multiplicative speckle of the given ``(n_pings, n_bins)`` shape: ``|g|^2`` of
        the speckle `apply` draws from its seed when no scene speckle is given.

        Parameters
        ----------
        shape : tuple
            Output shape; the last axis is range.
        seed : int or numpy.random.Generator
            The seed of the draws (`mitsonar.receiver.devicechain`); a Generator gives one.
        corr_bins : ndarray or None
            Amplitude weights of the pulse along range (see `range_kernel`); the complex field
            is filtered with them so that speckle is correlated over the resolution cell. The
            marginal law is unchanged (exponential for ``rayleigh``, Weibull for ``weibull``).

        Returns
        -------
        ndarray float64
            Ones for ``off``; otherwise positive factors with mean 1.
        """
        shape = tuple(shape)
        if self.speckle == "off":
            return np.ones(shape)
        devicechain.check_variant()
        if isinstance(seed, np.random.Generator):
            seed = int(seed.integers(0, 2 ** 63))
        rows = math.prod(shape[:-1])
        # |g|^2 of a unit complex Gaussian is Exp(1); reshaped, |g|^2 = E^(1/k) / Gamma(1 + 1/k),
        # Weibull(k) of mean 1
        e = devicechain.drawn_speckle_power(_seed(seed), rows, shape[-1], corr_bins, self._weibull())
        return e.numpy().reshape(shape)

    def scene_speckle(self, poses, ranges, *, sound_speed: float, beamwidth_h: float,
                      aperture_h: float) -> np.ndarray:
        """The scene's complex speckle amplitude per bin for `apply`'s ``speckle``: the field of
        the resolution cells the rows' ``poses`` see at ``ranges`` (`mitsonar.receiver.speckle.cell_speckle`),
        seeded by ``speckle_seed``; its range resolution is the pulse's ``c pulse_length / 2``
        (at least one bin), its aperture the head's across the narrow beam (``aperture_h``, m:
        the beam's ``across_aperture()``, recorded by `render_scan` in ``meta['aperture_h']``)."""
        return self.scene_speckle_field(poses, ranges, sound_speed=sound_speed, beamwidth_h=beamwidth_h,
                                        aperture_h=aperture_h).numpy()

    def scene_speckle_field(self, poses, ranges, *, sound_speed: float, beamwidth_h: float,
                            aperture_h: float):
        """`scene_speckle` on the device: a `mitsonar.receiver.speckle.Field` for `device_bytes`."""
        from mitsonar.receiver.speckle import field

        devicechain.check_variant()
        ranges = np.asarray(ranges, dtype=np.float64)
        resolution = max(sound_speed * self.pulse_length / 2.0, _bin_width(ranges))
        if resolution <= 0:   # one bin and no pulse: cells are told apart by pose only
            resolution = 1.0
        return field(poses, ranges, seed=self.speckle_seed, beamwidth_h=beamwidth_h, aperture_h=aperture_h,
                     resolution=resolution)

    def ringdown_db(self, ranges) -> np.ndarray:
        """The transducer's ring-down on the A/D level scale, per range (``-inf`` without one).

        A ringing transducer's amplitude decays as ``exp(-t / tau)`` after the transmit pulse, so
        its level falls linearly in dB with time ``t = 2 r / c``: from ``ringdown_level`` at
        ``r = 0`` to ``ad_low`` at ``r = ringdown``, ``ring(r) = ringdown_level + (ad_low -
        ringdown_level) r / ringdown``, and on below the window beyond it.
        """
        r = np.maximum(np.asarray(ranges, dtype=np.float64), 0.0)
        if self.ringdown <= 0:
            return np.full(r.shape, -np.inf)
        return self.ringdown_level + (self.ad_low - self.ringdown_level) * r / self.ringdown

    def background_db(self, ranges) -> np.ndarray:
        """Background power (noise floor plus ring-down) on the A/D level scale, per range.

        Parameters
        ----------
        ranges : array_like
            Ranges in metres.

        Returns
        -------
        ndarray float64
            ``10 log10(10^(noise_floor/10) + 10^(ring(r)/10))`` with
            ``ring(r) = ringdown_level + (ad_low - ringdown_level) r / ringdown`` (no ring-down
            when ``ringdown = 0``); ``-inf`` where there is neither.
        """
        r = np.maximum(np.asarray(ranges, dtype=np.float64), 0.0)
        power = np.full(r.shape, 10.0 ** (self.noise_floor / 10.0))
        if self.ringdown > 0:
            ring = self.ringdown_level + (self.ad_low - self.ringdown_level) * r / self.ringdown
            power = power + 10.0 ** (ring / 10.0)
        with np.errstate(divide="ignore"):
            return 10.0 * np.log10(power)

    # ------------------------------------------------------------------------------------------

    def apply(self, intensity, ranges, absorption=0.0, sound_speed=SOUND_SPEED, seed=0, speckle=None) -> np.ndarray:
        """Turn noise-free echo intensity into device bytes.

        The received amplitude of a bin is the coherent sum of the echo (its amplitude times the
        speckle ``g``), the transducer's ring-down and the receiver's noise ``n`` (a unit circular
        complex Gaussian, correlated over the pulse like the matched filter's output); its power
        ``|sqrt(I) g + sqrt(R) + sqrt(N) n|^2`` (``R``, ``N`` the ring-down and noise floor referred
        back through the chain) goes through the chain and the A/D window. The intensity is
        uploaded and the chain run as Dr.Jit kernels (`device_bytes`), on any ``llvm`` or ``cuda``
        variant.

        Parameters
        ----------
        intensity : array_like (n_pings, n_bins) or (n_bins,)
            Linear echo energy per bin, >= 0 (``Scan.intensity``; not modified).
        ranges : array_like (n_bins,)
            Bin-centre ranges in metres, evenly spaced.
        absorption : float
            dB/m, compensated by the TVG (``2 absorption r``).
        sound_speed : float
            m/s, turns ``pulse_length`` into range.
        seed : int
            Seed of the receiver's noise (and of the speckle when ``speckle`` is None), a whole
            number from 0 to 2^64 - 1: the key of the counter-based generator
            (`mitsonar.receiver.devicechain`); the same seed gives the same bytes (``None`` draws
            fresh entropy).
        speckle : complex array_like, mitsonar.receiver.speckle.Field or None
            The scene's complex speckle amplitude per bin (`mitsonar.receiver.speckle`, mean power 1),
            shaped like ``intensity``; ``speckle`` = ``weibull`` reshapes its modulus to the
            Weibull law, ``off`` ignores it. None: drawn from ``seed`` (independent per bin,
            correlated over the pulse), for intensities that do not say where their echoes come from.

        Returns
        -------
        ndarray uint8 (uint16, uint32 at ``bit_depth`` 16, 32), the shape of ``intensity``

        Raises
        ------
        ValueError
            Mismatched shapes, negative or non-finite intensity, uneven ranges, bad absorption,
            sound speed or seed, or a variant without Dr.Jit kernels.
        """
        intensity = np.asarray(intensity)
        ranges = np.asarray(ranges, dtype=np.float64)
        one_ping = intensity.ndim == 1
        if intensity.dtype == object or intensity.dtype.kind not in "biuf":
            raise ValueError(f"electronics: intensity of dtype {intensity.dtype} is not allowed (real numbers)")
        inten = intensity.reshape(1, -1) if one_ping else intensity
        if inten.ndim != 2 or ranges.ndim != 1 or inten.shape[-1] != ranges.shape[0]:
            raise ValueError(f"electronics: intensity {np.shape(intensity)} and ranges {ranges.shape} do not match "
                             "(expected (n_pings, n_bins) and (n_bins,))")
        if not np.all(np.isfinite(inten)) or np.any(inten < 0):
            raise ValueError("electronics: intensity must be finite and >= 0")
        if speckle is not None and not hasattr(speckle, "re"):
            speckle = np.asarray(speckle, dtype=np.complex128)
            speckle = speckle[None] if speckle.ndim == 1 else speckle
            if speckle.shape != inten.shape:
                raise ValueError(f"electronics: speckle {speckle.shape} does not match intensity {inten.shape}")
        devicechain.check_variant()
        import mitsuba as mi

        src = np.ascontiguousarray(inten, dtype=np.float32 if inten.dtype == np.float32 else np.float64)
        up = (mi.Float32 if src.dtype == np.float32 else mi.Float64)(src.reshape(-1))
        data = self.device_bytes(up, inten.shape, ranges, absorption=absorption, sound_speed=sound_speed,
                                 seed=seed, speckle=speckle)
        data = devicechain.host_codes(data, inten.shape, self.bit_depth)
        return data[0] if one_ping else data

    def device_bytes(self, intensity, shape, ranges, absorption=0.0, sound_speed=SOUND_SPEED, seed=0, speckle=None):
        """`apply` on the device: ``intensity`` a Dr.Jit array (``mi.Float32`` or ``mi.Float64``
        of ``shape = (n_rows, n_bins)`` values, row-major, >= 0 and finite: not checked here, a
        render's histogram), the bytes a ``mi.UInt8`` array of the same layout (16 or 32 bits:
        ``mi.UInt32``), computed as Dr.Jit kernels of the active variant, no NumPy array on the way (the per-bin
        settings tables are computed once per settings and ranges). ``speckle``: a
        `mitsonar.receiver.speckle.Field` (or a complex NumPy array, uploaded) or None; the other
        arguments as `apply`'s."""
        if not (math.isfinite(absorption) and absorption >= 0):
            raise ValueError(f"electronics: absorption {absorption!r} is not a finite value >= 0 dB/m")
        if not (math.isfinite(sound_speed) and sound_speed > 0):
            raise ValueError(f"electronics: sound_speed {sound_speed!r} is not a speed > 0 m/s")
        devicechain.check_variant()
        seed = _seed(seed)
        n_rows, n_bins = (int(n) for n in shape)
        t = self._tables(np.asarray(ranges, dtype=np.float64), float(absorption), float(sound_speed))
        g = None
        if self.speckle != "off" and speckle is not None:
            if hasattr(speckle, "re"):
                if tuple(speckle.shape) != (n_rows, n_bins):
                    raise ValueError(f"electronics: speckle {tuple(speckle.shape)} does not match intensity "
                                     f"{(n_rows, n_bins)}")
                g = (speckle.re, speckle.im)
            else:
                import mitsuba as mi

                sp = np.ascontiguousarray(speckle, dtype=np.complex128).reshape(-1)
                g = (mi.Float64(sp.view(np.float64)),)
        return devicechain.received_bytes(
            intensity, n_rows, n_bins, kernel=t["kernel"], corr=t["corr"], g=g,
            g_seed=seed if self.speckle != "off" and g is None else None, weibull=self._weibull(),
            ring=t["ring"], f=t["f"], noise_seed=seed, levels=(t["calibration"], self.gain, t["tvg"]),
            ad=(self.ad_low, self.ad_span, self.bit_depth))

    def _weibull(self):
        """The Weibull shape of the speckle's intensity (None: fully developed, or no speckle)."""
        return self.speckle_shape if self.speckle == "weibull" else None

    def _tables(self, ranges, absorption, sound_speed):
        """The chain's per-bin settings on the device (TVG, ring-down and noise amplitudes) and
        its kernels, computed once per settings, ranges, absorption and sound speed (`MAX_CACHED`)."""
        key = ("tables", devicechain.variant(), tuple(self.to_dict().items()), ranges.shape, ranges.tobytes(),
               absorption, sound_speed)
        hit = devicechain.cached(key)
        if hit is not None:
            return hit
        import mitsuba as mi

        bin_width = _bin_width(ranges)
        calibration = self.source_level + self.receiver_sensitivity
        tvg = self.tvg_db(ranges, absorption)
        chain = calibration + self.gain + tvg
        out = {"kernel": self.range_kernel(bin_width, sound_speed) if bin_width > 0 else np.ones(1),
               "corr": self._noise_corr(bin_width, sound_speed), "calibration": calibration,
               "tvg": mi.Float64(tvg), "ring": None, "f": None}
        if self.ringdown > 0:
            out["ring"] = mi.Float64(np.sqrt(10.0 ** ((self.ringdown_db(ranges) - chain) / 10.0)))
        if self.noise_floor > -math.inf:
            out["f"] = mi.Float64(math.sqrt(10.0 ** (self.noise_floor / 10.0)) * 10.0 ** (-chain / 20.0))
        return devicechain.keep(key, out)

    def _noise_corr(self, bin_width, sound_speed):
        """The receiver noise's correlation over the pulse (amplitude taps), None for one bin."""
        pulse = devicechain.spread_kernel(sound_speed * self.pulse_length / 2.0, 0.0, bin_width) if bin_width > 0 else np.ones(1)
        return pulse if pulse.size > 1 else None


def apply_to_scan(scan, electronics: "Electronics | dict | None" = None, seed: int | None = None):
    """Return a copy of ``scan`` whose ``data`` is made from its ``intensity`` by ``electronics``.

    Parameters
    ----------
    scan : mitsonar.scan.Scan
        Not modified.
    electronics : Electronics, dict, ElectronicsSettings or None
        Settings, read with `Electronics.from_dict`; ``None``: those of ``scan.electronics``.
    seed : int or None
        The receiver's noise seed. The speckle of a rendered scan (``meta['speckle'] ==
        'scene'``) follows its poses and the settings' ``speckle_seed``; a scan from elsewhere
        (a real head's) has its speckle drawn from this seed too. ``None`` takes ``scan.electronics.seed``, else
        ``scan.meta.electronics_seed`` (what `render_scan` records), else ``scan.meta.seed``, else 0.

    Returns
    -------
    Scan
        A copy with new ``data`` and ``electronics`` = the settings plus ``seed``.
    """
    import copy

    if electronics is None:
        electronics = Electronics.from_dict(scan.electronics.to_dict())
    elif isinstance(electronics, (dict, ElectronicsSettings)):
        electronics = Electronics.from_dict(dict(electronics))
    if seed is None:
        seed = next((s for s in (scan.electronics.seed, scan.meta.electronics_seed, scan.meta.seed) if s is not None), 0)
    speckle = None
    if electronics.speckle != "off" and has_scene_speckle(scan):
        speckle = electronics.scene_speckle(scan.poses, scan.ranges, sound_speed=scan.sound_speed,
                                            beamwidth_h=scan.beamwidth_h, aperture_h=float(scan.meta.aperture_h))
    data = electronics.apply(scan.intensity, scan.ranges, absorption=scan.absorption,
                             sound_speed=scan.sound_speed, seed=seed, speckle=speckle)
    out = copy.deepcopy(scan)
    out.data = data
    out.electronics = ElectronicsSettings.from_dict({**electronics.to_dict(), "seed": seed})
    return out


def has_scene_speckle(scan) -> bool:
    """Whether ``scan`` says where its echoes come from: a rendered scan records ``meta.speckle
    == 'scene'`` and the head's ``meta.aperture_h`` (a real head's scan does neither)."""
    return scan.meta.speckle == "scene" and scan.meta.aperture_h is not None


def _seed(seed) -> int:
    """A noise seed: a whole number from 0 to 2^64 - 1 (None: fresh entropy)."""
    if seed is None:
        return int(np.random.SeedSequence().entropy) & devicechain.SEED_MAX
    if isinstance(seed, (bool, np.bool_)) or not isinstance(seed, (int, np.integer)) or not 0 <= seed <= devicechain.SEED_MAX:
        raise ValueError(f"electronics: seed {seed!r} is not allowed (a whole number from 0 to 2^64 - 1, or None)")
    return int(seed)


def _round_half_up(v: np.ndarray) -> np.ndarray:
    """Round to the nearest integer, halves up (v >= 0). ``floor(v + 0.5)`` would round the
    largest double below 0.5 up, because the addition itself rounds."""
    q = np.floor(v)
    return q + (v - q >= 0.5)


def _bin_width(ranges) -> float:
    """Spacing of evenly spaced, increasing bin centres (0 for a single bin)."""
    r = np.asarray(ranges, dtype=np.float64)
    if r.ndim != 1:
        raise ValueError(f"electronics: ranges must be one-dimensional, got shape {r.shape}")
    if r.size < 2:
        return 0.0
    width = (r[-1] - r[0]) / (r.size - 1)
    if not (math.isfinite(width) and width > 0) or not np.allclose(np.diff(r), width, rtol=1e-6, atol=0.0):
        raise ValueError("electronics: ranges must be evenly spaced increasing bin centres")
    return float(width)


def check_head_settings(settings: dict, source: str) -> None:
    """Refuse a head setting outside what the real head accepts (`HEAD_LIMITS`), naming ``source``
    and the field. Only the fields present are checked; their types are `Electronics.validate`'s."""
    for name, (lo, hi) in HEAD_LIMITS.items():
        value = settings.get(name)
        if is_number(value) and not lo <= float(value) <= hi:
            raise not_allowed(source, name, value, f"{lo:.2g}..{hi:g} dB, the range of the head's {name}")
