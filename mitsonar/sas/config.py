"""A strip-map synthetic aperture sonar: the array, the ping rate and the closed forms they set.

A side-looking receive array of ``N`` contiguous elements of length ``D`` along track (the beam
frame's +x of a `sidescan` head's channel), a wideband transmit element of the same length at the
array's centre, on a platform moving at ``v`` and pinging every ``T`` s. The figures
(Hayes and Gough, "Synthetic aperture sonar: a review of current status", IEEE J. Oceanic Eng.
34(3), 2009, sections II-III; Cutrona, "Comparison of sonar system performance achievable using
synthetic-aperture techniques with the performance achievable by more conventional means",
J. Acoust. Soc. Am. 58(2), 1975):

* real-aperture beamwidth ``theta = lambda / D`` (rad), so a target at range ``R`` stays in the
  beam over the synthetic aperture ``L_sa = R lambda / D``;
* along-track resolution of the full synthetic aperture ``delta_x = D / 2``, whatever the range
  (the two-way path doubles the phase history: the synthetic beam is ``lambda / (2 L_sa)``;
  Cutrona 1975; Hayes and Gough 2009, the strip-map resolution). For a processed beamwidth
  ``theta_p`` (full angle) and a weighting, the image's -3 dB width is
  ``k_w lambda / (4 sin(theta_p / 2))`` with ``k_w`` the window's -3 dB factor (0.886 uniform,
  1.44 Hann), ``k_w D / 2`` for ``theta_p = lambda / D`` (`along_track_resolution`);
* range (slant) resolution ``k_w c / (2 B)`` after pulse compression (0.886 for an unweighted
  chirp), ``/ cos(grazing)`` on a ground-range grid (`range_resolution`);
* the displaced-phase-centre (DPCA) condition: each transmitter-receiver pair acts as one element
  at their midpoint (its phase centre), so a ping's ``N`` phase centres are ``D / 2`` apart and
  span ``N D / 2``; the along-track sampling stays at ``D / 2`` (no grating lobes) while the
  platform advances at most ``N D / 2`` per ping, ``v T <= N D / 2`` (Hayes and Gough 2009, the
  along-track sampling requirement; Bellettini and Pinto, "Theoretical accuracy of synthetic
  aperture sonar micronavigation using a displaced phase-center antenna", IEEE J. Oceanic Eng.
  27(4), 2002, whose overlapping phase centres the micronavigation uses). A faster platform
  undersamples the aperture: `check` warns;
* the ping period is at least the two-way flight to the farthest range, ``T >= 2 R_max / c``, so
  the maximum speed is ``N D c / (4 R_max)`` (`max_speed`): the range-rate trade of SAS.
"""
from __future__ import annotations

import math
import warnings
from dataclasses import dataclass

import numpy as np

from mitsonar.acoustics.water import SOUND_SPEED

#: -3 dB width factors of the processing windows, in units of the inverse of their support
#: (the uniform window's sinc: 0.886; the Hann window's: 1.44; Harris, "On the use of windows for
#: harmonic analysis with the discrete Fourier transform", Proc. IEEE 66(1), 1978, table 1).
WINDOW_FACTORS = {"uniform": 0.886, "hann": 1.44}


class SASWarning(UserWarning):
    """A strip-map configuration that undersamples the synthetic aperture."""


def _positive(name, value, what="a finite value > 0"):
    if isinstance(value, bool) or not isinstance(value, (int, float, np.integer, np.floating)) \
            or not math.isfinite(value) or value <= 0:
        raise ValueError(f"StripMap '{name}': {value!r} is not allowed ({what})")
    return float(value)


@dataclass(frozen=True)
class StripMap:
    """A strip-map SAS (module docstring for the closed forms).

    ``n_elements`` receivers of ``element_length`` m along track, ``frequency`` (carrier) and
    ``bandwidth`` Hz, ``speed`` m/s of the platform, ``ping_period`` s, ``range_max`` m,
    ``sound_speed`` m/s. `check` is called on construction: a ping period shorter than the two-way
    flight to ``range_max`` is refused, a platform that breaks the DPCA condition warned of."""

    n_elements: int
    element_length: float
    frequency: float
    bandwidth: float
    speed: float
    ping_period: float
    range_max: float
    sound_speed: float = SOUND_SPEED

    def __post_init__(self):
        n = self.n_elements
        if isinstance(n, bool) or not isinstance(n, (int, np.integer)) or not 1 <= n <= 4096:
            raise ValueError(f"StripMap 'n_elements': {n!r} is not allowed (a whole number 1 to 4096)")
        for name in ("element_length", "frequency", "bandwidth", "speed", "ping_period", "range_max", "sound_speed"):
            _positive(name, getattr(self, name))
        if self.bandwidth >= 2.0 * self.frequency:
            raise ValueError(f"StripMap 'bandwidth': {self.bandwidth!r} is not allowed (below twice the frequency, "
                             f"{2 * self.frequency:g} Hz)")
        self.check()

    # ---------------------------------------------------------------- closed forms
    @property
    def wavelength(self) -> float:
        return self.sound_speed / self.frequency

    @property
    def beamwidth(self) -> float:
        """rad: ``lambda / D``, the element's beamwidth, the classical processed beamwidth."""
        return self.wavelength / self.element_length

    def synthetic_aperture(self, slant_range) -> float:
        """m: ``R lambda / D``, the track over which a target at ``slant_range`` stays in the beam."""
        return float(slant_range) * self.beamwidth

    def along_track_resolution(self, beamwidth=None, window="uniform") -> float:
        """m: the -3 dB along-track width ``k_w lambda / (4 sin(theta_p / 2))`` for a processed
        beamwidth ``theta_p`` (rad, default ``lambda / D``) and a ``window`` (`WINDOW_FACTORS`):
        ``0.886 D / 2`` for the classical uniform, full-beam case; independent of range."""
        theta = self.beamwidth if beamwidth is None else float(beamwidth)
        return WINDOW_FACTORS[window] * self.wavelength / (4.0 * math.sin(0.5 * theta))

    def range_resolution(self, grazing=None, window="uniform") -> float:
        """m: ``k_w c / (2 B)`` in slant range; divided by ``cos(grazing)`` (rad) on the ground."""
        r = WINDOW_FACTORS[window] * self.sound_speed / (2.0 * self.bandwidth)
        return r if grazing is None else r / math.cos(float(grazing))

    @property
    def advance(self) -> float:
        """m the platform moves between pings, ``v T``."""
        return self.speed * self.ping_period

    @property
    def dpca_advance(self) -> float:
        """m: ``N D / 2``, the largest advance per ping that keeps the phase centres ``D / 2`` apart."""
        return 0.5 * self.n_elements * self.element_length

    @property
    def dpca_ok(self) -> bool:
        return self.advance <= self.dpca_advance * (1.0 + 1e-9)

    @property
    def max_speed(self) -> float:
        """m/s: ``N D c / (4 R_max)``, the fastest DPCA-sampled platform at the shortest ping period."""
        return self.dpca_advance / (2.0 * self.range_max / self.sound_speed)

    @property
    def overlap(self) -> int:
        """Phase centres shared by consecutive pings, ``N - round(2 v T / D)`` (the DPCA pairs of
        `mitsonar.sas.micronavigation`; 0 or less: none)."""
        return int(self.n_elements - round(2.0 * self.advance / self.element_length))

    def check(self):
        """Refuse a ping period under the two-way flight; warn (`SASWarning`) when ``v T > N D / 2``."""
        flight = 2.0 * self.range_max / self.sound_speed
        if self.ping_period < flight * (1.0 - 1e-9):
            raise ValueError(f"StripMap 'ping_period': {self.ping_period!r} is not allowed (at least the two-way "
                             f"flight 2 range_max / sound_speed = {flight:.6g} s)")
        if not self.dpca_ok:
            warnings.warn(f"StripMap: the platform advances {self.advance:.4g} m per ping, more than N D / 2 = "
                          f"{self.dpca_advance:.4g} m (the DPCA condition): the synthetic aperture is undersampled "
                          f"and the image will have grating lobes; slow to {self.dpca_advance / self.ping_period:.4g} "
                          "m/s or shorten the ping period", SASWarning, stacklevel=3)

    # ---------------------------------------------------------------- what render_echoes needs
    def elements(self) -> np.ndarray:
        """(N, 3) m: the receivers' centres along the beam frame's +x, centred on the transmitter."""
        x = (np.arange(self.n_elements) - 0.5 * (self.n_elements - 1)) * self.element_length
        return np.stack([x, np.zeros_like(x), np.zeros_like(x)], axis=1)

    def pulse(self, duration=None, window=None):
        """An LFM over the band (`mitsonar.signals.lfm`), ``duration`` s (default 2 ms, at most a
        tenth of the ping period)."""
        from mitsonar.signals.pulses import lfm

        T = min(2e-3, 0.1 * self.ping_period) if duration is None else duration
        return lfm(self.frequency - 0.5 * self.bandwidth, self.frequency + 0.5 * self.bandwidth, T, window)

    def sensor_xml(self, *, side="port", depression=20.0, beamwidth_v=60.0, flat=False, n_pings=64,
                   source_level=200.0) -> str:
        """A ``<sensor type="sonar">`` of kind ``sidescan`` for this configuration: its transmit
        beam the element's own ``sinc`` of aperture ``D`` along track, or with ``flat`` a
        ``uniform`` beam over twice ``lambda / D`` (flat across the processed beam: for
        closed-form checks); ``beamwidth_v`` deg across track, its band, ping period and range."""
        from mitsonar.kinds import SIDESCAN

        beam = {"beam_pattern": "uniform", "beamwidth_h": 2.0 * math.degrees(self.beamwidth)} if flat else \
            {"beam_pattern": "sinc", "beamwidth_h": math.degrees(self.beamwidth), "aperture_h": self.element_length}
        items = {"kind": SIDESCAN.name, "side": side, "depression": float(depression), "range_max": self.range_max,
                 "n_bins": 200, "n_pings": int(n_pings), **beam,
                 "beamwidth_v": float(beamwidth_v), "frequency": self.frequency, "bandwidth": self.bandwidth,
                 "ping_period": self.ping_period, "sound_speed": self.sound_speed, "absorption": 0.0,
                 "source_level": float(source_level)}
        from mitsonar.sim.sensor_xml import sensor_xml

        return sensor_xml(items)

    def track(self, duration, *, start=(0.0, 0.0, 0.0), sway=None, step=None):
        """A `mitsonar.Trajectory` at ``speed`` along world +x from ``start`` for ``duration`` s,
        heading +x (port is +y); ``sway`` a function of the along-track distance (m) giving the
        across-track offset (m, +y), sampled every ``step`` s (default a twentieth of a ping)."""
        from mitsonar.geometry.trajectory import Trajectory

        dt = self.ping_period / 20.0 if step is None else float(step)
        t = np.linspace(0.0, float(duration), max(2, int(math.ceil(float(duration) / dt)) + 1))
        x = self.speed * t
        poses = np.tile(np.eye(4), (len(t), 1, 1))
        poses[:, 0, 3] = start[0] + x
        poses[:, 1, 3] = start[1] + (0.0 if sway is None else np.asarray(sway(x), dtype=np.float64))
        poses[:, 2, 3] = start[2]
        return Trajectory(t, poses)
