"""Processing of element data: pulse compression, delay-and-sum beamforming, interferometry.

Everything here is numpy on complex baseband samples ``x[k] = s(k / fs)`` of
``p(t) = Re{ x(t) exp(i 2 pi f_c t) }`` (`mitsonar.signals.pulses`), one row of element data
``(n_elements, n_samples)`` at a time, so it serves rendered `Echoes` and recorded data alike.

* `matched_filter`: correlation with the transmitted replica, normalised so an echo ``a s(t - tau)``
  compresses to a peak of ``a`` at ``tau`` (Lurton, *An Introduction to Underwater Acoustics*, 2nd ed.,
  2010, ch. 3, matched filtering: the output SNR is the pulse energy over the noise density whatever
  the pulse shape).
* `delay_and_sum`: the wideband (true time delay) beamformer of Van Trees, *Optimum Array
  Processing*, 2002, ch. 2 (delay-and-sum of a plane wave), applied in the frequency domain: an element at
  ``e`` hears a far source in direction ``u`` ``e . u / c`` earlier, so its spectrum is multiplied by
  ``exp(-i 2 pi (f_c + f) e . u / c)`` and summed. For a uniform line array of ``N`` elements at
  spacing ``d`` the narrowband beam is ``sin(N psi / 2) / (N sin(psi / 2))`` with
  ``psi = 2 pi d (sin phi - sin phi_0) / lambda``, -3 dB wide ``0.886 lambda / (N d cos phi_0)`` rad
  (Van Trees 2002, ch. 2, the uniform line array's half-power beam width).
* `arrival_angle`: two elements a baseline ``b`` apart hear an echo from angle ``psi`` off the
  baseline's normal with phase difference ``2 pi b sin(psi) / lambda`` (Lurton 2010, ch. 8,
  interferometric sonars); unambiguous for ``b <= lambda / 2``.

Coherent or incoherent? `mitsonar.render_scan` estimates mean intensity per bin (what a display
averages); use it for images, maps, training data and speed. Use `mitsonar.render_echoes` and these
functions where the waveform itself matters: pulse design, beamformers, interferometric bathymetry,
Doppler, speckle statistics of a given head. The two agree on average: the mean over speckle seeds
of the matched-filtered power is the incoherent intensity convolved with ``|R(tau)|^2``, the
pulse's autocorrelation (`expected_power`).
"""
from __future__ import annotations

import math

import numpy as np
from scipy import fft as sfft
from scipy import signal as ssig


def matched_filter(data, pulse, sample_rate) -> np.ndarray:
    """Pulse compression along the last axis: ``y[k] = sum_m x[k + m] s*[m] / sum_m |s[m]|^2``.

    ``data`` complex (..., n_samples); returns complex128 of the same shape, sample k the echo that
    started at ``k / sample_rate`` (an echo ``a s(t - k0 / fs)`` peaks at ``y[k0] = a``)."""
    x = np.asarray(data)
    s = pulse.samples(sample_rate)
    kernel = np.conj(s[::-1]) / np.sum(np.abs(s) ** 2)
    shape = (1,) * (x.ndim - 1) + (len(s),)
    full = ssig.fftconvolve(x, kernel.reshape(shape), mode="full", axes=-1)
    return full[..., len(s) - 1:len(s) - 1 + x.shape[-1]]


def compressed_autocorrelation(pulse, sample_rate) -> tuple[np.ndarray, np.ndarray]:
    """(lags in s, ``R(lag)``) of the sampled pulse, normalised ``R(0) = 1``: the matched filter's
    response to a lone echo, sample by sample."""
    s = pulse.samples(sample_rate)
    r = np.correlate(s, s, mode="full") / np.sum(np.abs(s) ** 2)
    lags = (np.arange(len(r)) - (len(s) - 1)) / sample_rate
    return lags, r


def equivalent_duration(pulse, sample_rate) -> float:
    """s: ``int |R(tau)|^2 dtau``, the time over which a lone echo's compressed power spreads
    (its energy ``a^2`` is the sum of ``|y|^2`` over that many seconds of samples)."""
    _, r = compressed_autocorrelation(pulse, sample_rate)
    return float(np.sum(np.abs(r) ** 2) / sample_rate)


def expected_power(times, echo_times, echo_energy, pulse, sample_rate) -> np.ndarray:
    """The mean matched-filtered power ``E|y(t)|^2 = sum_j E_j |R(t - tau_j)|^2`` at ``times`` of
    echoes of energy ``echo_energy`` arriving at ``echo_times`` with random relative phases
    (speckle): the incoherent intensity convolved with the pulse's autocorrelation."""
    lags, r = compressed_autocorrelation(pulse, sample_rate)
    p = np.abs(r) ** 2
    d = np.asarray(times)[:, None] - np.asarray(echo_times)[None, :]
    return np.interp(d, lags, p, left=0.0, right=0.0) @ np.asarray(echo_energy, dtype=np.float64)


def look_directions(bearings) -> np.ndarray:
    """(n, 3) unit vectors in the beam frame of bearings (rad): ``(sin b, 0, cos b)`` (the bearing
    turns the boresight +z towards +x, `mitsonar.geometry.frames.bearing_rotation`)."""
    b = np.asarray(bearings, dtype=np.float64)
    return np.stack([np.sin(b), np.zeros_like(b), np.cos(b)], axis=-1)


def delay_and_sum(data, elements, directions, sample_rate, carrier, sound_speed, weights=None,
                  chunk=16) -> np.ndarray:
    """Wideband delay-and-sum beams (module docstring): complex128 (n_directions, n_samples).

    ``data`` complex (n_elements, n_samples) of one row; ``elements`` (n_elements, 3) positions in the
    beam frame (m); ``directions`` (n_directions, 3) unit look directions in the same frame;
    ``weights`` (n_elements,) the shading (default uniform, ``1 / n_elements`` so a unit plane wave
    from the look direction gives a unit beam). Delays are exact (frequency-domain phase ramps on a
    zero-padded FFT, no wrap-around)."""
    x = np.asarray(data)
    e = np.asarray(elements, dtype=np.float64)
    u = np.atleast_2d(np.asarray(directions, dtype=np.float64))
    n_el, n = x.shape
    w = np.full(n_el, 1.0 / n_el) if weights is None else np.asarray(weights, dtype=np.float64)
    span = np.max(np.abs(e @ u.T)) / sound_speed if n_el else 0.0
    n_fft = sfft.next_fast_len(n + 2 * int(math.ceil(span * sample_rate)) + 1)
    spec = sfft.fft(x, n_fft, axis=1) * w[:, None]
    f = carrier + sfft.fftfreq(n_fft, 1.0 / sample_rate)
    out = np.empty((len(u), n), dtype=np.complex128)
    for i in range(0, len(u), chunk):
        d = (u[i:i + chunk] @ e.T) / sound_speed                      # (c, n_el) s
        phase = np.exp(-2j * np.pi * d[:, :, None] * f[None, None, :])
        out[i:i + chunk] = sfft.ifft(np.einsum("cef,ef->cf", phase, spec), axis=1)[:, :n]
    return out


def phase_difference(first, second, average=1) -> np.ndarray:
    """rad: ``arg(second first*)``, averaged over ``average`` samples (a running mean of the cross
    product along the last axis, which lowers the phase noise of speckle)."""
    cross = np.asarray(second) * np.conj(np.asarray(first))
    if average > 1:
        k = np.ones(int(average)) / int(average)
        cross = np.apply_along_axis(lambda v: np.convolve(v, k, mode="same"), -1, cross)
    return np.angle(cross)


def arrival_angle(first, second, baseline, wavelength, average=1) -> np.ndarray:
    """rad: the angle ``psi`` off the baseline's normal of echoes heard by two elements, the second
    ``baseline`` m from the first along the baseline: ``sin psi = dphi lambda / (2 pi b)``
    (module docstring); NaN where the phase asks for ``|sin psi| > 1``."""
    s = phase_difference(first, second, average) * wavelength / (2.0 * np.pi * baseline)
    with np.errstate(invalid="ignore"):
        return np.where(np.abs(s) <= 1.0, np.arcsin(np.clip(s, -1.0, 1.0)), np.nan)
