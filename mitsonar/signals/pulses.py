"""Transmit pulses: a CW tone and a linear FM chirp, as complex baseband waveforms.

A pulse is the complex envelope ``s(t)`` of the passband ``p(t) = Re{ s(t) exp(i 2 pi f_c t) }``
(``f_c`` its `Pulse.carrier`), zero outside ``[0, duration)``:

* CW of frequency ``f`` and duration ``T``: ``s(t) = w(t / T)``, carrier ``f``; its
  autocorrelation is the rectangle's triangle ``1 - |tau| / T`` (unwindowed), nominal bandwidth
  ``1 / T``;
* LFM from ``f0`` to ``f1`` in ``T``: ``s(t) = w(t / T) exp(i 2 pi ((f0 - f_c) t + k t^2 / 2))``
  with sweep rate ``k = (f1 - f0) / T`` and carrier ``f_c = (f0 + f1) / 2``; bandwidth
  ``B = |f1 - f0|``. After the matched filter its envelope is ``|sin(pi B tau) / (pi B tau)|`` for a
  large time-bandwidth product, -3 dB wide ``0.886 / B`` in time, ``0.886 c / (2 B)`` in range
  (Lurton, *An Introduction to Underwater Acoustics*, 2nd ed., 2010, ch. 3, pulse compression of a linear chirp).

``w`` is the window (None: rectangular; ``hann``, ``hamming``), evaluated in continuous time so a
pulse can be sampled at any delay (`Pulse.baseband`), which is how the echo renderer places
delayed, Doppler-compressed copies without interpolation.
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from mitsonar._moved import renamed_keyword, warn_renamed

WINDOWS = ("hann", "hamming")


def _positive(name, value, what):
    if isinstance(value, bool) or not isinstance(value, (int, float, np.integer, np.floating)) \
            or not math.isfinite(value) or value <= 0:
        raise ValueError(f"pulse '{name}': {value!r} is not allowed ({what})")
    return float(value)


def _window(window):
    if window is not None and window not in WINDOWS:
        raise ValueError(f"pulse 'window': {window!r} is not allowed (None for rectangular, or one of "
                         f"{', '.join(WINDOWS)})")
    return window


@dataclass(frozen=True)
class Pulse:
    """A transmit pulse (build it with `cw` or `lfm`).

    ``waveform`` ``cw`` or ``lfm`` (was ``kind``, which still works with a DeprecationWarning until
    0.4.0); ``f_start``, ``f_stop`` (Hz, equal for a CW); ``duration`` (s);
    ``window`` (None, ``hann`` or ``hamming``).
    """

    waveform: str
    f_start: float
    f_stop: float
    duration: float
    window: str | None = None

    @property
    def kind(self) -> str:
        """The waveform's name: `waveform` (the old name, removed in 0.4.0)."""
        warn_renamed("Pulse.kind")
        return self.waveform

    @property
    def carrier(self) -> float:
        """Hz: the CW's frequency, the LFM's centre ``(f_start + f_stop) / 2``."""
        return 0.5 * (self.f_start + self.f_stop)

    @property
    def bandwidth(self) -> float:
        """Hz: the LFM's swept band ``|f_stop - f_start|``; a CW's nominal ``1 / duration``."""
        if self.waveform == "cw":
            return 1.0 / self.duration
        return abs(self.f_stop - self.f_start)

    @property
    def sweep_rate(self) -> float:
        """Hz/s: ``(f_stop - f_start) / duration`` (0 for a CW)."""
        return (self.f_stop - self.f_start) / self.duration

    def range_resolution(self, sound_speed: float) -> float:
        """m: ``c / (2 B)``, the range extent of one resolution cell after compression."""
        return sound_speed / (2.0 * self.bandwidth)

    def default_sample_rate(self) -> float:
        """Hz: twice the bandwidth for an LFM, ``4 / duration`` for a CW (the contract's defaults)."""
        return 4.0 / self.duration if self.waveform == "cw" else 2.0 * self.bandwidth

    def envelope(self, t) -> np.ndarray:
        """The window ``w(t / T)`` at times ``t`` (s), zero outside ``[0, T)``."""
        t = np.asarray(t, dtype=np.float64)
        u = t / self.duration
        inside = (u >= 0.0) & (u < 1.0)
        if self.window == "hann":
            w = 0.5 - 0.5 * np.cos(2.0 * np.pi * u)
        elif self.window == "hamming":
            w = 0.54 - 0.46 * np.cos(2.0 * np.pi * u)
        else:
            w = np.ones_like(u)
        return np.where(inside, w, 0.0)

    def phase(self, t) -> np.ndarray:
        """rad: the baseband phase ``2 pi ((f_start - f_c) t + k t^2 / 2)`` at times ``t`` (s)."""
        t = np.asarray(t, dtype=np.float64)
        return 2.0 * np.pi * ((self.f_start - self.carrier) * t + 0.5 * self.sweep_rate * t * t)

    def baseband(self, t) -> np.ndarray:
        """Complex baseband ``s(t) = w(t / T) exp(i phase(t))`` at times ``t`` (s) from the pulse's start."""
        return self.envelope(t) * np.exp(1j * self.phase(t))

    def samples(self, sample_rate: float) -> np.ndarray:
        """complex128 ``s(k / sample_rate)`` for the ``ceil(duration * sample_rate)`` samples of the pulse."""
        fs = _positive("sample_rate", sample_rate, "a sampling rate > 0 Hz")
        n = max(1, int(math.ceil(self.duration * fs - 1e-9)))
        return self.baseband(np.arange(n) / fs)

    def autocorrelation(self, lag) -> np.ndarray:
        """The normalised autocorrelation ``R(tau) = int s(t + tau) s*(t) dt / int |s|^2 dt`` at lags
        ``tau`` (s), by quadrature on 64 points per period of the highest baseband frequency (R(0) = 1)."""
        lag = np.atleast_1d(np.asarray(lag, dtype=np.float64))
        n = int(max(2048, 64 * self.duration * (self.bandwidth + 1.0 / self.duration)))
        t = (np.arange(n) + 0.5) * self.duration / n
        s = self.baseband(t)
        norm = np.sum(np.abs(s) ** 2)
        return np.array([np.sum(self.baseband(t + x) * np.conj(s)) for x in lag]) / norm


# ``Pulse(kind="cw", ...)``: the old keyword, with a DeprecationWarning until 0.4.0
Pulse.__init__ = renamed_keyword("kind", "waveform", "Pulse(kind=...)")(Pulse.__init__)


def cw(frequency, duration, window=None) -> Pulse:
    """A CW tone of ``frequency`` Hz lasting ``duration`` s (rectangular unless ``window``)."""
    f = _positive("frequency", frequency, "a frequency > 0 Hz")
    return Pulse("cw", f, f, _positive("duration", duration, "a duration > 0 s"), _window(window))


def lfm(f_start, f_stop, duration, window=None) -> Pulse:
    """A linear FM chirp from ``f_start`` to ``f_stop`` Hz (up or down) in ``duration`` s."""
    f0 = _positive("f_start", f_start, "a frequency > 0 Hz")
    f1 = _positive("f_stop", f_stop, "a frequency > 0 Hz")
    if f0 == f1:
        raise ValueError(f"pulse 'f_stop': {f_stop!r} is not allowed (a frequency other than f_start = {f0:g} Hz; "
                         "use cw() for a tone)")
    return Pulse("lfm", f0, f1, _positive("duration", duration, "a duration > 0 s"), _window(window))
