"""Element waveforms of point scatterers: delays per element, with the platform's motion.

A scatterer ``s`` at ``x`` (world, m) whose echo left the transmitter (at ``o`` when the pulse
starts, t = 0) and travelled ``L`` m to reach ``x`` (``L = |x - o|`` for a single bounce; longer after
earlier bounces) answers at element ``e`` (at ``e`` when the pulse starts, moving with the platform at
velocity ``v``) with

    a s(t - tau(t)) exp(-i 2 pi f_c tau(t))                      (complex baseband, t from the ping)

where ``a`` is its complex amplitude and ``tau(t)`` the delay of what arrives at time ``t``: to first
order in ``v / c``, arrival of the pulse's start at ``t0 = (L + R_e) / (c + u_e . v)``
(``R_e = |x - e|``, ``u_e = (x - e) / R_e``) and ``dtau/dt = -(u_o . v + u_e . v) / (c - u_o . v)``
(``u_o = (x - o) / |x - o|``): the pulse leaves a moving source compressed and reaches a moving
receiver compressed again, so a head closing on a wall at ``v`` hears its carrier shifted by
``2 v f_c / (c - v)`` (the two-way Doppler shift; Lurton 2010, section 3.5, eq. 3.55, to first
order). The waveform is evaluated exactly at each sample (`Pulse.baseband`), no interpolation.
The spreading ``1 / R`` is in ``a`` (the echo's energy at the transmitter); the elements' extra
spreading over an array a few wavelengths wide is neglected (far field).
"""
from __future__ import annotations

import math

import numpy as np

#: Complex values one synthesis chunk may hold (scatterers x elements x pulse samples).
CHUNK_VALUES = 1 << 22


def synthesize(amplitudes, positions, outbound, elements, origin, pulse, sample_rate, n_samples, sound_speed,
               velocity=None, carrier=None, t_start=0.0) -> np.ndarray:
    """complex128 (n_elements, n_samples): the sum of the scatterers' echoes (module docstring).

    ``amplitudes`` (n,) complex; ``positions`` (n, 3) world; ``outbound`` (n,) m from the transmitter
    to each scatterer; ``elements`` (n_elements, 3) world positions at t = 0; ``origin`` (3,) the
    transmitter at t = 0; ``velocity`` (3,) m/s of the platform (None: still); ``carrier`` Hz
    (default the pulse's); sample k is at ``t_start + k / sample_rate``."""
    a = np.asarray(amplitudes, dtype=np.complex128).reshape(-1)
    x = np.asarray(positions, dtype=np.float64).reshape(-1, 3)
    L = np.asarray(outbound, dtype=np.float64).reshape(-1)
    e = np.asarray(elements, dtype=np.float64).reshape(-1, 3)
    o = np.asarray(origin, dtype=np.float64).reshape(3)
    v = np.zeros(3) if velocity is None else np.asarray(velocity, dtype=np.float64).reshape(3)
    fc = pulse.carrier if carrier is None else float(carrier)
    c, fs, T = float(sound_speed), float(sample_rate), pulse.duration
    n_el = len(e)
    out_re = np.zeros(n_el * n_samples)
    out_im = np.zeros(n_el * n_samples)
    if not len(a):
        return (out_re + 1j * out_im).reshape(n_el, n_samples)
    speed = float(np.linalg.norm(v))
    n_p = int(math.ceil(T * fs / max(1.0 - 2.0 * speed / c, 0.5))) + 2
    step = max(1, CHUNK_VALUES // (n_el * n_p))
    k_rel = np.arange(n_p)
    for i in range(0, len(a), step):
        xs, ls, amp = x[i:i + step], L[i:i + step], a[i:i + step]
        ro = xs - o
        u_o = ro / np.maximum(np.linalg.norm(ro, axis=1), 1e-12)[:, None]
        d = xs[:, None, :] - e[None, :, :]                                 # (c, n_el, 3)
        r_e = np.linalg.norm(d, axis=2)
        u_e = d / np.maximum(r_e, 1e-12)[:, :, None]
        uev = u_e @ v                                                      # (c, n_el)
        uov = (u_o @ v)[:, None]
        t0 = (ls[:, None] + r_e) / (c + uev)
        beta = -(uov + uev) / (c - uov)
        k0 = np.ceil((t0 - t_start) * fs)
        k = k0[:, :, None] + k_rel                                         # (c, n_el, n_p)
        t = t_start + k / fs
        tau = t0[:, :, None] + beta[:, :, None] * (t - t0[:, :, None])
        val = amp[:, None, None] * pulse.baseband(t - tau) * np.exp(-2j * np.pi * fc * tau)
        ok = (k >= 0) & (k < n_samples) & (val != 0)
        flat = (np.arange(n_el)[None, :, None] * n_samples + k).astype(np.int64)
        out_re += np.bincount(flat[ok], weights=val.real[ok], minlength=n_el * n_samples)
        out_im += np.bincount(flat[ok], weights=val.imag[ok], minlength=n_el * n_samples)
    return (out_re + 1j * out_im).reshape(n_el, n_samples)
