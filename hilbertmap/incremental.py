"""``IncrementalHilbertMap``: a Hilbert map learnt ping by ping along a survey, in bounded memory.

The map of :class:`~hilbertmap.HilbertMap` fixes its inducing points at the first fit and whitens
the features with an ``n x n`` eigen-decomposition: fine for one station, not for a vehicle that
keeps moving into water it has not seen. This estimator keeps the same logit

    f(x) = sum_j a_j k(x, nu_j) + b,    k(x, nu) = exp(-|x - nu|^2 / (2 l^2))  (cut below kernel_cut)

but learns the kernel coefficients ``a_j`` directly (thesis eq. 4.2 without the Nystroem whitening,
as the sparse-feature Hilbert maps of Ramos and Ott 2016), so nodes can be added and removed at
any time:

- **Nodes where data arrives.** The nodes ``nu_j`` sit on a lattice of pitch ``node_spacing``.
  Each scan adds the lattice cells holding a point of a full bin's group (an echo), dilated by
  ``node_margin`` cells (the water just in front of a wall needs nodes to become free there).
  Open water far from any echo has no node: its probability is the intercept's, which the free
  samples push low. New nodes join the kernel grid in batches (once they are 5 % of the nodes in
  it, or 8 scans on); until then they hold a zero coefficient.
- **Per-ping poses.** Samples are placed with each row's own pose ``scan.poses[k]``
  (:mod:`hilbertmap.embedding`), so a mechanical sweep smeared over metres of motion maps where
  each ping actually looked.
- **Learning.** Mini-batch AdaGrad on the logistic loss with an l2 penalty ``alpha/2 |a|^2``:
  ``G_j += g_j^2; a_j -= eta0 g_j / (sqrt(G_j) + 1e-8)`` with ``g_j = sum_i c_i (p_i - y_i)
  k(x_i, nu_j) / sum_i c_i + alpha a_j`` (Duchi, Hazan and Singer 2011). Per-coordinate steps
  need no global schedule, so a node seen for the first time late in the survey learns as fast
  as the first ones did. Samples whose kernel support holds no node only update the intercept.
- **Bounded memory; forgetting rule.** At most ``max_nodes`` nodes. When a scan would exceed it,
  the nodes least recently *used* (touched by a training sample's kernel) are dropped, oldest
  first, down to ``(1 - FORGET_SHARE) max_nodes`` (95 %: a slice at once rather than a few nodes
  every scan, since each forgetting rebuilds the kernel grid and the region seen; at the cap this
  was most of a multibeam scan's cost): the map forgets the places the vehicle left longest ago, which then
  read as the prior (the intercept). The region-seen voxels are pruned to the kept nodes' reach
  and the ping records (for :meth:`insonified`) to the last ``max_pings_kept``; memory is then
  ``O(max_nodes + max_pings_kept)`` whatever the survey's length.

``fit(scans)`` is the batch version on the same pings (nodes from all of them, ``n_passes``
shuffled passes); ``partial_fit(scan)`` is the online one (``partial_passes`` passes over that
scan's samples). Queries (``predict_proba``, ``surface``, ``slice``, ``insonified``) are those of
:class:`~hilbertmap.HilbertMap`.
"""
from __future__ import annotations

import inspect
import math
import time

import numpy as np

from . import sgd
from ._backend import LatticeGrid, cut_radius
from ._checks import CHOICES, check_coverage_params, check_echo_params, check_pass_params, int_param, need, num_param
from .embedding import Samples
from .inducing import Coverage, LazyCoverage, sorted_unique
from .model import HilbertMap, _unique_rows, embed_with
from .scanlike import as_scan_list, check_scan

__all__ = ["IncrementalHilbertMap"]

_OFFSET = 1 << 20  # lattice indices in [-2^20, 2^20) per axis
REBUILD_SHARE = 0.05  # new nodes join the kernel grid once they are this share of those in it ...
REBUILD_SCANS = 8     # ... or this many scans after the last rebuild
FORGET_SHARE = 0.05   # the forgetting rule drops nodes down to (1 - FORGET_SHARE) max_nodes


def _keys(idx: np.ndarray) -> np.ndarray:
    i = idx.astype(np.int64) + _OFFSET
    return (i[:, 0] << 42) | (i[:, 1] << 21) | i[:, 2]


def _unkey(keys: np.ndarray) -> np.ndarray:
    m = (1 << 21) - 1
    return np.stack([(keys >> 42) & m, (keys >> 21) & m, keys & m], axis=1) - _OFFSET


class IncrementalHilbertMap(HilbertMap):
    """Hilbert map learnt incrementally along a survey (see the module docstring).

    Parameters
    ----------
    node_spacing : float > 0, default 0.15
        Lattice pitch of the nodes (metres).
    lengthscale_factor : float > 0, default 1.0
        Kernel length ``l = lengthscale_factor * node_spacing``.
    node_margin : int >= 0, default 2
        Lattice cells around every echo point that get a node.
    max_nodes : int >= 1, default 200000
        The cap on nodes (forgetting rule above: once over it, down to 95 % of it). 200000 nodes
        take about 10 MB.
    max_pings_kept : int >= 0, default 100000
        Ping records kept for :meth:`insonified` (most recent first).
    eta0 : float > 0, default 0.1
        AdaGrad step.
    kernel_cut : float in (0, 1), default 1e-2
        Kernel values below this are zero (support radius ``l sqrt(2 ln(1/kernel_cut))``).
    alpha : float >= 0, default 1e-4
        l2 strength on the coefficients.
    n_passes, partial_passes : int >= 1, default 3, 1
        Passes of ``fit`` over all samples, of ``partial_fit`` over one scan's.

    max_free_per_ping, near_free, occupied_samples : int or 'auto', default 'auto'
        The sampling budget of each scan (see :class:`~hilbertmap.HilbertMap`); ``'auto'`` takes
        it from the scan's ``kind``: 24 / 8 / 8 for a multibeam frame (about 26 training lanes a
        beam: fast enough for a 256-beam head at 10 Hz), 400 / 32 / 16 for the other kinds.
        On the harbour survey's multibeam (100 frames) the light budget gives the same AUC (0.951
        against 0.950), near-wall AUC 0.914 against 0.919, ridge F-score at 0.1 m 0.26 against
        0.085, but a ridge with more false surface (its mean distance to the walls 0.90 m against
        0.19 m); pass numbers to choose otherwise.

    source ... beam_stride, occupied_weight, coverage_voxel, max_free_per_voxel, max_groups_per_voxel, batch_size, fit_intercept, random_state, variant
        The other embedding and thinning parameters, ``batch_size``, ``fit_intercept``,
        ``random_state`` and ``variant`` are those of :class:`~hilbertmap.HilbertMap`.

    Attributes
    ----------
    inducing_points_ (n, 3), dual_coef_ (n,), intercept_, lengthscale_ : the map.
    node_keys_ (n,) int64 lattice keys; node_last_used_ (n,) scan counter of the last use;
        ``node_accum_`` (n,) AdaGrad's sums of squared gradients.
    n_scans_seen_, n_pings_seen_, n_samples_seen_, n_forgotten_ : counts.
    track_ (T, 3) : transducer positions of the pings (at most ``max_pings_kept``).
    timings_ : seconds of the last fit / partial_fit (``embed_s``, ``nodes_s``, ``sgd_s``, ``total_s``).
    """

    def __init__(self, node_spacing=0.15, *, lengthscale_factor=1.0, node_margin=2, max_nodes=200_000,
                 max_pings_kept=100_000, eta0=0.1, kernel_cut=1e-2, alpha=1e-4, source="auto",
                 bin_rule="otsu+cfar", threshold=None, min_level=None, cfar_train=16, cfar_guard=2,
                 cfar_offset=None, blanking="auto", min_echo_bins=4, free_density=40.0,
                 max_free_per_ping="auto", free_margin=0.0, near_free="auto", near_depth=0.3, occupied_samples="auto",
                 occupied_bins="first_run",
                 max_run=0.3, occupied_weight=5.0, beam_sampling="pattern", beam_extent=1.0, beam_stride=1,
                 batch_size=4096, n_passes=3, partial_passes=1, fit_intercept=True, coverage_voxel=0.25,
                 max_free_per_voxel=12, max_groups_per_voxel=2, random_state=None, variant="llvm"):
        args = locals()
        for name in self._get_param_names():
            setattr(self, name, args[name])

    def __repr__(self) -> str:
        return super().__repr__().replace("HilbertMap(", "IncrementalHilbertMap(", 1)

    # -- checks ------------------------------------------------------------------------------
    def _check(self) -> None:
        for name in ("source", "bin_rule", "occupied_bins", "beam_sampling", "variant"):
            v = getattr(self, name)
            need(name, v, isinstance(v, str) and v in CHOICES[name], "one of " + ", ".join(map(repr, CHOICES[name])))
        num_param("node_spacing", self.node_spacing, 0, lo_open=True)
        num_param("lengthscale_factor", self.lengthscale_factor, 0, lo_open=True)
        int_param("node_margin", self.node_margin, 0)
        int_param("max_nodes", self.max_nodes, 1)
        int_param("max_pings_kept", self.max_pings_kept, 0)
        num_param("eta0", self.eta0, 0, lo_open=True)
        num_param("kernel_cut", self.kernel_cut, 0, 1, lo_open=True, hi_open=True)
        num_param("alpha", self.alpha, 0)
        check_echo_params(self)
        num_param("occupied_weight", self.occupied_weight, 0, lo_open=True)
        num_param("beam_extent", self.beam_extent, 0, lo_open=True)
        num_param("beam_stride", self.beam_stride, 1)
        check_pass_params(self)
        check_coverage_params(self)

    def embed(self, scan, rng=None) -> Samples:
        """Labelled samples of one scan (each row at its own pose), after :func:`check_scan`: the
        batch map's embedding, with this estimator's own settings checked first."""
        self._check()
        check_scan(scan, self.source)
        return embed_with(self, scan, rng)

    # -- training ----------------------------------------------------------------------------
    def fit(self, scans, samples: Samples | None = None) -> "IncrementalHilbertMap":
        """Batch fit on all pings of ``scans`` (nodes from all, ``n_passes`` shuffled passes)."""
        t0 = time.perf_counter()
        self._check()
        scans = as_scan_list(scans, self.source) if samples is None else []
        rng = np.random.default_rng(self.random_state)
        if samples is None:
            samples = Samples.concatenate([self.embed(s, rng) for s in scans])
        self._reset()  # only once every scan is known good: a refused one leaves the map as it was
        self._rng = rng
        samples = self._thin(samples)
        if len(samples.free) + len(samples.occupied) == 0:
            raise ValueError("HilbertMap: the scans gave no samples (no pings, or all bins blanked)")
        t1 = time.perf_counter()
        self._record(samples)
        self._grow(samples)
        t2 = time.perf_counter()
        self.loss_curve_ = [self._pass(samples) for _ in range(int(self.n_passes))]
        self.n_scans_seen_ += len(scans)
        t3 = time.perf_counter()
        self.timings_ = dict(embed_s=t1 - t0, nodes_s=t2 - t1, sgd_s=t3 - t2, total_s=t3 - t0)
        return self

    def partial_fit(self, scan, samples: Samples | None = None) -> "IncrementalHilbertMap":
        """Learn one more scan (or its ``samples``): new nodes where it saw echoes, the forgetting
        rule if the cap is reached, then ``partial_passes`` passes over its samples."""
        t0 = time.perf_counter()
        self._check()
        fresh = not hasattr(self, "dual_coef_")
        rng = np.random.default_rng(self.random_state) if fresh else self._rng
        if samples is None:
            samples = self.embed(scan, rng)
        if fresh:  # after the scan's checks: a refused first scan leaves the estimator unfitted
            self._reset()
            self._rng = rng
        samples = self._thin(samples)
        t1 = time.perf_counter()
        self._record(samples)
        self._grow(samples)
        t2 = time.perf_counter()
        if len(samples.free) + len(samples.occupied):
            for _ in range(int(self.partial_passes)):
                self.loss_curve_.append(self._pass(samples))
        self.n_scans_seen_ += 1
        t3 = time.perf_counter()
        self.timings_ = dict(embed_s=t1 - t0, nodes_s=t2 - t1, sgd_s=t3 - t2, total_s=t3 - t0)
        return self

    def _reset(self) -> None:
        self._rng = np.random.default_rng(self.random_state)
        self.lengthscale_ = float(self.lengthscale_factor) * float(self.node_spacing)
        self.gamma_ = 1.0 / (2.0 * self.lengthscale_ ** 2)
        self.occupied_weight_ = float(self.occupied_weight)
        self.node_keys_ = np.zeros(0, dtype=np.int64)
        self.inducing_points_ = np.zeros((0, 3))
        self.dual_coef_ = np.zeros(0)
        self.node_accum_ = np.zeros(0)
        self.node_last_used_ = np.zeros(0, dtype=np.int64)
        self.intercept_ = 0.0
        self._b_accum = 0.0
        self.coverage_ = LazyCoverage(self.coverage_voxel)
        self.echo_coverage_ = LazyCoverage(self.coverage_voxel)
        self.free_coverage_ = LazyCoverage(self.coverage_voxel)
        self.ping_frames_ = np.zeros((0, 4, 4), dtype=np.float32)
        self.ping_beams_ = np.zeros((0, 3), dtype=np.float32)
        self.ping_spans_ = np.zeros((0, 3), dtype=np.float32)
        self.track_ = np.zeros((0, 3))
        self.n_scans_seen_ = 0
        self.n_pings_seen_ = 0
        self.n_samples_seen_ = 0
        self.n_forgotten_ = 0
        self.t_ = 0.0
        self.loss_curve_ = []
        self._grid = None
        self._scans_since_build = 0

    def _record(self, s: Samples) -> None:
        """The region seen and the ping records (the latter capped at ``max_pings_kept``)."""
        occ = s.occupied.reshape(-1, 3)
        self.coverage_.add(s.free)
        self.coverage_.add(occ)
        self.echo_coverage_.add(occ)
        self.free_coverage_.add(s.free)
        keep = int(self.max_pings_kept)
        cat = lambda a, b: np.concatenate([a, b.astype(a.dtype)])[-keep:] if keep else a[:0]  # noqa: E731
        self.ping_frames_ = cat(self.ping_frames_, s.frames)
        self.ping_beams_ = cat(self.ping_beams_, s.beams)
        self.ping_spans_ = cat(self.ping_spans_, s.spans)
        self.track_ = cat(self.track_, s.origins)
        self.n_pings_seen_ += len(s.frames)

    def _grow(self, s: Samples) -> None:
        """Nodes at the lattice cells of the echoes, dilated by ``node_margin``; then the cap."""
        h = float(self.node_spacing)
        occ = s.occupied.reshape(-1, 3)
        if len(occ):
            base = sorted_unique(_keys(np.floor(occ / h).astype(np.int64)))
            r = int(self.node_margin)
            offs = np.stack(np.meshgrid(*[np.arange(-r, r + 1)] * 3, indexing="ij"), -1).reshape(-1, 3)
            offs = offs[np.sum(offs ** 2, axis=1) <= r * r + 1e-9]  # a ball of cells, not a cube
            idx = _unkey(base)
            cand = sorted_unique(_keys((idx[:, None, :] + offs[None, :, :]).reshape(-1, 3)))
            known = self._sorted_keys()
            pos = np.minimum(np.searchsorted(known, cand), max(len(known) - 1, 0))
            new = cand[known[pos] != cand] if len(known) else cand
        else:
            new = np.zeros(0, dtype=np.int64)
        if len(new):
            stamp = self.n_scans_seen_
            self.node_keys_ = np.concatenate([self.node_keys_, new])
            # keep the sorted copy sorted: new keys inserted where they belong (O(n), no sort)
            self._keys_sorted = (self.node_keys_, np.insert(known, np.searchsorted(known, new), new))
            self.inducing_points_ = np.concatenate([self.inducing_points_, (_unkey(new) + 0.5) * h])
            self.dual_coef_ = np.concatenate([self.dual_coef_, np.zeros(len(new))])
            self.node_accum_ = np.concatenate([self.node_accum_, np.zeros(len(new))])
            self.node_last_used_ = np.concatenate([self.node_last_used_, np.full(len(new), stamp, dtype=np.int64)])
        cap = int(self.max_nodes)
        over = len(self.node_keys_) - cap
        if over > 0:
            self._forget(min(over + int(FORGET_SHARE * cap), len(self.node_keys_)))
        built = self._grid.n if self._grid is not None else 0
        self._scans_since_build += 1
        pending = len(self.node_keys_) - built
        # New nodes join the kernel grid in batches (rebuilding it costs a sort of every node):
        # once they are REBUILD_SHARE of the nodes built, or REBUILD_SCANS scans after the last
        # rebuild. Until then they hold a zero coefficient and this scan trains the nodes built;
        # a survey's next scans see the same places again.
        if over > 0 or self._grid is None or (pending and (pending >= REBUILD_SHARE * built
                                                            or self._scans_since_build >= REBUILD_SCANS)):
            self._rebuild()

    def _sorted_keys(self) -> np.ndarray:
        """``node_keys_`` sorted (for the lookup of a scan's cells among the nodes): kept up to date
        by :meth:`_grow`, sorted anew whenever ``node_keys_`` was replaced otherwise (forgetting,
        loading)."""
        cached = getattr(self, "_keys_sorted", None)
        if cached is None or cached[0] is not self.node_keys_:
            cached = self._keys_sorted = (self.node_keys_, np.sort(self.node_keys_))
        return cached[1]

    def _forget(self, n: int) -> None:
        """Drop the ``n`` least recently used nodes (ties: the oldest added first) and the
        region-seen voxels no kept node reaches."""
        order = np.argsort(self.node_last_used_, kind="stable")
        keep = np.ones(len(self.node_keys_), dtype=bool)
        keep[order[:n]] = False
        for name in ("node_keys_", "inducing_points_", "dual_coef_", "node_accum_", "node_last_used_"):
            setattr(self, name, getattr(self, name)[keep])
        self.n_forgotten_ += int(n)
        # the voxels of the kept nodes dilated by one voxel, marked once on a dense grid over
        # their box: a region-seen voxel is kept when it is marked (the same as a node's voxel
        # lying within one voxel of it)
        reach = Coverage(self.coverage_voxel)
        reach.add(self.inducing_points_)
        idx = reach._idx(reach.keys)
        lo = idx.min(axis=0) - 1 if len(idx) else np.zeros(3, dtype=np.int64)
        shape = idx.max(axis=0) - lo + 2 if len(idx) else np.ones(3, dtype=np.int64)
        if np.prod(shape) <= 1 << 26:
            from scipy.ndimage import binary_dilation

            mark = np.zeros(tuple(shape), dtype=bool)
            mark[tuple((idx - lo).T)] = True
            mark = binary_dilation(mark, structure=np.ones((3, 3, 3), dtype=bool))

            def kept(keys):
                c = reach._idx(keys) - lo
                ok = np.all((c >= 0) & (c < shape), axis=1)
                c = np.where(ok[:, None], c, 0)
                return ok & mark[c[:, 0], c[:, 1], c[:, 2]]
        else:
            def kept(keys):
                return reach.contains(reach._idx(keys) * reach.voxel + 0.5 * reach.voxel, dilate=1)
        for name in ("coverage_", "echo_coverage_", "free_coverage_"):
            cov = getattr(self, name)
            k = cov.keys
            setattr(self, name, LazyCoverage(cov.voxel, k[kept(k)] if len(k) and len(idx) else k[:0]))

    def _rebuild(self) -> None:
        """The kernel grid of the current nodes: a :class:`~hilbertmap._backend.LatticeGrid` (the
        nodes sit on the lattice of pitch ``node_spacing``: a point's lattice cell gives its
        neighbouring nodes directly, no search)."""
        self._scans_since_build = 0
        if len(self.inducing_points_) == 0:
            self._grid = None
            return
        self._grid = LatticeGrid(_unkey(self.node_keys_), float(self.node_spacing), self.lengthscale_,
                                 float(self.kernel_cut), self.variant)

    def _near(self, pts: np.ndarray) -> np.ndarray:
        """Whether a node may lie within the kernel's support of each point (a superset:
        :meth:`~hilbertmap._backend.LatticeGrid.near`)."""
        g = self._grid
        if g is None or len(pts) == 0:
            return np.zeros(len(pts), dtype=bool)
        return g.near(pts)

    def _pass(self, s: Samples) -> float:
        """One shuffled pass of mini-batch AdaGrad; the mean weighted loss seen."""
        return self._pass_inner(s)

    def _pass_inner(self, s: Samples) -> float:
        """The mini-batches in order. Per batch: the logits of the lanes that have nodes near
        (one Dr.Jit kernel, lanes sorted by lattice brick for cache locality; the result does not
        depend on their order), the loss and per-sample gradients in numpy, the kernel's adjoint
        into the nodes and the AdaGrad step of the touched nodes (Dr.Jit, float32, in place: the
        coefficients stay on the Dr.Jit side for the whole pass)."""
        import drjit as dr

        F, G = len(s.free), len(s.occupied)
        m = s.occupied.shape[1] if G else 1
        nb = max(1, int(math.ceil((F + G * m) / int(self.batch_size))))
        pf = np.array_split(self._rng.permutation(F), nb)
        pg = np.array_split(self._rng.permutation(G), nb)
        grid = self._grid
        n = grid.n if grid is not None else 0  # the nodes built (newer ones wait, coefficient 0)
        near_f = self._near(s.free)
        near_g = self._near(s.occupied.reshape(-1, 3)).reshape(G, m).any(axis=1) if G else np.zeros(0, bool)
        if grid is not None:
            key_f = grid.sort_keys(s.free)
            key_g = grid.sort_keys(s.occupied[:, 0]) if G else np.zeros(0, dtype=np.int64)
            coef = grid.upload(self.dual_coef_[:n])
            accum = grid.upload(self.node_accum_[:n])
            pool = grid.pooled(coef)
            used = dr.zeros(grid.mod.Bool, n)
            alpha_dr = dr.opaque(grid.Float, float(self.alpha))
            eta_dr = dr.opaque(grid.Float, float(self.eta0))
        c_occ = self.occupied_weight_
        eta = float(self.eta0)
        loss_sum = wsum = 0.0
        for b in range(nb):
            i_f, i_g = pf[b], pg[b]
            bf, bg = len(i_f), len(i_g)
            if bf + bg == 0:
                continue
            f_free = np.full(bf, self.intercept_)
            f_grp = np.full(bg, self.intercept_)
            jf, jg = np.nonzero(near_f[i_f])[0], np.nonzero(near_g[i_g])[0]
            lanes = None
            if grid is not None and len(jf) + len(jg):
                jf = jf[np.argsort(key_f[i_f[jf]], kind="stable")]
                jg = jg[np.argsort(key_g[i_g[jg]], kind="stable")]
                lanes = np.concatenate([s.free[i_f[jf]], s.occupied[i_g[jg]].reshape(-1, 3)])
                x, y, z = grid.to_lanes(lanes)
                fl = grid.kernel_sum(x, y, z, pool, pooled=True).numpy().astype(np.float64)
                f_free[jf] += fl[:len(jf)]
                f_grp[jg] += fl[len(jf):].reshape(len(jg), m).mean(axis=1)
            f = np.concatenate([f_free, f_grp])
            yv = np.concatenate([np.zeros(bf), np.ones(bg)])
            c = np.concatenate([np.ones(bf), np.full(bg, c_occ)])
            csum = c.sum()
            loss_sum += float(np.sum(c * np.logaddexp(0.0, -(2 * yv - 1) * f)))
            wsum += csum
            g = c * (sgd.sigmoid(f) - yv) / csum
            if lanes is not None:
                g_lane = np.concatenate([g[jf], np.repeat(g[bf + jg] / m, m)]).astype(np.float32)
                gj = grid.kernel_scatter(x, y, z, grid.upload(g_lane), dr.zeros(grid.Float, n))
                touched = gj != 0
                gj = gj + alpha_dr * coef
                accum = dr.select(touched, dr.fma(gj, gj, accum), accum)
                coef = dr.select(touched, coef - eta_dr * gj / (dr.sqrt(accum) + 1e-8), coef)
                grid.update_pooled(pool, coef, touched)
                used = used | touched
                dr.eval(coef, accum, pool, used)
            if self.fit_intercept:
                gb = float(g.sum())
                self._b_accum += gb * gb
                self.intercept_ -= eta * gb / (math.sqrt(self._b_accum) + 1e-8)
            self.t_ += bf + bg
            self.n_samples_seen_ += bf + bg
        if grid is not None:
            self.dual_coef_[:n] = coef.numpy()
            self.node_accum_[:n] = accum.numpy()
            self.node_last_used_[:n][used.numpy()] = self.n_scans_seen_
        return loss_sum / max(wsum, 1e-300)

    # -- queries -------------------------------------------------------------------------------
    def decision_function(self, points, chunk: int = 1 << 20) -> np.ndarray:
        """Logit ``f(x) = sum_j a_j k(x, nu_j) + b`` at (N, 3) world points (no side effects).

        Points go to the kernel in chunks of ``chunk``, each sorted by lattice brick (neighbouring
        lanes read the same nodes: :meth:`~hilbertmap._backend.LatticeGrid.kernel_sum_at`); a point
        no node reaches reads only the empty block and gets ``b``."""
        from ._checks import as_points

        self._check_fitted()
        pts = as_points(points)
        out = np.full(len(pts), self.intercept_, dtype=np.float64)
        grid = self._grid if getattr(self, "_grid", None) is not None else None
        if grid is None and len(self.inducing_points_):
            self._rebuild()
            grid = self._grid
        if grid is None:
            return out
        pool = grid.pooled(grid.upload(self.dual_coef_[:grid.n]))  # nodes not yet built hold 0
        for a in range(0, len(pts), chunk):
            out[a:a + chunk] += grid.kernel_sum_at(pts[a:a + chunk], pool, pooled=True)
        return out

    @property
    def sensor_positions_(self) -> np.ndarray:
        """(S, 3) the distinct transducer positions of the kept pings (from ``track_``)."""
        return _unique_rows(self.track_) if hasattr(self, "track_") else np.zeros((0, 3))

    @property
    def support_radius_(self) -> float:
        """Distance at which a node's kernel is cut (m)."""
        return cut_radius(self.lengthscale_, float(self.kernel_cut))

    # -- persistence -------------------------------------------------------------------------
    def save(self, path) -> None:
        """Write the map to ``.npz`` (format ``hilbertmap-incremental/1``, :mod:`hilbertmap.incremental_io`)."""
        from . import incremental_io

        incremental_io.save(self, path)

    @classmethod
    def load(cls, path) -> "IncrementalHilbertMap":
        """Read a map written by :meth:`save`; anything else is refused with a ValueError naming
        the file and what is wrong, and no object is returned."""
        from . import incremental_io

        return incremental_io.load(cls, path)

    @classmethod
    def _get_param_names(cls) -> list:
        return [p for p in inspect.signature(cls.__init__).parameters if p != "self"]
