"""Focused delay-and-sum of pulse-compressed element data on arbitrary points, as a Dr.Jit kernel.

The one focusing mechanism of the coherent products: strip-map SAS backprojection
(`mitsonar.sas.form_image`: points of a ground grid, pairs the pings x receivers) and the 3D imaging
sonar's near-field beamformer (`mitsonar.signals.volumetric.beamform_3d`: points on range x azimuth x
elevation, pairs one transmission x the 2D array's elements). For a point ``p`` and a
transmitter-receiver pair (transmitter ``t``, receiver ``e`` at the pulse's start, moving at ``v``):

    tau = (|p - t| + |p - e - v tau_0|) / c,   tau_0 = (|p - t| + |p - e|) / c
    b(p) = sum_pairs w(s) y(tau) exp(i 2 pi f_c tau)

``y`` the compressed complex baseband data (`compressed`: matched-filtered, upsampled by a
zero-padded spectrum) linearly interpolated at ``tau``; the exponential restores the carrier's
phase, so the sum is the exact-delay (near-field, focused) delay-and-sum of every pair (Van Trees,
*Optimum Array Processing*, 2002, ch. 2, the delay-and-sum beamformer, focused at a point: the
delays are the point's own, not a plane wave's); ``s`` is the sine of the pair's squint from
``axis`` (the mean of the unit vectors' components) and ``w`` the window over ``|s| / s_max``
(uniform or Hann; ``s_max = 1`` lets every direction in).

Lanes are points; one symbolic loop (`drjit.while_loop`) runs over the pairs, every value that
changes between calls opaque, so one compiled kernel serves every call. Geometry is float32
relative to the caller's origin (pass coordinates relative to the points' centre:
millimetre-exact at kilometres).
"""
from __future__ import annotations

import math

import numpy as np


def compressed(echoes, upsample=8):
    """complex64 (n_rows, n_elements, n_samples * upsample): matched-filtered element data at
    ``upsample`` times the sample rate (spectrum zero-padded: exact band-limited interpolation)."""
    from scipy import fft as sfft

    from mitsonar.signals.processing import matched_filter

    n = echoes.n_samples
    m = n * int(upsample)
    out = np.empty(echoes.signal.shape[:2] + (m,), np.complex64)
    for r in range(echoes.signal.shape[0]):
        y = matched_filter(echoes.signal[r], echoes.pulse, echoes.sample_rate)
        spec = sfft.fft(y, axis=-1)
        pad = np.zeros(y.shape[:-1] + (m,), np.complex128)
        h = (n + 1) // 2
        pad[..., :h] = spec[..., :h]
        pad[..., m - (n - h):] = spec[..., h:]
        out[r] = (sfft.ifft(pad, axis=-1) * upsample).astype(np.complex64)
    return out



class FocusKernel:
    """The focusing loop as one Dr.Jit kernel (module docstring)."""

    def __init__(self, data, fs_up, carrier, c, smax, window):
        import drjit as dr
        import mitsuba as mi

        from mitsonar.sim.variant import ensure_variant

        ensure_variant()
        self.dr, self.mi = dr, mi
        flat = data.reshape(-1)
        from mitsonar.plugins.jit_arrays import upload

        self.upload = upload
        # interleaved (re, im, re, im, ...): one packet gather of both parts per sample
        self.data = upload(mi.Float, np.ascontiguousarray(flat.astype(np.complex64)).view(np.float32), np.float32)
        self.n_up = int(data.shape[-1])
        self.scalars = (fs_up, carrier / c, 1.0 / c, 1.0 / smax)
        self.hann = window == "hann"

    def __call__(self, p, tx, rx, vel, axis, pair_index):
        """complex64 (n_points,): the focused sum at points ``p`` (n, 3) over the pairs: transmitters
        ``tx``, receivers ``rx``, platform velocities ``vel`` and along-track axes ``axis`` (each
        (n_pairs, 3), relative to the same origin as ``p``) and ``pair_index`` (n_pairs,) each pair's
        row in the flattened data."""
        dr, mi = self.dr, self.mi
        Float, UInt32 = mi.Float, mi.UInt32
        V3 = mi.Vector3f
        f32 = lambda a: self.upload(Float, a, np.float32)  # noqa: E731  (aligned: one kernel whatever the address)
        P = V3(f32(p[:, 0]), f32(p[:, 1]), f32(p[:, 2]))
        T = [f32(tx[:, k]) for k in range(3)]
        R = [f32(rx[:, k]) for k in range(3)]
        Vv = [f32(vel[:, k]) for k in range(3)]
        A = [f32(axis[:, k]) for k in range(3)]
        base = self.upload(UInt32, pair_index * self.n_up, np.uint32)
        fs, k_cyc, inv_c, inv_s = (dr.opaque(Float, v) for v in self.scalars)
        n_pairs = dr.opaque(UInt32, len(tx))
        n_up = dr.opaque(UInt32, self.n_up)
        data, hann = self.data, self.hann

        def body(i, acc_re, acc_im):
            g = lambda arr: dr.gather(Float, arr, i)  # noqa: E731
            t = V3(*(g(a) for a in T))
            e0 = V3(*(g(a) for a in R))
            v = V3(*(g(a) for a in Vv))
            ax = V3(*(g(a) for a in A))
            dt = P - t
            rt = dr.norm(dt)
            tau0 = (rt + dr.norm(P - e0)) * inv_c
            de = P - (e0 + v * tau0)
            re_ = dr.norm(de)
            dist = rt + re_
            tau = dist * inv_c
            s = 0.5 * (dr.dot(dt, ax) / rt + dr.dot(de, ax) / re_)
            u = dr.abs(s) * inv_s
            k = tau * fs
            k0 = dr.floor(k)
            frac = k - k0
            ki = UInt32(dr.maximum(k0, 0.0))
            ok = (u < 1.0) & (k0 >= 0.0) & (ki + 1 < n_up)
            idx = dr.gather(UInt32, base, i) + ki
            a = dr.gather(mi.Vector2f, data, idx, ok)
            b = dr.gather(mi.Vector2f, data, idx + 1, ok)
            y_re = dr.lerp(a.x, b.x, frac)
            y_im = dr.lerp(a.y, b.y, frac)
            cyc = dist * k_cyc
            sn, cs = dr.sincos(2.0 * math.pi * (cyc - dr.round(cyc)))
            w = 0.5 + 0.5 * dr.cos(math.pi * u) if hann else Float(1.0)
            w = dr.select(ok, w, 0.0)
            acc_re = dr.fma(w, y_re * cs - y_im * sn, acc_re)
            acc_im = dr.fma(w, y_re * sn + y_im * cs, acc_im)
            return i + 1, acc_re, acc_im

        n = dr.width(P.x)
        i = dr.zeros(UInt32, n)
        acc_re, acc_im = dr.zeros(Float, n), dr.zeros(Float, n)
        with dr.suspend_grad():
            i, acc_re, acc_im = dr.while_loop((i, acc_re, acc_im), lambda i, a, b: i < n_pairs, body,
                                              label="focused_delay_and_sum")
            dr.eval(acc_re, acc_im)
        return (acc_re.numpy() + 1j * acc_im.numpy()).astype(np.complex64)
