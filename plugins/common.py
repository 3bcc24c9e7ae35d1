"""What the sonar integrators share: the echo-path function, the per-render setup, the base class.

Following Mitsuba's own integrators (``mitsuba/python/ad/integrators/common.py``), the machinery
lives here and each integrator (``sonar_tof``, ``sonar_mlt``) is one class that decides how
paths are sampled and where their echoes go. The path itself is one method,
`SonarIntegrator.sample`: a function of the primary samples, reporting every echo to a
``record`` callback, so it can be run forward into a histogram, driven by a Metropolis sampler,
or audited path by path (``benchmarks/weights.py``).

Echo energy (thesis section 2.3, with next-event estimation towards the transducer): at bounce
``k`` of a path emitted from the transducer, the echo that returns straight to it carries

    throughput * f(x; wi, to transducer) cos(theta_o) * B_rx / r^2 * 10^(-absorption L / 10)

at range ``L / 2`` (``L`` the total path length summed from the hit points), with throughput
starting at ``B_tx / pdf`` for the emitted direction (on-axis source intensity 1 W/sr, on-axis
receive aperture 1 m^2) and multiplied by the BSDF sample weight at every bounce.
"""
from __future__ import annotations

import math

import drjit as dr
import mitsuba as mi

from mitsonar._checks import not_allowed

from .props import count
from .range_bins import RangeBins
from .samples import DIMS_EMIT, DIMS_PER_BOUNCE
from .sonar_sensor import PingFrames, SonarSensor

MAX_DEPTH = 64


def check_max_depth(value, source="sonar_tof"):
    """``value`` if it is a whole number of surface bounces in 1..64, else a ValueError naming ``source``."""
    if not (isinstance(value, int) and 1 <= value <= MAX_DEPTH):
        raise not_allowed(source, "max_depth", value, f"an integer number of surface bounces from 1 to "
                          f"{MAX_DEPTH}; 1 = single bounce")
    return value


def resolve_sensor(scene, sensor):
    """The `SonarSensor` that ``sensor`` (an index into the scene's sensors, or a sensor) names."""
    if isinstance(sensor, int):
        sensors = scene.sensors()
        if not 0 <= sensor < len(sensors):
            raise ValueError(f"the scene has {len(sensors)} sensor(s); index {sensor} does not exist")
        sensor = sensors[sensor]
    if not isinstance(sensor, SonarSensor):
        raise ValueError(f"sonar integrators need a <sensor type=\"sonar\">, got {type(sensor).__name__}")
    return sensor


class PathSetup:
    """What every path of one render shares, built once per render.

    ``scene``, ``sensor``; ``frames`` the per-ping beam frames at ``pose``; ``connect`` what weights
    the connection back to the transducer (``SonarSensor.connection``); ``depth`` the surface
    bounces (and ``depth_o``, its opaque copy); ``absorption`` (opaque, dB/m); ``bins`` the range
    window. Every value that differs between renders is opaque: a new pose, window or depth never
    recompiles a kernel.
    """

    def __init__(self, scene, sensor, depth, pose=None):
        self.scene, self.sensor, self.depth = scene, sensor, int(depth)
        self.frames = PingFrames(sensor.ping_poses(pose))
        self.connect = sensor.connection(pose)
        self.depth_o = dr.opaque(mi.UInt32, self.depth)
        self.absorption = dr.opaque(mi.Float, sensor.absorption)
        self.bins = RangeBins(sensor)


class SonarIntegrator(mi.SamplingIntegrator):
    """Base of the sonar integrators: ``mi.render`` gives the range-intensity image.

    A subclass sets ``name`` (its plugin name, for messages) and implements `render_histogram`;
    it traces paths with `sample`.
    """

    name = "sonar"

    def __init__(self, props: mi.Properties):
        super().__init__(props)
        self.max_depth = check_max_depth(count(props, "max_depth", 5, self.name), self.name)

    def render(self, scene, sensor=0, seed=0, spp=0, develop=True, evaluate=True):
        import numpy as np

        sensor = resolve_sensor(scene, sensor)
        if not spp:
            spp = sensor.sampler().sample_count()
        hist = self.render_histogram(scene, sensor, seed=seed, spp=spp)
        return mi.TensorXf(hist.astype(np.float32)[..., None])

    def render_histogram(self, scene, sensor=0, seed=0, spp=4096, pose=None, max_depth=None, progress=None):
        """Mean echo energy per bin, float64 ``(n_pings, n_bins)``; ``progress(done, total)`` after
        each pass. ``pose`` replaces the sensor's ``to_world``, ``max_depth`` the integrator's."""
        raise NotImplementedError(f"{type(self).__name__} must implement render_histogram")

    def setup(self, scene, sensor=0, pose=None, max_depth=None) -> PathSetup:
        """The `PathSetup` of one render (sensor resolved, ``max_depth`` checked)."""
        depth = check_max_depth(self.max_depth if max_depth is None else int(max_depth), self.name)
        return PathSetup(scene, resolve_sensor(scene, sensor), depth, pose)

    @dr.syntax
    def sample(self, setup: PathSetup, ping, samples, record, active=True):
        """Trace one echo path per lane and report each bounce's echo.

        ``ping`` (UInt32) is each lane's ping, ``samples`` its primary samples (anything with
        ``get(dim)``/``get2(dim)``, see `samples`), ``record(k, range, energy, valid, hit)`` is
        called once per bounce ``k`` (0-based) with the echo's range (m, half the total path length)
        and energy (the formula in the module docstring); ``valid`` marks the lanes whose echo exists
        (nonzero and not occluded on its way back) and ``hit`` is the bounce's
        ``mi.SurfaceInteraction3f`` (where the echo comes from: ``hit.p``, ``hit.shape``), for
        callbacks that label or key echoes by their surface point. A multibeam head's paths start in the row's
        receive beam and connect back through the transmit fan (``setup.connect``; reciprocity).
        """
        scene, beam = setup.scene, setup.sensor.beam
        x_ax, y_ax, z_ax, origin = setup.frames.gather(ping)
        if setup.connect is None:
            cx, cy, cz, c_beam = x_ax, y_ax, z_ax, beam
        else:
            cx, cy, cz, _ = setup.connect[0].gather(ping)
            c_beam = setup.connect[1]
        d_local, weight = beam.sample(samples.get2(0), active)
        ray = mi.Ray3f(origin, x_ax * d_local.x + y_ax * d_local.y + z_ax * d_local.z)
        throughput = mi.Float(weight)
        path_length = mi.Float(0.0)
        previous = mi.Point3f(origin)
        depth = mi.UInt32(0)
        active = mi.Bool(active) & (weight > 0)
        # Attenuation of intensity: 10^(-absorption L / 10) = 2^(-absorption L log2(10) / 10).
        atten = setup.absorption * (math.log2(10.0) / 10.0)
        max_depth = setup.depth_o
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
            record(depth, 0.5 * total, energy, echo, si)

            base = DIMS_EMIT + DIMS_PER_BOUNCE * depth
            bs, bsdf_weight = bsdf.sample(ctx, si, samples.get(base), samples.get2(base + 1), active)
            throughput *= bsdf_weight.x
            ray = si.spawn_ray(si.to_world(bs.wo))
            previous = mi.Point3f(si.p)
            depth += 1
            active &= (depth < max_depth) & (throughput > 0)
