"""The ``sonar_mlt`` integrator: primary-sample-space Metropolis transport for sonar echoes."""
from __future__ import annotations

import math

import drjit as dr
import mitsuba as mi
import numpy as np

from .echo_path import ArraySamples, HashSamples, n_dims, trace_echoes
from .range_bins import RangeBins
from .sonar_sensor import PingFrames
from .sonar_tof import SonarIntegrator, check_max_depth, resolve_sensor

# Salts that keep the random streams of the stages apart for one user seed.
_SALT_BOOT, _SALT_MUT, _SALT_START = 0x5EED0001, 0x5EED0002, 0x5EED0003


class SonarMLTIntegrator(SonarIntegrator):
    r"""Primary-sample-space Metropolis light transport (Kelemen et al. 2002) for sonar.

    The target of a path is the sum of its per-bounce echo energies that land in the range
    window: ``f(U) = sum_k e_k(U)``, with ``U`` the primary-sample vector of the echo path that
    ``sonar_tof`` traces (the same function, `echo_path.trace_echoes`). For every ping:

    1. a bootstrap of uniform paths estimates the normalisation ``b = E[f]``;
    2. chains start from bootstrap paths resampled in proportion to ``f``;
    3. each mutation is a large step (a fresh uniform ``U``) with probability ``large_step``, else a
       Kelemen small step (every coordinate moved by ``+-s``, ``s`` log-uniform between
       ``small_step_min`` and ``small_step_max``, wrapped into [0, 1));
    4. expected-value splatting: the proposed path adds ``a e_k / f`` and the current one
       ``(1 - a) e_k / f`` to each bounce's own range bin, scaled by ``b / (chains mutations)``.

    All chains of all pings run in one wavefront; every quantity that changes between
    mutations or renders is opaque, so a render compiles its kernels once.

    ================ ======== =================================================================
    Parameter        Default  Meaning
    ================ ======== =================================================================
    max_depth        5        surface bounces per path (1 = single bounce)
    chains           0        chains per ping; 0 chooses about 2^16 chains in all (at least 32
                              and at most spp/16 per ping)
    mutations        0        mutations per chain; 0 spends the ``spp`` budget
    large_step       0.3      probability of a large step
    small_step_min   1/1024   smallest small-step size (Kelemen's s1)
    small_step_max   1/64     largest small-step size (Kelemen's s2)
    bootstrap        0        bootstrap paths per ping; 0 takes 10 % of ``spp`` (at least 4x chains)
    ================ ======== =================================================================

    ``spp`` counts path evaluations per ping (bootstrap plus chains x mutations), so equal
    ``spp`` means about equal work for ``sonar_tof`` and ``sonar_mlt``.
    """

    def __init__(self, props: mi.Properties):
        super().__init__(props)
        self.max_depth = check_max_depth(props.get("max_depth", 5), "sonar_mlt")
        self.chains = int(props.get("chains", 0))
        self.mutations = int(props.get("mutations", 0))
        self.large_step = float(props.get("large_step", 0.3))
        self.small_step_min = float(props.get("small_step_min", 1.0 / 1024.0))
        self.small_step_max = float(props.get("small_step_max", 1.0 / 64.0))
        self.bootstrap = int(props.get("bootstrap", 0))
        self._check()

    def _check(self):
        def bad(name, value, allowed):
            raise ValueError(f"sonar_mlt '{name}': {value!r} is not allowed ({allowed})")
        if self.chains < 0:
            bad("chains", self.chains, "0 for automatic, or a positive number of chains per ping")
        if self.mutations < 0:
            bad("mutations", self.mutations, "0 to spend spp, or a positive number per chain")
        if self.bootstrap < 0:
            bad("bootstrap", self.bootstrap, "0 for automatic, or a positive number of paths per ping")
        if not 0.0 <= self.large_step <= 1.0:
            bad("large_step", self.large_step, "a probability in [0, 1]")
        if not 0.0 < self.small_step_min <= self.small_step_max < 0.5:
            bad("small_step_min/small_step_max", (self.small_step_min, self.small_step_max),
                "0 < small_step_min <= small_step_max < 0.5")

    # ------------------------------------------------------------------ budget
    def plan(self, n_pings, spp):
        """(bootstrap paths, chains, mutations) per ping for a budget of ``spp`` path evaluations."""
        spp = int(spp)
        if spp < 1:
            raise ValueError(f"spp must be a positive number of paths per ping, got {spp}")
        chains = self.chains or int(np.clip((1 << 16) // n_pings, 32, max(32, spp // 16)))
        boot = self.bootstrap or max(4 * chains, spp // 10)
        mutations = self.mutations or max(1, (spp - boot) // chains)
        return boot, chains, mutations

    # ------------------------------------------------------------------ rendering
    def render_histogram(self, scene, sensor=0, seed=0, spp=4096, pose=None, max_depth=None, progress=None):
        """Mean echo energy per bin, float64 ``(n_pings, n_bins)`` (same units as ``sonar_tof``)."""
        sensor = resolve_sensor(scene, sensor)
        depth = check_max_depth(self.max_depth if max_depth is None else int(max_depth), "sonar_mlt")
        n_pings, n_bins = sensor.n_pings, sensor.n_bins
        boot, chains, mutations = self.plan(n_pings, spp)
        self.last_plan = {"bootstrap": boot, "chains": chains, "mutations": mutations}
        frames = PingFrames(sensor.ping_poses(pose))
        dims = n_dims(depth)
        ctx = _Context(scene, sensor, frames, depth, n_pings * chains)
        seed = int(seed) & 0xFFFFFFFF

        with dr.suspend_grad():
            # 1. Bootstrap: f of uniform paths, per ping.
            lanes = n_pings * boot
            lane = dr.arange(mi.UInt32, lanes)
            boot_o = dr.opaque(mi.UInt32, boot)
            ping = lane // boot_o
            f_boot = dr.zeros(mi.Float, lanes)
            ctx.trace(HashSamples(dr.opaque(mi.UInt32, seed ^ _SALT_BOOT), ping, lane - ping * boot_o),
                      ping, lane, f_boot, None, None)
            f_boot = f_boot.numpy().astype(np.float64).reshape(n_pings, boot)
            norm = f_boot.mean(axis=1)  # b per ping

            # 2. Start states resampled in proportion to f (pings without echoes get none).
            rng = np.random.default_rng([seed, _SALT_START])
            start = np.zeros((n_pings, chains), dtype=np.uint32)
            for p in range(n_pings):
                if norm[p] > 0:
                    start[p] = rng.choice(boot, size=chains, p=f_boot[p] / f_boot[p].sum())
            n = n_pings * chains
            chain_ping = np.repeat(np.arange(n_pings, dtype=np.uint32), chains)
            elem = dr.arange(mi.UInt32, n * dims)
            dims_o = dr.opaque(mi.UInt32, dims)
            e_lane = elem // dims_o
            e_dim = elem - e_lane * dims_o
            ping_c = mi.UInt32(chain_ping)
            idx_c = mi.UInt32(start.ravel())
            hs = HashSamples(dr.opaque(mi.UInt32, seed ^ _SALT_BOOT), dr.gather(mi.UInt32, ping_c, e_lane),
                             dr.gather(mi.UInt32, idx_c, e_lane))
            U = hs.get(e_dim)
            lane_c = dr.arange(mi.UInt32, n)
            f_cur, bins_cur, vals_cur = ctx.evaluate(U, ping_c, lane_c, dims)
            active_ping = mi.Bool(norm[chain_ping] > 0)
            # Each accepted/rejected pair of splats carries b / (chains * mutations), with b the
            # mean f of the very bootstrap the start states were drawn from: that pairing makes the
            # estimate unbiased at any chain length (Veach 1997, 11.3.3), start-up bias included.
            scale = dr.opaque(mi.Float, 1.0 / (chains * mutations))
            hist = dr.zeros(mi.Float64, n_pings * n_bins)
            dr.eval(U, f_cur, bins_cur, vals_cur, scale, hist)

            # 3-4. Mutations, one wavefront per step.
            mut_seed = dr.opaque(mi.UInt32, seed ^ _SALT_MUT)
            p_large = dr.opaque(mi.Float, self.large_step)
            s1 = dr.opaque(mi.Float, self.small_step_min)
            log_ratio = dr.opaque(mi.Float, math.log(self.small_step_max / self.small_step_min))
            for m in range(mutations):
                step = dr.opaque(mi.UInt32, m)
                key0, key1 = mi.sample_tea_32(step, mut_seed, 4)
                large = mi.sample_tea_float32(lane_c + key0, key1 ^ 0x9E3779B9, 8) < p_large
                # One TEA call per coordinate gives the step size, its sign and a large-step value.
                # Eight rounds: with four, consecutive counters gave large steps a 3 % biased mean.
                v0, v1 = mi.sample_tea_32(elem + key0, key1, 8)
                u1 = mi.Float(v0 >> 8) * (1.0 / 16777216.0)
                u3 = mi.Float(v1 >> 8) * (1.0 / 16777216.0)
                s = s1 * dr.exp(log_ratio * u1)
                moved = U + dr.select((v1 & 1) == 0, s, -s)
                moved -= dr.floor(moved)
                U_new = dr.select(dr.gather(mi.Bool, large, e_lane), u3, moved)
                f_new, bins_new, vals_new = ctx.evaluate(U_new, ping_c, lane_c, dims)
                accept_p = dr.select(f_cur > 0, dr.minimum(1.0, f_new / dr.select(f_cur > 0, f_cur, 1.0)), 1.0)
                w_new = dr.select(f_new > 0, accept_p / f_new, 0.0) * scale
                w_cur = dr.select(f_cur > 0, (1.0 - accept_p) / f_cur, 0.0) * scale
                ctx.splat(hist, bins_new, vals_new, w_new, ping_c, lane_c, active_ping)
                ctx.splat(hist, bins_cur, vals_cur, w_cur, ping_c, lane_c, active_ping)
                accept = mi.sample_tea_float32(lane_c + key0, key1 ^ 0x27D4EB2F, 8) < accept_p
                U = dr.select(dr.gather(mi.Bool, accept, e_lane), U_new, U)
                rec_accept = dr.gather(mi.Bool, accept, ctx.rec_lane)
                bins_cur = dr.select(rec_accept, bins_new, bins_cur)
                vals_cur = dr.select(rec_accept, vals_new, vals_cur)
                f_cur = dr.select(accept, f_new, f_cur)
                dr.eval(U, f_cur, bins_cur, vals_cur, hist)
                if progress is not None:
                    progress(boot + (m + 1) * chains, boot + mutations * chains)
            out = hist.numpy().reshape(n_pings, n_bins) * norm[:, None]
        return out

    def to_string(self):
        return (f"SonarMLTIntegrator[max_depth={self.max_depth}, chains={self.chains or 'auto'}, "
                f"large_step={self.large_step}]")


class _Context:
    """What one render's path evaluations share: scene, frames, bins, per-bounce records."""

    def __init__(self, scene, sensor, frames, depth, n_chains):
        self.scene, self.sensor, self.frames = scene, sensor, frames
        self.depth = depth
        self.depth_o = dr.opaque(mi.UInt32, depth)
        self.bins = RangeBins(sensor)
        self.absorption = dr.opaque(mi.Float, sensor.absorption)
        # Chain of each per-bounce record slot (lane * depth + k).
        self.rec_lane = dr.arange(mi.UInt32, n_chains * depth) // self.depth_o

    def trace(self, samples, ping, lane, f, bins, vals):
        """Trace one path per lane; add its in-window echo energy to ``f[lane]`` and, when
        ``bins``/``vals`` are given, record each bounce's bin and energy at ``lane * depth + k``."""
        window, depth = self.bins, self.depth

        def record(k, rng, energy, valid):
            b, valid = window.index(rng, valid)
            dr.scatter_add(f, energy, lane, valid)
            if bins is not None:
                slot = lane * depth + k
                dr.scatter(bins, b, slot, valid)
                dr.scatter(vals, energy, slot, valid)

        trace_echoes(self.scene, self.frames, self.sensor.beam, ping, samples, self.depth_o,
                     self.absorption, record)

    def evaluate(self, U, ping, lane, dims):
        n = dr.width(lane)
        f = dr.zeros(mi.Float, n)
        bins = dr.zeros(mi.UInt32, n * self.depth)
        vals = dr.zeros(mi.Float, n * self.depth)
        self.trace(ArraySamples(U, lane, dims), ping, lane, f, bins, vals)
        return f, bins, vals

    def splat(self, hist, bins, vals, weight, ping, lane, active):
        w = dr.gather(mi.Float, weight, self.rec_lane)
        p = dr.gather(mi.UInt32, ping, self.rec_lane)
        ok = (vals > 0) & dr.gather(mi.Bool, active, self.rec_lane)
        dr.scatter_add(hist, mi.Float64(vals * w), self.bins.flat(p, bins), ok)
