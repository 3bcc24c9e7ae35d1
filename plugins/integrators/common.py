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

Gradients: `SonarIntegrator.sample` takes Mitsuba's AD arguments (``mode``, ``δ``, ``state_in``)
and ``render_forward``/``render_backward`` follow Mitsuba's ``RBIntegrator``, so ``mi.render(scene,
params)`` is differentiable on the AD variants; the replayed path and what its derivative means:
``plugins/integrators/paths/path_replay.py``.
"""
from __future__ import annotations

import drjit as dr
import mitsuba as mi

from mitsonar._checks import not_allowed, require
from mitsonar._limits import LIMITS
from mitsonar.plugins.props import count, text
from mitsonar.plugins.sensors.sonar import PingFrames, SonarSensor

from .paths import image_guide
from .paths.emission import DB_TO_LOG2, start
from .paths.denormals import flushed
from .paths.exact_sum import ExactBins
from .paths.range_bins import RangeBins
from .paths.samples import DIMS_EMIT, DIMS_PER_BOUNCE

MAX_DEPTH = int(LIMITS["max_depth"].hi)   # the bound of `mitsonar._limits`
# Lanes in one gradient pass: a replayed path carries ~40 floats of state, so passes of 2^20
# lanes bound the memory of a gradient render whatever its spp.
GRADIENT_LANES_PER_PASS = 1 << 20


def check_max_depth(value, source="sonar_tof"):
    """``value`` if it is a whole number of surface bounces in 1..64, else a ValueError naming ``source``."""
    if not (isinstance(value, int) and LIMITS["max_depth"].holds(value)):
        raise not_allowed(source, "max_depth", value, LIMITS["max_depth"].allowed() + "; 1 = single bounce")
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
    window; ``guide`` whether paths are image guided (`image_guide`; set by the integrator);
    ``tag_hard`` whether ``record`` is told the hard echoes (`tagging_hard`).
    Every value that differs between renders is opaque: a new pose, window or depth never
    recompiles a kernel.
    """

    def __init__(self, scene, sensor, depth, pose=None):
        self.scene, self.sensor, self.depth = scene, sensor, int(depth)
        self.frames = PingFrames(sensor.ping_poses(pose))
        self.connect = sensor.connection(pose)
        self.depth_o = dr.opaque(mi.UInt32, self.depth)
        self.absorption = dr.opaque(mi.Float, sensor.absorption)
        self.bins = RangeBins(sensor)
        self.guide = False
        self.tag_hard = False
        self.ad = None
        # The water's sound-speed profile (`refraction.Refraction`); None: straight rays.
        self.refraction = None

    def attach(self):
        """Make ``self.ad`` (`AttachedSetup`): the values the gradient passes differentiate."""
        self.ad = AttachedSetup(self)
        return self


def tagging_hard(setup):
    """A shallow copy of ``setup`` whose paths tell their hard echoes apart (``record``'s sixth
    argument, `SonarIntegrator.sample`); the setup itself is left as it is."""
    import copy

    tagged = copy.copy(setup)
    tagged.tag_hard = True
    return tagged


class AttachedSetup:
    """The parameters of a `PathSetup` that carry derivatives, with the setup's exact values.

    ``beam`` (widths attached), ``absorption``, ``frames`` and ``connect`` (the per-row beam frames
    and the multibeam transmit frames, attached to the sensor's traversed ``to_world``): each is
    ``dr.replace_grad(value used by the primal, expression of the traversed parameter)``, so the
    replayed paths are the primal's to the bit while their derivatives reach the parameters.
    """

    def __init__(self, setup):
        sensor = setup.sensor
        diff = sensor.differentiable()
        self.absorption = dr.replace_grad(setup.absorption, diff["absorption"])
        self.beam = sensor.beam.attached(diff.get("beamwidth_h"), diff.get("beamwidth_v"))
        head = sensor.head_pose()
        self.frames = _AttachedFrames(setup.frames, diff["to_world"], head, sensor.ping_poses())
        from .paths.path_replay import acoustic_bsdfs, moving_meshes

        self.bsdfs, self.other_bsdfs = acoustic_bsdfs(setup.scene)
        self.geometry = moving_meshes(setup.scene)
        self.connect = None
        if setup.connect is not None:
            frames, fan = setup.connect
            self.connect = (_AttachedFrames(frames, diff["to_world"], head, sensor.head_pose()[None]), fan)


    def seal_forward(self):
        """Forward mode: push the tangents of the traversed parameters into the attached values now
        and restart them as leaves holding those tangents, so that the derivatives taken inside
        the path loop start within its scope (Dr.Jit cannot forward-propagate across an edge made
        before a symbolic loop or call began)."""
        def leaf(v):
            if not dr.grad_enabled(v):
                return v
            t = dr.forward_to(v, flags=dr.ADFlag.ClearEdges | dr.ADFlag.AllowNoGrad)
            out = type(v)(dr.detach(v))
            dr.enable_grad(out)
            dr.set_grad(out, t)
            return out

        self.absorption = leaf(self.absorption)
        self.beam._p_bh, self.beam._p_bv = leaf(self.beam._p_bh), leaf(self.beam._p_bv)
        for frames in (self.frames, None if self.connect is None else self.connect[0]):
            if frames is not None:
                frames.x, frames.y, frames.z, frames.p = (leaf(v) for v in (frames.x, frames.y, frames.z, frames.p))


class _AttachedFrames:
    """`PingFrames` whose axes and origins carry the derivatives of the head pose ``to_world``
    (a ``mi.Transform4f``): row k's frame is ``to_world @ (head^-1 @ poses[k])``."""

    def __init__(self, frames, to_world, head, poses):
        import numpy as np

        rel = np.linalg.inv(head) @ np.broadcast_to(poses, (len(frames.x) // 3, 4, 4))
        m = to_world.matrix
        cols = []
        for c, flat in enumerate((frames.x, frames.y, frames.z, frames.p)):
            r = [mi.Float(rel[:, j, c].astype(np.float32)) for j in range(4)]
            comp = [sum(m[i][j] * r[j] for j in range(4)) for i in range(3)]
            cols.append(dr.replace_grad(flat, dr.ravel(mi.Vector3f(*comp))))
        self.x, self.y, self.z, self.p = cols

    def gather(self, ping):
        return (dr.gather(mi.Vector3f, self.x, ping), dr.gather(mi.Vector3f, self.y, ping),
                dr.gather(mi.Vector3f, self.z, ping), dr.gather(mi.Point3f, self.p, ping))


class SonarIntegrator(mi.SamplingIntegrator):
    """Base of the sonar integrators: ``mi.render`` gives the range-intensity image.

    A subclass sets ``name`` (its plugin name, for messages) and implements `render_histogram`;
    it traces paths with `sample`.
    """

    name = "sonar"
    #: The ``guide`` values this integrator takes, the first its default (`image_guide`).
    GUIDES = ("image", "none")
    #: Whether the integrator's paths refract through a ``sound_speed_profile`` (`refraction`).
    REFRACTS = False

    def __init__(self, props: mi.Properties):
        super().__init__(props)
        self.max_depth = check_max_depth(count(props, "max_depth", 5, self.name), self.name)
        self.guide = text(props, "guide", self.GUIDES[0], self.name)
        require(self.guide in self.GUIDES, self.name, "guide", self.guide, "one of " + ", ".join(self.GUIDES))
        from .paths.refraction import DEFAULT_CHORDS, check_chords, read_profile

        self.sound_speed_profile = read_profile(props, self.name, self.REFRACTS)
        self.svp_chords = check_chords(count(props, "svp_chords", DEFAULT_CHORDS, self.name), self.name)

    def render(self, scene, sensor=0, seed=0, spp=0, develop=True, evaluate=True):
        import numpy as np

        sensor = resolve_sensor(scene, sensor)
        if not spp:
            spp = sensor.sampler().sample_count()
        seed = int(seed[0]) if isinstance(seed, dr.ArrayBase) else seed
        hist = self.render_histogram(scene, sensor, seed=seed, spp=spp)
        return mi.TensorXf(hist.astype(np.float32)[..., None])

    def render_histogram(self, scene, sensor=0, seed=0, spp=4096, pose=None, max_depth=None, progress=None):
        """Mean echo energy per bin, float64 ``(n_pings, n_bins)``; ``progress(done, total)`` after
        each pass. ``pose`` replaces the sensor's ``to_world``, ``max_depth`` the integrator's."""
        raise NotImplementedError(f"{type(self).__name__} must implement render_histogram")

    def render_histogram_device(self, scene, sensor=0, seed=0, spp=4096, pose=None, max_depth=None,
                                progress=None):
        """`render_histogram`'s mean on the device, ``(mean, intensity)``: a ``mi.Float64`` of
        ``n_pings * n_bins`` values, row-major, and the same as float32 (`exact_sum.to_float32`:
        `mitsonar.sim.render.render_frame`'s intensity). This default uploads `render_histogram`'s
        NumPy array (integrators that sum their passes on the host); ``sonar_tof`` keeps its sums
        on the device."""
        import numpy as np

        from .paths.exact_sum import with_float32

        return with_float32(np.ravel(self.render_histogram(scene, sensor, seed=seed, spp=spp, pose=pose,
                                                           max_depth=max_depth, progress=progress)))

    # ------------------------------------------------------------------ gradients (path replay)
    @flushed   # the calling thread computes like the pool's threads (`denormals`)
    def render_forward(self, scene, params=None, sensor=0, seed=0, spp=0):
        """Forward-mode derivative of the scan ``mi.render`` returns, along the tangents set on the
        traversed parameters: a tensor (n_rows, n_bins, 1). The estimator and what its range
        derivative means: ``plugins/integrators/paths/path_replay.py``."""
        from .paths.path_replay import edge_bins

        setup, seed, passes = self._gradient_setup(scene, params, sensor, seed, spp)
        n_rows, n_bins = setup.sensor.n_pings, setup.sensor.n_bins
        bins = setup.bins
        self._check_forward(params, setup)
        with dr.resume_grad():
            setup.ad.seal_forward()
        # Integer words per bin (`exact_sum`): the same derivative image whatever the threads.
        grad = ExactBins(n_rows * n_bins)
        for start, count in passes:
            ping, samples = self.lanes(n_rows, seed, start, count)

            def record(k, rng, energy, valid, hit, d_energy, d_range):
                b, inside = bins.index(rng, valid)
                grad.add(d_energy, bins.flat(ping, b), inside)
                up, lo, e = edge_bins(bins, rng, valid)
                flow = energy * d_range * bins.inv_width
                grad.add(flow, bins.flat(ping, e), up)
                grad.add(-flow, bins.flat(ping, e - 1), lo)

            grad.reserve(3 * count * setup.depth)
            with dr.suspend_grad():
                self.sample(setup, ping, samples, record, mode=dr.ADMode.Forward)
            dr.eval(grad.words)
        out = mi.Float(grad.total() * (1.0 / self._spp))
        dr.eval(out)   # inside `flushed`
        return mi.TensorXf(out, shape=(n_rows, n_bins, 1))

    @flushed
    def render_backward(self, scene, params, grad_in, sensor=0, seed=0, spp=0):
        """Reverse-mode derivative: back-propagates ``grad_in`` (n_rows, n_bins, 1) into the traversed
        parameters with gradients enabled, by path replay (memory independent of ``spp``)."""
        from .paths.path_replay import Adjoint

        setup, seed, passes = self._gradient_setup(scene, params, sensor, seed, spp)
        n_rows, n_bins = setup.sensor.n_pings, setup.sensor.n_bins
        g = dr.detach(mi.TensorXf(grad_in)).array
        if dr.width(g) != n_rows * n_bins:
            raise ValueError(f"{self.name}: the gradient image has {dr.width(g)} values, the scan "
                             f"{n_rows} x {n_bins}")
        adjoint = Adjoint(setup.bins, mi.Float(g) * (1.0 / self._spp))
        for start, count in passes:
            ping, samples = self.lanes(n_rows, seed, start, count)
            with dr.suspend_grad():
                s = self.sample(setup, ping, samples, mode=dr.ADMode.Primal, δ=adjoint)
                self.sample(setup, ping, samples, mode=dr.ADMode.Backward, δ=adjoint, state_in=s)
            dr.eval()
            del s  # this pass's per-path state goes before the next pass makes its own

    def _check_forward(self, params, setup):
        """Forward mode reaches an acoustic BSDF's parameters only where the BSDF is a shape's own
        (`path_replay._eval_attached`): refuse tangents on one nested in another BSDF (``twosided``)."""
        if params is None or not hasattr(params, "properties"):
            return
        direct = {id(b) for b, _ in setup.ad.bsdfs}
        for k in params.keys():
            node = params.properties[k][2]
            if type(node).__name__ == "AcousticBSDF" and id(node) not in direct and dr.grad_enabled(params[k]):
                raise ValueError(f"{self.name}: forward-mode derivatives of {k!r} need its acoustic BSDF attached "
                                 f"directly to the shapes (not inside a twosided BSDF); use reverse mode (dr.backward)")

    def _gradient_setup(self, scene, params, sensor, seed, spp):
        """(attached `PathSetup`, seed as an int, passes [(start, count)]) of a gradient render;
        refuses a variant without automatic differentiation in one line."""
        variant = mi.variant()
        if not dr.is_diff_v(mi.Float):
            raise ValueError(f"{self.name}: gradients need a Mitsuba variant with automatic "
                             f"differentiation (llvm_ad_mono, llvm_ad_rgb, cuda_ad_mono, ...); the active "
                             f"variant is {variant}")
        if not hasattr(self, "lanes"):
            raise ValueError(f"{self.name}: gradients are rendered by the sonar_tof integrator only")
        from .paths.path_replay import check_attached

        check_attached(params, self.name)
        sensor = resolve_sensor(scene, sensor)
        spp = int(spp) or sensor.sampler().sample_count()
        if spp < 1:
            raise ValueError(f"spp must be a positive number of paths per row, got {spp}")
        self._spp = spp
        seed = int(seed[0]) if isinstance(seed, dr.ArrayBase) else int(seed)
        setup = self.setup(scene, sensor)
        if setup.refraction is not None:
            raise ValueError(f"{self.name}: gradients of a render through a sound_speed_profile are not "
                             "implemented (refracted paths are primal only)")
        # The replayed path (`path_replay`) is the unguided one: a gradient render samples its own
        # paths, so it estimates the same derivative without the guide.
        setup.guide = False
        with dr.resume_grad():
            setup.attach()
        # Passes of (nearly) equal size, each at most GRADIENT_LANES_PER_PASS lanes: what a pass
        # allocates is reused by the next, so memory stays that of one pass whatever the spp.
        n = -(-spp // max(1, GRADIENT_LANES_PER_PASS // sensor.n_pings))
        sizes = [spp // n + (1 if i < spp % n else 0) for i in range(n)]
        passes = [(sum(sizes[:i]), sizes[i]) for i in range(n)]
        return setup, seed, passes

    def setup(self, scene, sensor=0, pose=None, max_depth=None) -> PathSetup:
        """The `PathSetup` of one render (sensor resolved, ``max_depth`` checked)."""
        depth = check_max_depth(self.max_depth if max_depth is None else int(max_depth), self.name)
        setup = PathSetup(scene, resolve_sensor(scene, sensor), depth, pose)
        setup.guide = self.guide == "image" and image_guide.scene_guide(scene)
        profile = getattr(self, "sound_speed_profile", None)
        if profile is not None:
            from .paths.refraction import from_profile

            if not self.REFRACTS:
                raise ValueError(f"{self.name}: a sound_speed_profile (refracted paths) is traced by the "
                                 "sonar_tof integrator only")
            setup.refraction = from_profile(profile, setup.sensor, getattr(self, "svp_chords", None))
        return setup

    def sample(self, setup: PathSetup, ping, samples, record=None, active=True, mode=None, δ=None,
               state_in=None):
        """Trace one echo path per lane and report each bounce's echo.

        Mitsuba's AD signature (``mitsuba/python/ad/integrators/common.py``): ``mode`` None (or
        ``dr.ADMode.Primal`` without ``δ``) is the primal path below, unchanged; with a ``mode`` and
        ``setup.attach()`` done, the path is replayed for its derivatives by
        `path_replay.replay` (``δ`` the adjoint image, `path_replay.Adjoint`; ``state_in`` the
        primal replay's output in ``dr.ADMode.Backward``; ``record`` gets the echoes' derivatives
        in ``dr.ADMode.Forward``).
        """
        if getattr(setup, "refraction", None) is not None:
            if not (mode is None or (mode == dr.ADMode.Primal and δ is None)):
                raise ValueError("sonar_tof: gradients of a render through a sound_speed_profile are not "
                                 "implemented (refracted paths are primal only)")
            from .paths.refraction import sample_path

            return sample_path(setup, ping, samples, record, active)
        if mode is None or (mode == dr.ADMode.Primal and δ is None):
            return SonarIntegrator._sample_primal(self, setup, ping, samples, record, active)
        if mode == dr.ADMode.Primal:
            # The reverse pass's primal replay is the primal path itself: per lane, the sum
            # S = sum_k a_k E_k and the bounces whose echo reached the transducer (bit k), so that
            # the adjoint replay needs no visibility rays.
            n = dr.width(ping)
            total, seen = dr.zeros(mi.Float, n), dr.zeros(mi.UInt32, n)
            lane = dr.arange(mi.UInt32, n)

            def weigh(k, rng, energy, valid, hit):
                dr.scatter_add(total, δ.own_bin(ping, rng, valid) * energy, lane, valid)
                dr.scatter_add(seen, mi.UInt32(1) << k, lane, valid & (k < 32))

            SonarIntegrator._sample_primal(self, setup, ping, samples, weigh, active)
            return total, seen
        from .paths.path_replay import replay

        return replay(setup, mode, ping, samples, δ, state_in, record, active)

    @dr.syntax
    def _sample_primal(self, setup: PathSetup, ping, samples, record, active=True):
        """The primal echo path: trace one path per lane and report each bounce's echo.

        ``ping`` (UInt32) is each lane's ping, ``samples`` its primary samples (anything with
        ``get(dim)``/``get2(dim)``, see `samples`), ``record(k, range, energy, valid, hit)`` is
        called once per bounce ``k`` (0-based) with the echo's range (m, half the total path length)
        and energy (the formula in the module docstring); ``valid`` marks the lanes whose echo exists
        (nonzero and not occluded on its way back) and ``hit`` is the bounce's
        ``mi.SurfaceInteraction3f`` (where the echo comes from: ``hit.p``, ``hit.shape``), for
        callbacks that label or key echoes by their surface point. A multibeam head's paths start in the row's
        receive beam and connect back through the transmit fan (``setup.connect``; reciprocity).
        """
        scene = setup.scene
        (x_ax, y_ax, z_ax, origin, d_local, weight, ray), (cx, cy, cz, c_beam) = start(setup, ping, samples, active)
        throughput = mi.Float(weight)
        path_length = mi.Float(0.0)
        previous = mi.Point3f(origin)
        depth = mi.UInt32(0)
        active = mi.Bool(active) & (weight > 0)
        atten = setup.absorption * DB_TO_LOG2     # 10^(-a L / 10) = 2^(-a L DB_TO_LOG2)
        max_depth = setup.depth_o
        ctx = mi.BSDFContext(mi.TransportMode.Importance)
        # Image guiding (`image_guide`): the transducer's image through the chain of mirror-like
        # vertices since the last diffuse one, the chain's narrowest lobe, and the way back's target.
        guide = setup.guide
        chain = image_guide.start_chain(origin)
        flags = image_guide.ray_flags(guide)
        # With ``setup.tag_hard`` the echoes after a chained vertex are told apart (``record``'s
        # sixth argument): the paths that only the guide finds well (`sonar_mlt`'s split). An
        # unguided kernel (a scene without mirrors) forms no chain: none of its echoes is hard.
        tag = getattr(setup, "tag_hard", False)
        hard = mi.Bool(False)

        while dr.hint(active, label="sonar_echo_path"):
            si = scene.ray_intersect(ray, flags, False, active)
            active &= si.is_valid()
            segment = dr.norm(si.p - previous)
            path_length += segment

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
            if dr.hint(tag, mode="scalar"):
                record(depth, 0.5 * total, energy, echo, si, hard)
            else:
                record(depth, 0.5 * total, energy, echo, si)

            ray, bounce_weight, chain, was_chained = image_guide.scatter(
                bsdf, ctx, si, samples, DIMS_EMIT + DIMS_PER_BOUNCE * depth, guide, chain, origin, segment, active)
            throughput *= bounce_weight
            if was_chained is not None:
                hard |= was_chained
            previous = mi.Point3f(si.p)
            depth += 1
            active &= (depth < max_depth) & (throughput > 0)
