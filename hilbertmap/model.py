"""``HilbertMap``: continuous 3-D occupancy learnt from sonar scans (thesis chapter 4).

    p(x) = sigmoid(w . phi(x) + b),   phi(x) = Lambda^(-1/2) Q^T k(x)      (eq. 4.2, 4.3)

with ``k(x)_j = exp(-|x - nu_j|^2 / (2 l^2))`` on ``n_inducing`` points ``nu_j`` and
``G = K(nu, nu) = Q Lambda Q^T``. The logit is evaluated as ``(M^T w) . k(x)`` with
``M = Lambda^(-1/2) Q^T``: a query costs only the kernel values of its neighbours (the kernel is cut
below ``kernel_cut``), and a mini-batch gradient ``M sum_i g_i k(x_i)`` costs the batch's kernel
values (Dr.Jit) plus one ``n x n`` product (BLAS); ``M^T w`` after the step is the second.

Loss: mean logistic loss with an elastic-net penalty ``alpha (l1_ratio |w|_1 + (1 - l1_ratio)/2 |w|^2)``
(eq. 4.4, 4.5) minimised by mini-batch SGD (eq. 4.10) with the schedules of
:mod:`hilbertmap.schedules`; the l1 part is applied as a proximal (soft-threshold) step
(:mod:`hilbertmap.sgd`).

This module holds the estimator: construction, ``fit``, ``partial_fit``, ``decision_function``,
``predict_proba`` and the region queries. Parameter checks live in :mod:`hilbertmap._checks`,
surfaces and slices in :mod:`hilbertmap.surfaces`, the file format in
:mod:`hilbertmap.persistence`; the methods of the same names delegate to them.
"""
from __future__ import annotations

import inspect
import time

import numpy as np

from . import persistence, sgd, surfaces
from ._backend import KernelGrid
from ._threads import interruptible
from ._checks import as_points, check_params
from .embedding import Samples, embed_scan, sampling_for
from .inducing import Coverage, choose_inducing, spacing
from .scanlike import ScanLike, as_scan_list, check_scan
from .surfaces import MapSlice

__all__ = ["HilbertMap", "MapSlice"]


class HilbertMap:
    """Hilbert map of 3-D occupancy from sonar scans, a scikit-learn style estimator.

    The constructor only stores its arguments (hyper-parameters); each is checked at ``fit``,
    ``partial_fit`` and ``embed``, and a bad one raises a ValueError naming it. Learnt state lives
    in attributes ending with ``_``. ``get_params`` / ``set_params`` / ``repr`` follow
    scikit-learn's conventions.

    Parameters
    ----------
    n_inducing : int, default 3000
        Nystroem inducing points (3000 in the thesis); at most the number of training samples the
        scans give (free samples plus occupied bins).
    inducing : {'kmeans', 'grid', 'random', 'samples'}, default 'kmeans'
        Where the inducing points go: k-means centres of the samples (as the original Hilbert-maps
        code), a lattice over the region seen, uniform points in it, or a subset of the samples.
    inducing_occupied_share : float in [0, 1], default 0.85
        Share of occupied samples among the k-means input points: open water needs few centres
        (the intercept keeps it free), the surfaces need them dense to come out thin and unbroken.
    inducing_voxel : float >= 0 or None, default 0.1
        The k-means input is thinned to one point per voxel of this side (0 or None: off), so the
        centres spread over the area seen instead of following how many pings saw it.
    lengthscale : float > 0 or 'auto', default 'auto'
        RBF length ``l`` in metres; ``auto`` is ``lengthscale_factor`` times the median
        nearest-neighbour spacing of the inducing points.
    lengthscale_factor : float > 0, default 1.2
        See ``lengthscale``.
    kernel_cut : float in (0, 1), default 1e-5
        Kernel values below this are zero (locality; no denormals).
    eig_floor : float in [0, 1), default 1e-6
        Eigenvalues of ``G`` below ``eig_floor`` times the largest are dropped (rank cut).
    source : {'auto', 'data', 'intensity'}, default 'auto'
        What the bins are classified on; ``auto`` takes ``data`` unless it is all zero.
    bin_rule : {'otsu+cfar', 'otsu', 'cfar', 'threshold'}, default 'otsu+cfar'
        How bins are called full (:mod:`hilbertmap.classify`).
    threshold, min_level, cfar_offset : float or None, default None
        Tuning of the bin rules. ``None``: for ``data`` a floor of 96 and a CFAR offset of 40
        levels; for ``intensity``, classified in dB, -95 dB and 10 dB.
    cfar_train, cfar_guard : int, default 16, 2
        CFAR training and guard cells on each side of the cell under test.
    blanking : float >= 0 or 'auto', default 'auto'
        Range (m) below which bins are ignored (ring-down); ``auto`` finds it from the scan.
    min_echo_bins : int >= 0, default 4
        Full bins in runs shorter than this are taken as noise. A surface's echo lasts the pulse
        (``c tau / 2`` = 7.5 cm, 3.1 bins of 2.4 cm for a Micron) widened by the range jitter, so
        it fills at least 4 full bins; the receiver's noise is correlated over the pulse too: 200
        pings of the thesis box held, in 2.5 m of open water, 92 runs of 2 bins above the floor,
        18 of 3, 3 of 4 and 2 of 5. With 2, 60-66 % of the pings had their first echo in the
        water, 0.15 m or more before the wall; with 5, 8-10 %, 32 of those 34 within 0.3 m of an
        oblique wall, where the beam's skirt meets the wall first (horizontal scans, seeds 0 and
        3). Measured on the thesis box (seeds 0, 3, 11; two-sided slice distance of the ridge) and
        on the forward-looking box frames of ``tests/test_multibeam.py`` (ridge F-score at 0.2 m):
        3 bins 0.21 / 3.0 / 0.23 m and 0.86; 4 bins 0.24 / 0.24 / 0.23 m and 0.82; 5 bins
        0.26 / 0.36 / 0.45 m and 0.66 (a multibeam frame's weak grazing echoes break into runs of
        3-4 bins under speckle).
    free_density : float >= 0, default 40.0
        Free samples per cubic metre of empty beam volume ...
    max_free_per_ping : int >= 0 or 'auto', default 400
        ... at most this many per ping. ``'auto'`` (here and for ``near_free`` and
        ``occupied_samples``): chosen per scan by its ``kind``, 24 / 8 / 8 for a multibeam frame,
        400 / 32 / 16 for the others (``hilbertmap.embedding.SAMPLING_AUTO``, where the measured
        trade-off is stated); :class:`~hilbertmap.IncrementalHilbertMap`'s default.
    free_margin : float >= 0, default 0.0
        Metres of the empty beam left unsampled before the first echo.
    near_free : int >= 0 or 'auto', default 32
        Extra free samples per ping with an echo, uniform in range over the last ``near_depth``
        metres before it. Volume sampling puts few there, yet that shell is what tells the wall from
        the water just in front of it; they are thinned on their own per-voxel budget.
    near_depth : float >= 0, default 0.3
        See ``near_free``.
    occupied_samples : int >= 1 or 'auto', default 16
        Points per full bin (averaged in feature space, eq. 4.6).
    occupied_bins : {'first_run', 'first', 'all'}, default 'first_run'
        The first full bin, the full bins contiguous with it (at most ``max_run`` metres), or all.
    max_run : float > 0, default 0.3
        See ``occupied_bins``.
    occupied_weight : float > 0 or 'balanced', default 5.0
        Weight of an occupied bin relative to a free sample; ``balanced`` makes both classes weigh
        the same in total. A bin's points spread over the beam's fan, much of it in front of the
        wall, so a heavy weight pushes the wall's face into the water.
    occupied_pooling : {'mean', 'lse'}, default 'mean'
        How a full bin's points make one logit: ``mean`` (kernel mean embedding, eq. 4.6) or
        ``lse``, the soft maximum ``tau log mean exp(f / tau)`` (an echo needs only one reflector in
        the bin, so the learner may place it where the free space of other pings leaves room).
    pooling_temperature : float > 0, default 1.0
        ``tau`` of ``lse``.
    beam_sampling : {'pattern', 'uniform'}, default 'pattern'
        Sample directions drawn by the two-way beam pattern, or uniformly in the nominal frustum
        (the thesis).
    beam_extent : float > 0, default 1.0
        Samples lie within this many -3 dB half widths of the boresight (1: the nominal frustum,
        where the two-way gain is >= -6 dB).
    beam_stride : float >= 1, default 1
        Use every ``beam_stride``-th ping (Algorithm 3's partition; 10/3 keeps 30 % of the beams,
        evenly spread).
    alpha : float >= 0, default 1e-6
        Elastic-net strength (eq. 4.5); a strong penalty caps the logits and thickens the walls.
    l1_ratio : float in [0, 1], default 0.15
        The l1 share of the penalty.
    schedule : {'thesis', 'classic', 'ramos_ott', 'constant'}, default 'thesis'
        Step schedule: eq. 4.12, eq. 4.11, Ramos and Ott's, or constant.
    eta0 : float > 0 or 'auto', default 'auto'
        Initial step; ``auto`` is ``1 / L`` with ``L`` the largest curvature of the mean loss at
        ``w = 0`` (:func:`hilbertmap.sgd.initial_step`).
    k1 : float >= 0, default 1.0
        Eq. 4.12's ``k1``.
    t0 : float > 0 or None, default None
        Ramos and Ott's ``t0`` (``None``: the first step is ``eta0``).
    batch_size : int >= 1, default 2048
        Points (lanes) per mini-batch.
    n_passes : int >= 1, default 5
        Passes over the samples in ``fit``.
    partial_passes : int >= 1, default 1
        Passes over a scan's samples in ``partial_fit``.
    fit_intercept : bool, default True
        Learn an unregularised bias ``b``.
    bounds : (lo, hi) or None, default None
        Region (two 3-vectors, metres) for ``grid`` / ``random`` inducing points; default the region
        seen.
    coverage_voxel : float > 0, default 0.25
        Voxel side (metres) of the record of the region seen and of the per-voxel caps.
    max_free_per_voxel : int >= 1 or None, default 12
        Keep at most this many free samples per voxel (``None``: all). Where many pings overlap,
        the surfaces that few pings see (grazing incidence) otherwise drown in the free space of the
        pings around them; the free evidence right in front of the walls is what pulls the 0.5
        level onto them.
    max_groups_per_voxel : int >= 1 or None, default 2
        The same cap for occupied bins, by their centre.
    multi_echo : bool, default False
        Label free also the water between a ping's echoes where the beam reached it: after a fit
        on first-echo evidence, each candidate between the first and the last echo run is kept
        with probability ``1 - max p`` along its path from the transducer (its visibility in that
        map: a direction the first echo's reflector shadows crosses it), and the map is learnt
        again on both (:mod:`hilbertmap.multiecho`); about twice the SGD time. Off by default: in
        the thesis box (seed 11) 91 % of the candidates lie behind the walls (multipath echoes),
        6 of 43155 pass and the slice distance stays 0.23 m; on the harbour's multibeam frames
        (100, batch) 1 of 911 passes.
    random_state : int >= 0 or None, default None
        Seed of every random choice.
    variant : {'llvm', 'cuda'}, default 'llvm'
        Dr.Jit backend.

    Attributes
    ----------
    inducing_points_ : ndarray (n, 3)
        The inducing points ``nu``, in the kernel grid's order.
    lengthscale_, gamma_ : float
        The kernel length ``l`` and ``1 / (2 l^2)``.
    n_components_ : int
        Eigen-components kept (``k``).
    weights_ : ndarray (k,)
        ``w``; ``dual_coef_`` (n,) is ``M^T w``, the kernel expansion's coefficients.
    intercept_ : float
        ``b``.
    coverage_, echo_coverage_, free_coverage_ : Coverage
        Voxels holding samples, full-bin samples and free samples.
    sensor_positions_, ping_frames_, ping_beams_, ping_spans_ : ndarray
        Where the training pings were and what they saw (for :meth:`insonified`).
    occupied_weight_, eta0_, n_schedule_, t_, n_samples_seen_ : float
        Resolved weight and initial step, epoch size of the schedule, samples seen.
    loss_curve_ : list of float
        Mean weighted loss per pass.
    timings_ : dict
        Seconds of the last ``fit``: ``embed_s``, ``features_s``, ``sgd_s``, ``total_s``.
    """

    def __init__(self, n_inducing=3000, *, inducing="kmeans", inducing_occupied_share=0.85, inducing_voxel=0.1,
                 lengthscale="auto", lengthscale_factor=1.2, kernel_cut=1e-5, eig_floor=1e-6, source="auto",
                 bin_rule="otsu+cfar", threshold=None, min_level=None, cfar_train=16, cfar_guard=2,
                 cfar_offset=None, blanking="auto", min_echo_bins=4, free_density=40.0, max_free_per_ping=400,
                 free_margin=0.0, near_free=32, near_depth=0.3, occupied_samples=16, occupied_bins="first_run",
                 max_run=0.3, occupied_weight=5.0, occupied_pooling="mean", pooling_temperature=1.0,
                 beam_sampling="pattern", beam_extent=1.0, beam_stride=1, alpha=1e-6, l1_ratio=0.15,
                 schedule="thesis", eta0="auto", k1=1.0, t0=None, batch_size=2048, n_passes=5, partial_passes=1,
                 fit_intercept=True, bounds=None, coverage_voxel=0.25, max_free_per_voxel=12,
                 max_groups_per_voxel=2, multi_echo=False, random_state=None, variant="llvm"):
        args = locals()
        for name in self._get_param_names():
            setattr(self, name, args[name])

    # -- scikit-learn plumbing ------------------------------------------------------------------
    @classmethod
    def _get_param_names(cls) -> list:
        """The hyper-parameters: the constructor's arguments, in order."""
        return [p for p in inspect.signature(cls.__init__).parameters if p != "self"]

    @classmethod
    def _defaults(cls) -> dict:
        return {k: p.default for k, p in inspect.signature(cls.__init__).parameters.items() if k != "self"}

    def get_params(self, deep: bool = True) -> dict:
        """The hyper-parameters as a dict (``deep`` is accepted for scikit-learn; nothing nests)."""
        return {k: getattr(self, k) for k in self._get_param_names()}

    def set_params(self, **params) -> "HilbertMap":
        """Set hyper-parameters (checked at the next ``fit``); an unknown name is a ValueError."""
        names = set(self._get_param_names())
        for k, v in params.items():
            if k not in names:
                raise ValueError(f"HilbertMap: unknown parameter {k!r}")
            setattr(self, k, v)
        return self

    def __repr__(self) -> str:
        defaults = self._defaults()
        changed = {k: v for k, v in self.get_params().items() if v != defaults[k]}
        args = ", ".join(f"{k}={v!r}" for k, v in changed.items())
        return f"HilbertMap({args})"

    # -- embedding --------------------------------------------------------------------------
    def embed(self, scan: ScanLike, rng: np.random.Generator | None = None) -> Samples:
        """Labelled samples of one scan with this map's embedding settings (thesis 4.2.1); a scan
        without poses, with poses that are not rigid or with NaN ranges is refused in one line
        (:func:`hilbertmap.scanlike.check_scan`)."""
        check_params(self)
        check_scan(scan, self.source)
        return embed_with(self, scan, rng)

    def embed_all(self, scans, rng: np.random.Generator | None = None, *, progress=None) -> Samples:
        """The samples of one :class:`~hilbertmap.scanlike.ScanLike` scan or a list of them, concatenated
        (``progress("embedding", done, total)`` after each scan, as :meth:`fit`'s)."""
        scans = as_scan_list(scans, self.source)
        rng = rng if rng is not None else np.random.default_rng(self.random_state)
        parts = []
        for k, scan in enumerate(scans):
            parts.append(self.embed(scan, rng))
            _report(progress, "embedding", k + 1, len(scans))
        return Samples.concatenate(parts)

    # -- training ----------------------------------------------------------------------------
    def fit(self, scans, samples: Samples | None = None, *, progress=None) -> "HilbertMap":
        """Learn the map from scratch from a list of scans (or one scan).

        ``samples`` (from :meth:`embed_all`) skips the embedding. ``timings_`` records the
        seconds spent embedding, building the features (inducing points, Gram matrix and its
        eigen-decomposition, step-size estimate) and in SGD.

        ``progress``: called as ``progress(stage, done, total)`` as the fit goes: ``"embedding"``
        after each scan, ``"features"`` (0 of 1, then 1 of 1 once the Gram matrix is decomposed),
        ``"sgd"`` after each mini-batch of all ``n_passes`` passes, and ``"sgd multi-echo"`` for
        the refit of ``multi_echo``. A KeyboardInterrupt (Ctrl-C) acts between batches, and during
        the eigen-decomposition at once (:func:`hilbertmap._threads.interruptible`); the
        estimator is then partly trained: fit it again before use.
        """
        t_start = time.perf_counter()
        check_params(self)
        self._rng = np.random.default_rng(self.random_state)
        if samples is None:
            samples = self.embed_all(scans, self._rng, progress=progress)
        samples = self._thin(samples)
        t_embed = time.perf_counter()
        if len(samples.free) + len(samples.occupied) == 0:
            raise ValueError("HilbertMap: the scans gave no samples (no pings, or all bins blanked)")
        self._check_n_inducing(samples, "these scans")
        _report(progress, "features", 0, 1)
        self._initialise(samples)
        _report(progress, "features", 1, 1)
        self._set_weights(samples)
        self.n_schedule_ = len(samples.free) + len(samples.occupied)
        self.eta0_ = sgd.initial_step(self, samples)
        t_init = time.perf_counter()
        self.loss_curve_ = []
        self._passes(samples, "sgd", progress)
        if self.multi_echo and len(samples.between_points()):
            self._refit_multi_echo(samples, progress)
        t_end = time.perf_counter()
        self.timings_ = dict(embed_s=t_embed - t_start, features_s=t_init - t_embed, sgd_s=t_end - t_init,
                             total_s=t_end - t_start)
        return self

    def _passes(self, samples: Samples, stage: str, progress=None) -> None:
        """``n_passes`` SGD passes over ``samples``, their losses added to ``loss_curve_``, the
        batches reported as ``stage``."""
        total = int(self.n_passes) * sgd.n_batches(self, samples)
        done = 0

        def step():
            nonlocal done
            done += 1
            _report(progress, stage, done, total)

        _report(progress, stage, 0, total)
        for _ in range(int(self.n_passes)):
            self.loss_curve_.append(self._sgd_pass(samples, step if progress is not None else None))

    def partial_fit(self, scan: ScanLike, samples: Samples | None = None) -> "HilbertMap":
        """Online update with one scan (``partial_passes`` passes over its samples).

        The first call places the inducing points: in ``bounds`` when given, else in the region
        this first scan saw (later scans that look elsewhere are only learnt where that region
        reaches). Later calls go on from the current weights and step count.
        """
        check_params(self)
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
            self.eta0_ = sgd.initial_step(self, samples)
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

    def _refit_multi_echo(self, samples: Samples, progress=None) -> None:
        """Label free the multi-echo candidates the first map shows reached (kept with probability
        their visibility, :mod:`hilbertmap.multiecho`), thin them on the per-voxel budget and learn
        the weights again, from zero, on both kinds of free space (same inducing points)."""
        import dataclasses

        from . import multiecho

        cand = samples.between_points()
        ping = samples.between_ping
        vis = multiecho.visibility(self, cand, samples.origins[ping], samples.spans[ping, 0], margin=self.near_depth)
        keep = multiecho.keep_visible(vis, self._rng)
        extra = dataclasses.replace(samples, free=cand[keep], free_gap=samples.between_gap[keep],
                                    occupied=samples.occupied[:0])
        extra = self._thin(extra)
        self.n_between_candidates_ = int(len(cand))
        self.between_visibility_ = vis
        self.multi_echo_free_ = extra.free  # the candidates labelled free (not saved with the map)
        if not len(extra.free):
            return  # nothing reached: the first map stands (a refit would only redraw the SGD's batches)
        merged = dataclasses.replace(samples, free=np.concatenate([samples.free, extra.free]),
                                     free_gap=np.concatenate([samples.gaps(), extra.gaps()]))
        self.free_coverage_.add(extra.free)
        self.coverage_.add(extra.free)
        self.weights_ = np.zeros_like(self.weights_)
        self.dual_coef_ = np.zeros_like(self.dual_coef_)
        self.intercept_ = 0.0
        self.t_ = 0.0
        self.n_schedule_ = len(merged.free) + len(merged.occupied)
        self.eta0_ = sgd.initial_step(self, merged)
        self._passes(merged, "sgd multi-echo", progress)

    def _check_n_inducing(self, samples: Samples, source: str) -> None:
        # More inducing points than samples leaves the kernel no data to span (the length-scale
        # shrinks to the sample spacing and the map to beads), and the n x n Gram matrix grows
        # with n^2: 100000 points would need 75 GiB. Checked before anything that large is made.
        n = len(samples.free) + len(samples.occupied)
        if self.n_inducing > n:
            raise ValueError(f"HilbertMap: n_inducing must be at most the number of training samples "
                             f"({n} from {source}), not {self.n_inducing}")

    def _thin(self, samples: Samples) -> Samples:
        """Cap the free samples and occupied groups per voxel (:func:`hilbertmap.sgd.thin`)."""
        return sgd.thin(self, samples)

    def _sgd_pass(self, samples: Samples, step=None) -> float:
        """One pass of mini-batch SGD (:func:`hilbertmap.sgd.sgd_pass`); the mean weighted loss."""
        return sgd.sgd_pass(self, samples, step)

    def _set_weights(self, samples: Samples) -> None:
        F, G = len(samples.free), len(samples.occupied)
        if isinstance(self.occupied_weight, str):
            if self.occupied_weight != "balanced":
                raise ValueError("HilbertMap: occupied_weight must be 'balanced' or a number")
            self.occupied_weight_ = float(F) / max(G, 1) if G else 1.0
        else:
            self.occupied_weight_ = float(self.occupied_weight)

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
        """``M = Lambda^(-1/2) Q^T`` from the eigen-decomposition of the Gram matrix (rank cut)."""
        G = self._grid.gram()
        lam, Q = interruptible(np.linalg.eigh, G)  # Ctrl-C acts at once
        keep = lam > self.eig_floor * lam[-1]
        lam, Q = lam[keep], Q[:, keep]
        self.n_components_ = int(keep.sum())
        M = (Q / np.sqrt(lam)).T  # (k, n) = Lambda^-1/2 Q^T
        self._M = np.ascontiguousarray(M, dtype=np.float32)
        self._MT = np.ascontiguousarray(M.T, dtype=np.float32)

    def _make_grid(self) -> KernelGrid:
        """The kernel grid of the learnt inducing points (already in grid order)."""
        grid = KernelGrid(self.inducing_points_, self.lengthscale_, self.kernel_cut, self.variant)
        grid.order = np.arange(len(self.inducing_points_))
        grid.inv_order = grid.order
        return grid

    def _ensure_features(self) -> None:
        if not hasattr(self, "_grid"):
            self._grid = self._make_grid()
        if not hasattr(self, "_M"):
            self._build_features()
            if len(self.weights_) != self._M.shape[0]:
                raise ValueError("HilbertMap: saved weights do not match the rebuilt features")
        if not hasattr(self, "_rng"):
            self._rng = np.random.default_rng(self.random_state)

    # -- queries (none of them changes the map) ----------------------------------------------
    def _check_fitted(self) -> None:
        if not hasattr(self, "dual_coef_"):
            raise RuntimeError("HilbertMap: call fit() or partial_fit() before querying the map")

    def decision_function(self, points, chunk: int = 1 << 21) -> np.ndarray:
        """Logit ``f(x) = w . phi(x) + b = sum_j dual_coef_j k(x, nu_j) + b`` at (N, 3) world points."""
        self._check_fitted()
        pts = as_points(points)
        grid = self._grid if hasattr(self, "_grid") else self._make_grid()
        coef = grid.upload(self.dual_coef_)
        out = np.empty(len(pts), dtype=np.float64)
        for a in range(0, len(pts), chunk):
            out[a:a + chunk] = grid.kernel_sum_at(pts[a:a + chunk], coef)
        return out + self.intercept_

    def predict_proba(self, points) -> np.ndarray:
        """Occupancy probability ``sigmoid(f(x))`` in [0, 1] at (N, 3) world points -> (N,)."""
        return sgd.sigmoid(self.decision_function(points))

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
        # pings in blocks: the line-of-sight test runs once per block on the distinct (sensor
        # position, point) pairs of its pings (a multibeam frame's beams share one position)
        block = 256
        for k0 in range(0, len(frames), block):
            rest = np.nonzero(~out)[0]
            if len(rest) == 0:
                break
            pairs_o, pairs_i = [], []
            for k in range(k0, min(k0 + block, len(frames))):
                if part == "echo" and not np.isfinite(spans[k, 1]):
                    continue
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
                if vertices is None or part == "echo":
                    out[idx] = True
                elif len(idx):
                    pairs_o.append(np.broadcast_to(o, (len(idx), 3)))
                    pairs_i.append(idx)
            if pairs_i:
                O = np.concatenate(pairs_o)
                I = np.concatenate(pairs_i)
                key = np.unique(np.column_stack([O, I.astype(np.float64)]), axis=0)
                O, I = key[:, :3], key[:, 3].astype(np.int64)
                todo = ~out[I]
                blocked = segments_blocked(O[todo], P[I[todo]], vertices, faces)
                out[I[todo][~blocked]] = True
        return out

    # -- surfaces and slices (hilbertmap.surfaces) --------------------------------------------
    def slice(self, axis="z", value: float = 0.0, extent=None, resolution: float = 0.05) -> MapSlice:
        """Probability on the plane ``axis = value``.

        ``extent``: ((u_min, u_max), (v_min, v_max)) over the two other axes in x, y, z order
        (default: the region seen); ``resolution`` in metres, at most ``MAX_GRID_POINTS`` points in
        all. Returns a :class:`MapSlice`.
        """
        return surfaces.cross_section(self, axis, value, extent=extent, resolution=resolution)

    def isosurface(self, level: float = 0.5, resolution: float | None = None, bounds=None,
                   only_seen: bool = True, grid=None):
        """Triangle mesh (vertices (V,3), faces (F,3)) of the ``p = level`` surface
        (:func:`hilbertmap.surfaces.isosurface`)."""
        return surfaces.isosurface(self, level=level, resolution=resolution, bounds=bounds, only_seen=only_seen,
                                   grid=grid)

    def ridge_surface(self, resolution: float | None = None, bounds=None, level: float = 0.5,
                      max_shift: float | None = None, only_seen: bool = True, plateau: float | None = 0.1,
                      front_only: bool = True, grid=None):
        """Triangle mesh on the probability ridge: the wall as seen from the free side
        (:func:`hilbertmap.surfaces.ridge_surface`)."""
        return surfaces.ridge_surface(self, resolution=resolution, bounds=bounds, level=level, max_shift=max_shift,
                                      only_seen=only_seen, plateau=plateau, front_only=front_only, grid=grid)

    def surface(self, method: str = "ridge", **kw):
        """``method='ridge'`` (default) or ``'level'`` (the ``level`` isosurface)."""
        return surfaces.surface(self, method, **kw)

    # -- persistence (hilbertmap.persistence) --------------------------------------------------
    def save(self, path) -> None:
        """Write the map (hyper-parameters and learnt state) to an ``.npz`` file."""
        persistence.save(self, path)

    @classmethod
    def load(cls, path) -> "HilbertMap":
        """Read a map written by :meth:`save`. A file that is not one, or whose arrays do not agree
        with each other, is refused with a ValueError naming the file and what is wrong."""
        return persistence.load(cls, path)


def _report(progress, stage: str, done: int, total: int) -> None:
    if progress is not None:
        progress(stage, done, total)


def _unique_rows(a: np.ndarray) -> np.ndarray:
    if len(a) == 0:
        return np.zeros((0, 3))
    return np.unique(np.round(np.asarray(a, dtype=np.float64), 6), axis=0)


def embed_with(hm, scan, rng=None) -> Samples:
    """`embed_scan` of ``scan`` with the embedding settings of the estimator ``hm`` (a
    `HilbertMap` or an incremental one), its ``random_state`` seeding ``rng`` when None."""
    rng = rng if rng is not None else np.random.default_rng(hm.random_state)
    budget = sampling_for(scan, hm.max_free_per_ping, hm.near_free, hm.occupied_samples)  # "auto": by kind
    return embed_scan(
        scan, rng, source=hm.source, bin_rule=hm.bin_rule, threshold=hm.threshold,
        min_level=hm.min_level, cfar_train=hm.cfar_train, cfar_guard=hm.cfar_guard,
        cfar_offset=hm.cfar_offset, blanking=hm.blanking, free_density=hm.free_density,
        free_margin=hm.free_margin, near_depth=hm.near_depth, **budget,
        occupied_bins=hm.occupied_bins, max_run=hm.max_run,
        beam_sampling=hm.beam_sampling, beam_extent=hm.beam_extent, ping_stride=hm.beam_stride,
        min_echo_bins=hm.min_echo_bins, multi_echo=bool(getattr(hm, "multi_echo", False)),
    )
