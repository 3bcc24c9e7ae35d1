"""Order-independent sums for the SGD gradient's scatter: integer words per entry.

``kernel_scatter`` adds ``g k(x, nu_j)`` of every lane into entry ``j`` with atomics, whose order
is the threads' and changes a float32 sum in its last bits from run to run (a batch fit's weights
differed by 4e-6 between two identical runs). Here each float32 term is split into fixed-point
integers added with 64-bit integer atomics, exact and so order-independent, and the words become
one float64 per entry afterwards in a fixed order: the same batch gives the same bytes with any
thread count (a superaccumulator; Demmel and Nguyen, "Parallel reproducible summation", IEEE
Trans. Computers 64(7), 2015). mitsonar's histograms do the same (``plugins/integrators/paths/exact_sum.py``;
this package does not import mitsonar).

A finite float32 ``v = +-m 2^(e - 150)`` (biased exponent ``e`` 1..254, 24-bit significand ``m``)
is ``(m << s) 2^(32 k - 149)`` with ``b = e - 1``, ``k = b >> 5``, ``s = b & 31``: its low 32 bits go
into word ``k``, the rest into word ``k + 1``. Nine words cover every float32; a word takes 2^30
adds before it could overflow. Zeros and subnormals add nothing (the RBF cut keeps them out of
the products anyway); non-finite terms make the entry NaN, as a float sum would.
"""
from __future__ import annotations

import drjit as dr

WORDS = 9
STRIDE = WORDS + 1


class ExactSum:
    """``n`` entries of ``mod`` (``drjit.llvm``, ``drjit.cuda``): `add` where a float
    ``dr.scatter_add`` would be, `total` the sums (a ``mod.Float64``)."""

    def __init__(self, mod, n: int, mode=dr.ReduceMode.Local):
        self.mod, self.n, self.mode = mod, int(n), mode
        self.words = dr.zeros(mod.Int64, self.n * STRIDE)

    def add(self, values, index, active=True):
        mod = self.mod
        bits = dr.reinterpret_array(mod.UInt32, mod.Float(values))
        e = (bits >> 23) & 0xFF
        finite = active & (e > 0) & (e < 255)
        b = dr.maximum(e, 1) - 1
        wide = mod.UInt64((bits & 0x7FFFFF) | 0x800000) << mod.UInt64(b & 31)
        lo, hi = mod.Int64(wide & 0xFFFFFFFF), mod.Int64(wide >> 32)
        neg = (bits >> 31) != 0
        lo, hi = dr.select(neg, -lo, lo), dr.select(neg, -hi, hi)
        slot = mod.UInt32(index) * STRIDE + (b >> 5)
        dr.scatter_add(self.words, lo, slot, finite, mode=self.mode)
        dr.scatter_add(self.words, hi, slot + 1, finite & (hi != 0), mode=self.mode)
        dr.scatter_add(self.words, mod.Int64(1), mod.UInt32(index) * STRIDE + WORDS, active & (e == 255),
                       mode=self.mode)

    def total(self):
        mod = self.mod
        at = dr.arange(mod.UInt32, self.n) * STRIDE
        out = dr.zeros(mod.Float64, self.n)
        for k in range(WORDS):   # a fixed order: the float64 roundings are the same every time
            out += mod.Float64(dr.gather(mod.Int64, self.words, at + k)) * float(2.0 ** (32 * k - 149))
        bad = dr.gather(mod.Int64, self.words, at + WORDS) != 0
        return dr.select(bad, dr.nan, out)
