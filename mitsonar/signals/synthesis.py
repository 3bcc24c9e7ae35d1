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
``2 v f_c / (c - v)`` (the two-way Doppler shift; Lurton 2010, ch. 3, to first
order). A scatterer moving at ``w`` (a moving object) enters through the relative velocity: ``v - w``
in place of ``v``, which to first order in ``v / c`` gives the delay at the ping's start and the
shift ``f_c (u_o + u_e) . (v - w) / c``. The waveform is evaluated exactly at each sample (`Pulse.baseband`), no interpolation.
The spreading ``1 / R`` is in ``a`` (the echo's energy at the transmitter); the elements' extra
spreading over an array a few wavelengths wide is neglected (far field).
"""
from __future__ import annotations

import math

import numpy as np

#: Complex values one synthesis chunk may hold (scatterers x elements x pulse samples).
CHUNK_VALUES = 1 << 22


def synthesize(amplitudes, positions, outbound, elements, origin, pulse, sample_rate, n_samples, sound_speed,
               velocity=None, carrier=None, t_start=0.0, scatterer_velocity=None) -> np.ndarray:
    """complex128 (n_elements, n_samples): the sum of the scatterers' echoes (module docstring).

    ``amplitudes`` (n,) complex; ``positions`` (n, 3) world; ``outbound`` (n,) m from the transmitter
    to each scatterer; ``elements`` (n_elements, 3) world positions at t = 0; ``origin`` (3,) the
    transmitter at t = 0; ``velocity`` (3,) m/s of the platform (None: still); ``carrier`` Hz
    (default the pulse's); sample k is at ``t_start + k / sample_rate``; ``scatterer_velocity`` (n, 3)
    m/s of each scatterer (None: still): to first order in ``v / c`` only the velocity of the head
    relative to the scatterer counts, ``v - w`` in place of ``v`` above (positions are the
    scatterers' at the ping's start)."""
    a = np.asarray(amplitudes, dtype=np.complex128).reshape(-1)
    x = np.asarray(positions, dtype=np.float64).reshape(-1, 3)
    L = np.asarray(outbound, dtype=np.float64).reshape(-1)
    e = np.asarray(elements, dtype=np.float64).reshape(-1, 3)
    o = np.asarray(origin, dtype=np.float64).reshape(3)
    v = np.zeros(3) if velocity is None else np.asarray(velocity, dtype=np.float64).reshape(3)
    w = None if scatterer_velocity is None else np.asarray(scatterer_velocity, dtype=np.float64).reshape(-1, 3)
    fc = pulse.carrier if carrier is None else float(carrier)
    c, fs, T = float(sound_speed), float(sample_rate), pulse.duration
    n_el = len(e)
    out_re = np.zeros(n_el * n_samples)
    out_im = np.zeros(n_el * n_samples)
    if not len(a):
        return (out_re + 1j * out_im).reshape(n_el, n_samples)
    speed = float(np.linalg.norm(v)) if w is None else float(np.linalg.norm(v[None, :] - w, axis=1).max(initial=0.0))
    n_p = int(math.ceil(T * fs / max(1.0 - 2.0 * speed / c, 0.5))) + 2
    step = max(1, CHUNK_VALUES // (n_el * n_p))
    kernel = _drjit_kernel() if USE_DRJIT else None
    for i in range(0, len(a), step):
        xs, ls, amp = x[i:i + step], L[i:i + step], a[i:i + step]
        ro = xs - o
        u_o = ro / np.maximum(np.linalg.norm(ro, axis=1), 1e-12)[:, None]
        d = xs[:, None, :] - e[None, :, :]                                 # (c, n_el, 3)
        r_e = np.linalg.norm(d, axis=2)
        u_e = d / np.maximum(r_e, 1e-12)[:, :, None]
        if w is None:
            uev = u_e @ v                                                  # (c, n_el)
            uov = (u_o @ v)[:, None]
        else:                                                              # the head relative to each scatterer
            rel = v[None, :] - w[i:i + step]
            uev = np.einsum("cej,cj->ce", u_e, rel)
            uov = np.sum(u_o * rel, axis=1)[:, None]
        t0 = (ls[:, None] + r_e) / (c + uev)
        beta = -(uov + uev) / (c - uov)
        k0 = np.ceil((t0 - t_start) * fs)
        mag = np.broadcast_to(np.abs(amp)[:, None], t0.shape)
        arg = np.broadcast_to((np.angle(amp) / (2.0 * np.pi))[:, None], t0.shape)
        elem = np.broadcast_to(np.arange(n_el)[None, :], t0.shape)
        terms = (kernel or _numpy_terms)(pulse, fc, fs, t_start, n_p, n_samples, t0.ravel(), beta.ravel(), k0.ravel(),
                                         mag.ravel(), arg.ravel(), elem.ravel())
        flat, re, im = terms
        out_re += np.bincount(flat, weights=re, minlength=n_el * n_samples)
        out_im += np.bincount(flat, weights=im, minlength=n_el * n_samples)
    return (out_re + 1j * out_im).reshape(n_el, n_samples)


#: Evaluate the samples with Dr.Jit (one fused kernel per chunk, both cores) when it is importable;
#: the numpy path computes the same values (`_numpy_terms`). The sums stay in numpy (bincount in
#: sample order), so the result is the same bytes for any thread count.
USE_DRJIT = True


def _numpy_terms(pulse, fc, fs, t_start, n_p, n_samples, t0, beta, k0, mag, arg, elem):
    """(flat sample index, real part, imaginary part) of every (pair, pulse sample): numpy."""
    k = k0[:, None] + np.arange(n_p)[None, :]
    t = t_start + k / fs
    tau = t0[:, None] + beta[:, None] * (t - t0[:, None])
    u = t - tau
    # the pulse's phase and the carrier's -2 pi f_c tau, in cycles reduced to [-0.5, 0.5) in float64
    cycles = pulse.phase(u) / (2.0 * np.pi) - fc * tau + arg[:, None]
    theta = 2.0 * np.pi * (cycles - np.round(cycles))
    m = pulse.envelope(u) * mag[:, None]
    m[(k < 0) | (k >= n_samples)] = 0.0
    flat = (elem[:, None] * n_samples + np.clip(k, 0, n_samples - 1)).astype(np.int64).ravel()
    return flat, (m * np.cos(theta)).ravel(), (m * np.sin(theta)).ravel()


def _drjit_kernel():
    """`_numpy_terms` as a Dr.Jit LLVM kernel (None when Dr.Jit's LLVM backend is missing)."""
    from mitsonar.backend import prepare_llvm_environment

    prepare_llvm_environment()          # a working libLLVM, if Dr.Jit is not loaded yet
    try:
        import drjit as dr
        from drjit.llvm import Float, Float64, Int64, UInt32
    except Exception:   # noqa: BLE001 - any failure to load means: use numpy
        return None

    def terms(pulse, fc, fs, t_start, n_p, n_samples, t0, beta, k0, mag, arg, elem):
        n = len(t0) * n_p
        lane = dr.arange(UInt32, n)
        pair = lane // n_p
        j = lane - pair * n_p
        g = lambda arr, typ=Float64: dr.gather(typ, typ(arr), pair)   # noqa: E731
        t0_, beta_, k_ = g(t0), g(beta), g(k0) + Float64(j)
        t = t_start + k_ / fs
        tau = t0_ + beta_ * (t - t0_)
        u = t - tau
        cycles = ((pulse.f_start - pulse.carrier) * u + 0.5 * pulse.sweep_rate * u * u) - fc * tau + g(arg)
        theta = Float(2.0 * math.pi * (cycles - dr.round(cycles)))
        x = u / pulse.duration
        inside = (x >= 0.0) & (x < 1.0) & (k_ >= 0.0) & (k_ < float(n_samples))
        if pulse.window == "hann":
            w = 0.5 - 0.5 * dr.cos(Float(2.0 * math.pi) * Float(x))
        elif pulse.window == "hamming":
            w = 0.54 - 0.46 * dr.cos(Float(2.0 * math.pi) * Float(x))
        else:
            w = Float(1.0)
        m = dr.select(inside, w * Float(g(mag)), 0.0)
        s, co = dr.sincos(theta)
        kk = Int64(dr.clip(k_, 0.0, float(n_samples - 1)))
        flat = Int64(g(elem, Float64)) * n_samples + kk
        re, im = m * co, m * s
        dr.eval(flat, re, im)
        return flat.numpy(), re.numpy().astype(np.float64), im.numpy().astype(np.float64)

    return terms
