"""Histogram sums that do not depend on the order of the adds: integer words per bin.

A float sum depends on the order of its terms, and atomic adds (``dr.scatter_add``) take the
order the threads happen to run in, so a float32 or float64 histogram changes in its last bits
with the thread count, the machine's load or the GPU. Integer addition is associative: each
float32 echo is split into fixed-point integers added with 64-bit integer atomics into words of
its bin, exactly, and the words are turned into one float64 per bin afterwards in a fixed order.
The same echoes give the same bytes whatever the threads (a superaccumulator, as in Kulisch's
exact dot product; Demmel and Nguyen, "Parallel reproducible summation", IEEE Trans. Computers
64(7), 2015, use the same idea with fewer bits).

Layout: a finite float32 ``v = +-m 2^(e - 150)`` (``e`` its biased exponent 1..254, ``m`` its 24-bit
significand with the implicit bit) is ``(m << s) 2^(32 k - 149)`` with ``b = e - 1``, ``k = b >> 5``,
``s = b & 31``: ``m << s`` (< 2^55) goes into words ``k`` (its low 32 bits) and ``k + 1`` (the rest).
Nine signed words per bin cover every float32 exponent, stored word-major: word ``k`` of bin ``i``
at ``k n + i`` (``n`` bins), so the conversion reads each word of all bins as one contiguous run
(bin-major, ``i (WORDS + 1) + k``, it gathered with a stride of 80 bytes, 6x slower for the sum
step of a 512-beam frame) and gives the same integers, summed in the same order: the same bytes; each add puts less than 2^32 into a word,
so a word holds `MAX_ADDS` adds without overflow: a pass of 2^22 lanes of 64 bounces adds at
most 2^28 echoes to a bin. A caller that adds to the same bins in many launches (`sonar_mlt`)
calls `ExactBins.reserve` before each: it folds the words into a float64 partial sum when they
could overflow, at a point fixed by the sizes of the launches, not by the threads. A tenth
word counts non-finite values: such a bin's total is NaN, as a float sum would be. Zeros and
float32 subnormals (< 1.2e-38) add nothing: Dr.Jit's pool threads flush subnormals to zero and
the calling thread may not, so they would differ with the thread count.

Cost: one or two integer atomics per echo instead of one float64 atomic (a compare-and-swap loop
on x86); memory 80 bytes per bin instead of 8 (`benchmarks/exact_sum.py` measures the time).
"""
from __future__ import annotations

import drjit as dr
import mitsuba as mi

WORDS = 9            # significand words per bin
STRIDE = WORDS + 1   # and the count of non-finite values
#: Adds a word takes before it could overflow: each add is below 2^32 in magnitude.
MAX_ADDS = 1 << 30


class ExactBins:
    """An order-independent sum of float32 values into ``n`` bins (see the module docstring).

    ``add(values, index, active)`` where ``dr.scatter_add(hist, values, index, active)`` would be;
    ``total()`` the sums, a ``mi.Float64`` of ``n`` values; ``numpy()`` the same as a float64 array.
    """

    def __init__(self, n: int, mode=dr.ReduceMode.Direct):
        self.n = int(n)
        self.mode = mode
        self.words = dr.zeros(mi.Int64, self.n * STRIDE)
        self.partial = None   # float64 sums of the words folded so far (`reserve`)
        self.adds = 0         # adds reserved since the last fold

    def reserve(self, adds: int):
        """Make room for ``adds`` more adds into any one bin (outside symbolic loops: a fold
        evaluates the words)."""
        if self.adds + adds > MAX_ADDS:
            self._fold()
        self.adds += adds

    def add(self, values, index, active=True, mode=None):
        """Add ``values`` (float32, one per lane) into bins ``index`` where ``active``, the
        ``dr.scatter_add`` that a float histogram would do (``mode``: its ``dr.ReduceMode``)."""
        mode = self.mode if mode is None else mode
        bits = dr.reinterpret_array(mi.UInt32, mi.Float(values))
        e = (bits >> 23) & 0xFF
        finite = active & (e > 0) & (e < 255)
        b = dr.maximum(e, 1) - 1
        wide = mi.UInt64((bits & 0x7FFFFF) | 0x800000) << mi.UInt64(b & 31)
        lo, hi = mi.Int64(wide & 0xFFFFFFFF), mi.Int64(wide >> 32)
        neg = (bits >> 31) != 0
        lo, hi = dr.select(neg, -lo, lo), dr.select(neg, -hi, hi)
        index = mi.UInt32(index)
        slot = (b >> 5) * self.n + index          # word-major: word k of bin i at k n + i
        # A non-finite value counts 1 in the tenth word through the low word's add: one atomic
        # pass over the lanes instead of two (an LLVM scatter-add loops over the packet's lanes
        # even where none is active), the same integers in the same words.
        bad = e == 255
        dr.scatter_add(self.words, dr.select(bad, mi.Int64(1), lo), dr.select(bad, index + WORDS * self.n, slot),
                       active & (e > 0), mode=mode)
        dr.scatter_add(self.words, hi, slot + self.n, finite & (hi != 0), mode=mode)

    def _sum_words(self):
        at = dr.arange(mi.UInt32, self.n)
        out = dr.zeros(mi.Float64, self.n)
        for k in range(WORDS):   # a fixed order: the float64 rounding is the same every time
            out += mi.Float64(dr.gather(mi.Int64, self.words, at + k * self.n)) * float(2.0 ** (32 * k - 149))
        bad = dr.gather(mi.Int64, self.words, at + WORDS * self.n) != 0
        return dr.select(bad, dr.nan, out)

    def _fold(self):
        s = self._sum_words()
        self.partial = s if self.partial is None else self.partial + s
        self.words = dr.zeros(mi.Int64, self.n * STRIDE)
        self.adds = 0
        dr.eval(self.partial)

    def total(self):
        """The sums per bin, ``mi.Float64`` (exact but for the last float64 rounding)."""
        s = self._sum_words()
        return s if self.partial is None else self.partial + s

    def numpy(self):
        return self.total().numpy()
