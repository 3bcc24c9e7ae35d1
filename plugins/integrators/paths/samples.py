"""Primary samples of an echo path: the layout of the vector U and path tracing's hash sampler.

A path is a deterministic function of a primary-sample vector U in [0, 1)^D:
dims 0-1 draw the emitted direction from the beam pattern, and bounce ``k`` (0-based) uses dim
``2 + 3k`` to pick a BSDF lobe and dims ``3 + 3k``, ``4 + 3k`` for the outgoing direction.
Path tracing draws U from a counter-based hash (`HashSamples`), with the emitted direction from an
Owen-scrambled Sobol sequence per row by default (`SobolSamples`); the Metropolis integrator stores
U per chain and hands the path a sampler that computes the mutated U on the fly
(``sonar_mlt._Mutation``). Anything with ``get(dim)`` and ``get2(dim)`` is a sampler.
"""
from __future__ import annotations

import drjit as dr
import mitsuba as mi

DIMS_EMIT = 2
DIMS_PER_BOUNCE = 3


def n_dims(max_depth: int) -> int:
    """Length of the primary-sample vector of a path with ``max_depth`` bounces."""
    return DIMS_EMIT + DIMS_PER_BOUNCE * int(max_depth)


class HashSamples:
    """Primary samples for path tracing: ``U[dim] = TEA(seed, ping, sample, dim)``.

    Stateless, so a path's samples do not depend on how a render is split into passes.
    """

    def __init__(self, seed: mi.UInt32, ping: mi.UInt32, sample: mi.UInt32):
        a, _ = mi.sample_tea_32(ping, seed, 4)
        self.k0, self.k1 = mi.sample_tea_32(sample, a, 4)

    def get(self, dim):
        # Eight rounds: TEA over consecutive counters needs them (four measurably biased a mean).
        return mi.sample_tea_float32(self.k0 + mi.UInt32(dim), self.k1, 8)

    def get2(self, dim):
        return mi.Point2f(self.get(dim), self.get(mi.UInt32(dim) + 1))


def _reverse_bits(x):
    """The 32 bits of ``x`` (UInt32) in reverse order."""
    x = ((x >> 1) & 0x55555555) | ((x & 0x55555555) << 1)
    x = ((x >> 2) & 0x33333333) | ((x & 0x33333333) << 2)
    x = ((x >> 4) & 0x0F0F0F0F) | ((x & 0x0F0F0F0F) << 4)
    x = ((x >> 8) & 0x00FF00FF) | ((x & 0x00FF00FF) << 8)
    return (x >> 16) | (x << 16)


def _scrambled(r, seed):
    """Nested uniform (Owen) scrambling of the bits of ``x`` given in bit-reversed order,
    ``r = reverse(x)``, by the Laine-Karras hash in the bit-reversed domain (Burley 2020,
    "Practical hash-based Owen scrambling", JCGT 9(4)): every bit is flipped by a hash of the bits
    above it, so a scrambled (0, m, 2)-net stays one and every point is uniform on [0, 1).
    Returns the scrambled ``x`` (its bits in their order)."""
    r = r ^ (r * 0x3D20ADEA)    # not in place: ``r`` may be the caller's array (an index)
    r = r + seed
    r = r * ((seed >> 16) | 1)
    r = r ^ (r * 0x05526C56)
    r = r ^ (r * 0x53A22864)
    return _reverse_bits(r)


#: Bit positions whose bit ``b`` is clear (b = 0..4): the masks of `_sobol_dim2_reversed`.
_CLEAR = (0x55555555, 0x33333333, 0x0F0F0F0F, 0x00FF00FF, 0x0000FFFF)


def _sobol_dim2_reversed(i):
    """The second dimension of the Sobol sequence at index ``i`` (UInt32), bit-reversed, in 15
    operations instead of 32 conditional XORs of direction numbers.

    The direction numbers are ``v_0 = 2^31``, ``v_{k+1} = v_k ^ (v_k >> 1)``; reversed, ``v_k``
    is the polynomial ``(1 + x)^k`` over GF(2), whose bit ``m`` is ``C(k, m) mod 2``, that is 1
    exactly when the bits of ``m`` are among those of ``k`` (Lucas's theorem). So bit ``m`` of the
    reversed point ``XOR_{k in i} v_k`` is the XOR of the bits ``k`` of ``i`` with ``k``
    containing ``m``: the superset-sum transform of ``i``'s bits over the 5-bit lattice of
    positions, five steps of ``y ^= (y >> 2^b) & (positions without bit b)``. Both maps are linear
    over GF(2), and they agree on the 32 one-bit indices (tests/test_samples.py): the same bits
    for every index."""
    y = mi.UInt32(i)
    for b, clear in enumerate(_CLEAR):
        y = y ^ ((y >> (1 << b)) & clear)
    return y


def _unit(x):
    """A float in [0, 1) from the top 24 bits of ``x``."""
    return mi.Float(x >> 8) * (1.0 / 16777216.0)


class SobolSamples(HashSamples):
    """Primary samples for path tracing with a stratified emission: dims 0-1 (the emitted
    direction) are point ``sample`` of a two-dimensional Sobol sequence, a (0, 2)-sequence, Owen
    scrambled with seeds hashed from (seed, ping), so the paths of a row cover the beam evenly at
    any spp; the other dims are `HashSamples`'. Each point is uniform on [0, 1)^2, so the estimate
    stays unbiased; rows are scrambled independently; the samples depend on (seed, ping, sample)
    only, so they do not depend on how a render is split into passes.
    """

    def __init__(self, seed: mi.UInt32, ping: mi.UInt32, sample: mi.UInt32):
        super().__init__(seed, ping, sample)
        self.index = mi.UInt32(sample)
        self.scramble = mi.sample_tea_32(ping, seed ^ 0x50B01, 4)

    def get2(self, dim):
        if isinstance(dim, int) and dim == 0:
            # both points handed to the scramble bit-reversed, as it hashes them (the first
            # dimension, the van der Corput sequence, is the index reversed): two reversals fewer
            x = _scrambled(self.index, self.scramble[0])
            y = _scrambled(_sobol_dim2_reversed(self.index), self.scramble[1])
            return mi.Point2f(_unit(x), _unit(y))
        return super().get2(dim)


def opaque_u32(v):
    """An opaque UInt32 of ``v`` (an int, taken mod 2^32), or ``v`` if it is a JIT value already."""
    return v if isinstance(v, dr.ArrayBase) else dr.opaque(mi.UInt32, int(v) & 0xFFFFFFFF)


def row_lanes(sampler, n_rows, seed, start, count):
    """The lanes of one pass: samples ``start .. start + count`` of every row, row-major, as
    ``(ping, samples)`` (each lane's row, and its primary samples from ``sampler``, e.g.
    `SobolSamples`). Everything that varies between renders is opaque, so the kernel compiles
    once (``seed`` and ``start``: ints, or opaque UInt32 values)."""
    count_o = dr.opaque(mi.UInt32, count)
    lane = dr.arange(mi.UInt32, n_rows * count)
    ping = lane // count_o
    return ping, sampler(opaque_u32(seed), ping, lane - ping * count_o + opaque_u32(start))
