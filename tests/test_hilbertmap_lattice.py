"""The lattice kernels of the incremental Hilbert map (hilbertmap._backend.LatticeGrid).

Nodes sit at ``(k + 1/2) h`` for integer lattice indices ``k``; the grid finds a point's nodes
from its lattice cell. Checked against the dense numpy sums of the cut RBF kernel, for several
kernel supports (the number of lattice offsets a lane visits changes with them).
"""
import numpy as np
import pytest

import drjit as dr

from hilbertmap import IncrementalHilbertMap
from hilbertmap._backend import LatticeGrid, cut_radius
from hilbertmap.testing import box_scan, moving_poses


def _dense(idx, h, ell, cut, x):
    nu = (idx + 0.5) * h
    d2 = ((x[:, None, :] - nu[None]) ** 2).sum(-1)
    K = np.exp(-d2 / (2 * ell ** 2))
    K[d2 >= cut_radius(ell, cut) ** 2] = 0.0
    return K


@pytest.mark.parametrize("ell_factor,cut", [(1.0, 1e-2), (0.6, 1e-3), (1.7, 1e-2)])
def test_lattice_kernels_match_dense_numpy(ell_factor, cut):
    rng = np.random.default_rng(1)
    h = 0.15
    # a sheet with a margin and scattered nodes, some at negative indices, across brick borders
    sheet = np.stack(np.meshgrid(np.arange(-9, 9), np.arange(-3, 11), np.arange(-2, 1), indexing="ij"), -1)
    idx = np.unique(np.concatenate([sheet.reshape(-1, 3), rng.integers(-20, 20, (300, 3))]), axis=0)
    ell = ell_factor * h
    g = LatticeGrid(idx, h, ell, cut)
    # points near the nodes, between them and far outside their bounding box
    x = np.concatenate([(idx[rng.integers(0, len(idx), 600)] + rng.uniform(-2, 3, (600, 3))) * h,
                        rng.uniform(-5, 5, (200, 3)), [[1e4, -1e4, 3.0], [-40.0, 0.0, 0.0]]])
    K = _dense(idx, h, ell, cut, x)
    coef = rng.normal(size=len(idx))
    f = g.kernel_sum(*g.to_lanes(x), g.upload(coef))
    np.testing.assert_allclose(f.numpy(), K @ coef, atol=3e-5 * np.abs(coef).sum() ** 0.5)
    gl = rng.normal(size=len(x))
    out = g.kernel_scatter(*g.to_lanes(x), g.upload(gl), dr.zeros(g.Float, g.n))
    np.testing.assert_allclose(out.numpy(), K.T @ gl, atol=1e-4)
    # near() is a superset of the points that some node reaches, and not everything
    reached = (K > 0).any(axis=1)
    near = g.near(x)
    assert near[reached].all() and not near.all()
    # the offsets visited are all those that can reach, and no more than the ball allows
    assert len(g.offsets) < (2 * g.R + 1) ** 3
    assert np.ptp(g.offsets, axis=0).max() == 2 * g.R


def test_query_order_and_seed_do_not_change_the_map():
    scans = [box_scan(moving_poses((-2 + i, -1, 0), (-1 + i, 0, 0)), rays=40, seed=i) for i in range(2)]
    maps = []
    for _ in range(2):
        hm = IncrementalHilbertMap(random_state=3)
        for s in scans:
            hm.partial_fit(s)
        maps.append(hm)
    # the same up to the order of float32 atomic additions (Dr.Jit's threads): 1e-6 here
    np.testing.assert_allclose(maps[0].dual_coef_, maps[1].dual_coef_, rtol=0, atol=1e-5)
    assert abs(maps[0].intercept_ - maps[1].intercept_) < 1e-5
    rng = np.random.default_rng(0)
    pts = rng.uniform([-5, -4, -3], [5, 4, 1], (5000, 3))
    f = maps[0].decision_function(pts)
    perm = rng.permutation(len(pts))
    np.testing.assert_array_equal(maps[0].decision_function(pts[perm]), f[perm])
    # the chunked evaluation (each chunk sorted on its own) gives the same values
    np.testing.assert_array_equal(maps[0].decision_function(pts, chunk=777), f)
    # the logit is the dense kernel expansion of the nodes that are built
    hm = maps[0]
    n = hm._grid.n
    idx = np.floor(hm.inducing_points_[:n] / hm.node_spacing).astype(np.int64)
    K = _dense(idx, hm.node_spacing, hm.lengthscale_, hm.kernel_cut, pts[:800])
    np.testing.assert_allclose(f[:800], K @ hm.dual_coef_[:n] + hm.intercept_, atol=1e-4)


def test_a_rebuilt_grid_reuses_the_compiled_kernels():
    # two grids over different boxes (the box size was a literal in the kernels: every rebuild of
    # a survey's grid compiled them anew); the second grid's kernels come from the in-memory cache
    rng = np.random.default_rng(2)
    h, ell, cut = 0.15, 0.15, 1e-2
    grids = [LatticeGrid(rng.integers(-n, n, (400, 3)), h, ell, cut) for n in (6, 11)]
    assert not np.array_equal(grids[0].dims, grids[1].dims)
    x = rng.uniform(-1, 1, (300, 3))
    was = dr.flag(dr.JitFlag.KernelHistory)
    dr.set_flag(dr.JitFlag.KernelHistory, True)
    try:
        history = []
        for g in grids:
            dr.kernel_history()  # clears it
            f = g.kernel_sum(*g.to_lanes(x), g.upload(np.ones(g.n)))
            out = g.kernel_scatter(*g.to_lanes(x), g.upload(np.ones(len(x))), dr.zeros(g.Float, g.n))
            dr.eval(f, out)
            history.append([k for k in dr.kernel_history() if k["type"] == dr.KernelType.JIT])
    finally:
        dr.set_flag(dr.JitFlag.KernelHistory, was)
    assert len(history[1]) >= 2
    assert all(k["cache_hit"] and not k["cache_disk"] for k in history[1]), \
        [(k["cache_hit"], k["cache_disk"]) for k in history[1]]


def test_forgetting_drops_a_slice_below_the_cap():
    # the forgetting rule drops nodes down to 95 % of max_nodes, so the next scans' new nodes do
    # not trigger it again (each forgetting rebuilds the kernel grid and prunes the region seen)
    from hilbertmap.incremental import FORGET_SHARE

    scans = [box_scan(moving_poses((-3 + 1.5 * i, -1 + i, 0), (-1.5 + 1.5 * i, i, 0)), rays=20, n_pings=60,
                      seed=i) for i in range(4)]
    free = IncrementalHilbertMap(random_state=0)
    counts = []
    for s in scans:
        free.partial_fit(s)
        counts.append(len(free.node_keys_))
    cap = (counts[0] + counts[1]) // 2  # the second scan goes over it
    hm = IncrementalHilbertMap(random_state=0, max_nodes=cap)
    events = 0
    for s in scans:
        before = hm.n_forgotten_ if hasattr(hm, "n_forgotten_") else 0
        hm.partial_fit(s)
        assert len(hm.node_keys_) <= cap
        if hm.n_forgotten_ > before:
            events += 1
            assert len(hm.node_keys_) == cap - int(FORGET_SHARE * cap)
    assert events >= 1
    assert events < len(scans) - 1  # not every scan after the cap was reached
    assert len(hm.inducing_points_) == len(hm.dual_coef_) == len(hm.node_accum_) == len(hm.node_keys_)


def test_auto_sampling_follows_the_scan_kind():
    # "auto" (IncrementalHilbertMap's default) samples a multibeam frame lightly (24 free + 8 near
    # samples a beam, 8 points a full bin) and the other kinds as before (400 + 32, 16)
    import dataclasses

    from hilbertmap.embedding import SAMPLING_AUTO, Samples

    mech = box_scan(moving_poses((-2, -1, 0), (-1, 0, 0)), rays=20, n_pings=40, seed=0)
    multi = dataclasses.replace(mech, kind="multibeam")
    hm = IncrementalHilbertMap(random_state=0)
    for scan, budget in ((mech, SAMPLING_AUTO[None]), (multi, SAMPLING_AUTO["multibeam"])):
        s = hm.embed(scan, np.random.default_rng(0))
        assert s.occupied.shape[1] == budget["occupied_samples"]
        assert len(s.free) <= len(s.frames) * (budget["max_free_per_ping"] + budget["near_free"])
        near = np.isfinite(s.gaps()) & (s.gaps() <= hm.near_depth)
        assert near.sum() >= budget["near_free"] * int(np.isfinite(s.spans[:, 1]).sum())
    light = hm.embed(multi, np.random.default_rng(0))
    # explicit numbers are kept whatever the kind
    same = IncrementalHilbertMap(random_state=0, max_free_per_ping=400, near_free=32, occupied_samples=16)
    dense = same.embed(multi, np.random.default_rng(0))
    assert dense.occupied.shape[1] == 16 and len(dense.free) > 4 * len(light.free)
    assert len(dense.occupied) == len(light.occupied)  # the same full bins, fewer points each
    # a batch of both kinds: the 8-point groups are repeated to 16 points, with the same means
    both = Samples.concatenate([light, dense])
    assert both.occupied.shape[1] == 16
    np.testing.assert_allclose(both.occupied[:len(light.occupied)].mean(axis=1), light.occupied.mean(axis=1))
    IncrementalHilbertMap(random_state=0).fit([mech, multi])
    with pytest.raises(ValueError, match="near_free must be 'auto' or an integer >= 0"):
        IncrementalHilbertMap(near_free="light").partial_fit(multi)
