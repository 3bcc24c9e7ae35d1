"""The training steps of :meth:`HilbertMap.fit`: evidence thinning, initial step, SGD passes.

Loss (thesis eq. 4.4, 4.5): the weighted mean logistic loss of the samples,
``sum_i c_i log(1 + exp(-s_i f_i)) / sum_i c_i`` with ``s_i = +-1`` (occupied / free) and the weight
``c_i`` (1 for a free sample, ``occupied_weight_`` for a full bin), plus the elastic-net penalty
``alpha (l1_ratio |w|_1 + (1 - l1_ratio) / 2 |w|^2)``. A full bin's logit pools the logits of its
points: their mean (kernel mean embedding, eq. 4.6) or the soft maximum
``tau log mean exp(f / tau)``.

Mini-batch SGD (eq. 4.10) with the step ``eta_t`` of :mod:`hilbertmap.schedules`:
``w <- prox(w - eta_t (M sum_i g_i k(x_i) + alpha (1 - l1_ratio) w))``, the l1 part applied as a
proximal soft threshold ``sign(w) max(|w| - eta_t alpha l1_ratio, 0)``. The kernel sum and its
adjoint run in Dr.Jit (:mod:`hilbertmap._backend`), the two ``n x n`` products in BLAS.

The functions take the estimator and update its learnt state (``weights_``, ``dual_coef_``,
``intercept_``, ``t_``, ``n_samples_seen_``); they are called from ``fit`` and ``partial_fit``.
"""
from __future__ import annotations

import dataclasses
import math

import numpy as np

from . import schedules as _sched
from .embedding import Samples


def sigmoid(z):
    """The logistic function ``1 / (1 + exp(-z))``, written with tanh (no overflow)."""
    return 0.5 * (1.0 + np.tanh(0.5 * z))


def thin(hm, samples: Samples) -> Samples:
    """Cap the free samples and occupied groups per voxel of ``coverage_voxel``
    (``max_free_per_voxel``, ``max_groups_per_voxel``); which are kept is drawn at random."""
    if hm.max_free_per_voxel is None and hm.max_groups_per_voxel is None:
        return samples
    rng = np.random.default_rng(None if hm.random_state is None else hm.random_state + 7)

    def keep(points, cap):
        if cap is None or len(points) == 0:
            return np.arange(len(points))
        idx = np.floor(points / hm.coverage_voxel).astype(np.int64)
        key = (idx[:, 0] * 1_000_003 + idx[:, 1]) * 1_000_033 + idx[:, 2]
        perm = rng.permutation(len(points))
        order = perm[np.argsort(key[perm], kind="stable")]
        k = key[order]
        start = np.r_[0, np.nonzero(k[1:] != k[:-1])[0] + 1]
        rank = np.arange(len(k)) - np.repeat(start, np.diff(np.r_[start, len(k)]))
        return np.sort(order[rank < int(cap)])

    gap = samples.gaps()
    near = gap < float(hm.near_depth) if hm.near_free else np.zeros(len(gap), dtype=bool)
    # the shell before the echoes is thinned on its own budget, not crowded out by open water
    i_far, i_near = np.nonzero(~near)[0], np.nonzero(near)[0]
    kf = np.sort(np.concatenate([i_far[keep(samples.free[i_far], hm.max_free_per_voxel)],
                                 i_near[keep(samples.free[i_near], hm.max_free_per_voxel)]]))
    kg = keep(samples.occupied.mean(axis=1) if len(samples.occupied) else np.zeros((0, 3)),
              hm.max_groups_per_voxel)
    return dataclasses.replace(samples, free=samples.free[kf], occupied=samples.occupied[kg], free_gap=gap[kf],
                               occupied_ping=samples.occupied_ping[kg] if samples.occupied_ping is not None else None)


def initial_step(hm, samples: Samples, lanes: int = 8192, iters: int = 12) -> float:
    """``eta0``, or for ``eta0='auto'`` the step ``1 / L`` with ``L`` the largest curvature of the
    mean loss at ``w = 0``: a quarter of the top eigenvalue of the weighted feature covariance
    ``M K^T C K M^T`` (``C`` the normalised sample weights), by ``iters`` power iterations on a
    batch of at most ``lanes`` points. It is the largest step plain gradient descent takes safely."""
    if hm.eta0 != "auto":
        return float(hm.eta0)
    import drjit as dr

    grid = hm._grid
    rng = np.random.default_rng(0 if hm.random_state is None else hm.random_state)
    F, G = len(samples.free), len(samples.occupied)
    m = samples.occupied.shape[1] if G else 1
    share = F / max(F + G * m, 1)
    nf = min(F, int(lanes * share))
    ng = min(G, max(1, (lanes - nf) // m)) if G else 0
    i_f = rng.choice(F, nf, replace=False) if nf else np.zeros(0, dtype=np.int64)
    i_g = rng.choice(G, ng, replace=False) if ng else np.zeros(0, dtype=np.int64)
    pts = np.concatenate([samples.free[i_f], samples.occupied[i_g].reshape(-1, 3)])
    c = np.concatenate([np.ones(nf), np.full(ng, hm.occupied_weight_)])
    c = c / c.sum()
    x, y, z = grid.to_lanes(pts)
    v = rng.normal(size=hm._M.shape[0])
    lam = 1.0
    for _ in range(iters):
        v = v / np.linalg.norm(v)
        coef = grid.upload(hm._MT @ v.astype(np.float32))
        f = grid.kernel_sum(x, y, z, coef).numpy().astype(np.float64)  # Phi v per lane
        f_item = np.concatenate([f[:nf], f[nf:].reshape(ng, m).mean(axis=1)]) if ng else f[:nf]
        u = c * f_item
        u_lane = np.concatenate([u[:nf], np.repeat(u[nf:] / m, m)]).astype(np.float32)
        out = dr.zeros(grid.Float, grid.n)
        grid.kernel_scatter(x, y, z, grid.upload(u_lane), out)
        w = hm._M @ out.numpy()
        lam = float(np.linalg.norm(w))
        v = w
    L = 0.25 * max(lam, 1e-12)
    return 1.0 / L


def n_batches(hm, samples: Samples) -> int:
    """The mini-batches of one pass over ``samples`` (``batch_size`` lanes each, an occupied
    group's points being lanes)."""
    F, G = len(samples.free), len(samples.occupied)
    m = samples.occupied.shape[1] if G else 1
    return max(1, int(math.ceil((F + G * m) / max(int(hm.batch_size), 1))))


def sgd_pass(hm, samples: Samples, step=None) -> float:
    """One shuffled pass of mini-batch SGD over ``samples``; returns the mean weighted loss seen.
    ``step``: called after each mini-batch (``n_batches`` in all; progress).

    The two n x n products of a step run on one BLAS thread when ``threadpoolctl`` is
    installed: idle BLAS threads spin and slow the Dr.Jit kernels that follow.
    """
    try:
        from threadpoolctl import threadpool_limits
    except ImportError:
        return _sgd_pass(hm, samples, step)
    with threadpool_limits(limits=1, user_api="blas"):
        return _sgd_pass(hm, samples, step)


def _sgd_pass(hm, samples: Samples, step=None) -> float:
    import drjit as dr

    grid = hm._grid
    F, G = len(samples.free), len(samples.occupied)
    m = samples.occupied.shape[1] if G else 1
    nb = n_batches(hm, samples)
    pf = np.array_split(hm._rng.permutation(F), nb)
    pg = np.array_split(hm._rng.permutation(G), nb)
    free = samples.free
    occ = samples.occupied
    occ_centre_keys = grid.cell_keys(occ.mean(axis=1)) if G else np.zeros(0, dtype=np.int64)
    free_keys = grid.cell_keys(free) if F else np.zeros(0, dtype=np.int64)
    Float = grid.Float

    alpha_dr = grid.upload(hm.dual_coef_)
    c_occ = hm.occupied_weight_
    lam = float(hm.alpha)
    rho = float(hm.l1_ratio)
    loss_sum = 0.0
    wsum_all = 0.0
    for b in range(nb):
        i_f = pf[b]
        i_g = pg[b]
        i_f = i_f[np.argsort(free_keys[i_f], kind="stable")]
        i_g = i_g[np.argsort(occ_centre_keys[i_g], kind="stable")]
        bf, bg = len(i_f), len(i_g)
        if bf + bg == 0:
            if step is not None:
                step()
            continue
        pts = np.concatenate([free[i_f], occ[i_g].reshape(-1, 3)])
        x, y, z = grid.to_lanes(pts)
        f_lane = grid.kernel_sum(x, y, z, alpha_dr).numpy().astype(np.float64) + hm.intercept_
        f_occ = f_lane[bf:].reshape(bg, m)
        if hm.occupied_pooling == "mean":  # kernel mean embedding: mean of w . phi (eq. 4.6)
            f_pool = f_occ.mean(axis=1)
            share = np.full((bg, m), 1.0 / m)
        elif hm.occupied_pooling == "lse":  # soft maximum over the bin's points
            tau = float(hm.pooling_temperature)
            mx = f_occ.max(axis=1, keepdims=True)
            e = np.exp((f_occ - mx) / tau)
            f_pool = mx[:, 0] + tau * np.log(e.mean(axis=1))
            share = e / e.sum(axis=1, keepdims=True)
        else:
            raise ValueError(f"HilbertMap: occupied_pooling must be 'mean' or 'lse', not {hm.occupied_pooling!r}")
        f_item = np.concatenate([f_lane[:bf], f_pool])
        y_item = np.concatenate([np.zeros(bf), np.ones(bg)])
        c_item = np.concatenate([np.ones(bf), np.full(bg, c_occ)])
        csum = c_item.sum()
        p = sigmoid(f_item)
        # logistic loss log(1 + exp(-s f)), s = +-1, computed stably
        s = 2.0 * y_item - 1.0
        loss_sum += float(np.sum(c_item * np.logaddexp(0.0, -s * f_item)))
        wsum_all += csum
        g_item = c_item * (p - y_item) / csum
        g_lane = np.concatenate([g_item[:bf], (g_item[bf:, None] * share).ravel()]).astype(np.float32)
        out = dr.zeros(Float, grid.n)
        grid.kernel_scatter(x, y, z, grid.upload(g_lane), out)
        svec = out.numpy()
        eta = _sched.step_size(hm.schedule, hm.t_, hm.n_schedule_, float(hm.eta0_), float(hm.k1),
                               hm.t0, lam, rho)
        w = hm.weights_
        grad = hm._M @ svec + lam * (1.0 - rho) * w
        w = w - eta * grad
        if rho > 0:
            thr = eta * lam * rho
            w = np.sign(w) * np.maximum(np.abs(w) - thr, 0.0)
        hm.weights_ = w
        hm.dual_coef_ = (hm._MT @ w.astype(np.float32)).astype(np.float64)
        alpha_dr = grid.upload(hm.dual_coef_)
        if hm.fit_intercept:
            # the bias sees the whole batch's curvature (<= 1/4): its step is capped for stability
            hm.intercept_ -= min(eta, 2.0) * float(g_item.sum())
        hm.t_ += bf + bg
        hm.n_samples_seen_ += bf + bg
        if step is not None:
            step()
    return loss_sum / max(wsum_all, 1e-300)
