"""The ``sonar_mlt`` integrator: primary-sample-space Metropolis transport for sonar echoes."""
from __future__ import annotations

import math

import drjit as dr
import mitsuba as mi
import numpy as np

from mitsonar._checks import require
from mitsonar._limits import check
from mitsonar.plugins.jit_arrays import upload
from mitsonar.plugins.props import count, number, text
from mitsonar.plugins.registry import register_plugin

from .common import PathSetup, SonarIntegrator, tagging_hard
from .paths.denormals import flushed
from .paths.exact_sum import ExactBins
from .mlt_split import MAX_SHARE, render_split
from .paths.samples import HashSamples, n_dims
from .sonar_tof import SonarTOFIntegrator

# Salts that keep the random streams of the stages apart for one user seed.
_SALT_BOOT, _SALT_MUT, _SALT_START = 0x5EED0001, 0x5EED0002, 0x5EED0003


class SonarMLTIntegrator(SonarIntegrator):
    r"""Primary-sample-space Metropolis light transport (Kelemen et al. 2002) for sonar.

    The target of a path is the sum of its per-bounce echo energies that land in the range
    window: ``f(U) = sum_k e_k(U)``, with ``U`` the primary-sample vector of the echo path that
    ``sonar_tof`` traces (the same function, `SonarIntegrator.sample`). With
    ``normalisation="scan"`` (the default) the ping is one more primary coordinate: the chains
    sample ``f`` over (ping, ``U``) of the whole scan and go to the pings where the echoes are;
    with ``"ping"`` every ping is a target of its own. With the image guide (the default) the
    chains take only the *hard* echoes, those after a bounce that follows a mirror-like one, and
    path tracing the rest, with the split of the budget chosen by ``split`` (`mlt_split`); a scene
    without mirror-like surfaces is then path traced. The chains, over every echo or the hard
    ones:

    1. a bootstrap of uniform paths (``bootstrap`` per ping) estimates the normalisation
       ``b = E[f]``, over the scan or per ping;
    2. chains start from bootstrap paths resampled in proportion to ``f`` (their totals and echo
       records are reused, not traced again);
    3. each mutation is a large step (a fresh uniform ``U``, and ping) with probability
       ``large_step``, else a Kelemen small step (every coordinate moved by ``+-s``, ``s``
       log-uniform between ``small_step_min`` and ``small_step_max``, wrapped into [0, 1); the
       ping coordinate by ``ping_step`` times that);
    4. expected-value splatting combined with the uniform samples (Kelemen's combination, the
       balance heuristic between the chain density ``f / b`` and the ``p_uni`` uniform samples per
       chain sample: the bootstrap and the large steps): a sample adds its echoes ``e_k``, each to
       its own range bin, with weight ``w / (f + p_uni b)``, ``w`` = ``a`` (+1 for a large step)
       for the proposal, ``1 - a`` for the current state, 1 for a bootstrap path; the histogram is
       scaled by ``b / (chains mutations)`` (chains and mutations per ping). Where ``f`` is small
       against ``p_uni b`` the uniform samples carry the estimate, where it is large the chains do.

    All chains of all pings run in one wavefront; every quantity that changes between
    mutations or renders is opaque, so a render compiles its kernels once. A proposal is computed
    inside the path kernel and a state's weight is splatted once, when its chain leaves it.
    The estimate is consistent and, by the tests (`tests/test_mlt.py`), has the expectation of
    ``sonar_tof`` within Monte Carlo error on every scene; the reuse of the bootstrap both for ``b``
    and as samples leaves a bias of order 1/bootstrap, far below the noise.

    ================ ======== =================================================================
    Parameter        Default  Meaning
    ================ ======== =================================================================
    max_depth        5        surface bounces per path (1 = single bounce)
    normalisation    scan     ``scan``: one target over all pings (the ping a primary
                              coordinate, one ``b``); ``ping``: one target and ``b`` per ping
    chains           0        chains per ping (``scan``: the total is chains x pings); 0 chooses
                              about 2^13 chains in all for ``scan`` (at most spp/16 per ping),
                              about 2^16 for ``ping`` (32 to spp/16 per ping)
    mutations        0        mutations per chain; 0 spends the ``spp`` budget
    large_step       0.1      probability of a large step
    small_step_min   1/128    smallest small-step size (Kelemen's s1)
    small_step_max   1/4      largest small-step size (Kelemen's s2)
    ping_step        1        small steps of the ping coordinate, as a fraction of the others'
                              (``scan`` only; 0 changes pings by large steps alone)
    bootstrap        0        bootstrap paths per ping; 0 takes half of ``spp`` (at least 4x chains)
    guide            image    ``image``: primary samples map to image-guided paths (`image_guide`,
                              as ``sonar_tof``'s ``guide``); ``none``: BSDF sampling
    split            0        with the guide: the chains' share of the budget; path tracing
                              estimates the echoes before any chained bounce, the chains the
                              others (`mlt_split`). 0 (the default): no chains, the path
                              tracer's estimate, ``sonar_tof``'s own (shared beams where the
                              head can share, `mlt_split.path_traced`) (at equal time the chains
                              lost 2-6x to the guided path tracer on every scene with mirrors,
                              docs/benchmarks.rst); ``auto``: the share from a pilot's
                              variances; a number in [0, 0.9]; ``off`` (or ``guide="none"``):
                              chains over every echo, Kelemen's PSSMLT as before the guide
    allocation       auto     paths per ping of the path-traced render (``split`` 0), as
                              ``sonar_tof``'s ``allocation`` (`row_allocation`): ``auto``
                              (its default: the pilot's allocation for renders of 2^18 paths
                              and more on heads that do not share beams), ``uniform``,
                              ``adaptive``
    ================ ======== =================================================================

    The defaults are the best settings measured on ``scenes_xml/`` (see the documentation's
    Benchmarks page and ``benchmarks/mlt.py``): one target over the scan, few long chains (about 2^13 in
    all) and mostly small steps. With no parameters ``sonar_mlt`` is ``sonar_tof``'s scan: the
    chains lost to the guided path tracer on every scene measured, ``pile_quay`` included
    (0.28-0.69x at equal time), whose room the oracle bounds at 6.1-6.6x
    (``benchmarks/mlt_oracle.py``), and measured again against ``sonar_tof`` with its pilot's
    allocation (its default ``allocation="auto"`` since 2026-11-27, which moves paths to the pings
    with noisy echoes and guides their emitted elevations: the room the oracle found on
    ``intake``, and on ``pile_quay`` all but 2.4-2.6x, of which a sampler normalised by uniform
    paths could take at most 1.5-1.6x).

    ``spp`` counts path evaluations per ping (bootstrap plus chains x mutations), so equal
    ``spp`` means about equal work for ``sonar_tof`` and ``sonar_mlt``. Its paths are straight: a
    ``sound_speed_profile`` (XML, or ``render_scan``'s) is refused in one line before any work
    (refracted paths are ``sonar_tof``'s).
    """

    name = "sonar_mlt"

    def __init__(self, props: mi.Properties):
        super().__init__(props)
        self.chains = count(props, "chains", 0, "sonar_mlt")
        self.mutations = count(props, "mutations", 0, "sonar_mlt")
        self.large_step = number(props, "large_step", 0.1, "sonar_mlt")
        self.small_step_min = number(props, "small_step_min", 1.0 / 128.0, "sonar_mlt")
        self.small_step_max = number(props, "small_step_max", 1.0 / 4.0, "sonar_mlt")
        self.bootstrap = count(props, "bootstrap", 0, "sonar_mlt")
        self.normalisation = text(props, "normalisation", "scan", "sonar_mlt")
        self.ping_step = number(props, "ping_step", 1.0, "sonar_mlt")
        self.allocation = text(props, "allocation", "auto", "sonar_mlt")
        self.split = 0.0
        if "split" in props:
            if props.type("split").name == "String":
                self.split = text(props, "split", "auto", "sonar_mlt")
            else:
                self.split = number(props, "split", 0.0, "sonar_mlt")
        self._check()

    def _check(self):
        def need(ok, name, value, allowed):
            require(ok, "sonar_mlt", name, value, allowed)
        for name in ("chains", "mutations", "bootstrap"):   # the bounds of `mitsonar._limits`
            check("sonar_mlt", name, getattr(self, name))
        need(self.normalisation in ("scan", "ping"), "normalisation", self.normalisation,
             "'scan' (one target over all pings) or 'ping'")
        need(self.allocation in SonarTOFIntegrator.ALLOCATIONS, "allocation", self.allocation,
             "one of " + ", ".join(f"'{a}'" for a in SonarTOFIntegrator.ALLOCATIONS)
             + " (paths per ping of the path-traced render, as sonar_tof's)")
        need(0.0 <= self.ping_step <= 1.0, "ping_step", self.ping_step,
             "a fraction in [0, 1] of the small step applied to the ping")
        need(0.0 <= self.large_step <= 1.0, "large_step", self.large_step, "a probability in [0, 1]")
        need(self.split in ("auto", "off") or (not isinstance(self.split, str) and 0.0 <= self.split <= MAX_SHARE),
             "split", self.split, f"'auto', 'off', or the chains' share of the budget, a number in [0, {MAX_SHARE}]")
        need(0.0 < self.small_step_min <= self.small_step_max < 0.5, "small_step_min/small_step_max",
             (self.small_step_min, self.small_step_max), "0 < small_step_min <= small_step_max < 0.5")

    # ------------------------------------------------------------------ budget
    def plan(self, n_pings, spp):
        """(bootstrap paths, chains, mutations) per ping for a budget of ``spp`` path evaluations."""
        spp = int(spp)
        if spp < 1:
            raise ValueError(f"spp must be a positive number of paths per ping, got {spp}")
        boot, chains, mutations = self._counts(n_pings, spp)
        total = boot + chains * mutations
        # spp is the work a scan records and the compare tool equalises: explicit settings may not
        # exceed it (200000 mutations at spp 64 once ran minutes for a scan labelled 64 spp).
        if not self._fits(n_pings, spp):
            raise ValueError(f"sonar_mlt: bootstrap {boot} + chains {chains} x mutations {mutations} = {total} "
                             f"path evaluations per ping exceed spp = {spp}; raise spp to at least "
                             f"{self.min_spp(n_pings)}, or lower chains, mutations or bootstrap (0 fits them to spp)")
        return boot, chains, mutations

    def _counts(self, n_pings, spp):
        if self.normalisation == "scan":
            # about 8k chains in all: the chains share one target, so fewer, longer chains forget
            # their (resampled) starts, whose spread over the pings is the bootstrap's noise
            chains = self.chains or int(np.clip((1 << 13) // n_pings, 1, max(1, spp // 16)))
        else:
            chains = self.chains or int(np.clip((1 << 16) // n_pings, 32, max(32, spp // 16)))
        boot = self.bootstrap or max(4 * chains, spp // 2)
        mutations = self.mutations or max(1, (spp - boot) // chains)
        return boot, chains, mutations

    def _fits(self, n_pings, spp):
        """Automatic counts always fit spp; explicit ones must."""
        boot, chains, mutations = self._counts(n_pings, spp)
        return boot + chains * mutations <= spp or not (self.chains or self.mutations or self.bootstrap)

    def min_spp(self, n_pings):
        """The smallest spp that the explicit chains/mutations/bootstrap fit (1 when none is set;
        the compare tool starts its timings there)."""
        lo, hi = 1, 1
        while not self._fits(n_pings, hi):  # from some spp on it fits: the chains saturate, spp // 2 covers the rest
            lo, hi = hi + 1, hi * 2
        while lo < hi:
            mid = (lo + hi) // 2
            lo, hi = (lo, mid) if self._fits(n_pings, mid) else (mid + 1, hi)
        return lo

    # ------------------------------------------------------------------ rendering
    @flushed   # the calling thread computes like the pool's threads (`denormals`)
    def render_histogram(self, scene, sensor=0, seed=0, spp=4096, pose=None, max_depth=None, progress=None):
        """Mean echo energy per bin, float64 ``(n_pings, n_bins)`` (same units as ``sonar_tof``):
        the split render (`mlt_split`) with the image guide, else chains over every echo."""
        setup = self.setup(scene, sensor, pose, max_depth)
        self.plan(setup.sensor.n_pings, spp)  # refuses explicit counts that do not fit, before any work
        if self.split != "off" and self.guide == "image":
            return render_split(self, setup, seed, int(spp), progress, pose)
        return self.metropolis(setup, seed, spp, progress=progress)

    def metropolis(self, setup, seed, spp, hard_only=False, progress=None):
        """The Metropolis estimate of every echo (of the hard ones, `mlt_split`, with
        ``hard_only``) with a budget of ``spp`` path evaluations per row."""
        ctx = _Context(self, setup, hard_only)
        sensor, depth = ctx.sensor, ctx.depth
        n_pings, n_bins = sensor.n_pings, sensor.n_bins
        boot, chains, mutations = self.plan(n_pings, spp)
        dims = n_dims(depth)
        seed = int(seed) & 0xFFFFFFFF
        n = n_pings * chains
        n_m = chains * mutations                          # Metropolis samples per ping
        p_uni = (boot + self.large_step * n_m) / n_m      # uniform samples per Metropolis sample

        with dr.suspend_grad():
            # 1. Bootstrap: uniform paths, per ping; b = their mean f.
            lanes = n_pings * boot
            lane = dr.arange(mi.UInt32, lanes)
            boot_o = dr.opaque(mi.UInt32, boot)
            ping = lane // boot_o
            f_boot, bins_boot, vals_boot = ctx.records(lanes)
            ctx.trace(HashSamples(dr.opaque(mi.UInt32, seed ^ _SALT_BOOT), ping, lane - ping * boot_o),
                      ping, lane, f_boot, bins_boot, vals_boot)
            dr.eval(f_boot, bins_boot, vals_boot)
            f_np = f_boot.numpy().astype(np.float64).reshape(n_pings, boot)
            # One target per ping, or one over (ping, U) for the whole scan: then the ping is a
            # primary coordinate, b the mean over all bootstrap paths, and the chains spend their
            # time where the scan's echoes are. Both are "targets = groups of bootstrap rows".
            per_ping = self.normalisation == "ping"
            groups = f_np.reshape(n_pings if per_ping else 1, -1)
            norm = np.repeat(groups.mean(axis=1), n_pings // len(groups))
            live = norm > 0
            self.last_plan = {"bootstrap": boot, "chains": chains, "mutations": mutations}

            # 2. Start states resampled in proportion to f within each target.
            pick = _resample(groups, n // len(groups), np.random.default_rng([seed, _SALT_START]))
            pick = (pick + np.arange(len(groups))[:, None] * groups.shape[1]).ravel()
            chain_ping, start = (pick // boot).astype(np.uint32), (pick % boot).astype(np.uint32)
            ping_c = upload(mi.UInt32, chain_ping, np.uint32)
            lane_c = dr.arange(mi.UInt32, n)
            # A start state is a bootstrap path: its samples are regenerated from the hash, its total
            # and records gathered instead of traced again.
            src = upload(mi.UInt32, pick, np.uint32)
            boot_seed, start_c = dr.opaque(mi.UInt32, seed ^ _SALT_BOOT), upload(mi.UInt32, start, np.uint32)
            n_pings_o = dr.opaque(mi.UInt32, n_pings)

            def start_samples(lane, dim):
                p = dr.gather(mi.UInt32, ping_c, lane)
                u = HashSamples(boot_seed, p, dr.gather(mi.UInt32, start_c, lane)).get(dim)
                # the ping coordinate: uniform inside the start ping's cell
                return dr.select(dim == dims, (mi.Float(p) + u) / mi.Float(n_pings_o), u)

            mutate = _Mutation(start_samples, lane_c, dims + (0 if per_ping else 1),
                               dr.opaque(mi.UInt32, seed ^ _SALT_MUT), self, ping_dim=None if per_ping else dims)
            f_cur = dr.gather(mi.Float, f_boot, src)
            rec_lane, rec_k = ctx.owner(n * depth)
            rec_src = dr.gather(mi.UInt32, src, rec_lane) * ctx.depth_o + rec_k
            bins_cur = dr.gather(mi.UInt32, bins_boot, rec_src)
            vals_cur = dr.gather(mi.Float, vals_boot, rec_src)
            active = upload(mi.Bool, live[chain_ping], np.bool_)

            # Kelemen's combination: the bootstrap paths and the large steps are uniform samples,
            # the chain states samples of f / b; the balance heuristic over the two gives every
            # sample the weight 1 / (f + p_uni b) (per Metropolis sample, times b / n_m below).
            # Expected values: a proposal adds a (+1 if a large step), the current state 1 - a.
            pu_norm = upload(mi.Float, p_uni * norm, np.float32)   # p_uni b per ping
            pu_b = dr.gather(mi.Float, pu_norm, ping_c)    # scan: the same for every ping, so it
                                                            # need not follow a chain's ping
            hist = ExactBins(n_pings * n_bins)   # order-independent (`exact_sum`)
            d_b = f_boot + dr.gather(mi.Float, pu_norm, ping)
            ctx.splat(hist, bins_boot, vals_boot, dr.select(d_b > 0, 1.0 / d_b, 0.0), ping,
                      dr.gather(mi.Bool, upload(mi.Bool, live, np.bool_), ping))
            # The weight the current state has gathered, not yet splatted (opaque: a literal zero
            # would give the first mutation a kernel of its own).
            w_cur = dr.opaque(mi.Float, 0.0, n)
            dr.eval(mutate.U, f_cur, bins_cur, vals_cur, hist.words, w_cur)

            # 3-4. Mutations, one wavefront per step.
            for m in range(mutations):
                large = mutate.step(m)
                ping_new = ping_c if per_ping else dr.minimum(
                    mi.UInt32(mutate.get(dims) * mi.Float(n_pings_o)), n_pings_o - 1)
                f_new, bins_new, vals_new = ctx.evaluate(mutate, ping_new, lane_c)
                a = dr.select(f_cur > 0, dr.minimum(1.0, f_new / dr.select(f_cur > 0, f_cur, 1.0)), 1.0)
                d_new = f_new + pu_b
                d_cur = f_cur + pu_b
                w_new = dr.select(d_new > 0, (a + dr.select(large, 1.0, 0.0)) / d_new, 0.0)
                w_cur += dr.select(d_cur > 0, (1.0 - a) / d_cur, 0.0)
                accept = mutate.accept(a)
                rec_accept = dr.gather(mi.Bool, accept, rec_lane)
                # Lazy splatting: a state's weight is written once, when the chain leaves it (or
                # at the end); a rejected proposal's at once.
                ctx.splat(hist, dr.select(rec_accept, bins_cur, bins_new), dr.select(rec_accept, vals_cur, vals_new),
                          dr.select(accept, w_cur, w_new), dr.select(accept, ping_c, ping_new), active)
                w_cur = dr.select(accept, w_new, w_cur)
                if not per_ping:
                    ping_c = dr.select(accept, ping_new, ping_c)
                bins_cur = dr.select(rec_accept, bins_new, bins_cur)
                vals_cur = dr.select(rec_accept, vals_new, vals_cur)
                f_cur = dr.select(accept, f_new, f_cur)
                dr.eval(mutate.U, f_cur, bins_cur, vals_cur, hist.words, w_cur, ping_c)
                if progress is not None:
                    progress(boot + (m + 1) * chains, boot + mutations * chains)
            ctx.splat(hist, bins_cur, vals_cur, w_cur, ping_c, active)
            out = hist.numpy().reshape(n_pings, n_bins) * (norm / n_m)[:, None]
        return out

    def to_string(self):
        return (f"SonarMLTIntegrator[max_depth={self.max_depth}, chains={self.chains or 'auto'}, "
                f"large_step={self.large_step}, guide={self.guide}, split={self.split}, "
                f"allocation={self.allocation}]")


def _resample(f, k, rng):
    """``k`` indices per row of ``f`` drawn with probability proportional to ``f`` (rows of zeros
    give index 0): one inverse-CDF search over all rows at once, each row's CDF shifted to [p, p+1)."""
    rows, n = f.shape
    total = f.sum(axis=1, keepdims=True)
    cdf = np.cumsum(np.divide(f, total, out=np.zeros_like(f), where=total > 0), axis=1)
    cdf[:, -1] = 1.0
    cdf += np.arange(rows)[:, None]
    u = np.arange(rows)[:, None] + rng.random((rows, k))
    idx = np.searchsorted(cdf.ravel(), u.ravel(), side="right").reshape(rows, k)
    idx -= np.arange(rows)[:, None] * n
    idx[total[:, 0] <= 0] = 0
    return np.clip(idx, 0, n - 1).astype(np.uint32)


def _mix32(x):
    """Chris Wellons' lowbias32 integer hash: a few operations, well mixed."""
    x = mi.UInt32(x)
    x ^= x >> 16
    x *= 0x7FEB352D
    x ^= x >> 15
    x *= 0x846CA68B
    return x ^ (x >> 16)


def _unit(v):
    """A uniform float in [0, 1) from the top 24 bits of ``v``."""
    return mi.Float(v >> 8) * (1.0 / 16777216.0)


class _Mutation:
    """The chains' primary samples ``U`` (``lane * dims + dim``) and their proposals.

    A proposal is not stored: `get` computes its coordinates inside the path kernel from ``U`` and
    a hash of (coordinate, step), and `accept` recomputes them where a chain moves, which saves
    writing and reading a second ``U`` every step.
    """

    def __init__(self, start, lane, dims, seed, params, ping_dim=None):
        """``start(lane, dim)``: coordinate ``dim`` of chain ``lane``'s start state; coordinate
        ``ping_dim`` (if any) is the ping, whose small steps are ``params.ping_step`` times the others'."""
        self.lane, self.dims = lane, dims
        self.seed = seed
        self.ping_dim = ping_dim
        self.ping_step = dr.opaque(mi.Float, params.ping_step)
        self.p_large = dr.opaque(mi.Float, params.large_step)
        self.s1 = dr.opaque(mi.Float, params.small_step_min)
        self.log_ratio = dr.opaque(mi.Float, math.log(params.small_step_max / params.small_step_min))
        self.elem = dr.arange(mi.UInt32, dr.width(lane) * dims)
        self.e_lane = self.elem // dr.opaque(mi.UInt32, dims)
        self.e_dim = self.elem - self.e_lane * dr.opaque(mi.UInt32, dims)
        self.U = start(self.e_lane, self.e_dim)

    def step(self, m):
        """Start mutation ``m``: decide each chain's large steps (returned)."""
        self.key0, self.key1 = mi.sample_tea_32(dr.opaque(mi.UInt32, m), self.seed, 8)
        self.large = mi.sample_tea_float32(self.lane + self.key0, self.key1 ^ 0x9E3779B9, 8) < self.p_large
        return self.large

    def _proposal(self, index, u, large, dim):
        # Per coordinate: the small step's size and sign and a large-step value, from one cheap
        # hash of (coordinate, step key); TEA is kept for the per-chain decisions.
        v0 = _mix32(_mix32(index ^ self.key0) + self.key1)
        v1 = _mix32(v0 ^ 0x9E3779B9)
        s = self.s1 * dr.exp(self.log_ratio * _unit(v0))
        if self.ping_dim is not None:
            s = dr.select(dim == self.ping_dim, s * self.ping_step, s)
        moved = u + dr.select((v0 & 1) == 0, s, -s)
        moved -= dr.floor(moved)
        return dr.select(large, _unit(v1), moved)

    def get(self, dim):
        index = self.lane * self.dims + mi.UInt32(dim)
        return self._proposal(index, dr.gather(mi.Float, self.U, index), self.large, dim)

    def get2(self, dim):
        return mi.Point2f(self.get(dim), self.get(mi.UInt32(dim) + 1))

    def accept(self, a):
        """Draw each chain's acceptance with probability ``a``; move the accepted chains' ``U``."""
        accept = mi.sample_tea_float32(self.lane + self.key0, self.key1 ^ 0x27D4EB2F, 8) < a
        moving = dr.gather(mi.Bool, accept, self.e_lane)
        self.U = dr.select(moving, self._proposal(self.elem, self.U, dr.gather(mi.Bool, self.large, self.e_lane),
                                                  self.e_dim), self.U)
        return accept


class _Context:
    """One render's `PathSetup` and the per-bounce records of its path evaluations."""

    def __init__(self, integrator, setup: PathSetup, hard_only=False):
        self.integrator, self.setup = integrator, setup
        self.hard_only = hard_only
        self.sensor, self.depth, self.depth_o, self.bins = setup.sensor, setup.depth, setup.depth_o, setup.bins

    def trace(self, samples, ping, lane, f, bins, vals):
        """Trace one path per lane; add its in-window echo energy to ``f[lane]`` and, when
        ``bins``/``vals`` are given, record each bounce's bin and energy at ``lane * depth + k``."""
        window, depth = self.bins, self.depth

        hard_only = self.hard_only

        def record(k, rng, energy, valid, hit, hard=None):
            b, valid = window.index(rng, valid)
            if hard_only:
                valid &= hard
            # Each lane adds only to its own total: no conflicts. Left to Auto, Dr.Jit would
            # expand f into one copy per thread with its size written into the kernel, which
            # recompiles the bootstrap at every new spp and adds a reduction pass.
            dr.scatter_add(f, energy, lane, valid, mode=dr.ReduceMode.NoConflicts)
            if bins is not None:
                slot = lane * depth + k
                dr.scatter(bins, b, slot, valid)
                dr.scatter(vals, energy, slot, valid)

        self.integrator.sample(tagging_hard(self.setup) if hard_only else self.setup, ping, samples, record)

    def records(self, n):
        """Zeroed path totals and per-bounce (bin, energy) records for ``n`` lanes."""
        return (dr.zeros(mi.Float, n), dr.zeros(mi.UInt32, n * self.depth),
                dr.zeros(mi.Float, n * self.depth))

    def evaluate(self, samples, ping, lane):
        f, bins, vals = self.records(dr.width(lane))
        self.trace(samples, ping, lane, f, bins, vals)
        return f, bins, vals

    def owner(self, n_records):
        """Lane and bounce of each record slot ``lane * depth + k`` of ``n_records``."""
        lane = dr.arange(mi.UInt32, n_records) // self.depth_o
        return lane, dr.arange(mi.UInt32, n_records) - lane * self.depth_o

    def splat(self, hist, bins, vals, weight, ping, active):
        rec_lane, _ = self.owner(dr.width(bins))
        w = dr.gather(mi.Float, weight, rec_lane)
        p = dr.gather(mi.UInt32, ping, rec_lane)
        ok = (vals > 0) & dr.gather(mi.Bool, active, rec_lane)
        hist.reserve(dr.width(bins))
        hist.add(vals * w, self.bins.flat(p, bins), ok)


register_plugin("integrator", "sonar_mlt", SonarMLTIntegrator)
