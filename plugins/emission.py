"""The start of every echo path and the absorption law, shared by the path functions (the primal
`common.SonarIntegrator.sample`, the gradients' `path_replay.replay`, `bdpt_paths`)."""
from __future__ import annotations

import math

import mitsuba as mi

#: Attenuation of intensity over a path of ``L`` metres at ``a`` dB/m:
#: ``10^(-a L / 10) = 2^(-a L DB_TO_LOG2)`` (``dr.exp2`` is the cheap exponential).
DB_TO_LOG2 = math.log2(10.0) / 10.0


def emit(setup, ping, samples, active):
    """Each lane's ping frame and first ray, drawn from the emitting beam ``setup.sensor.beam``.

    Returns ``(x_ax, y_ax, z_ax, origin, d_local, weight, ray)``: the ping's beam-frame axes and
    origin (world), the emitted direction in the beam frame, its weight ``B / pdf`` and the ray.
    """
    x_ax, y_ax, z_ax, origin = setup.frames.gather(ping)
    d_local, weight = setup.sensor.beam.sample(samples.get2(0), active)
    ray = mi.Ray3f(origin, x_ax * d_local.x + y_ax * d_local.y + z_ax * d_local.z)
    return x_ax, y_ax, z_ax, origin, d_local, weight, ray
