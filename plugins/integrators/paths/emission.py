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


def start(setup, ping, samples, active):
    """A path's start: `emit`'s ``(x, y, z, origin, d_local, weight, ray)`` and the frame and beam
    of the way back (``cx, cy, cz, c_beam``): the row's own beam, or a multibeam head's transmit fan
    (``setup.connect``, reciprocity). The straight and the refracted path functions both begin here."""
    x_ax, y_ax, z_ax, origin, d_local, weight, ray = emit(setup, ping, samples, active)
    if setup.connect is None:
        cx, cy, cz, c_beam = x_ax, y_ax, z_ax, setup.sensor.beam
    else:
        cx, cy, cz, _ = setup.connect[0].gather(ping)
        c_beam = setup.connect[1]
    return (x_ax, y_ax, z_ax, origin, d_local, weight, ray), (cx, cy, cz, c_beam)
