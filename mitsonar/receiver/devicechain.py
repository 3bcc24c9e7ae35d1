"""The receiver chain as Dr.Jit kernels of the active variant (issue 55, "The whole frame on the device").

`mitsonar.receiver.electronics.Electronics` hands a frame's per-bin work here: the range spread,
the scene speckle (`mitsonar.receiver.speckle`, itself Dr.Jit kernels) or speckle drawn from the
seed, the receiver noise, the received power, the dB levels and the A/D quantisation, in one
kernel over the frame's ``n_rows x n_bins`` bins, after one kernel that draws the noise. The
intensity may come from the render as a Dr.Jit array (`mitsonar.sim.render.render_frame`): no
NumPy array on the way, the bytes a ``mi.UInt8`` array (on the GPU for ``cuda``).

Random numbers come from a counter-based generator, Philox4x32 (Salmon et al. 2011, *Parallel
random numbers: as easy as 1, 2, 3*; Dr.Jit's ``Philox4x32``, 7 rounds): the numbers of a bin are
a function of the seed (the generator's 64-bit key) and of the counter ``(column, row, stream)``,
not of the order threads run in. So the same seed gives the same bytes on ``llvm`` for any thread
count, and ``cuda`` draws the same integers. A unit circular complex Gaussian is drawn from two
32-bit words by Box and Muller's transform, ``sqrt(-ln u1) exp(2 pi i u2)`` with ``u1 = (x0 +
1/2) 2^-32``, ``u2 = x1 2^-32`` (in float64: Dr.Jit computes ``log`` and ``sincos`` in float64 with
its own polynomials on both back ends; its power ``-ln u1`` is exponential with mean 1).

Streams (``counter[2]``) keep the generator's uses apart: `STREAM_NOISE` the receiver's noise
(electronics seed), `STREAM_SPECKLE` speckle drawn from the electronics seed for an intensity
that does not say where its echoes come from, `STREAM_FEATURES` the scene speckle's random
Fourier features (speckle seed).

Every bin goes through the same operations in the same order whatever the thread count: the
spread's taps added one by one to a sum that starts at ``+0.0``, the noise filter's likewise,
``sqrt(I) g + ring + f n`` then ``re^2 + im^2``, ``10 log10`` (``log2`` times ``log10(2)``) plus
calibration, gain and TVG, the A/D window, halves rounded up. ``cuda`` and ``llvm`` may differ in
the last bits of a level (ptxas fusing multiply-adds), which changes a byte only where a level
falls within that of a quantisation step's half.

Imports nothing of mitsonar.
"""
from __future__ import annotations

import math

import numpy as np

STREAM_NOISE = 0
STREAM_SPECKLE = 1
STREAM_FEATURES = 2
#: Philox rounds (Dr.Jit's default; pinned so that a later default does not change the bytes).
ROUNDS = 7
SEED_MAX = 2 ** 64 - 1
#: Settings tables kept (the electronics' per-bin arrays, the range kernels), then all dropped.
MAX_CACHED = 64
_cached: dict = {}


def cached(key):
    """What `keep` kept under ``key``, else None."""
    return _cached.get(key)


def keep(key, value):
    """Keep ``value`` under ``key`` (bounded: `MAX_CACHED`); returns it."""
    if len(_cached) >= MAX_CACHED:
        _cached.clear()
    _cached[key] = value
    return value


def variant() -> str:
    """The active Mitsuba variant; on first use (none active yet) the one mitsonar chooses
    (`mitsonar.backend.ensure_active`: ``MITSONAR_VARIANT``, else ``llvm_ad_mono``), so the
    chain runs without a scene loaded first."""
    from mitsonar.backend import ensure_active, prepare_llvm_environment

    prepare_llvm_environment()
    import mitsuba as mi

    if mi.variant() is None:
        ensure_active()
    return mi.variant() or ""


def check_variant() -> None:
    """Refuse, in one line, a variant the chain cannot run on (a Dr.Jit ``llvm``/``cuda`` one)."""
    v = variant()
    if not (v.startswith("llvm") or v.startswith("cuda")):
        raise ValueError(f"electronics: the receiver chain runs as Dr.Jit kernels of an llvm or cuda variant; "
                         f"the active Mitsuba variant is {v or 'none'}")


def _words(seed, stream, ctr0, ctr1):
    import drjit as dr
    import mitsuba as mi

    key = dr.opaque(mi.UInt64, int(seed))   # opaque: a new seed is new data for the same kernel
    rng = mi.Philox4x32(key, mi.UInt32(ctr0), mi.UInt32(ctr1), mi.UInt32(stream), ROUNDS)
    return rng.next_uint32x4()


def _box_muller(x0, x1):
    """``sqrt(-ln u1)``, ``cos 2 pi u2``, ``sin 2 pi u2`` of Box and Muller's transform."""
    import drjit as dr
    import mitsuba as mi

    u1 = (mi.Float64(x0) + 0.5) * 2.0 ** -32
    u2 = mi.Float64(x1) * 2.0 ** -32
    s, c = dr.sincos(u2 * (2.0 * math.pi))
    return dr.sqrt(-dr.log(u1)), c, s


def complex_normals(seed, stream, ctr0, ctr1):
    """A unit circular complex Gaussian (``E|z|^2 = 1``) per lane, (re, im) ``mi.Float64``, from
    the counter ``(ctr0, ctr1, stream)`` under ``seed``."""
    x = _words(seed, stream, ctr0, ctr1)
    r, c, s = _box_muller(x[0], x[1])
    return r * c, r * s


def normals(seed, stream, ctr0, ctr1):
    """Four independent standard normals per lane (``mi.Float64``) from one counter."""
    x = _words(seed, stream, ctr0, ctr1)
    r0, c0, s0 = _box_muller(x[0], x[1])
    r1, c1, s1 = _box_muller(x[2], x[3])
    k = math.sqrt(2.0)
    return r0 * c0 * k, r0 * s0 * k, r1 * c1 * k, r1 * s1 * k


def uniforms(seed, stream, ctr0, ctr1):
    """A uniform in [0, 1) per lane (``mi.Float64``) from one counter."""
    import mitsuba as mi

    return mi.Float64(_words(seed, stream, ctr0, ctr1)[0]) * 2.0 ** -32


def draws(seed, stream, n_rows, width):
    """Unit circular complex Gaussians ``z[row, j]`` (re, im), ``n_rows x width`` values,
    row-major, evaluated: the counter of ``z[row, j]`` is ``(j, row, stream)``."""
    import drjit as dr
    import mitsuba as mi

    lane = dr.arange(mi.UInt32, n_rows * width)
    w = dr.opaque(mi.UInt32, width)
    row = lane // w
    re, im = complex_normals(seed, stream, lane - row * w, row)
    dr.eval(re, im)
    return re, im


def taps(corr_bins) -> np.ndarray:
    """The noise filter's taps: ``corr_bins``' positive weights normalised to unit power (one tap
    of 1 for None)."""
    h = np.ones(1) if corr_bins is None else np.asarray(corr_bins, dtype=np.float64)
    h = h[h > 0]
    return h / math.sqrt(float(np.sum(h * h)))


def _filtered(z, h, row, col, width):
    """``sum_j h_j z[row, col + j]`` (re, im), taps in order from ``+0.0``."""
    import drjit as dr
    import mitsuba as mi

    start = row * width + col
    if h.size == 1:
        return dr.gather(mi.Float64, z[0], start), dr.gather(mi.Float64, z[1], start)
    n_re, n_im = mi.Float64(0.0), mi.Float64(0.0)
    for j, hj in enumerate(h):
        n_re = n_re + dr.gather(mi.Float64, z[0], start + j) * float(hj)
        n_im = n_im + dr.gather(mi.Float64, z[1], start + j) * float(hj)
    return n_re, n_im


def _spread(x_all, kernel, base, col, n_bins):
    """The range spread of row-major ``x_all`` at ``(base, col)``: ``out[b] += w_j x[b - (j - m)]``,
    tap by tap from ``+0.0``; energy pushed past either end is dropped."""
    import drjit as dr
    import mitsuba as mi

    kernel = np.asarray(kernel, dtype=np.float64)
    array_type = type(x_all)   # read as stored (a cast of mapped host memory would compile for its alignment)
    if kernel.size == 1:
        return mi.Float64(dr.gather(array_type, x_all, base + mi.UInt32(col))) * float(kernel[0])
    m = (kernel.size - 1) // 2
    x = mi.Float64(0.0)
    for j, w in enumerate(kernel):
        shift = j - m
        if w == 0.0 or abs(shift) >= n_bins:
            continue
        src = col - shift
        ok = (src >= 0) & (src < n_bins)
        v = mi.Float64(dr.gather(array_type, x_all, base + mi.UInt32(dr.maximum(src, 0)), ok))
        x = dr.select(ok, x + float(w) * v, x)
    return x


def _lanes(n_rows, n_bins):
    """(lane, row, column as Int32, row's first lane) of a row-major ``n_rows x n_bins`` frame."""
    import drjit as dr
    import mitsuba as mi

    lane = dr.arange(mi.UInt32, n_rows * n_bins)
    nb = dr.opaque(mi.UInt32, n_bins)
    row = lane // nb
    return lane, row, mi.Int32(lane - row * nb), row * nb


def spread(inten, n_rows, n_bins, kernel):
    """The range spread (step 1 of the chain) of ``inten`` (``mi.Float64``, row-major), evaluated."""
    import drjit as dr
    import mitsuba as mi

    with dr.suspend_grad():
        _, _, col, base = _lanes(n_rows, n_bins)
        out = _spread(inten, kernel, base, col, n_bins)
        dr.eval(out)
    return out


def _weibull(g_re, g_im, k):
    """``g`` with ``|g|^2`` reshaped to a Weibull law of shape ``k`` and mean 1: ``E^(1/k) /
    Gamma(1 + 1/k)`` of the exponential ``E = |g|^2``."""
    import drjit as dr

    power = g_re * g_re + g_im * g_im
    k = float(k)
    factor = dr.select(power > 0, dr.power(power, 0.5 / k - 0.5), 0.0) * (1.0 / math.sqrt(math.gamma(1.0 + 1.0 / k)))
    return g_re * factor, g_im * factor


def drawn_speckle_power(seed, n_rows, n_bins, corr, weibull):
    """``|g|^2`` (``mi.Float64``, row-major) of the speckle `received_bytes` draws from ``seed``
    when it is given none: mean 1, exponential (``weibull`` None) or Weibull."""
    import drjit as dr
    import mitsuba as mi

    h = taps(corr)
    width = n_bins + h.size - 1
    with dr.suspend_grad():
        zg = draws(seed, STREAM_SPECKLE, n_rows, width)
        _, row, col, _ = _lanes(n_rows, n_bins)
        g_re, g_im = _filtered(zg, h, row, mi.UInt32(col), width)
        if weibull is not None:
            g_re, g_im = _weibull(g_re, g_im, weibull)
        out = g_re * g_re + g_im * g_im
        dr.eval(out)
    return out


def received_bytes(inten, n_rows, n_bins, *, kernel, corr, g, g_seed, weibull, ring, f, noise_seed, levels, ad):
    """Device bytes (``mi.UInt8``, ``n_rows x n_bins`` row-major) of the chain; a 16- or
    32-bit A/D's codes as ``mi.UInt32`` (``bit_depth`` 16, 32: the same levels on ``2^bits - 1``).

    ``inten`` the intensity (``mi.Float64`` or ``mi.Float32``, row-major; not modified);
    ``kernel`` the range spread's weights (NumPy, offsets ``-m..m``); ``corr`` the pulse's
    amplitude weights (the correlation of drawn noise and speckle) or None; ``g`` the scene's
    speckle (``(re, im)`` of ``mi.Float64``, or ``(pairs,)`` its interleaved real and imaginary
    parts, or None: drawn from ``g_seed``, or no speckle when
    ``g_seed`` is None too); ``weibull`` the Weibull shape of the speckle's intensity (None:
    fully developed); ``ring`` the ring-down amplitude per bin (``mi.Float64``) or None; ``f``
    the noise's amplitude per bin or None (no noise); ``levels`` (calibration, gain, TVG per bin
    ``mi.Float64``) added in that order; ``ad`` (ad_low, ad_span, bit_depth).
    """
    import drjit as dr
    import mitsuba as mi

    if n_rows * n_bins == 0:   # an empty frame: no kernels
        return mi.UInt8() if ad[2] <= 8 else mi.UInt32()
    calibration, gain, tvg = levels
    ad_low, ad_span, bit_depth = ad
    scale = float(AD_CODES[bit_depth][0])
    h = taps(corr)
    width = n_bins + h.size - 1
    with dr.suspend_grad():
        z = draws(noise_seed, STREAM_NOISE, n_rows, width) if f is not None else None
        zg = draws(g_seed, STREAM_SPECKLE, n_rows, width) if g is None and g_seed is not None else None
        lane, row, col, base = _lanes(n_rows, n_bins)
        ucol = mi.UInt32(col)
        x = _spread(inten, kernel, base, col, n_bins)
        if g is not None:
            if len(g) == 1:   # (real, imaginary) pairs of a host array, read in place
                g_re = mi.Float64(dr.gather(type(g[0]), g[0], 2 * lane))
                g_im = mi.Float64(dr.gather(type(g[0]), g[0], 2 * lane + 1))
            else:
                g_re = mi.Float64(dr.gather(type(g[0]), g[0], lane))
                g_im = mi.Float64(dr.gather(type(g[1]), g[1], lane))
        elif zg is not None:
            g_re, g_im = _filtered(zg, h, row, ucol, width)
        else:
            g_re, g_im = None, None
        if g_re is not None and weibull is not None:
            g_re, g_im = _weibull(g_re, g_im, weibull)
        if ring is None and f is None:   # no background: I |g|^2
            total = x if g_re is None else x * (g_re * g_re + g_im * g_im)
        else:   # |sqrt(I) g + sqrt(R) + f n|^2
            amp = dr.sqrt(x)
            re, im = (amp, mi.Float64(0.0)) if g_re is None else (amp * g_re, amp * g_im)
            if ring is not None:
                re = re + dr.gather(mi.Float64, ring, ucol)
            if f is not None:
                n_re, n_im = _filtered(z, h, row, ucol, width)
                fb = dr.gather(mi.Float64, f, ucol)
                re = re + n_re * fb
                im = im + n_im * fb
            total = re * re + im * im
        level = dr.log2(total) * (10.0 * math.log10(2.0))
        level = level + float(calibration)
        level = level + float(gain)
        level = level + dr.gather(mi.Float64, tvg, ucol)
        level = (level - float(ad_low)) / float(ad_span)
        level = dr.select(dr.isnan(level), 0.0, dr.clip(level, 0.0, 1.0)) * scale
        q = dr.floor(level)
        q = dr.select(level - q >= 0.5, q + 1.0, q)
        if bit_depth == 4:
            q = q * 17.0
        out = mi.UInt32(q) if bit_depth > 8 else mi.UInt8(mi.UInt32(q))
        dr.eval(out)
    return out


#: each A/D width's codes: (full scale, step between reported codes, NumPy type of the data)
AD_CODES = {8: (255, 1, np.uint8), 4: (15, 17, np.uint8), 16: (65535, 1, np.uint16),
            32: (4294967295, 1, np.uint32)}


def host_codes(data, shape, bit_depth: int) -> np.ndarray:
    """`received_bytes`'s array as NumPy of ``shape`` in the A/D's type (uint8; uint16 or
    uint32 at 16 or 32 bits)."""
    return data.numpy().reshape(shape).astype(AD_CODES[bit_depth][2], copy=False)


def spread_kernel(length: float, sigma: float, bin_width: float) -> np.ndarray:
    """Bin weights of U[0, length) + N(0, sigma^2) for an echo at a bin centre (see range_kernel),
    computed once per setting (read-only)."""
    key = (float(length), float(sigma), float(bin_width))
    w = cached(key)
    if w is None:
        w = _spread_kernel_computed(*key)
        w.setflags(write=False)
        keep(key, w)
    return w


def _spread_kernel_computed(length: float, sigma: float, bin_width: float) -> np.ndarray:
    if length <= 0 and sigma <= 0:
        return np.ones(1)
    m = int(math.ceil((length + 6.0 * sigma) / bin_width)) + 1
    edges = (np.arange(-m, m + 2) - 0.5) * bin_width
    w = np.maximum(np.diff([_box_gauss_cdf(x, length, sigma) for x in edges]), 0.0)
    return w / w.sum()


def _box_gauss_cdf(x: float, length: float, sigma: float) -> float:
    """CDF at x of U[0, length) + N(0, sigma^2) (either part may be absent)."""
    if sigma <= 0:
        return min(max(x / length, 0.0), 1.0)
    if length <= 0:
        return 0.5 * (1.0 + math.erf(x / (sigma * math.sqrt(2.0))))

    def g(u):  # integral of the normal CDF: u Phi(u/s) + s phi(u/s)
        t = u / sigma
        return u * 0.5 * (1.0 + math.erf(t / math.sqrt(2.0))) + sigma * math.exp(-0.5 * t * t) / math.sqrt(2.0 * math.pi)

    return (g(x) - g(x - length)) / length
