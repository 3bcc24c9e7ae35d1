"""A test oracle: the receiver chain's arithmetic in NumPy (the runtime chain before version 0.3,
`mitsonar.receiver.fastchain`; now only tests/test_devicechain.py runs it, against the Dr.Jit
kernels of `mitsonar.receiver.devicechain` given the same draws and speckle).

It did the range spread, the receiver noise's filter, the received power, the dB
levels and the A/D quantisation, a block of `ROW_BLOCK` rows at a time so that the block's
float64 arrays stay in the CPU's cache, with the random draws and the working copy in buffers
kept per thread. Every bin goes through the same floating-point operations in the same order as
the straightforward chain (``FAST = False``), so the bytes are the same
(tests/test_frame_overhead.py runs both): a complex number times a real one is computed as two
real products (NumPy's complex product adds ``0 x imag``, which changes at most the sign of a
zero, and every amplitude is squared before it is used). Measured in benchmarks/frame_profile.py:
the straightforward chain's fresh 2-4 MB temporaries were most of a frame's system time (page
faults).
"""
from __future__ import annotations

import math
import threading

import numpy as np

#: Rows taken at a time: a block's float64 arrays (32 x 500 bins: 128 KB) stay in cache.
ROW_BLOCK = 32
#: Kernels kept (`cached`), each a handful of weights.
MAX_CACHED = 64

_scratch = threading.local()
_cached: dict = {}


def _buffer(name, shape) -> np.ndarray:
    """A float64 array of ``shape`` kept per thread under ``name`` (overwritten by the next user)."""
    buffers = _scratch.__dict__.setdefault(name, {})
    buf = buffers.get(shape)
    if buf is None:
        buffers.clear()
        buf = buffers[shape] = np.empty(shape)
    return buf


def cached(key, compute) -> np.ndarray:
    """``compute(*key)`` computed once per ``key`` and kept read-only (small arrays: the range kernels)."""
    w = _cached.get(key)
    if w is None:
        if len(_cached) >= MAX_CACHED:
            _cached.clear()
        w = _cached[key] = compute(*key)
        w.setflags(write=False)
    return w


def scratch_copy(values) -> np.ndarray:
    """``np.array(values, dtype=float64, ndmin=2)`` (a copy: the input stays untouched) in a
    buffer kept per thread and shape, overwritten by the next call: `apply`'s working copy."""
    src = np.asarray(values)
    if src.dtype == object or src.dtype.kind in "USV":
        return np.array(values, dtype=np.float64, ndmin=2)
    shape = (1,) * max(0, 2 - src.ndim) + src.shape
    buf = _buffer("inten", shape)
    np.copyto(buf, src.reshape(shape), casting="unsafe")
    return buf


def complex_gaussian(shape, rng: np.random.Generator, corr_bins=None) -> np.ndarray:
    """Unit circular complex Gaussian samples of ``shape`` (mean power 1), filtered along the last
    axis with the amplitude weights ``corr_bins`` (normalised), so that neighbouring bins within
    one pulse are correlated like the matched filter's output; the marginal law is unchanged."""
    n_bins = shape[-1]
    h = _taps(corr_bins)
    k = h.size
    z = rng.standard_normal(_draws_shape(shape, h)).view(np.complex128)[..., 0]
    z *= math.sqrt(0.5)
    if k == 1:
        return z
    zf = np.zeros(shape, dtype=np.complex128)
    for j in range(k):
        zf += h[j] * z[..., j:j + n_bins]
    return zf


def gaussian_draws(shape, rng: np.random.Generator, corr_bins=None):
    """`complex_gaussian`'s draws (the same numbers from ``rng``), unfiltered, as
    float64 (..., n_bins + k - 1, 2) (real, imaginary) in a kept buffer, and its normalised taps;
    `filtered` filters them."""
    h = _taps(corr_bins)
    z = _buffer("draws", _draws_shape(shape, h))
    rng.standard_normal(out=z)
    z *= math.sqrt(0.5)
    return z, h


def _taps(corr_bins):
    """The noise filter's taps: ``corr_bins``' positive weights normalised to unit power (one tap
    of 1 for None)."""
    h = np.ones(1) if corr_bins is None else np.asarray(corr_bins, dtype=np.float64)
    h = h[h > 0]
    return h / math.sqrt(float(np.sum(h * h)))


def _draws_shape(shape, h):
    """The draws behind a filtered ``shape`` with taps ``h``: (..., n_bins + taps - 1, 2) (re, im)."""
    return tuple(shape[:-1]) + (shape[-1] + h.size - 1, 2)


def filtered(z, h, n_bins):
    """(real, imaginary) of `complex_gaussian`'s filtered samples from `gaussian_draws`' ``z``
    (the same sums in the same order, without complex temporaries)."""
    if h.size == 1:
        return z[..., 0].copy(), z[..., 1].copy()
    zf = np.zeros(z.shape[:-2] + (n_bins, 2))
    tmp = np.empty_like(zf)
    for j in range(h.size):
        zf += np.multiply(z[..., j:j + n_bins, :], h[j], out=tmp)
    return zf[..., 0], zf[..., 1]


def convolve_range(inten: np.ndarray, kernel: np.ndarray) -> np.ndarray:
    """Convolve along the last axis with a centred kernel; energy pushed off the ends is dropped.
    One scratch buffer serves every tap (``np.multiply(..., out=)``: the products and sums of
    ``out += w * x``, without a new temporary per tap)."""
    m = (kernel.size - 1) // 2
    n = inten.shape[-1]
    out = np.zeros_like(inten)
    tmp = np.empty_like(inten)
    for j, w in enumerate(kernel):
        shift = j - m
        if w == 0.0 or abs(shift) >= n:
            continue
        if shift >= 0:
            out[..., shift:] += np.multiply(w, inten[..., :n - shift], out=tmp[..., :n - shift])
        else:
            out[..., :n + shift] += np.multiply(w, inten[..., -shift:], out=tmp[..., :n + shift])
    return out


def convolve_span(inten: np.ndarray, kernel: np.ndarray) -> np.ndarray:
    """`convolve_range` of a block of rows (intensities >= 0, weights >= 0) computed only over
    the columns that can receive energy: those within ``kernel.size`` of a column holding a
    non-zero value. The same bytes: every other output is ``+0.0`` either way (sums of ``w x 0``),
    and inside the span the skipped terms are ``+0.0`` products, which leave a sum unchanged
    (no ``-0.0`` arises from non-negative terms). A sonar frame's echoes start at the nearest
    surface: the bins before it (a third of the quay frame's) are not convolved."""
    n = inten.shape[-1]
    cols = np.flatnonzero(inten.any(axis=0))
    if cols.size == 0:
        return np.zeros_like(inten)
    lo, hi = max(0, int(cols[0]) - kernel.size), min(n, int(cols[-1]) + 1 + kernel.size)
    if lo == 0 and hi == n:
        return convolve_range(inten, kernel)
    out = np.zeros_like(inten)
    out[..., lo:hi] = convolve_range(inten[..., lo:hi], kernel)
    return out


def convolve_sparse(inten: np.ndarray, kernel: np.ndarray) -> np.ndarray:
    """`convolve_range` computed from the non-zero values only (a new array): for each tap in
    `convolve_range`'s order, every non-zero value's product is added to its output bin. The
    same bytes: an output's sum takes the same non-zero products in the same order (tap by tap;
    within a tap no two values share an output bin), and the dense sum's other terms are
    ``+0.0`` products (intensities >= 0, weights >= 0), which leave a sum unchanged. A frame
    rendered with few paths holds few echoes (the quay frame at spp 1: 1 % of its bins), so its
    spread costs a few thousand products instead of 17 passes over every bin."""
    n = inten.shape[-1]
    m = (kernel.size - 1) // 2
    flat = inten.reshape(-1)
    at = np.flatnonzero(flat)
    values = flat[at]
    cols = at % n
    out = np.zeros_like(flat)
    for j, w in enumerate(kernel):
        shift = j - m
        if w == 0.0 or abs(shift) >= n:
            continue
        keep = (cols >= -shift) & (cols < n - shift)
        to = at[keep] + shift
        out[to] += w * values[keep]
    return out.reshape(inten.shape)


#: `received_bytes` spreads a scan through `convolve_sparse` when at most one bin in this many
#: holds an echo (a scattered add costs about as much as this many bins of a dense pass).
SPARSE_RATIO = 16


def received_bytes(inten, g, kernel, quiet, ring, z, taps, f, levels, ad):
    """Device bytes (uint8, the shape of ``inten``) of the chain after its set-up (`Electronics._apply_fast`).

    ``inten`` float64 (n_rows, n_bins), overwritten; ``g`` the complex speckle per bin; ``kernel``
    the range spread; ``quiet``: no ring-down and no noise (power = I |g|^2); ``ring`` the
    ring-down amplitude per bin or None; ``z``, ``taps`` the noise draws (`gaussian_draws`) or
    None, ``f`` its amplitude per bin; ``levels`` (calibration, gain, TVG per bin) in dB, added
    in that order; ``ad`` (ad_low, ad_span, bit_depth)."""
    calibration, gain, tvg = levels
    ad_low, ad_span, bit_depth = ad
    scale = 15.0 if bit_depth == 4 else 255.0
    out = np.empty(inten.shape, dtype=np.uint8)
    spread = None
    if kernel.size > 1 and np.count_nonzero(inten) * SPARSE_RATIO <= inten.size:
        spread = convolve_sparse(inten, kernel)
    for r0 in range(0, inten.shape[0], ROW_BLOCK):
        rows = slice(r0, r0 + ROW_BLOCK)
        if spread is not None:
            x = spread[rows]
        else:
            x = convolve_span(inten[rows], kernel) if kernel.size > 1 else inten[rows]
        gb = g[rows]
        if quiet:
            total = np.abs(gb) ** 2
            total *= x
        else:   # |sqrt(I) g + sqrt(R) + f n|^2
            np.sqrt(x, out=x)
            re = np.multiply(x, gb.real)
            im = np.multiply(x, gb.imag, out=x)
            if ring is not None:
                re += ring
            if z is not None:
                n_re, n_im = filtered(z[rows], taps, x.shape[-1])
                n_re *= f
                re += n_re
                n_im *= f
                im += n_im
            total = np.multiply(re, re, out=re)
            total += np.multiply(im, im, out=im)
        with np.errstate(divide="ignore"):
            level = np.log10(total, out=total)
        level *= 10.0
        level += calibration
        level += gain
        level += tvg
        # quantise: round(scale clip((level - ad_low) / ad_span, 0, 1)), halves up, NaN -> 0
        level -= ad_low
        level /= ad_span
        np.clip(level, 0.0, 1.0, out=level)
        level[np.isnan(level)] = 0.0
        level *= scale
        q = np.floor(level)
        level -= q
        q += level >= 0.5
        if bit_depth == 4:
            q *= 17.0
        out[rows] = q
    return out
