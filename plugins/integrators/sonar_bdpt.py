"""The ``sonar_bdpt`` integrator: bidirectional sonar path tracing into range bins."""
from __future__ import annotations

import drjit as dr
import mitsuba as mi
import numpy as np

from mitsonar._checks import not_allowed, require
from mitsonar.plugins.props import count, text
from mitsonar.plugins.registry import register_plugin

from .paths.bdpt_paths import HEURISTICS, trace_bidirectional
from .paths.exact_sum import ExactBins
from .sonar_tof import SonarTOFIntegrator

# Subpath B vertices kept in one pass (~80 bytes each: 320 MiB).
MAX_STORED_VERTICES = 1 << 22

# Subpath B's samples are the same sampler's with this seed: independent of subpath A's.
_SEED_B = 0x6A09E667


class SonarBDPTIntegrator(SonarTOFIntegrator):
    """Bidirectional sonar path tracer (Veach 1997, ch. 10) with multiple importance sampling.

    Every ping of the scan is traced in one wavefront (lane -> ping). A lane draws two subpaths
    from the transducer, each starting in proportion to its beam pattern and continued by BSDF
    sampling: A from the row's beam (the beam a mechanical head transmits and receives with; a
    multibeam row's receive beam), B from the other end (the same beam, or a multibeam head's
    transmit fan). Every vertex of A (the transducer included) is joined to every vertex of B
    (likewise) with a visibility-tested segment, for every path of 1 to ``max_depth`` surface
    bounces: the strategy with all bounces on A is ``sonar_tof``'s next-event estimator, the
    others find what it finds only by chance, such as an echo seen through a glossy surface.
    Each strategy's echo is weighted by the power (or balance) heuristic and lands in the bin of
    range = its total path length / 2 (`range_bins`); energies are in ``sonar_tof``'s units
    (`common`), so the two agree within Monte-Carlo error. Derivation: `bdpt_paths`.
    Same seed, same scan; passes are summed in float64 as in ``sonar_tof``.

    ============ ======== ====================================================================
    Parameter    Default  Meaning
    ============ ======== ====================================================================
    max_depth    5        surface bounces of the whole echo path (1 = single bounce), as
                          ``sonar_tof``
    sampling     sobol    the emitted directions of both subpaths: ``sobol`` (Owen-scrambled
                          Sobol per row) or ``independent`` (`samples.HashSamples`)
    mis          power    multiple importance sampling weights: ``power`` (exponent 2) or
                          ``balance`` heuristic (Veach 1997, 9.2); power has the lower
                          variance on glossy scenes (0.61x on glossy_corridor), the same
                          elsewhere
    strategy     all      ``all`` (every strategy, MIS weighted) or a whole number s: only the
                          strategies with s surface vertices on subpath A, unweighted (for
                          validation: unbiased for paths of at least max(s, 1) bounces)
    guide        none     only ``none``: the subpaths are sampled by the BSDFs alone (the MIS
                          weights would need ``sonar_tof``'s image guide's density at the other
                          subpath's vertices)
    emission     transmit only ``transmit``: subpath B starts in proportion to the transmit fan
                          (no shared multibeam paths for ``sonar_tof``'s ``receive`` to weight)
    ============ ======== ====================================================================

    Its paths are straight: a ``sound_speed_profile`` (XML, or ``render_scan``'s) is refused in one
    line before any work (refracted paths are ``sonar_tof``'s).

    ``render_histogram`` returns the float64 ``(n_pings, n_bins)`` histogram like ``sonar_tof``'s;
    ``spp`` counts lanes (subpath pairs) per row. With ``D = max_depth`` a lane casts ``2 D``
    rays and ``(D + 1)(D + 2) / 2 - 1`` shadow rays against ``D`` and ``D`` for a ``sonar_tof``
    path: at ``D = 5`` it took 1.5 to 7.5 times as long (``benchmarks/bdpt.py``, shared machine).
    """

    name = "sonar_bdpt"
    # Its subpaths are sampled by the BSDFs alone: the MIS weights would need the guide's density
    # along the other subpath's vertices.
    GUIDES = ("none",)
    # Its subpaths start from each row's own beam or the transmit fan: it has no shared
    # multibeam paths for ``emission=receive`` to weight.
    EMISSIONS = ("transmit",)
    # Its subpaths and their joins are straight segments (`bdpt_paths`): a ``sound_speed_profile``
    # is refused in one line when the scene loads (`refraction.read_profile`) or a render is
    # given one (``render_scan``), not inherited from ``sonar_tof`` and silently ignored.
    REFRACTS = False

    def __init__(self, props: mi.Properties):
        super().__init__(props)
        self.mis = text(props, "mis", "power", self.name)
        require(self.mis in HEURISTICS, self.name, "mis", self.mis, "one of " + ", ".join(HEURISTICS))
        strategy = (str(count(props, "strategy", 0, self.name))
                    if "strategy" in props and props.type("strategy").name != "String"
                    else text(props, "strategy", "all", self.name))
        self.strategy = None if strategy == "all" else _whole(strategy, self.max_depth, self.name)

    def render_histogram(self, scene, sensor=0, seed=0, spp=4096, pose=None, max_depth=None, progress=None):
        """Mean echo energy per bin, float64 ``(n_pings, n_bins)``; ``progress(done_spp, spp)`` after
        each pass. A pass keeps subpath B's vertices (``max_depth`` per lane, about 80 bytes
        each), so it holds at most `MAX_STORED_VERTICES` of them."""
        setup = self.setup(scene, sensor, pose, max_depth)
        n_pings, n_bins = setup.sensor.n_pings, setup.sensor.n_bins
        lanes = max(1, MAX_STORED_VERTICES // setup.depth)
        total = self.accumulate(spp, lanes // n_pings, lambda start, count: self._pass(setup, seed, start, count),
                                progress)
        return total.reshape(n_pings, n_bins)

    def _pass(self, setup, seed, start, count):
        n_pings, n_bins = setup.sensor.n_pings, setup.sensor.n_bins
        ping, samples_a = self.lanes(n_pings, seed, start, count)
        _, samples_b = self.lanes(n_pings, (int(seed) ^ _SEED_B) & 0xFFFFFFFF, start, count)
        hist = ExactBins(n_pings * n_bins)   # the same sums whatever the threads (`exact_sum`)
        bins = setup.bins

        def record(s, t, rng, energy, valid):
            b, valid = bins.index(rng, valid)
            hist.add(energy, bins.flat(ping, b), valid)

        trace_bidirectional(setup, ping, samples_a, samples_b, record, power=HEURISTICS[self.mis],
                            only_s=self.strategy)
        return hist.numpy()

    def to_string(self):
        strategy = "all" if self.strategy is None else self.strategy
        return (f"SonarBDPTIntegrator[max_depth={self.max_depth}, sampling={self.sampling}, mis={self.mis}, "
                f"strategy={strategy}]")


def _whole(value: str, max_depth: int, source: str) -> int:
    """The strategy number in ``value`` (0..max_depth), else the one-line error."""
    if not (value.isdigit() and int(value) <= max_depth):
        raise not_allowed(source, "strategy", value, "'all' or a whole number of surface vertices on the subpath "
                          f"from the row's beam, 0 to max_depth ({max_depth})")
    return int(value)


register_plugin("integrator", "sonar_bdpt", SonarBDPTIntegrator)
