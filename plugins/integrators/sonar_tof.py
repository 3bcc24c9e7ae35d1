"""The ``sonar_tof`` integrator: particle tracing from the transducer into range bins."""
from __future__ import annotations

import drjit as dr
import mitsuba as mi
import numpy as np

from mitsonar._checks import require
from mitsonar.plugins.props import text
from mitsonar.plugins.registry import register_plugin

from .paths import exact_sum, frozen_pass, row_allocation
from .common import SonarIntegrator, resolve_sensor
from .paths.denormals import flushing
from .paths.exact_sum import ExactBins
from .paths.samples import HashSamples, SobolSamples, opaque_u32, row_lanes

# Lanes in one kernel launch. Larger launches keep both cores busy; the cap bounds the adds a
# bin's integer words receive in one pass (`exact_sum.MAX_ADDS`: 2^22 lanes x 64 bounces < 2^30).
MAX_LANES_PER_PASS = 1 << 22
MAX_SPP_PER_PASS = 1 << 16
#: The default ``emission`` of shared multibeam paths (see the class docstring): ``receive``.
EMISSION = "receive"


class SonarTOFIntegrator(SonarIntegrator):
    """Time-of-flight sonar integrator (particle tracing with next-event backscatter).

    Every ping of the scan is traced in one wavefront (lane -> ping). From the transducer a path
    is emitted in proportion to the beam pattern; at each of up to ``max_depth`` surface bounces
    it connects back to the transducer (visibility tested) and its echo energy is added to the
    bin of range = total path length / 2; the path then continues by sampling the BSDF.
    Echoes outside ``[range_min, range_max)`` are dropped. Bins hold energy per bin (not per
    metre), averaged over ``spp`` paths per ping; each pass sums its echoes exactly, whatever the
    order of the threads (`exact_sum`), and the passes are summed in float64 in order.

    =================== ======== ========================================================================
    Parameter           Default  Meaning
    =================== ======== ========================================================================
    max_depth           5        surface bounces per path (1 = single bounce; the thesis uses 5)
    sampling            sobol    the emitted directions of a row: ``sobol`` (an Owen-scrambled Sobol
                                 sequence per row, `samples.SobolSamples`: the beam is covered evenly)
                                 or ``independent`` (uniform random, `samples.HashSamples`); both are
                                 unbiased, the bounces are sampled independently either way
    share_beams         auto     multibeam: trace a frame's ``n_rows * spp`` paths from the transmit
                                 fan and score each echo into every receive beam that hears it,
                                 weighted by that beam's gain (`shared_beams`); ``sampling`` then
                                 draws the fan's directions as one sequence per frame. Same
                                 expectation, lower error per path. Unset (auto): on for a
                                 multibeam head that can share, else per-row paths, silently: a
                                 ``sinc`` receive beam (side lobes over the whole half-space, so
                                 every echo would be scored into every row), echoes reaching more
                                 than `shared_beams.MAX_BEAMS` beams, windows overlapping across a
                                 full turn, rows with their own poses (a moving head), other kinds.
                                 ``true``: share, and refuse in one line a head that cannot;
                                 ``false``: per-row paths. Gradients use the per-row paths
    emission            receive  shared multibeam paths: ``receive`` draws the emitted directions in
                                 proportion to the transmit fan times the receive beams' summed
                                 azimuth pattern, mixed with a quarter of the fan's own density
                                 (`receive_emission`): the same expectation, fewer paths wasted
                                 beyond the swath (the 512-beam quay frame: 1.2-1.35x fewer paths to
                                 5 %); ``transmit``: in proportion to the fan (before)
    guide               image    ``image``: after a bounce on a mirror-like surface (a Phong lobe of
                                 exponent >= 100: steel plates, a calm sea surface), half of the next
                                 bounces aim at the transducer's image in its plane (`image_guide`):
                                 echoes seen only through such plates get 5-20x less noise at equal
                                 time (hidden_target, periscope); scenes without mirror-like BSDFs
                                 trace the unguided kernel (no cost), others pay up to 31 % more time per
                                 path. At the first mirror of a chain half of the bounces aim at the
                                 specular strip of a mirror-like sphere or cylinder, where the scene
                                 has one besides other mirrors (`curved_mirror.strip_lobe`): the pile
                                 seen in a quay wall, 1.3-2.5x less error at equal time (pile_quay).
                                 A scene without mirrors but with glossy rectangles (exponent >= 10:
                                 a concrete quay wall) aims a quarter of its bounces at their
                                 specular points towards the transducer (`plane_guide`): the quay
                                 wall's dihedral corner needs 2.9x fewer paths for 5 %.
                                 ``none``: BSDF sampling only. Gradient renders are unguided
    sound_speed_profile (none)   a CSV file (``depth,sound_speed``; a path relative to the scene
                                 file): the water the paths refract through (`refraction`): arcs out,
                                 an eigenray back, range = sensor ``sound_speed`` x two-way travel
                                 time / 2. Unset, or constant at the sensor's speed: straight rays.
                                 Primal renders only
    svp_chords          4        chords per range window along which a refracted ray meets the scene
    allocation          auto     paths per row. ``uniform``: ``spp`` each. ``adaptive``: a pilot of
                                 ``spp / 16`` paths per row (paid on top; it only chooses), then the
                                 ``spp`` x rows paths shared out in proportion to the square root of
                                 each row's estimated variance, a quarter of them evenly, or evenly
                                 where the pilot predicts under 2x; and where its even and odd paths
                                 agree that it pays (>= 1.3x), each row's emitted elevation drawn by
                                 its echoes' second moments over 16 slices of that primary sample
                                 (`row_allocation`, step 3). Where neither, the render is the
                                 uniform render, byte for byte. At equal time: ``pile_quay`` 2.2x
                                 less error, ``intake`` 1.8x, ``box`` 1.4x, the pilot's 13-23 % of
                                 time lost where nothing changes (docs/benchmarks.rst). ``auto``:
                                 ``adaptive`` where the rows do not share paths (no shared beams)
                                 and the render traces at least 2^18 of them (rows x spp; the
                                 pilot's fixed 3-5 ms then costs under a tenth), else ``uniform``;
                                 the guide from spp 4096 (a pilot of 256 paths). Same expectation;
                                 renders whose samples should match row for row (finite
                                 differences, common random numbers) want ``uniform``.
                                 ``adaptive`` traces per-row paths (``share_beams`` auto then
                                 shares no beams; ``share_beams`` true refuses it). Primal renders
                                 only
    =================== ======== ========================================================================

    Each pass runs as a Dr.Jit frozen function (`frozen_pass`): its kernel is traced once per
    scene, sensor and pass size and replayed after, with the seed, pose, window and pass start as
    inputs (the same histogram as tracing every pass; ``frozen_pass.FREEZE = False`` traces).

    ``mi.render(scene)`` returns the range-intensity image as a tensor (n_pings, n_bins, 1);
    ``render_histogram`` returns it as a float64 numpy array and accepts a ``pose``;
    ``render_histogram_device`` as a ``mi.Float64`` kept on the device (`render_frame` uses it).
    ``mi.render(scene, params)`` is differentiable in both modes (``render_forward``,
    ``render_backward`` of `common.SonarIntegrator`, by path replay: ``plugins/integrators/paths/path_replay.py``).
    """

    name = "sonar_tof"
    #: ``emission`` values, the default first (the table above).
    EMISSIONS = (EMISSION, "transmit")
    REFRACTS = True
    SAMPLERS = {"sobol": SobolSamples, "independent": HashSamples}
    #: ``allocation`` values, the default first (the table above).
    ALLOCATIONS = ("auto", "uniform", "adaptive")

    def __init__(self, props: mi.Properties):
        super().__init__(props)
        self.sampling = text(props, "sampling", "sobol", self.name)
        require(self.sampling in self.SAMPLERS, self.name, "sampling", self.sampling,
                "one of " + ", ".join(self.SAMPLERS))
        self.emission = text(props, "emission", self.EMISSIONS[0], self.name)
        require(self.emission in self.EMISSIONS, self.name, "emission", self.emission,
                "one of " + ", ".join(self.EMISSIONS))
        self.share_beams = None   # auto: share when the head can (see the table)
        if "share_beams" in props:
            prop_type = props.type("share_beams").name
            require(prop_type == "Bool", self.name, "share_beams", props.get("share_beams"), "<boolean> true or false")
            self.share_beams = bool(props.get("share_beams"))
        self.allocation = text(props, "allocation", self.ALLOCATIONS[0], self.name)
        require(self.allocation in self.ALLOCATIONS, self.name, "allocation", self.allocation,
                "one of " + ", ".join(self.ALLOCATIONS))
        require(not (self.allocation == "adaptive" and self.share_beams), self.name, "allocation",
                self.allocation, "uniform when share_beams is true (adaptive allocates per-row paths)")

    def render_histogram(self, scene, sensor=0, seed=0, spp=4096, pose=None, max_depth=None, progress=None):
        """Mean echo energy per bin, float64 ``(n_pings, n_bins)``: `render_histogram_device`'s
        mean brought to the host.

        ``progress(done_spp, spp)`` is called after each pass (long renders run several).
        ``last_plan`` says how the paths were allocated (``extra_paths_per_row``: those traced
        per row beyond ``spp``, the adaptive allocation's pilot).
        """
        sensor = resolve_sensor(scene, sensor)
        mean, _ = self.render_histogram_device(scene, sensor, seed, spp, pose, max_depth, progress)
        return mean.numpy().reshape(sensor.n_pings, sensor.n_bins)

    def render_histogram_device(self, scene, sensor=0, seed=0, spp=4096, pose=None, max_depth=None,
                                progress=None):
        """`render_histogram`'s mean on the device, ``(mean, intensity)``: a ``mi.Float64`` of
        ``n_pings * n_bins`` values, row-major, and the same as float32 (`exact_sum.to_float32`,
        the frame's intensity), evaluated together. The passes' exact sums are summed and averaged
        there (the same bits as summing them on the host): nothing of the histogram comes to the
        host."""
        setup = self.setup(scene, sensor, pose, max_depth)
        n_pings = setup.sensor.n_pings
        shared = None
        if self.share_beams is not False and self.allocation != "adaptive":
            from .paths.shared_beams import SharedFrame, can_share, same_pose, window

            if self.share_beams:
                window(setup.sensor)  # refuses a head that cannot share, before any work
            if (self.share_beams or can_share(setup.sensor)) and same_pose(setup.sensor, pose):
                shared = SharedFrame(setup, pose)
        if shared is None and row_allocation.adaptive(self.allocation, n_pings, spp):
            return exact_sum.with_float32(row_allocation.render(self, setup, seed, spp, MAX_LANES_PER_PASS,
                                                                progress))
        # what this render did (`row_allocation.render` says so for its own): spp paths per row
        self.last_plan = {"allocation": "uniform", "extra_paths_per_row": 0}
        self.last_counts = np.full(n_pings, int(spp), dtype=np.int64)
        if shared is None:
            def one_pass(start, count):
                return self._pass(setup, seed, start, count)
        else:
            def one_pass(start, count):
                return self._shared_pass(shared, seed, start, count)
        return self.accumulate(spp, MAX_LANES_PER_PASS // n_pings, one_pass, progress, float32=True)

    @staticmethod
    def accumulate(spp, max_per_row, one_pass, progress=None, float32=False):
        """The mean over ``spp`` samples per row of ``one_pass(start, count)`` (a float64 array,
        NumPy or ``mi.Float64``: the summed energy of samples ``start .. start + count`` of every
        row; the mean is of the same kind, so a histogram of ``mi.Float64`` passes stays on the
        device), run in passes of at most ``max_per_row`` (and `MAX_SPP_PER_PASS`) samples per row
        with gradients off; ``progress(done_spp, spp)`` after each pass. The pass loop of every
        histogram integrator. ``float32``: ``(mean, the mean as float32)`` (`exact_sum.to_float32`
        on the device, NumPy's ``astype`` on the host).

        Both kinds give the same bits: ``0.0 + x``, the passes added in order, ``/ spp``. On the
        device the zero and ``spp`` are opaque (Dr.Jit would fold ``x + 0.0`` away, -0.0 kept, and
        turn ``/ spp`` into a product by ``1 / spp``), and every pass evaluates the running sum
        with the mean (and its float32) in one kernel, the same kernel whatever the number of
        passes (a live head's budget may pick any), whose conversion of the pass's words it joins
        (`exact_sum.pass_sums`). Subnormals flush to zero on the calling thread as on Dr.Jit's
        pool threads (`denormals`)."""
        spp = int(spp)
        if spp < 1:
            raise ValueError(f"spp must be a positive number of paths per ping, got {spp}")
        spp_pass = max(1, min(spp, MAX_SPP_PER_PASS, int(max_per_row)))
        total, start = None, 0
        # flushing: the calling thread computes like the pool's threads (1 thread = 2 threads)
        with dr.suspend_grad(), flushing():
            while start < spp:
                count = min(spp_pass, spp - start)
                part = one_pass(start, count)
                if isinstance(part, np.ndarray):
                    # 0.0 + x as before (x + 0.0: the same bits), then sums in place: no new
                    # array per pass nor for the mean
                    if total is None:
                        total = np.add(part, 0.0)
                    else:
                        total += part
                else:
                    if total is None:
                        total = dr.opaque(mi.Float64, 0.0, dr.width(part))
                    total = total + part
                    mean = total / dr.opaque(mi.Float64, spp)
                    out = (total, mean, exact_sum.to_float32(mean)) if float32 else (total, mean)
                    dr.eval(*out)
                start += count
                if progress is not None:
                    progress(start, spp)
            if not isinstance(total, np.ndarray):
                return out[1:] if float32 else mean
            total /= spp
        return (total, total.astype(np.float32)) if float32 else total

    @staticmethod
    def emitting(setup, d, w):
        """``setup`` with its beam drawing the directions ``d`` and weights ``w`` drawn beforehand."""
        return _emitting(setup, d, w)

    def lanes(self, n_rows, seed, start, count):
        """The lanes of one pass (`samples.row_lanes`) with this integrator's sampling."""
        return row_lanes(self.SAMPLERS[self.sampling], n_rows, seed, start, count)

    def _pass(self, setup, seed, start, count, guide=None):
        """One pass of per-row paths: the summed echo energy per bin, ``mi.Float64``. The emitted
        directions are drawn first (with ``guide``, the adaptive allocation's density over the
        emitted elevation: `row_allocation`), then the paths run as a frozen function
        (`frozen_pass`)."""
        seed_o, start_o = opaque_u32(seed), opaque_u32(start)
        ping, samples = self.lanes(setup.sensor.n_pings, seed_o, start_o, count)
        d, w = row_allocation.emitted(setup.sensor.beam, samples, ping, guide)
        return self._run(self._pass_body, setup, seed_o, start_o, d, w, count)

    def _run(self, body, ctx, *args):
        """``body(ctx, *args)``, a pass, through `exact_sum.pass_sums` (the window of words it sums
        in; the sums a ``mi.Float64``): frozen (`frozen_pass`), but traced when it runs again in
        nine words to widen the window after a pass that missed (a recording of it would not be
        replayed)."""
        return exact_sum.pass_sums(self, lambda learning: body(ctx, *args) if learning
                                  else frozen_pass.run(body, self, ctx, *args))

    def _pass_body(self, setup, seed_o, start_o, d, w, count):
        n_pings, n_bins = setup.sensor.n_pings, setup.sensor.n_bins
        ping, samples = self.lanes(n_pings, seed_o, start_o, count)
        # Integer words per bin (`exact_sum`): the sums do not depend on the order in which the
        # threads add the echoes, so the same seed gives the same bytes with 1 thread or 16.
        # Atomic adds straight to memory: the default (per-thread copies and a block reduction)
        # needs Dr.Jit to dry-run a frozen pass before replaying it, and costs as much. In a window
        # of the words (`exact_sum.pass_sums`): the same sums, half the memory.
        hist = ExactBins(n_pings * n_bins, window=exact_sum.window_of(self))
        bins = setup.bins

        def record(depth_k, rng, energy, valid, hit):
            b, valid = bins.index(rng, valid)
            hist.add(energy, bins.flat(ping, b), valid)

        self.sample(_emitting(setup, d, w), ping, samples, record)
        return exact_sum.pass_result(self, hist)

    def _shared_pass(self, shared, seed, start, count):
        """One pass of a frame's shared paths: paths ``start * n_rows .. (start + count) * n_rows``
        of the frame's one sequence, scored into every row that hears them (`shared_beams`)."""
        seed_o, first_o = opaque_u32(seed), opaque_u32(start * shared.n_rows)
        _, _, samples = self._shared_lanes(shared.n_rows * count, seed_o, first_o)
        d, w = self.shared_emitted(shared, samples)
        return self._run(self._shared_body, shared, seed_o, first_o, d, w, count)

    def shared_emitted(self, shared, samples):
        """The emitted directions and weights of a frame's shared paths (`frozen_pass.emitted`),
        drawn from the fan's density or the receive-weighted one (``emission``)."""
        beam = shared.path_setup.sensor.beam
        if self.emission == "receive":
            from .paths.receive_emission import for_frame

            beam = for_frame(shared)
        return frozen_pass.emitted(beam, samples)

    def _shared_lanes(self, n, seed_o, first_o):
        """``n`` lanes of a frame's one sequence from path ``first_o`` on: (row 0 for all, each
        lane's path number in the sequence, its primary samples)."""
        zero = dr.zeros(mi.UInt32, n)
        index = dr.arange(mi.UInt32, n) + first_o
        return zero, index, self.SAMPLERS[self.sampling](seed_o, zero, index)

    def _shared_body(self, shared, seed_o, first_o, d, w, count):
        n = shared.n_rows * count
        zero, index, samples = self._shared_lanes(n, seed_o, first_o)
        hist = ExactBins(shared.n_rows * shared.sensor.n_bins, window=exact_sum.window_of(self))

        refraction = shared.path_setup.refraction

        def record(depth_k, rng, energy, valid, hit):
            # the roulette's number: a hash of (path, bounce, seed), apart from the path's samples
            u = mi.sample_tea_float32(index, seed_o ^ (mi.UInt32(depth_k) * 0x9E3779B9 + 0x51ED), 4)
            # a refracted echo arrives along its eigenray, not straight from its surface point
            shared.score(hist, rng, energy, valid, hit, u, None if refraction is None else refraction.arrival)

        self.sample(_emitting(shared.path_setup, d, w), zero, samples, record)
        return exact_sum.pass_result(self, hist)

    def to_string(self):
        return (f"SonarTOFIntegrator[max_depth={self.max_depth}, sampling={self.sampling}, "
                f"share_beams={'auto' if self.share_beams is None else str(self.share_beams).lower()}, "
                f"emission={self.emission}, "
                f"guide={self.guide}, allocation={self.allocation}]")


def _emitting(setup, d, w):
    """``setup`` with its emitting beam's ``sample`` returning the directions ``d`` and weights
    ``w`` drawn beforehand (`frozen_pass.emitted`)."""
    from types import SimpleNamespace

    out = SimpleNamespace(**vars(setup))
    out.sensor = SimpleNamespace(beam=frozen_pass.Emitted(setup.sensor.beam, d, w))
    return out


register_plugin("integrator", "sonar_tof", SonarTOFIntegrator)
