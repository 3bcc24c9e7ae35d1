"""``HilbertMap``: continuous 3-D occupancy learnt from sonar scans (thesis chapter 4).

    p(x) = sigmoid(w . phi(x) + b),   phi(x) = Lambda^(-1/2) Q^T k(x)      (eq. 4.2, 4.3)

with ``k(x)_j = exp(-|x - nu_j|^2 / (2 l^2))`` on ``n_inducing`` points ``nu_j`` and
``G = K(nu, nu) = Q Lambda Q^T``. The logit is evaluated as ``(M^T w) . k(x)`` with
``M = Lambda^(-1/2) Q^T``: a query costs only the kernel values of its neighbours (the kernel is cut
below ``kernel_cut``), and a mini-batch gradient ``M sum_i g_i k(x_i)`` costs the batch's kernel
values (Dr.Jit) plus one ``n x n`` product (BLAS); ``M^T w`` after the step is the second.

Loss: mean logistic loss with an elastic-net penalty ``alpha (l1_ratio |w|_1 + (1 - l1_ratio)/2 |w|^2)``
(eq. 4.4, 4.5) minimised by mini-batch SGD (eq. 4.10) with the schedules of
:mod:`hilbertmap.schedules`; the l1 part is applied as a proximal (soft-threshold) step.
"""
from __future__ import annotations

import json
import math
import time

import numpy as np

from . import schedules as _sched
from ._backend import KernelGrid
from .embedding import Samples, embed_scan
from .inducing import Coverage, choose_inducing, spacing

_PARAMS = dict(
    n_inducing=3000,
    inducing="kmeans",
    inducing_occupied_share=0.85,
    inducing_voxel=0.1,
    lengthscale="auto",
    lengthscale_factor=1.2,
    kernel_cut=1e-5,
    eig_floor=1e-6,
    source="auto",
    bin_rule="otsu+cfar",
    threshold=None,
    min_level=None,
    cfar_train=16,
    cfar_guard=2,
    cfar_offset=None,
    blanking="auto",
    min_echo_bins=2,
    free_density=40.0,
    max_free_per_ping=400,
    free_margin=0.0,
    near_free=32,
    near_depth=0.3,
    occupied_samples=16,
    occupied_bins="first_run",
    max_run=0.3,
    occupied_weight=5.0,
    occupied_pooling="mean",
    pooling_temperature=1.0,
    beam_sampling="pattern",
    beam_extent=1.0,
    beam_stride=1,
    alpha=1e-6,
    l1_ratio=0.15,
    schedule="thesis",
    eta0="auto",
    k1=1.0,
    t0=None,
    batch_size=2048,
    n_passes=5,
    partial_passes=1,
    fit_intercept=True,
    bounds=None,
    coverage_voxel=0.25,
    max_free_per_voxel=12,
    max_groups_per_voxel=2,
    random_state=None,
    variant="llvm",
)


# Most grid points a slice or a surface may be sampled on: the surface's grid costs about 100
# bytes a point (coordinates, probabilities, the tetrahedra's masks), so 2e8 points is ~20 GB. The
# default resolution (at most 10 cm, at least 2 cm) stays well below it for rooms and tanks.
MAX_GRID_POINTS = 200_000_000


def _sigmoid(z):
    return 0.5 * (1.0 + np.tanh(0.5 * z))


def _is_int(v) -> bool:
    return isinstance(v, (int, np.integer)) and not isinstance(v, (bool, np.bool_))


def _is_number(v) -> bool:
    return (isinstance(v, (int, float, np.integer, np.floating)) and not isinstance(v, (bool, np.bool_))
            and math.isfinite(v))


def _choices(names) -> str:
    q = [repr(n) for n in names]
    return ", ".join(q[:-1]) + " or " + q[-1]


def _need(name: str, value, ok: bool, allowed: str) -> None:
    if not ok:
        raise ValueError(f"HilbertMap: {name} must be {allowed}, not {value!r}")


def _int_param(name, v, lo, none=False):
    _need(name, v, (none and v is None) or (_is_int(v) and v >= lo),
          ("None or " if none else "") + f"an integer >= {lo}")


def _num_param(name, v, lo=None, hi=None, lo_open=False, hi_open=False, special=()):
    ok = any(v is s or (isinstance(v, str) and v == s) for s in special)
    if not ok and _is_number(v):
        ok = ((lo is None or (v > lo if lo_open else v >= lo))
              and (hi is None or (v < hi if hi_open else v <= hi)))
    if lo is not None and hi is not None:
        rng = f"a number in {'(' if lo_open else '['}{lo:g}, {hi:g}{')' if hi_open else ']'}"
    elif lo is not None:
        rng = f"a number {'>' if lo_open else '>='} {lo:g}"
    else:
        rng = "a finite number"
    _need(name, v, ok, " or ".join([repr(s) for s in special] + [rng]))


def _check_bounds(name, bounds, none=True):
    """``(lo, hi)``, each 3 finite numbers with lo < hi; returns them as arrays."""
    if bounds is None and none:
        return None
    allowed = ("None or " if none else "") + "a pair (lo, hi) of 3 numbers each, with lo < hi"
    try:
        lo, hi = (np.asarray(b, dtype=np.float64) for b in bounds)
    except (TypeError, ValueError):
        lo = hi = None
    _need(name, bounds, lo is not None and lo.shape == (3,) and hi.shape == (3,)
          and bool(np.isfinite(lo).all() and np.isfinite(hi).all() and (lo < hi).all()), allowed)
    return lo, hi


def _check_params(hm) -> None:
    """Every hyper-parameter's type and range (at fit, as scikit-learn does: set_params may
    change them after construction)."""
    from .classify import RULES
    from .inducing import METHODS

    choices = dict(inducing=METHODS, source=("auto", "data", "intensity"), bin_rule=RULES,
                   occupied_bins=("first", "first_run", "all"), occupied_pooling=("mean", "lse"),
                   beam_sampling=("pattern", "uniform"), schedule=_sched.SCHEDULES, variant=("llvm", "cuda"))
    for name, names in choices.items():
        v = getattr(hm, name)
        _need(name, v, isinstance(v, str) and v in names, ("one of " if len(names) > 2 else "") + _choices(names))
    _int_param("n_inducing", hm.n_inducing, 1)
    _num_param("inducing_occupied_share", hm.inducing_occupied_share, 0, 1)
    _num_param("inducing_voxel", hm.inducing_voxel, 0, special=(None,))
    _num_param("lengthscale", hm.lengthscale, 0, lo_open=True, special=("auto",))
    _num_param("lengthscale_factor", hm.lengthscale_factor, 0, lo_open=True)
    _num_param("kernel_cut", hm.kernel_cut, 0, 1, lo_open=True, hi_open=True)
    _num_param("eig_floor", hm.eig_floor, 0, 1, hi_open=True)
    for name in ("threshold", "min_level", "cfar_offset"):
        _num_param(name, getattr(hm, name), special=(None,))
    _int_param("cfar_train", hm.cfar_train, 1)
    _int_param("cfar_guard", hm.cfar_guard, 0)
    _num_param("blanking", hm.blanking, 0, special=("auto",))
    _int_param("min_echo_bins", hm.min_echo_bins, 0)
    _num_param("free_density", hm.free_density, 0)
    _int_param("max_free_per_ping", hm.max_free_per_ping, 0)
    _num_param("free_margin", hm.free_margin, 0)
    _int_param("near_free", hm.near_free, 0)
    _num_param("near_depth", hm.near_depth, 0)
    _int_param("occupied_samples", hm.occupied_samples, 1)
    _num_param("max_run", hm.max_run, 0, lo_open=True)
    _num_param("occupied_weight", hm.occupied_weight, 0, lo_open=True, special=("balanced",))
    _num_param("pooling_temperature", hm.pooling_temperature, 0, lo_open=True)
    _num_param("beam_extent", hm.beam_extent, 0, lo_open=True)
    _num_param("beam_stride", hm.beam_stride, 1)
    _num_param("alpha", hm.alpha, 0)
    _num_param("l1_ratio", hm.l1_ratio, 0, 1)
    _num_param("eta0", hm.eta0, 0, lo_open=True, special=("auto",))
    _num_param("k1", hm.k1, 0)
    _num_param("t0", hm.t0, 0, lo_open=True, special=(None,))
    _int_param("batch_size", hm.batch_size, 1)
    _int_param("n_passes", hm.n_passes, 1)
    _int_param("partial_passes", hm.partial_passes, 1)
    _need("fit_intercept", hm.fit_intercept, isinstance(hm.fit_intercept, (bool, np.bool_)), "True or False")
    _check_bounds("bounds", hm.bounds)
    _num_param("coverage_voxel", hm.coverage_voxel, 0, lo_open=True)
    _int_param("max_free_per_voxel", hm.max_free_per_voxel, 1, none=True)
    _int_param("max_groups_per_voxel", hm.max_groups_per_voxel, 1, none=True)
    _int_param("random_state", hm.random_state, 0, none=True)


class HilbertMap:
    """Hilbert map of 3-D occupancy from sonar scans (scikit-learn estimator conventions).

    Parameters (hyper-parameters only; learnt state lives in attributes ending with ``_``; each is
    checked at ``fit``, ``partial_fit`` and ``embed``, and a bad one raises a ValueError naming it)
    ----------------------------------------------------------------------------------------
    n_inducing : int            Nystroem inducing points (3000 in the thesis); at most the number of
                                training samples the scans give (free samples plus occupied bins).
    inducing : str              ``kmeans`` (centres of the samples, as the original Hilbert-maps
                                code), ``grid`` (lattice over the region seen) or ``random``.
    inducing_occupied_share : float   share of occupied samples among the k-means input points: open
                                water needs few centres (the intercept keeps it free), the surfaces
                                need them dense to come out thin and unbroken.
    inducing_voxel : float      k-means input thinned to one point per voxel of this side (0: off), so
                                the centres spread over the area seen instead of following how many
                                pings saw it (walls seen by few pings otherwise break into beads).
    lengthscale : float | "auto"      RBF length l (metres); ``auto`` = ``lengthscale_factor`` times
                                the median nearest-neighbour spacing of the inducing points (1.2:
                                with 1.0 the length fell to 0.37 m on the 21-scan box at 100 %
                                beams, and the 0.1-0.3 m band AUC to 0.80; 1.2 gives 0.45 m, 0.88).
    kernel_cut : float          kernel values below this are zero (locality; no denormals).
    eig_floor : float           eigenvalues of G below ``eig_floor * max`` are dropped (rank cut).
    source : str                ``data``, ``intensity`` or ``auto`` (data unless all zero).
    bin_rule : str              ``threshold``, ``otsu``, ``cfar`` or ``otsu+cfar`` (see
                                :mod:`hilbertmap.classify`); ``threshold``, ``min_level``,
                                ``cfar_train``, ``cfar_guard``, ``cfar_offset`` tune them
                                (``None``: for ``data`` a floor of 64 and a CFAR offset of 40
                                levels; for ``intensity``, classified in dB, -95 dB and 10 dB).
    blanking : "auto" | float   range (m) below which bins are ignored (ring-down); ``auto`` finds it.
    min_echo_bins : int         full bins in runs shorter than this are taken as noise (an echo
                                spans the pulse length: 7.5 cm, three bins, for a Micron).
    free_density : float        free samples per cubic metre of empty beam volume ...
    max_free_per_ping : int     ... at most this many per ping.
    free_margin : float         metres of the empty beam left unsampled before the first echo.
    near_free, near_depth       extra free samples per ping with an echo, uniform in range over the
                                last ``near_depth`` metres before it. Volume sampling puts few there,
                                yet that shell is what tells the wall from the water just in front of
                                it (the 0.1-0.3 m band); they are thinned on their own per-voxel budget.
    occupied_samples : int      points per full bin (averaged in feature space, eq. 4.6).
    occupied_bins : str         ``first`` (first full bin), ``first_run`` (the full bins contiguous
                                with it, at most ``max_run`` metres) or ``all`` full bins.
    occupied_weight : "balanced" | float   weight of an occupied bin's embedding relative to a free
                                sample; ``balanced`` makes both classes weigh the same in total. A
                                bin's points spread over the beam's 35 deg fan, much of it in front of
                                the wall: weighed as heavily as all free samples (``balanced``, about
                                15-30 on the box) they push the wall's face 0.2 m into the water.
    occupied_pooling : str      how a full bin's points make one logit: ``mean`` (kernel mean
                                embedding, eq. 4.6: the mean of w . phi) or ``lse`` (a soft maximum,
                                ``tau log mean exp(f / tau)``: an echo needs only one reflector in
                                the bin, so the learner may place it where the free space of other
                                pings leaves room); ``pooling_temperature`` is tau.
    beam_sampling : str         ``pattern`` (directions drawn by the two-way beam pattern) or
                                ``uniform`` (uniform in the nominal frustum, the thesis).
    beam_extent : float         samples lie within this many -3 dB half widths of the boresight
                                (1: the nominal frustum, where the two-way gain is >= -6 dB).
    beam_stride : float         use every ``beam_stride``-th ping (Algorithm 3's partition; 10/3 keeps
                                30 % of the beams, evenly spread).
    alpha, l1_ratio : float     elastic-net strength and l1 share (a strong penalty, 1e-4, caps the
                                logits and leaves walls half a metre thick).
    schedule : str              ``thesis`` (eq. 4.12), ``classic`` (4.11), ``ramos_ott``, ``constant``.
    eta0 : "auto" | float      initial step; ``auto`` = 1 / L with L the largest curvature of the
                                mean loss at w = 0 (a quarter of the top eigenvalue of the weighted
                                feature covariance, by power iteration on a batch): the largest
                                step that plain gradient descent takes safely, about 400 for the
                                box with 3000 inducing points.
    k1, t0 : float              schedule constants (eq. 4.12's k1; Ramos-Ott's t0).
    batch_size : int            points (lanes) per mini-batch.
    n_passes : int              passes over the samples in ``fit``; ``partial_passes`` in ``partial_fit``.
    fit_intercept : bool        learn an unregularised bias b.
    bounds : (lo, hi) | None    region for ``grid``/``random`` inducing points; default the region seen.
    coverage_voxel : float      voxel side of the record of the region seen (metres).
    max_free_per_voxel, max_groups_per_voxel : int | None
                                thin the evidence where many pings overlap: keep at most this many
                                free samples (occupied bins, by their centre) per voxel of
                                ``coverage_voxel`` (``None``: keep all). Without it, the surfaces
                                that few pings see (grazing incidence) drown in the free space of
                                the many pings around them and the class balance is set by the
                                best-seen regions; with 2 and 2 the 21-scan box gained 0.07 of
                                F-score@0.1 m over no cap and fitted twice as fast. The default
                                keeps 12 free samples (2 bins): the free evidence right in front of
                                the walls is what pulls the 0.5 level onto them (with 2, the 0.5
                                contour of the 21-scan box lay up to 0.28 m off; with 12, 0.18 m).
    random_state : int | None   seed of every random choice.
    variant : str               Dr.Jit backend: ``llvm`` (default) or ``cuda``.
    """

    def __init__(self, n_inducing=3000, **params):
        unknown = set(params) - set(_PARAMS)
        if unknown:
            raise TypeError(f"HilbertMap: unknown parameter(s) {', '.join(sorted(unknown))}")
        self.n_inducing = n_inducing
        for k, v in _PARAMS.items():
            if k != "n_inducing":
                setattr(self, k, params.get(k, v))

    # -- scikit-learn plumbing ------------------------------------------------------------------
    def get_params(self, deep: bool = True) -> dict:
        return {k: getattr(self, k) for k in _PARAMS}

    def set_params(self, **params) -> "HilbertMap":
        for k, v in params.items():
            if k not in _PARAMS:
                raise ValueError(f"HilbertMap: unknown parameter {k!r}")
            setattr(self, k, v)
        return self

    def __repr__(self) -> str:
        changed = {k: v for k, v in self.get_params().items() if v != _PARAMS[k]}
        args = ", ".join(f"{k}={v!r}" for k, v in changed.items())
        return f"HilbertMap({args})"

    # -- embedding --------------------------------------------------------------------------
    def embed(self, scan, rng: np.random.Generator | None = None) -> Samples:
        """Labelled samples of one scan with this map's embedding settings."""
        _check_params(self)
        rng = rng if rng is not None else np.random.default_rng(self.random_state)
        return embed_scan(
            scan, rng, source=self.source, bin_rule=self.bin_rule, threshold=self.threshold,
            min_level=self.min_level, cfar_train=self.cfar_train, cfar_guard=self.cfar_guard,
            cfar_offset=self.cfar_offset, blanking=self.blanking, free_density=self.free_density,
            max_free_per_ping=self.max_free_per_ping, free_margin=self.free_margin,
            near_free=self.near_free, near_depth=self.near_depth,
            occupied_samples=self.occupied_samples, occupied_bins=self.occupied_bins, max_run=self.max_run,
            beam_sampling=self.beam_sampling, beam_extent=self.beam_extent, ping_stride=self.beam_stride,
            min_echo_bins=self.min_echo_bins,
        )

    def embed_all(self, scans, rng: np.random.Generator | None = None) -> Samples:
        scans = _as_scan_list(scans)
        rng = rng if rng is not None else np.random.default_rng(self.random_state)
        return Samples.concatenate([self.embed(s, rng) for s in scans])

    # -- training ----------------------------------------------------------------------------
    def fit(self, scans, samples: Samples | None = None) -> "HilbertMap":
        """Learn the map from scratch from a list of scans (or one scan).

        ``samples`` (from :meth:`embed_all`) skips the embedding. ``timings_`` records the
        seconds spent embedding, building the features (inducing points, Gram matrix and its
        eigen-decomposition, step-size estimate) and in SGD.
        """
        t_start = time.perf_counter()
        _check_params(self)
        self._rng = np.random.default_rng(self.random_state)
        if samples is None:
            samples = self.embed_all(scans, self._rng)
        samples = self._thin(samples)
        t_embed = time.perf_counter()
        if len(samples.free) + len(samples.occupied) == 0:
            raise ValueError("HilbertMap: the scans gave no samples (no pings, or all bins blanked)")
        self._check_n_inducing(samples, "these scans")
        self._initialise(samples)
        self._set_weights(samples)
        self.n_schedule_ = len(samples.free) + len(samples.occupied)
        self.eta0_ = self._initial_step(samples)
        t_init = time.perf_counter()
        self.loss_curve_ = []
        for _ in range(int(self.n_passes)):
            self.loss_curve_.append(self._sgd_pass(samples))
        t_end = time.perf_counter()
        self.timings_ = dict(embed_s=t_embed - t_start, features_s=t_init - t_embed, sgd_s=t_end - t_init,
                             total_s=t_end - t_start)
        return self

    def partial_fit(self, scan, samples: Samples | None = None) -> "HilbertMap":
        """Online update with one scan (``partial_passes`` passes over its samples).

        The first call places the inducing points: in ``bounds`` when given, else in the region
        this first scan saw (later scans that look elsewhere are only learnt where that region
        reaches). Later calls go on from the current weights and step count.
        """
        _check_params(self)
        if not hasattr(self, "_rng"):
            self._rng = np.random.default_rng(self.random_state)
        if samples is None:
            samples = self.embed(scan, self._rng)
        samples = self._thin(samples)
        if not hasattr(self, "dual_coef_"):
            if len(samples.free) + len(samples.occupied) == 0:
                raise ValueError("HilbertMap: the first scan gave no samples")
            self._check_n_inducing(samples, "the first scan")
            self._initialise(samples)
            self.n_schedule_ = len(samples.free) + len(samples.occupied)
            self._set_weights(samples)
            self.eta0_ = self._initial_step(samples)
            self.loss_curve_ = []
        else:
            self._ensure_features()
            self.coverage_.add(samples.free)
            self.coverage_.add(samples.occupied.reshape(-1, 3))
            self.echo_coverage_.add(samples.occupied.reshape(-1, 3))
            self.free_coverage_.add(samples.free)
            self.ping_frames_ = np.concatenate([self.ping_frames_, samples.frames.astype(np.float32)])
            self.ping_beams_ = np.concatenate([self.ping_beams_, samples.beams.astype(np.float32)])
            self.ping_spans_ = np.concatenate([self.ping_spans_, samples.spans.astype(np.float32)])
            self.sensor_positions_ = _unique_rows(np.concatenate([self.sensor_positions_, samples.origins]))
        self._set_weights(samples)
        for _ in range(int(self.partial_passes)):
            self.loss_curve_.append(self._sgd_pass(samples))
        return self

    def _check_n_inducing(self, samples: Samples, source: str) -> None:
        # More inducing points than samples leaves the kernel no data to span (the length-scale
        # shrinks to the sample spacing and the map to beads), and the n x n Gram matrix grows
        # with n^2: 100000 points would need 75 GiB. Checked before anything that large is made.
        n = len(samples.free) + len(samples.occupied)
        if self.n_inducing > n:
            raise ValueError(f"HilbertMap: n_inducing must be at most the number of training samples "
                             f"({n} from {source}), not {self.n_inducing}")

    def _thin(self, samples: Samples) -> Samples:
        """Cap the free samples and occupied groups per voxel (``max_*_per_voxel``)."""
        import dataclasses

        if self.max_free_per_voxel is None and self.max_groups_per_voxel is None:
            return samples
        rng = np.random.default_rng(None if self.random_state is None else self.random_state + 7)

        def keep(points, cap):
            if cap is None or len(points) == 0:
                return np.arange(len(points))
            idx = np.floor(points / self.coverage_voxel).astype(np.int64)
            key = (idx[:, 0] * 1_000_003 + idx[:, 1]) * 1_000_033 + idx[:, 2]
            perm = rng.permutation(len(points))
            order = perm[np.argsort(key[perm], kind="stable")]
            k = key[order]
            start = np.r_[0, np.nonzero(k[1:] != k[:-1])[0] + 1]
            rank = np.arange(len(k)) - np.repeat(start, np.diff(np.r_[start, len(k)]))
            return np.sort(order[rank < int(cap)])

        gap = samples.gaps()
        near = gap < float(self.near_depth) if self.near_free else np.zeros(len(gap), dtype=bool)
        # the shell before the echoes is thinned on its own budget, not crowded out by open water
        i_far, i_near = np.nonzero(~near)[0], np.nonzero(near)[0]
        kf = np.sort(np.concatenate([i_far[keep(samples.free[i_far], self.max_free_per_voxel)],
                                     i_near[keep(samples.free[i_near], self.max_free_per_voxel)]]))
        kg = keep(samples.occupied.mean(axis=1) if len(samples.occupied) else np.zeros((0, 3)),
                  self.max_groups_per_voxel)
        return dataclasses.replace(samples, free=samples.free[kf], occupied=samples.occupied[kg], free_gap=gap[kf],
                                   occupied_ping=samples.occupied_ping[kg] if samples.occupied_ping is not None else None)

    def _set_weights(self, samples: Samples) -> None:
        F, G = len(samples.free), len(samples.occupied)
        if isinstance(self.occupied_weight, str):
            if self.occupied_weight != "balanced":
                raise ValueError("HilbertMap: occupied_weight must be 'balanced' or a number")
            self.occupied_weight_ = float(F) / max(G, 1) if G else 1.0
        else:
            self.occupied_weight_ = float(self.occupied_weight)

    def _initial_step(self, samples: Samples, lanes: int = 8192, iters: int = 12) -> float:
        """``eta0``, or 1 / L for ``auto`` (see the class docstring)."""
        if self.eta0 != "auto":
            return float(self.eta0)
        import drjit as dr

        grid = self._grid
        rng = np.random.default_rng(0 if self.random_state is None else self.random_state)
        F, G = len(samples.free), len(samples.occupied)
        m = samples.occupied.shape[1] if G else 1
        share = F / max(F + G * m, 1)
        nf = min(F, int(lanes * share))
        ng = min(G, max(1, (lanes - nf) // m)) if G else 0
        i_f = rng.choice(F, nf, replace=False) if nf else np.zeros(0, dtype=np.int64)
        i_g = rng.choice(G, ng, replace=False) if ng else np.zeros(0, dtype=np.int64)
        pts = np.concatenate([samples.free[i_f], samples.occupied[i_g].reshape(-1, 3)])
        c = np.concatenate([np.ones(nf), np.full(ng, self.occupied_weight_)])
        c = c / c.sum()
        x, y, z = grid.to_lanes(pts)
        v = rng.normal(size=self._M.shape[0])
        lam = 1.0
        for _ in range(iters):
            v = v / np.linalg.norm(v)
            coef = grid.upload(self._MT @ v.astype(np.float32))
            f = grid.kernel_sum(x, y, z, coef).numpy().astype(np.float64)  # Phi v per lane
            f_item = np.concatenate([f[:nf], f[nf:].reshape(ng, m).mean(axis=1)]) if ng else f[:nf]
            u = c * f_item
            u_lane = np.concatenate([u[:nf], np.repeat(u[nf:] / m, m)]).astype(np.float32)
            out = dr.zeros(grid.Float, grid.n)
            grid.kernel_scatter(x, y, z, grid.upload(u_lane), out)
            w = self._M @ out.numpy()
            lam = float(np.linalg.norm(w))
            v = w
        L = 0.25 * max(lam, 1e-12)
        return 1.0 / L

    def _initialise(self, samples: Samples) -> None:
        self.coverage_ = Coverage(self.coverage_voxel)
        self.coverage_.add(samples.free)
        self.coverage_.add(samples.occupied.reshape(-1, 3))
        self.echo_coverage_ = Coverage(self.coverage_voxel)
        self.echo_coverage_.add(samples.occupied.reshape(-1, 3))
        self.free_coverage_ = Coverage(self.coverage_voxel)
        self.free_coverage_.add(samples.free)
        self.ping_frames_ = samples.frames.astype(np.float32)
        self.ping_beams_ = samples.beams.astype(np.float32)
        self.ping_spans_ = samples.spans.astype(np.float32)
        self.sensor_positions_ = _unique_rows(samples.origins)
        cov = self.coverage_
        if self.bounds is not None and self.inducing in ("grid", "random"):
            lo, hi = (np.asarray(b, dtype=np.float64) for b in self.bounds)
            cov = Coverage(self.coverage_voxel)
            axes = [np.arange(lo[a], hi[a], self.coverage_voxel) + 0.5 * self.coverage_voxel for a in range(3)]
            cov.add(np.stack(np.meshgrid(*axes, indexing="ij"), -1).reshape(-1, 3))
        nu = choose_inducing(self.inducing, self.n_inducing, samples.free, samples.occupied, cov, self._rng,
                             occupied_share=self.inducing_occupied_share, dedup=float(self.inducing_voxel or 0.0))
        if self.lengthscale == "auto":
            ell = float(self.lengthscale_factor) * spacing(nu)
        else:
            ell = float(self.lengthscale)
        if not ell > 0:
            raise ValueError("HilbertMap: the length-scale must be positive")
        self.lengthscale_ = ell
        self.gamma_ = 1.0 / (2.0 * ell * ell)
        self._grid = KernelGrid(nu, ell, self.kernel_cut, self.variant)
        self.inducing_points_ = np.asarray(nu, dtype=np.float64)[self._grid.order]
        self._grid.order = np.arange(len(nu))  # from here on everything is in grid order
        self._grid.inv_order = np.arange(len(nu))
        self._build_features()
        k = self._M.shape[0]
        self.weights_ = np.zeros(k, dtype=np.float64)
        self.dual_coef_ = np.zeros(len(nu), dtype=np.float64)
        self.intercept_ = 0.0
        self.t_ = 0.0
        self.n_samples_seen_ = 0

    def _build_features(self) -> None:
        G = self._grid.gram()
        lam, Q = np.linalg.eigh(G)
        keep = lam > self.eig_floor * lam[-1]
        lam, Q = lam[keep], Q[:, keep]
        self.n_components_ = int(keep.sum())
        M = (Q / np.sqrt(lam)).T  # (k, n) = Lambda^-1/2 Q^T
        self._M = np.ascontiguousarray(M, dtype=np.float32)
        self._MT = np.ascontiguousarray(M.T, dtype=np.float32)

    def _ensure_features(self) -> None:
        if not hasattr(self, "_grid"):
            self._grid = KernelGrid(self.inducing_points_, self.lengthscale_, self.kernel_cut, self.variant)
            self._grid.order = np.arange(len(self.inducing_points_))
            self._grid.inv_order = self._grid.order
        if not hasattr(self, "_M"):
            self._build_features()
            if len(self.weights_) != self._M.shape[0]:
                raise ValueError("HilbertMap: saved weights do not match the rebuilt features")
        if not hasattr(self, "_rng"):
            self._rng = np.random.default_rng(self.random_state)

    def _sgd_pass(self, samples: Samples) -> float:
        """One shuffled pass of mini-batch SGD; returns the mean weighted loss seen.

        The two n x n products of a step run on one BLAS thread when ``threadpoolctl`` is
        installed: idle BLAS threads spin and slow the Dr.Jit kernels that follow (measured 3x).
        """
        try:
            from threadpoolctl import threadpool_limits
        except ImportError:
            return self._sgd_pass_inner(samples)
        with threadpool_limits(limits=1, user_api="blas"):
            return self._sgd_pass_inner(samples)

    def _sgd_pass_inner(self, samples: Samples) -> float:
        grid = self._grid
        F, G = len(samples.free), len(samples.occupied)
        m = samples.occupied.shape[1] if G else 1
        lanes_total = F + G * m
        nb = max(1, int(math.ceil(lanes_total / max(int(self.batch_size), 1))))
        pf = np.array_split(self._rng.permutation(F), nb)
        pg = np.array_split(self._rng.permutation(G), nb)
        free = samples.free
        occ = samples.occupied
        occ_centre_keys = grid.cell_keys(occ.mean(axis=1)) if G else np.zeros(0, dtype=np.int64)
        free_keys = grid.cell_keys(free) if F else np.zeros(0, dtype=np.int64)
        Float = grid.Float
        import drjit as dr

        alpha_dr = grid.upload(self.dual_coef_)
        c_occ = self.occupied_weight_
        lam = float(self.alpha)
        rho = float(self.l1_ratio)
        loss_sum = 0.0
        wsum_all = 0.0
        for b in range(nb):
            i_f = pf[b]
            i_g = pg[b]
            i_f = i_f[np.argsort(free_keys[i_f], kind="stable")]
            i_g = i_g[np.argsort(occ_centre_keys[i_g], kind="stable")]
            bf, bg = len(i_f), len(i_g)
            if bf + bg == 0:
                continue
            pts = np.concatenate([free[i_f], occ[i_g].reshape(-1, 3)])
            x, y, z = grid.to_lanes(pts)
            f_lane = grid.kernel_sum(x, y, z, alpha_dr).numpy().astype(np.float64) + self.intercept_
            f_occ = f_lane[bf:].reshape(bg, m)
            if self.occupied_pooling == "mean":  # kernel mean embedding: mean of w . phi (eq. 4.6)
                f_pool = f_occ.mean(axis=1)
                share = np.full((bg, m), 1.0 / m)
            elif self.occupied_pooling == "lse":  # soft maximum over the bin's points
                tau = float(self.pooling_temperature)
                mx = f_occ.max(axis=1, keepdims=True)
                e = np.exp((f_occ - mx) / tau)
                f_pool = mx[:, 0] + tau * np.log(e.mean(axis=1))
                share = e / e.sum(axis=1, keepdims=True)
            else:
                raise ValueError(f"HilbertMap: occupied_pooling must be 'mean' or 'lse', not {self.occupied_pooling!r}")
            f_item = np.concatenate([f_lane[:bf], f_pool])
            y_item = np.concatenate([np.zeros(bf), np.ones(bg)])
            c_item = np.concatenate([np.ones(bf), np.full(bg, c_occ)])
            csum = c_item.sum()
            p = _sigmoid(f_item)
            # logistic loss log(1 + exp(-s f)), s = +-1, computed stably
            s = 2.0 * y_item - 1.0
            loss_sum += float(np.sum(c_item * np.logaddexp(0.0, -s * f_item)))
            wsum_all += csum
            g_item = c_item * (p - y_item) / csum
            g_lane = np.concatenate([g_item[:bf], (g_item[bf:, None] * share).ravel()]).astype(np.float32)
            out = dr.zeros(Float, grid.n)
            grid.kernel_scatter(x, y, z, grid.upload(g_lane), out)
            svec = out.numpy()
            eta = _sched.step_size(self.schedule, self.t_, self.n_schedule_, float(self.eta0_), float(self.k1),
                                   self.t0, lam, rho)
            w = self.weights_
            grad = self._M @ svec + lam * (1.0 - rho) * w
            w = w - eta * grad
            if rho > 0:
                thr = eta * lam * rho
                w = np.sign(w) * np.maximum(np.abs(w) - thr, 0.0)
            self.weights_ = w
            self.dual_coef_ = (self._MT @ w.astype(np.float32)).astype(np.float64)
            self._version = getattr(self, "_version", 0) + 1
            alpha_dr = grid.upload(self.dual_coef_)
            if self.fit_intercept:
                # the bias sees the whole batch's curvature (<= 1/4): its step is capped for stability
                self.intercept_ -= min(eta, 2.0) * float(g_item.sum())
            self.t_ += bf + bg
            self.n_samples_seen_ += bf + bg
        return loss_sum / max(wsum_all, 1e-300)

    # -- queries -----------------------------------------------------------------------------
    def _check_fitted(self) -> None:
        if not hasattr(self, "dual_coef_"):
            raise RuntimeError("HilbertMap: call fit() or partial_fit() before querying the map")

    def decision_function(self, points, chunk: int = 1 << 21) -> np.ndarray:
        """Logit ``w . phi(x) + b`` at (N, 3) world points."""
        self._check_fitted()
        pts = _as_points(points)
        if not hasattr(self, "_grid"):
            self._grid = KernelGrid(self.inducing_points_, self.lengthscale_, self.kernel_cut, self.variant)
            self._grid.order = np.arange(len(self.inducing_points_))
            self._grid.inv_order = self._grid.order
        grid = self._grid
        coef = grid.upload(self.dual_coef_)
        out = np.empty(len(pts), dtype=np.float64)
        for a in range(0, len(pts), chunk):
            p = pts[a:a + chunk]
            order = np.argsort(grid.cell_keys(p), kind="stable")
            x, y, z = grid.to_lanes(p[order])
            f = grid.kernel_sum(x, y, z, coef).numpy()
            res = np.empty(len(p), dtype=np.float64)
            res[order] = f
            out[a:a + chunk] = res
        return out + self.intercept_

    def predict_proba(self, points) -> np.ndarray:
        """Occupancy probability in [0, 1] at (N, 3) world points -> (N,)."""
        return _sigmoid(self.decision_function(points))

    def seen(self, points, dilate: int = 1, echoes: bool = False) -> np.ndarray:
        """Whether points lie in the region the training scans saw (voxels holding samples).

        With ``echoes`` only the voxels of full bins count: the surfaces that returned an echo.
        """
        self._check_fitted()
        cov = self.echo_coverage_ if echoes else self.coverage_
        return cov.contains(np.asarray(points, dtype=np.float64), dilate=dilate)

    def insonified(self, points, vertices=None, faces=None, part: str = "any", tolerance: float = 0.1) -> np.ndarray:
        """Whether points lie in the nominal frustum (-3 dB widths) of at least one training ping.

        ``part``: ``any`` (up to ``range_max``), ``free`` (before the ping's first echo) or
        ``echo`` (within ``tolerance`` of the ranges of the ping's first echo: surfaces that the
        sonar saw). Given the scene's triangles, the point must also be in the ping's line of sight.
        """
        self._check_fitted()
        from .geometry import segments_blocked

        if part not in ("any", "free", "echo"):
            raise ValueError("HilbertMap: part must be 'any', 'free' or 'echo'")
        P = np.asarray(points, dtype=np.float64).reshape(-1, 3)
        out = np.zeros(len(P), dtype=bool)
        frames = np.asarray(self.ping_frames_, dtype=np.float64)
        beams = np.asarray(self.ping_beams_, dtype=np.float64)
        spans = np.asarray(self.ping_spans_, dtype=np.float64)
        for k in range(len(frames)):
            if part == "echo" and not np.isfinite(spans[k, 1]):
                continue
            rest = np.nonzero(~out)[0]
            if len(rest) == 0:
                break
            R, o = frames[k, :3, :3], frames[k, :3, 3]
            loc = (P[rest] - o) @ R
            r = np.linalg.norm(loc, axis=1)
            az = np.arctan2(loc[:, 0], loc[:, 2])
            el = np.arcsin(np.clip(loc[:, 1] / np.maximum(r, 1e-12), -1, 1))
            inside = (np.abs(az) <= np.radians(beams[k, 0]) / 2) & (np.abs(el) <= np.radians(beams[k, 1]) / 2)
            if part == "any":
                inside &= r <= beams[k, 2]
            elif part == "free":
                end = spans[k, 1] if np.isfinite(spans[k, 1]) else beams[k, 2]
                inside &= (r >= spans[k, 0]) & (r < end)
            else:
                inside &= (r >= spans[k, 1] - tolerance) & (r <= spans[k, 2] + tolerance)
            idx = rest[inside]
            if len(idx) and vertices is not None and part != "echo":
                blocked = segments_blocked(np.broadcast_to(o, (len(idx), 3)), P[idx], vertices, faces)
                idx = idx[~blocked]
            out[idx] = True
        return out

    def slice(self, axis="z", value: float = 0.0, extent=None, resolution: float = 0.05) -> "MapSlice":
        """Probability on the plane ``axis = value``.

        ``extent``: ((u_min, u_max), (v_min, v_max)) over the two other axes in x, y, z order
        (default: the region seen); ``resolution`` in metres, at most ``MAX_GRID_POINTS`` points in
        all. Returns a :class:`MapSlice`.
        """
        self._check_fitted()
        a = _axis_index(axis)
        others = [i for i in range(3) if i != a]
        _num_param("value", value)
        _num_param("resolution", resolution, 0, lo_open=True)
        if extent is None:
            lo, hi = self.coverage_.bounds()
            extent = ((lo[others[0]], hi[others[0]]), (lo[others[1]], hi[others[1]]))
        try:
            ext = np.asarray(extent, dtype=np.float64)
        except (TypeError, ValueError):
            ext = None
        uv = "xyz"[others[0]] + ", " + "xyz"[others[1]]
        _need("extent", extent, ext is not None and ext.shape == (2, 2) and bool(np.isfinite(ext).all())
              and bool((ext[:, 0] <= ext[:, 1]).all()),
              f"((u_min, u_max), (v_min, v_max)) in metres over {uv}, each min <= max")
        u, v = _grid_axes("resolution", resolution, ext[:, 0], ext[:, 1], f"the slice's extent ({uv})")
        U, V = np.meshgrid(u, v, indexing="xy")
        pts = np.zeros((U.size, 3))
        pts[:, others[0]] = U.ravel()
        pts[:, others[1]] = V.ravel()
        pts[:, a] = value
        prob = self.predict_proba(pts).reshape(U.shape)
        seen = self.seen(pts).reshape(U.shape)
        return MapSlice(prob=prob, seen=seen, u=u, v=v, axis="xyz"[a], value=float(value),
                        axes=("xyz"[others[0]], "xyz"[others[1]]))

    def _surface_grid(self, resolution, bounds):
        if bounds is None:
            lo, hi = self.coverage_.bounds()
            where = "the region seen"
        else:
            lo, hi = _check_bounds("bounds", bounds, none=False)
            where = "the bounds"
        _num_param("resolution", resolution, 0, lo_open=True, special=(None,))
        if resolution is None:
            resolution = max(min(self.lengthscale_ / 4.0, 0.1), 0.02)
        axes = _grid_axes("resolution", resolution, lo, hi, where)
        return axes, resolution

    def isosurface(self, level: float = 0.5, resolution: float | None = None, bounds=None,
                   only_seen: bool = True):
        """Triangle mesh (vertices (V,3), faces (F,3)) of the ``p = level`` surface.

        Sampled on a grid of ``resolution`` metres (default a quarter of the length-scale, at
        most 10 cm; at most ``MAX_GRID_POINTS`` grid points in all) over ``bounds`` (default the
        region seen); ``level`` lies in (0, 1). With ``only_seen`` faces outside
        the region seen are dropped (behind walls the map has no data and sits at its prior).
        """
        from .mesh import marching_tetrahedra

        self._check_fitted()
        # p lies in (0, 1): any other level has no surface, and an empty mesh would hide the slip
        _num_param("level", level, 0, 1, lo_open=True, hi_open=True)
        axes, res = self._surface_grid(resolution, bounds)
        P = self._grid_proba(axes)
        V, Fc = marching_tetrahedra(P, axes, level)
        if only_seen and len(Fc):
            cen = V[Fc].mean(axis=1)
            keep = self.seen(cen, dilate=1)
            V, Fc = _compact(V, Fc[keep])
        return V, Fc

    def _free_coverage(self) -> Coverage:
        # maps saved before the free-sample record existed fall back to everything seen
        return getattr(self, "free_coverage_", None) or self.coverage_

    def ridge_surface(self, resolution: float | None = None, bounds=None, level: float = 0.5,
                      max_shift: float | None = None, only_seen: bool = True, plateau: float | None = 0.1,
                      front_only: bool = True):
        """Triangle mesh on the probability ridge: the wall as seen from the free side.

        The ``level`` isosurface is extracted, then every vertex moves along the gradient of p
        (uphill), at most ``max_shift`` (default 1.5 length-scales). A wall's evidence is one-sided:
        free space in front, and behind it the acoustic shadow, where nothing pulls p down. So p
        rises across the wall's face and then stays on a plateau that reaches into the shadow, and
        its maximum drifts behind the wall, the further the sharper the free side is learnt. A
        vertex therefore stops where p first comes within ``plateau`` of the largest p on its line
        (``None``: at the maximum itself, the classical ridge). With ``front_only`` the faces on
        the shadow side of the plateau are dropped: those whose low side (0.1 m downhill) holds no
        free sample, i.e. was never seen empty.
        """
        self._check_fitted()
        V, Fc = self.isosurface(level=level, resolution=resolution, bounds=bounds, only_seen=only_seen)
        if len(V) == 0:
            return V, Fc
        step = max_shift if max_shift is not None else 1.5 * self.lengthscale_
        h = 0.25 * min(self.lengthscale_, 0.2)
        offs = np.eye(3) * h
        grad = np.stack([(self.decision_function(V + o) - self.decision_function(V - o)) / (2 * h) for o in offs], axis=1)
        n = grad / np.maximum(np.linalg.norm(grad, axis=1, keepdims=True), 1e-12)
        ts = np.linspace(0.0, step, 25)
        pts = V[:, None, :] + ts[None, :, None] * n[:, None, :]
        f = self.decision_function(pts.reshape(-1, 3)).reshape(len(V), len(ts))
        rows = np.arange(len(V))
        k = np.argmax(f, axis=1)
        if plateau is None:
            # parabolic refinement around the discrete maximum
            k0 = np.clip(k, 1, len(ts) - 2)
            fm, f0, fp = f[rows, k0 - 1], f[rows, k0], f[rows, k0 + 1]
            den = fm - 2 * f0 + fp
            delta = np.where((den < 0) & (k == k0), 0.5 * (fm - fp) / np.where(den < 0, den, -1), 0.0)
            t = ts[k0] + np.clip(delta, -1, 1) * (ts[1] - ts[0])
            t = np.where(k == k0, t, ts[k])
        else:
            t = plateau_step(f, ts, plateau)
        R = V + t[:, None] * n
        if front_only:
            front = self._free_coverage().contains(V - 0.1 * n)
            keep = front[Fc].all(axis=1)
            if keep.any():
                R, Fc = _compact(R, Fc[keep])
        return R, Fc

    def surface(self, method: str = "ridge", **kw):
        """``method='ridge'`` (default) or ``'level'`` (the ``level`` isosurface)."""
        if method == "ridge":
            return self.ridge_surface(**kw)
        if method in ("level", "iso", "isosurface"):
            return self.isosurface(**kw)
        raise ValueError(f"HilbertMap: surface method must be 'ridge' or 'level', not {method!r}")

    def _grid_proba(self, axes) -> np.ndarray:
        key = (tuple((float(a[0]), float(a[-1]), len(a)) for a in axes), getattr(self, "_version", 0),
               float(self.intercept_))
        cache = getattr(self, "_grid_cache", None)
        if cache is not None and cache[0] == key:
            return cache[1]
        P = self._grid_proba_uncached(axes)
        self._grid_cache = (key, P)
        return P

    def _grid_proba_uncached(self, axes) -> np.ndarray:
        X, Y, Z = np.meshgrid(*axes, indexing="ij")
        pts = np.stack([X.ravel(), Y.ravel(), Z.ravel()], axis=1)
        return self.predict_proba(pts).reshape(X.shape)

    # -- persistence -------------------------------------------------------------------------
    def save(self, path) -> None:
        """Write the map (hyper-parameters and learnt state) to an ``.npz`` file."""
        self._check_fitted()
        params = {k: _jsonable(v) for k, v in self.get_params().items()}
        state = dict(lengthscale_=self.lengthscale_, intercept_=self.intercept_, t_=self.t_,
                     n_samples_seen_=int(self.n_samples_seen_), n_schedule_=float(self.n_schedule_),
                     occupied_weight_=float(getattr(self, "occupied_weight_", 1.0)), eta0_=float(self.eta0_),
                     n_components_=int(len(self.weights_)),
                     coverage_voxel=self.coverage_.voxel, loss_curve_=list(getattr(self, "loss_curve_", [])),
                     format="hilbertmap/1")
        with open(path, "wb") as fh:
            np.savez_compressed(
                fh, params=np.array(json.dumps(params)), state=np.array(json.dumps(state)),
                inducing_points=self.inducing_points_, weights=self.weights_, dual_coef=self.dual_coef_,
                coverage_keys=self.coverage_.keys, echo_coverage_keys=self.echo_coverage_.keys,
                free_coverage_keys=self._free_coverage().keys,
                sensor_positions=self.sensor_positions_, ping_frames=self.ping_frames_, ping_beams=self.ping_beams_,
                ping_spans=self.ping_spans_,
            )

    @classmethod
    def load(cls, path) -> "HilbertMap":
        """Read a map written by :meth:`save`. A file that is not one, or whose arrays do not agree
        with each other, is refused with a ValueError naming the file and what is wrong."""
        import zipfile
        import zlib

        def bad(why):
            return ValueError(f"HilbertMap: {path}: {why}")

        unreadable = (ValueError, EOFError, KeyError, zipfile.BadZipFile, zlib.error)
        try:
            z = np.load(path, allow_pickle=False)
        except unreadable as exc:
            # numpy takes what is neither zip nor .npy for a pickle, and says so
            why = "" if "pickle" in str(exc) else ": the file is empty" if isinstance(exc, EOFError) else \
                f": {_first_line(exc)}"
            raise bad(f"not a Hilbert map file (not an .npz archive{why})") from None
        if not isinstance(z, np.lib.npyio.NpzFile):
            raise bad("not a Hilbert map file (a single .npy array, not an .npz archive)")
        with z:
            names = ("params", "state", "inducing_points", "weights", "dual_coef", "coverage_keys",
                     "echo_coverage_keys", "sensor_positions", "ping_frames", "ping_beams", "ping_spans")
            for name in names:
                if name not in z.files:
                    raise bad(f"not a Hilbert map file (missing {name!r})")
            arr = {}
            for name in names + (("free_coverage_keys",) if "free_coverage_keys" in z.files else ()):
                try:
                    arr[name] = z[name]
                except unreadable as exc:  # a damaged or truncated member
                    raise bad(f"{name!r} cannot be read ({_first_line(exc)})") from None
        try:
            params = json.loads(str(arr.pop("params")))
            state = json.loads(str(arr.pop("state")))
        except ValueError:
            raise bad("not a Hilbert map file ('params' or 'state' is not JSON)") from None
        if not isinstance(params, dict) or not isinstance(state, dict):
            raise bad("not a Hilbert map file ('params' and 'state' must be JSON objects)")
        if state.get("format", "hilbertmap/1") != "hilbertmap/1":
            raise bad(f"format {state['format']!r} is not hilbertmap/1")
        try:
            hm = cls(**{k: (tuple(v) if isinstance(v, list) else v) for k, v in params.items()})
            _check_params(hm)
        except (TypeError, ValueError) as exc:
            raise bad(f"'params': {str(exc).replace('HilbertMap: ', '')}") from None
        try:
            st = {k: float(state[k]) for k in ("lengthscale_", "intercept_", "t_", "n_samples_seen_",
                                                "n_schedule_", "occupied_weight_", "eta0_", "n_components_",
                                                "coverage_voxel")}
            loss_curve = [float(x) for x in state["loss_curve_"]]
        except KeyError as exc:
            raise bad(f"'state' lacks {exc.args[0]!r}") from None
        except (TypeError, ValueError):
            raise bad("'state' holds a value that is not a number") from None
        for k in ("lengthscale_", "coverage_voxel"):
            if not (math.isfinite(st[k]) and st[k] > 0):
                raise bad(f"'state' {k} must be a number > 0, not {st[k]!r}")
        _check_map_arrays(arr, int(st["n_components_"]), bad)

        hm.inducing_points_ = arr["inducing_points"]
        hm.weights_ = arr["weights"]
        hm.dual_coef_ = arr["dual_coef"]
        hm.coverage_ = Coverage(st["coverage_voxel"], arr["coverage_keys"])
        hm.echo_coverage_ = Coverage(st["coverage_voxel"], arr["echo_coverage_keys"])
        if "free_coverage_keys" in arr:
            hm.free_coverage_ = Coverage(st["coverage_voxel"], arr["free_coverage_keys"])
        hm.sensor_positions_ = arr["sensor_positions"]
        hm.ping_frames_ = arr["ping_frames"]
        hm.ping_beams_ = arr["ping_beams"]
        hm.ping_spans_ = arr["ping_spans"]
        hm.lengthscale_ = st["lengthscale_"]
        hm.intercept_ = st["intercept_"]
        hm.t_ = st["t_"]
        hm.n_samples_seen_ = int(st["n_samples_seen_"])
        hm.n_schedule_ = st["n_schedule_"]
        hm.occupied_weight_ = st["occupied_weight_"]
        hm.eta0_ = st["eta0_"]
        hm.n_components_ = int(st["n_components_"])
        hm.gamma_ = 1.0 / (2.0 * hm.lengthscale_ ** 2)
        hm.loss_curve_ = loss_curve
        return hm


def _check_map_arrays(arr: dict, k: int, bad) -> None:
    """The shapes a saved map's arrays must have, and agree on (n inducing points, k components,
    P pings); ``bad(why)`` makes the error."""
    def need(name, ok, expected):
        if not ok:
            raise bad(f"{name!r} has shape {arr[name].shape}, expected {expected}")

    nu = arr["inducing_points"]
    need("inducing_points", nu.ndim == 2 and nu.shape[1] == 3 and len(nu) >= 1, "(n, 3) with n >= 1")
    n = len(nu)
    if not 1 <= k <= n:
        raise bad(f"'state' n_components_ is {k}, expected 1 to {n} (the number of inducing points)")
    for name, length, what in (("weights", k, "n_components_"), ("dual_coef", n, "one per inducing point")):
        a = arr[name]
        if a.ndim != 1 or len(a) != length:
            raise bad(f"{name!r} has {a.size} entries, expected {length} ({what})")
    for name in ("inducing_points", "weights", "dual_coef"):
        if arr[name].dtype.kind not in "fiu" or not np.isfinite(arr[name]).all():
            raise bad(f"{name!r} holds values that are not finite numbers")
    for name in ("coverage_keys", "echo_coverage_keys", "free_coverage_keys"):
        if name in arr:
            need(name, arr[name].ndim == 1 and arr[name].dtype.kind in "iu", "1-D integer voxel keys")
    need("sensor_positions", arr["sensor_positions"].ndim == 2 and arr["sensor_positions"].shape[1] == 3, "(S, 3)")
    need("ping_frames", arr["ping_frames"].ndim == 3 and arr["ping_frames"].shape[1:] == (4, 4), "(P, 4, 4)")
    p = len(arr["ping_frames"])
    need("ping_beams", arr["ping_beams"].shape == (p, 3), f"({p}, 3), one row per ping of 'ping_frames'")
    need("ping_spans", arr["ping_spans"].shape == (p, 3), f"({p}, 3), one row per ping of 'ping_frames'")


def _first_line(exc) -> str:
    text = str(exc).strip()
    return text.splitlines()[0] if text else type(exc).__name__


class MapSlice:
    """A planar cross-section: ``prob[iv, iu]`` at ``(u[iu], v[iv])`` on the plane ``axis = value``."""

    def __init__(self, prob, seen, u, v, axis, value, axes):
        self.prob, self.seen, self.u, self.v = prob, seen, u, v
        self.axis, self.value, self.axes = axis, value, axes

    @property
    def extent(self):
        """(u_min, u_max, v_min, v_max) for ``imshow(..., origin='lower')``."""
        du = self.u[1] - self.u[0] if len(self.u) > 1 else 1.0
        dv = self.v[1] - self.v[0] if len(self.v) > 1 else 1.0
        return (self.u[0] - du / 2, self.u[-1] + du / 2, self.v[0] - dv / 2, self.v[-1] + dv / 2)

    def __iter__(self):  # prob, extent = hm.slice(...)
        return iter((self.prob, self.extent))


def plateau_step(f: np.ndarray, ts: np.ndarray, plateau: float) -> np.ndarray:
    """Per row of logits ``f`` sampled at steps ``ts``: the step where p first comes within
    ``plateau`` of the row's largest p (linearly interpolated)."""
    p = _sigmoid(f)
    rows = np.arange(len(f))
    target = p.max(axis=1) - float(plateau)
    k1 = np.argmax(p >= target[:, None], axis=1)
    km = np.maximum(k1 - 1, 0)
    lo_p, hi_p = p[rows, km], p[rows, k1]
    frac = np.where(hi_p > lo_p, np.clip((target - lo_p) / np.maximum(hi_p - lo_p, 1e-12), 0, 1), 1.0)
    return np.where(k1 > 0, ts[km] + frac * (ts[k1] - ts[km]), ts[0])


def _axis_index(axis) -> int:
    if isinstance(axis, str) and axis.lower() in ("x", "y", "z"):
        return "xyz".index(axis.lower())
    if axis in (0, 1, 2):
        return int(axis)
    raise ValueError(f"HilbertMap: axis must be 'x', 'y', 'z' or 0-2, not {axis!r}")


def _as_points(points, name: str = "points") -> np.ndarray:
    """(N, 3) finite float64 points, or a ValueError naming the first bad row."""
    try:
        pts = np.asarray(points, dtype=np.float64)
    except (TypeError, ValueError) as exc:
        raise ValueError(f"HilbertMap: {name} must be an (N, 3) array of numbers ({exc})") from None
    if pts.ndim != 2 or pts.shape[1] != 3:
        raise ValueError(f"HilbertMap: {name} must have shape (N, 3), got {pts.shape}")
    bad = np.nonzero(~np.isfinite(pts).all(axis=1))[0]
    if len(bad):
        # a NaN would land in no kernel cell and come out as the bare intercept, a plausible p
        raise ValueError(f"HilbertMap: {name}: row {bad[0]} is not finite ({len(bad)} of {len(pts)} rows are not)")
    return pts


def _grid_axes(name_res: str, res: float, lo, hi, names: str) -> list:
    """Sample axes from lo to hi every ``res``; refused when they would hold more than
    MAX_GRID_POINTS points, with the finest resolution that fits."""
    ext = [max(float(b) - float(a), 0.0) for a, b in zip(lo, hi)]

    def counts(r):
        return [int(math.ceil(e / r + 0.5)) for e in ext]

    n = counts(res)
    if math.prod(n) > MAX_GRID_POINTS:
        r = res
        while math.prod(counts(r)) > MAX_GRID_POINTS:
            r *= 1.05
        e10 = 10.0 ** (math.floor(math.log10(r)) - 1)
        r = math.ceil(r / e10) * e10  # two significant digits, rounded up
        raise ValueError(
            f"HilbertMap: {name_res} {res:g} m needs a grid of {' x '.join(map(str, n))} = {math.prod(n):.3g} "
            f"points over {names} (at most {MAX_GRID_POINTS:.0e}); use {name_res} {r:.2g} or coarser")
    return [np.arange(float(a), float(b) + 0.5 * res, res) for a, b in zip(lo, hi)]


def _as_scan_list(scans):
    if hasattr(scans, "poses"):
        return [scans]
    if isinstance(scans, (str, bytes)) or not hasattr(scans, "__iter__"):
        raise TypeError(f"HilbertMap: fit() needs a scan or a list of scans, not {type(scans).__name__} "
                        "(load scan files with mitsonar.load_scan)")
    scans = list(scans)
    if not scans:
        raise ValueError("HilbertMap: fit() needs at least one scan")
    for s in scans:
        for a in ("poses", "ranges", "range_min", "range_max", "beamwidth_h", "beamwidth_v"):
            if not hasattr(s, a):
                raise TypeError(f"HilbertMap: a scan lacks the attribute {a!r} (got {type(s).__name__})")
    return scans


def _unique_rows(a: np.ndarray) -> np.ndarray:
    if len(a) == 0:
        return np.zeros((0, 3))
    return np.unique(np.round(np.asarray(a, dtype=np.float64), 6), axis=0)


def _compact(V, F):
    used = np.unique(F)
    remap = np.full(len(V), -1, dtype=np.int64)
    remap[used] = np.arange(len(used))
    return V[used], remap[F]


def _jsonable(v):
    if isinstance(v, np.ndarray):
        return v.tolist()
    if isinstance(v, (np.floating, np.integer)):
        return v.item()
    if isinstance(v, tuple):
        return [_jsonable(x) for x in v]
    return v
