"""The one echo-path function both sonar integrators share.

A path is a deterministic function of a primary-sample vector U in [0, 1)^D:
dims 0-1 draw the emitted direction from the beam pattern, and bounce ``k`` (0-based) uses dim
``2 + 3k`` to pick a BSDF lobe and dims ``3 + 3k``, ``4 + 3k`` for the outgoing direction.
Path tracing draws U from a counter-based hash (`HashSamples`); the Metropolis integrator
stores U per chain and hands the path a sampler that computes the mutated U on the fly
(`sonar_mlt._Mutation`). At every bounce the path connects back to
the transducer (visibility tested) and reports that echo to a callback with its range (half
the total path length, summed from hit points) and its energy:

    throughput * f(x; wi, to transducer) cos(theta_o) * B_rx / r^2 * 10^(-absorption L / 10)

with throughput starting at B_tx / pdf for the emitted direction (on-axis source intensity
1 W/sr, on-axis receive aperture 1 m^2).
"""
from __future__ import annotations

import math

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


@dr.syntax
def trace_echoes(scene, frames, beam, ping, samples, max_depth, absorption, record, active=True, connect=None):
    """Trace one echo path per lane and call ``record(depth, range, energy, valid)`` per bounce.

    ``frames`` are the per-ping beam frames, ``beam`` the `BeamPattern`, ``ping`` the ping of
    each lane, ``samples`` anything with ``get(dim)`` and ``get2(dim)`` (e.g. `HashSamples`),
    ``max_depth`` (opaque UInt32) the number of surface bounces, ``absorption`` (opaque Float) in dB/m. ``connect``: ``(frames,
    pattern)`` that weight the connection back to the transducer (a multibeam head's transmit
    fan, see ``SonarSensor.connection``); None: ``beam`` in the ping's frame (monostatic).
    """
    x_ax, y_ax, z_ax, origin = frames.gather(ping)
    if connect is None:
        cx, cy, cz, c_beam = x_ax, y_ax, z_ax, beam
    else:
        cx, cy, cz, _ = connect[0].gather(ping)
        c_beam = connect[1]
    d_local, weight = beam.sample(samples.get2(0), active)
    ray = mi.Ray3f(origin, x_ax * d_local.x + y_ax * d_local.y + z_ax * d_local.z)
    throughput = mi.Float(weight)
    path_length = mi.Float(0.0)
    previous = mi.Point3f(origin)
    depth = mi.UInt32(0)
    active = mi.Bool(active) & (weight > 0)
    # Attenuation of intensity: 10^(-absorption L / 10) = 2^(-absorption L log2(10) / 10).
    atten = absorption * (math.log2(10.0) / 10.0)
    ctx = mi.BSDFContext(mi.TransportMode.Importance)

    while dr.hint(active, label="sonar_echo_path"):
        si = scene.ray_intersect(ray, active)
        active &= si.is_valid()
        path_length += dr.norm(si.p - previous)

        # Next-event connection back to the transducer.
        to_tx = origin - si.p
        dist = dr.norm(to_tx)
        back = to_tx / dist
        bsdf = si.bsdf(ray)
        f = bsdf.eval(ctx, si, si.to_local(back), active).x
        rx = -back
        gain = c_beam.eval_dir(mi.Vector3f(dr.dot(rx, cx), dr.dot(rx, cy), dr.dot(rx, cz)))
        total = path_length + dist
        energy = throughput * f * gain / dr.square(dist) * dr.exp2(-atten * total)
        echo = active & (energy > 0)
        echo &= ~scene.ray_test(si.spawn_ray_to(origin), echo)
        record(depth, 0.5 * total, energy, echo)

        base = DIMS_EMIT + DIMS_PER_BOUNCE * depth
        bs, bsdf_weight = bsdf.sample(ctx, si, samples.get(base), samples.get2(base + 1), active)
        throughput *= bsdf_weight.x
        ray = si.spawn_ray(si.to_world(bs.wo))
        previous = mi.Point3f(si.p)
        depth += 1
        active &= (depth < max_depth) & (throughput > 0)
