"""The receiver chain's per-bin arithmetic as one Dr.Jit kernel (issue "Frame overhead").

`mitsonar.receiver.fastchain.received_bytes` does a frame's range spread, noise filter, received
power, dB levels and A/D quantisation in NumPy, pass after pass over the bins. On a GPU the render
of a 512-beam frame takes about 3 ms and that chain about 15-20 ms (NVIDIA H100,
``benchmarks/frame_profile.py``). `received_bytes` here runs the same arithmetic as one kernel of
the active variant, in float64 (on the GPU for ``cuda``, on all cores for ``llvm``): the random
draws, the speckle and the settings are computed as before (the same numbers from the same seeds)
and uploaded, the bytes come back.

Every bin goes through `fastchain`'s operations in its order: the spread's taps added one by one
to a sum that starts at ``+0.0`` (out-of-range taps add nothing), the noise filter's likewise,
``sqrt(I) g + ring + f n`` then ``re^2 + im^2``, ``10 log10`` plus calibration, gain and TVG, the
A/D window, halves rounded up. Two steps may round differently: ``log10`` (Dr.Jit's ``log`` times
``1 / ln 10`` against the C library's ``log10``: a few units in the last place) and, on a GPU,
ptxas fusing a multiply and an add into one FMA. Either matters only where a level falls on a
quantisation step's half, which exact settings do hit (the default ring-down without noise at
0.15 m: 32.5 dB, byte 212.5): the kernel marks every level within 1e-9 (relative) of a half and
`fastchain` recomputes those rows. tests/test_jitchain.py finds every byte equal to NumPy's
(every electronics setting, 512 x 500 quay frames) on ``llvm``, and did on an NVIDIA H100 before
that row check was added (not rerun there since).

Measured on the H100 (``python benchmarks/frame_targets.py --chain numpy`` then ``--chain auto``,
alternating, two rounds, *2026-11-26*): the quay frame at 5 % in 27-31 ms with the NumPy chain,
15-16 ms with this kernel (61-66 frames/s against 32-37); at spp 1, 23 ms against 13-15 ms.

On the CPU (``llvm``, 2 cores, `Electronics.apply` with its draws, interleaved medians) the kernel
fuses what NumPy does in passes: 1.3x faster for 32 x 500 bins, 1.75x for 200 x 500 (the box
scan), 1.76x for 512 x 500 (17.6 ms to 10.0 ms), but slower for one ping of 600 bins (0.35 ms
against 0.25 ms: tracing the kernel costs more than the arithmetic).

`CHAIN` chooses: ``"auto"`` (this kernel from `JIT_MIN` bins of a call on, NumPy below),
``"jit"`` (this kernel always), ``"numpy"`` (never). Imports nothing of mitsonar.
"""
from __future__ import annotations

import math

import numpy as np

#: ``"auto"``, ``"jit"`` or ``"numpy"`` (see the module docstring).
CHAIN = "auto"
CHOICES = ("auto", "jit", "numpy")
#: ``"auto"`` takes the kernel from this many bins of a call on (measured crossover: 1000-4000).
JIT_MIN = 4096


def use_jit(size: int = JIT_MIN) -> bool:
    """True when `received_bytes` of ``size`` bins should run here rather than in `fastchain`
    (`CHAIN`, `JIT_MIN`; a Dr.Jit ``mono`` variant must be active)."""
    if CHAIN not in CHOICES:
        raise ValueError(f"jitchain.CHAIN {CHAIN!r} is not one of {', '.join(CHOICES)}")
    if CHAIN == "numpy":
        return False
    try:
        import mitsuba as mi
    except ImportError:
        return False
    variant = mi.variant() or ""
    if not (variant.startswith("llvm") or variant.startswith("cuda")) or "mono" not in variant:
        return False
    return CHAIN == "jit" or size >= JIT_MIN


def _f64(values):
    """A flat float64 array of the variant. On ``llvm`` Dr.Jit maps a contiguous NumPy array (no
    copy) and would compile a contiguous read of it (a gather at a plain ``arange``) for the
    pointer's alignment, which NumPy leaves to chance: `received_bytes` reads every array through
    computed indices, which compile one way whatever the alignment (an aligned copy of the 10 MB a
    frame uploads cost more than the chain saved); a one-element array (a one-bin frame's per-bin
    settings) is copied into Dr.Jit's memory."""
    import drjit as dr
    import mitsuba as mi

    a = np.ascontiguousarray(values, dtype=np.float64).reshape(-1)
    # one element: a broadcast load, compiled for the mapped pointer's alignment, so it is put in
    # Dr.Jit's own memory instead; opaque, so that its value is not baked into the kernel either
    arr = mi.Float64(a) if a.size != 1 else mi.Float64(float(a[0]))
    dr.make_opaque(arr)
    return arr


def received_bytes(inten, g, kernel, quiet, ring, z, taps, f, levels, ad):
    """`fastchain.received_bytes` (same arguments, same result: uint8 of ``inten``'s shape) as one
    Dr.Jit kernel of the active variant. ``quiet`` (no ring-down, no noise) goes to `fastchain`:
    its ``|g|^2`` is NumPy's ``hypot``, which this kernel does not reproduce."""
    import drjit as dr
    import mitsuba as mi

    import mitsonar.receiver.fastchain as fastchain   # a leaf, like this module

    if quiet:
        return fastchain.received_bytes(inten, g, kernel, quiet, ring, z, taps, f, levels, ad)
    calibration, gain, tvg = levels
    ad_low, ad_span, bit_depth = ad
    scale = 15.0 if bit_depth == 4 else 255.0
    n_rows, n_bins = inten.shape
    with dr.suspend_grad():
        lane = dr.arange(mi.UInt32, n_rows * n_bins)
        # the bin count opaque: with a literal 1 Dr.Jit would simplify `at` back to `lane`
        nb = dr.opaque(mi.UInt32, n_bins)
        row = lane // nb
        col = mi.Int32(lane - row * nb)
        base = row * nb
        at = base + mi.UInt32(col)      # = lane, but computed: a gather, not an alignment-bound load
        x_all = _f64(inten)
        # the range spread: out[b] += w_j x[b - (j - m)], tap by tap (fastchain.convolve_range)
        if kernel.size > 1:
            m = (kernel.size - 1) // 2
            x = mi.Float64(0.0)
            for j, w in enumerate(np.asarray(kernel, dtype=np.float64)):
                shift = j - m
                if w == 0.0 or abs(shift) >= n_bins:
                    continue
                src = col - shift
                ok = (src >= 0) & (src < n_bins)
                v = dr.gather(mi.Float64, x_all, base + mi.UInt32(dr.maximum(src, 0)), ok)
                x = dr.select(ok, x + float(w) * v, x)
        else:
            x = dr.gather(mi.Float64, x_all, at)
        gc = np.asarray(g)
        amp = dr.sqrt(x)
        if np.iscomplexobj(gc) and gc.dtype == np.complex128 and gc.flags.c_contiguous:
            # (real, imaginary) pairs read in place: no copies of the real and imaginary parts
            g_all = _f64(gc.reshape(-1).view(np.float64))
            re = amp * dr.gather(mi.Float64, g_all, 2 * at)
            im = amp * dr.gather(mi.Float64, g_all, 2 * at + 1)
        elif np.iscomplexobj(gc):
            re = amp * dr.gather(mi.Float64, _f64(gc.real), at)
            im = amp * dr.gather(mi.Float64, _f64(gc.imag), at)
        else:
            re = amp * dr.gather(mi.Float64, _f64(gc), at)
            im = mi.Float64(0.0) * amp
        if ring is not None:
            re = re + dr.gather(mi.Float64, _f64(ring), mi.UInt32(col))
        if z is not None:
            width = z.shape[-2]          # n_bins + taps - 1 draws per row, (real, imaginary)
            z_all = _f64(z)
            start = (row * width + mi.UInt32(col)) * 2
            h = np.asarray(taps, dtype=np.float64)
            if h.size == 1:
                n_re = dr.gather(mi.Float64, z_all, start)
                n_im = dr.gather(mi.Float64, z_all, start + 1)
            else:
                n_re, n_im = mi.Float64(0.0), mi.Float64(0.0)
                for j, hj in enumerate(h):
                    n_re = n_re + dr.gather(mi.Float64, z_all, start + 2 * j) * float(hj)
                    n_im = n_im + dr.gather(mi.Float64, z_all, start + 2 * j + 1) * float(hj)
            fb = dr.gather(mi.Float64, _f64(f), mi.UInt32(col))
            re = re + n_re * fb
            im = im + n_im * fb
        total = re * re + im * im
        db = dr.log(total) * (1.0 / math.log(10.0))
        db = db * 10.0
        tvg_b = dr.gather(mi.Float64, _f64(tvg), mi.UInt32(col))
        level = db + float(calibration) + float(gain)
        level = level + tvg_b
        level = (level - float(ad_low)) / float(ad_span)
        level = dr.select(dr.isnan(level), 0.0, dr.clip(level, 0.0, 1.0)) * scale
        q = dr.floor(level)
        q = dr.select(level - q >= 0.5, q + 1.0, q)
        if bit_depth == 4:
            q = q * 17.0
        # A level within rounding of a step's half (`log` against NumPy's `log10`): marked 256,
        # its row's bytes come from `fastchain` below. The window, 1e-9 of the magnitudes added
        # up, is millions of times the few units in the last place the two logarithms differ by.
        window = 1e-9 * (1.0 + dr.abs(db) + abs(float(calibration)) + abs(float(gain)) + dr.abs(tvg_b)
                         + abs(float(ad_low))) * (scale / float(ad_span))
        q = dr.select(dr.abs(level - dr.floor(level) - 0.5) <= dr.minimum(window, 0.25), 256.0, q)
        data = mi.UInt32(q).numpy().reshape(n_rows, n_bins)
    redo = np.flatnonzero((data > 255).any(axis=1))
    if redo.size:   # NumPy's bytes for those rows (each row's chain is its own: spread and noise run along it)
        data[redo] = fastchain.received_bytes(inten[redo], gc[redo], kernel, quiet, ring,
                                              None if z is None else z[redo], taps, f, levels, ad)
    return data.astype(np.uint8)
