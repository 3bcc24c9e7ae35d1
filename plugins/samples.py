"""Primary samples of an echo path: the layout of the vector U and path tracing's hash sampler.

A path is a deterministic function of a primary-sample vector U in [0, 1)^D:
dims 0-1 draw the emitted direction from the beam pattern, and bounce ``k`` (0-based) uses dim
``2 + 3k`` to pick a BSDF lobe and dims ``3 + 3k``, ``4 + 3k`` for the outgoing direction.
Path tracing draws U from a counter-based hash (`HashSamples`); the Metropolis integrator stores
U per chain and hands the path a sampler that computes the mutated U on the fly
(``sonar_mlt._Mutation``). Anything with ``get(dim)`` and ``get2(dim)`` is a sampler.
"""
from __future__ import annotations

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
