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

Fewer words (``window=(lo, hi)``): a render's echoes reach only some of the nine words (the
shipped scenes: words 0-4 or 0-3; words 5-8 hold energies above 2^11), so a pass can keep words
``lo..hi`` alone, ``8 (hi - lo + 1)`` bytes per bin (40 with words 0-4, `DEFAULT`, instead of
80), and count in one more word the adds that would put a nonzero integer into a word outside
them, or are not finite.

Why that cannot lose a bit: each add puts the same integers into the same words as with nine
words, and integer addition is exact and associative, so when the count is 0 every nonzero
integer of the pass went into a kept word: the kept words hold the nine-word integers exactly and
the words left out would be 0. The conversion adds the same products in the same order k = lo..hi,
leaving out only the zero words' ``+0.0`` terms, which change nothing: the running sum starts at
``+0.0`` and is never ``-0.0`` (the product of a nonzero integer and a power of two is not zero,
and round-to-nearest gives ``+0.0`` for ``x + (-x)``), and ``x + 0.0 == x`` for every other
``x``. No word can overflow sooner than with nine: it receives the same integers (`MAX_ADDS`);
the count receives at most 1 per add. When the count is not 0 the kept words are incomplete, and
`pass_sums` renders the pass again with all nine words: the same integers, so the same bits as if
no window had been tried. The window's bounds are opaque in the pass (a kernel reads them), so a
pass with any window runs the same kernel: a new window records its frozen pass anew but compiles
no pass; the conversion reads the window's words alone and compiles once per window.
"""
from __future__ import annotations

import threading

import drjit as dr
import mitsuba as mi

WORDS = 9            # significand words per bin
STRIDE = WORDS + 1   # and the count of non-finite values
#: Adds a word takes before it could overflow: each add is below 2^32 in magnitude.
MAX_ADDS = 1 << 30
#: The window of a pass that learns which words its echoes reach: all nine.
ALL = (0, WORDS - 1)
#: The window an owner's passes sum in until one misses (`pass_sums`): 40 bytes per bin.
DEFAULT = (0, 4)
_LEARNING = -2


class ExactBins:
    """An order-independent sum of float32 values into ``n`` bins (see the module docstring).

    ``add(values, index, active)`` where ``dr.scatter_add(hist, values, index, active)`` would be;
    ``total()`` the sums, a ``mi.Float64`` of ``n`` values; ``numpy()`` the same as a float64 array.
    ``window=(lo, hi)`` keeps words ``lo..hi`` alone and counts the adds outside (`missed`).
    """

    def __init__(self, n: int, mode=dr.ReduceMode.Direct, window=None, words=None):
        self.n = int(n)
        self.mode = mode
        self.window = None
        if window is None:
            self.words = dr.zeros(mi.Int64, self.n * STRIDE) if words is None else words
        else:
            lo, hi = (int(w) for w in window)
            if not 0 <= lo <= hi < WORDS:
                raise ValueError(f"ExactBins window: {window!r}; allowed: (lo, hi) with 0 <= lo <= hi <= {WORDS - 1}")
            self.window = (lo, hi)
            count = hi - lo + 1
            # words lo..hi, word-major, then the count of the adds outside them; the bounds and
            # the count's place opaque: the same kernels whatever the window
            self.words = dr.zeros(mi.Int64, self.n * count + 1) if words is None else words
            self._lo, self._span = dr.opaque(mi.Int32, lo), dr.opaque(mi.UInt32, hi - lo)
            self._miss = dr.opaque(mi.UInt32, self.n * count)
        self.partial = None   # float64 sums of the words folded so far (`reserve`)
        self.adds = 0         # adds reserved since the last fold

    @classmethod
    def holding(cls, words, window=None):
        """The sums of ``words``, another `ExactBins`'s (summed in ``window``, None for nine
        words): `total` converts them (a pass's words come out of its frozen kernel, and their
        conversion joins the kernel of what follows: `pass_sums`)."""
        width = dr.width(words)
        n = width // STRIDE if window is None else (width - 1) // (int(window[1]) - int(window[0]) + 1)
        return cls(n, window=window, words=words)

    def reserve(self, adds: int):
        """Make room for ``adds`` more adds into any one bin (outside symbolic loops: a fold
        evaluates the words)."""
        if self.window is not None:
            raise ValueError("ExactBins.reserve: a sum in a window of words is one pass; use window=None")
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
        if self.window is not None:
            self._add_window(lo, hi, e, b >> 5, index, active, mode)
            return
        slot = (b >> 5) * self.n + index          # word-major: word k of bin i at k n + i
        # A non-finite value counts 1 in the tenth word through the low word's add: one atomic
        # pass over the lanes instead of two (an LLVM scatter-add loops over the packet's lanes
        # even where none is active), the same integers in the same words.
        bad = e == 255
        dr.scatter_add(self.words, dr.select(bad, mi.Int64(1), lo), dr.select(bad, index + WORDS * self.n, slot),
                       active & (e > 0), mode=mode)
        dr.scatter_add(self.words, hi, slot + self.n, finite & (hi != 0), mode=mode)

    def _add_window(self, lo, hi, e, k, index, active, mode):
        """`add` into words ``lo..hi`` of the window: the integers `add` puts into nine words, into
        the same words; an add with a nonzero integer for a word outside, or not finite, adds 1 to
        the count instead (through the low word's scatter, as the non-finite count above)."""
        # the word of the low integer relative to the window, unsigned: below the window wraps
        # past its span, so one comparison tells outside (and rel + 1 wraps back to 0 at k = lo - 1)
        rel = mi.UInt32(mi.Int32(k) - self._lo)
        outside = ((lo != 0) & (rel > self._span)) | ((hi != 0) & (rel + 1 > self._span))
        miss = (e == 255) | outside
        active = active & (e > 0)
        slot = rel * self.n + index
        dr.scatter_add(self.words, dr.select(miss, mi.Int64(1), lo), dr.select(miss, self._miss, slot),
                       active & (miss | (lo != 0)), mode=mode)
        dr.scatter_add(self.words, hi, slot + self.n, active & ~miss & (hi != 0), mode=mode)

    def missed(self) -> int:
        """The adds that fell outside the window (0: `total` holds the nine-word sums exactly);
        read from the host, without a kernel."""
        return _missed(self.words)

    def reached(self):
        """The largest magnitude in each of the window's words, a ``mi.Int64`` of ``hi - lo + 1``
        values (0: no add put anything there). One more pass over the words: for learning."""
        count = self.window[1] - self.window[0] + 1
        return dr.block_reduce(dr.ReduceOp.Max, dr.abs(dr.gather(mi.Int64, self.words,
                                                                 dr.arange(mi.UInt32, count * self.n))), self.n)

    def _sum_words(self):
        """The float64 sums of the words: ``word_k 2^(32 k - 149)`` added in a fixed order, k = lo
        upwards (the float64 rounding is the same every time). In a window, its words alone: the
        words left out would add +0.0 (module docstring); the bounds are Python numbers here, not
        opaque as in the pass, so the conversion compiles once per window (at most five in an
        owner's life, `pass_sums`) and reads hi - lo + 1 words instead of nine masked ones (the
        512-beam quay frame's conversion, 256 000 bins: 1.17 ms -> 0.80 ms). Nine words: a bin
        whose count of non-finite values is not 0 is NaN."""
        lo, hi = (0, WORDS - 1) if self.window is None else self.window
        at = dr.arange(mi.UInt32, self.n)
        out = dr.zeros(mi.Float64, self.n)
        for k in range(lo, hi + 1):
            w = dr.gather(mi.Int64, self.words, at + (k - lo) * self.n)
            out += mi.Float64(w) * float(2.0 ** (32 * k - 149))   # exact in float64
        if self.window is not None:
            return out
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

    def bytes_per_bin(self) -> float:
        """The memory of the sums per bin (80 with all nine words and the non-finite count)."""
        return 8.0 * dr.width(self.words) / self.n


def window_of(owner):
    """The window of words the next pass of ``owner`` (an integrator) sums in: `DEFAULT` at
    first, `ALL` while it learns (`pass_sums`), ``None`` (nine words and the non-finite count, no
    window) once its windows ended. Kept as two integers on the owner (``_exact_lo``,
    ``_exact_hi``; -2 while it learns, -1 when ended), so that a frozen pass's key
    (`frozen_pass.Context`: the owner's Python scalars) has it."""
    lo, hi = getattr(owner, "_exact_lo", None), getattr(owner, "_exact_hi", None)
    if lo is None:
        return DEFAULT
    if lo == _LEARNING:
        return ALL
    return None if lo < 0 else (lo, hi)


def _missed(words) -> int:
    """The count of a windowed sum's words (its last word), read without a kernel."""
    return int(words[dr.width(words) - 1])


def pass_result(owner, hist):
    """What a pass body returns to `pass_sums`: (the words (their count is read after the pass:
    `ExactBins.missed`; their sums converted after it too, `ExactBins.holding`),
    `ExactBins.reached` while the owner learns, else zeros)."""
    learning = getattr(owner, "_exact_lo", None) == _LEARNING
    reached = hist.reached() if learning and hist.window is not None else dr.zeros(mi.Int64, WORDS)
    return hist.words, reached


def run_pass(owner, call):
    """`pass_sums` as NumPy float64 (for callers that sum their passes on the host)."""
    return pass_sums(owner, call).numpy()


def pass_sums(owner, call):
    """Run one histogram pass ``call(learning)`` -> `pass_result`, whose body sums in
    ``ExactBins(..., window=window_of(owner))``; return its sums, a ``mi.Float64`` left on the
    device and not yet evaluated (the conversion of the words joins the kernel of what follows:
    the mean over the passes, the frame's float32 intensity): the nine-word sums' bits whatever
    the window. The host reads one word of the pass (the count of adds outside the window),
    nothing else. ``learning``: the pass learns the owner's window, in `ALL`, after a pass that
    missed (the caller traces it rather than record a frozen pass that will not be replayed).

    An owner sums in `DEFAULT` until a pass's count is not 0; that pass runs again in all nine
    words, which gives its sums and the words its echoes reached (`ExactBins.reached`), and the
    owner keeps words 0 up to the highest reached, and at least its window before: a window only
    grows, so an owner runs at most five passes again in its life (four widenings and one end). A window that could not
    grow (integers of both signs that cancelled to a zero word) and a non-finite echo (its bin is
    NaN: the pass runs a third time without a window, with the non-finite count per bin) end the
    windows for this owner: all nine words from then on, as before windows.

    Why `DEFAULT` is words 0-4: the shipped scenes rendered twice (`benchmarks/scene_hashes.py`,
    each render after one of another seed) and the live head turning reach words 0-4 or 0-3 in
    every render, down to word 0 or 1 (echoes below 1e-19 of the beam's far side lobes) and up to
    word 4 (words 5-8 take echoes above 2^11 = 2048). A window learned from an owner's first pass
    instead (its lowest to highest word) ran 2 of 28 second passes and one of three live pings
    twice, and a first pass in nine words costs a frozen recording of its own (one render of an
    integrator made per call, as ``render_scan(..., integrator={...})`` does, would never replay)."""
    # One pass of an owner at a time: the window is the owner's state, read here and by the
    # pass's body (and its frozen recording's key) and widened here; a pass of another thread
    # in between could read one window and sum in another, and convert its words wrongly.
    with owner.__dict__.setdefault("_exact_lock", threading.Lock()):
        return _pass_sums(owner, call)


def _pass_sums(owner, call):
    window = window_of(owner)
    words, reached = call(False)
    if window is None or _missed(words) == 0:
        return ExactBins.holding(words, window).total()
    owner._exact_lo = owner._exact_hi = _LEARNING      # words outside the window: all nine, and learn
    words, reached = call(True)
    dr.eval(words, reached)
    if _missed(words) != 0:                # nothing but a non-finite value misses nine words
        owner._exact_lo = owner._exact_hi = -1
        return ExactBins.holding(call(False)[0]).total()
    used = [k for k, m in enumerate(reached.numpy()) if m != 0]
    lo, hi = 0, max(used + [window[1]])
    owner._exact_lo, owner._exact_hi = (lo, hi) if (lo, hi) != window else (-1, -1)
    return ExactBins.holding(words, ALL).total()


#: The least normal float32, 2^-126: below it `to_float32` rounds by hand.
_TINY = 2.0 ** -126


def to_float32(x):
    """``x`` (``mi.Float64``) as ``mi.Float32``, rounded as NumPy's ``astype(np.float32)`` rounds
    (to nearest, ties to even), float32 subnormals included. Dr.Jit's pool threads run with FTZ
    set (`denormals`), so a plain conversion turns a mean below 2^-126 into 0 (an echo of word 0,
    under 2^-117, over a few thousand paths is one); such values are rounded here on their
    integer multiple of 2^-149 instead, exact in float64, and their bits assembled."""
    x = mi.Float64(x)
    sign = mi.UInt32(dr.reinterpret_array(mi.UInt64, x) >> 32) & 0x80000000
    ulps = mi.UInt32(dr.round(dr.abs(x) * 2.0 ** 149))   # < 2^23 + 1: the subnormal's bits
    small = dr.reinterpret_array(mi.Float32, sign | ulps)
    return dr.select(dr.abs(x) < _TINY, small, mi.Float32(x))


def with_float32(mean):
    """``(mean, to_float32(mean))`` of a ``mi.Float64`` mean, evaluated together."""
    mean = mi.Float64(mean)
    out = to_float32(mean)
    dr.eval(mean, out)
    return mean, out
