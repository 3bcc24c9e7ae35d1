"""Incremental Hilbert maps along a trajectory (issue 31): a moving mechanical head in a box basin.

The basin is hilbertmap.testing's box (walls x = +-5, y = +-4, floor z = -3); the head sweeps
horizontally (scan axis +z) while carried 1.5 m diagonally during each 200-ping sweep, so one
sweep's pings come from positions up to 1.5 m apart. Distances are those of the p = 0.5 contour
of the horizontal slice through the track (z = 0) to the true walls.
"""
import dataclasses

import numpy as np
import pytest

from hilbertmap import HilbertMap, IncrementalHilbertMap
from hilbertmap.testing import box_distance, box_scan, moving_poses, orthogonal_frames

N_SCANS = 3


@pytest.fixture(scope="module")
def survey():
    """Three sweeps along a track from (-3, -1, 0) to (1.5, 2, 0) (1.5 m per sweep)."""
    return [box_scan(moving_poses((-3 + 1.5 * i, -1 + i, 0), (-1.5 + 1.5 * i, i, 0)), rays=80, seed=i)
            for i in range(N_SCANS)]


@pytest.fixture(scope="module")
def online(survey):
    hm = IncrementalHilbertMap(random_state=0)
    for s in survey:
        hm.partial_fit(s)
    return hm


def _walls(n=40):
    """Points on each wall at z = 0, away from the corners: {name: (n, 3)}."""
    u = np.linspace(-0.9, 0.9, n)
    return {"x+": np.c_[np.full(n, 5.0), 4 * u, np.zeros(n)], "x-": np.c_[np.full(n, -5.0), 4 * u, np.zeros(n)],
            "y+": np.c_[5 * u, np.full(n, 4.0), np.zeros(n)], "y-": np.c_[5 * u, np.full(n, -4.0), np.zeros(n)]}


def _contour_distances(hm, res=0.05):
    """|distance to the box| of the p = 0.5 contour's pixels on the water side of the walls (the
    face the sonar saw; behind a wall is acoustic shadow) in the slice z = 0, and the share of the
    water (0.5 m clear of the walls) called occupied."""
    xs, ys = np.arange(-5.5, 5.5, res), np.arange(-4.5, 4.5, res)
    X, Y = np.meshgrid(xs, ys, indexing="ij")
    P = np.stack([X, Y, np.zeros_like(X)], -1)
    occ = hm.predict_proba(P.reshape(-1, 3)).reshape(X.shape) > 0.5
    edge = np.zeros_like(occ)
    edge[1:] |= occ[1:] != occ[:-1]
    edge[:, 1:] |= occ[:, 1:] != occ[:, :-1]
    sd = box_distance(P[edge])
    d = np.abs(sd[sd > -res])
    water = (np.abs(X) < 4.5) & (np.abs(Y) < 3.5)
    return d, float(occ[water].mean())


def test_moving_head_maps_every_wall_within_bounds(online):
    for name, pts in _walls().items():
        p = online.predict_proba(pts)
        assert p.mean() > 0.6 and np.mean(p > 0.5) >= 0.9, (name, p.mean(), np.mean(p > 0.5))
    d, false_occupied = _contour_distances(online)
    # the contour (both sides of a wall's occupied band) lies within a lattice pitch and a half
    assert np.mean(d) < 0.12 and np.percentile(d, 95) < 0.3, (np.mean(d), np.percentile(d, 95))
    assert false_occupied < 0.01
    assert online.n_scans_seen_ == N_SCANS and online.n_pings_seen_ == 200 * N_SCANS


def test_poses_matter(survey, online):
    """The same pings with every row put at the start position (bearings kept): walls smeared."""
    start = survey[0].poses[0, :3, 3]
    still = []
    for s in survey:
        q = s.poses.copy()
        q[:, :3, 3] = start
        still.append(dataclasses.replace(s, poses=q))
    hm = IncrementalHilbertMap(random_state=0)
    for s in still:
        hm.partial_fit(s)
    d_ok, fo_ok = _contour_distances(online)
    d_bad, fo_bad = _contour_distances(hm)
    assert np.mean(d_bad) > 4 * np.mean(d_ok), (np.mean(d_bad), np.mean(d_ok))
    hit_ok = np.mean([np.mean(online.predict_proba(p) > 0.5) for p in _walls().values()])
    hit_bad = np.mean([np.mean(hm.predict_proba(p) > 0.5) for p in _walls().values()])
    assert hit_bad < hit_ok - 0.2, (hit_bad, hit_ok)


def test_incremental_and_batch_agree(survey, online):
    batch = IncrementalHilbertMap(random_state=0).fit(survey)
    rng = np.random.default_rng(5)
    P = rng.uniform([-5.5, -4.5, -1.0], [5.5, 4.5, 1.0], (20000, 3))
    P = P[online.seen(P)]
    pa, pb = online.predict_proba(P), batch.predict_proba(P)
    # stated tolerance: the same label at >= 90 % of the region seen, mean |dp| <= 0.12
    assert np.mean((pa > 0.5) == (pb > 0.5)) >= 0.9
    assert np.mean(np.abs(pa - pb)) <= 0.12
    # nodes come from the echoes of independently drawn samples of the same pings: nearly the same set
    common = len(np.intersect1d(online.node_keys_, batch.node_keys_))
    assert common >= 0.85 * max(len(online.node_keys_), len(batch.node_keys_))


def test_memory_is_capped_and_old_places_are_forgotten(survey):
    hm = IncrementalHilbertMap(random_state=0, max_nodes=15000, max_pings_kept=250)
    for s in survey:
        hm.partial_fit(s)
        assert len(hm.inducing_points_) <= 15000
    assert hm.n_forgotten_ > 0 and len(hm.ping_frames_) == 250 and len(hm.track_) == 250
    # the nodes kept are the most recently used ones
    assert hm.node_last_used_.min() >= 1
    assert np.allclose(hm.track_[-1], survey[-1].poses[-1, :3, 3])


def test_save_load_round_trip_and_refusals(online, tmp_path):
    path = tmp_path / "survey.npz"
    online.save(path)
    back = IncrementalHilbertMap.load(path)
    P = np.random.default_rng(1).uniform(-5, 5, (500, 3))
    assert np.allclose(back.predict_proba(P), online.predict_proba(P), atol=1e-6)
    assert back.get_params() == online.get_params()
    with pytest.raises(ValueError, match="missing 'inducing_points'"):
        HilbertMap.load(path)
    old = tmp_path / "thesis.npz"
    HilbertMap(n_inducing=100, n_passes=1, random_state=0).fit(
        box_scan(orthogonal_frames()[0], n_pings=40, bearing_step=9.0, rays=20)).save(old)
    with pytest.raises(ValueError, match=r"format 'hilbertmap/1' is not hilbertmap-incremental/1"):
        IncrementalHilbertMap.load(old)
    broken = tmp_path / "broken.npz"
    broken.write_bytes(path.read_bytes()[:2000])
    with pytest.raises(ValueError, match="broken.npz"):
        IncrementalHilbertMap.load(broken)


def test_bad_input_one_line(survey):
    s = survey[0]
    hm = IncrementalHilbertMap(random_state=0)
    with pytest.raises(ValueError, match="has no 'poses'"):
        hm.partial_fit(dataclasses.replace(s, poses=None))
    q = s.poses.copy()
    q[7, :3, :3] *= 1.1
    with pytest.raises(ValueError, match=r"scan.poses\[7\] is not a rigid transform"):
        hm.partial_fit(dataclasses.replace(s, poses=q))
    with pytest.raises(ValueError, match=r"one 4x4 pose per row"):
        hm.partial_fit(dataclasses.replace(s, poses=s.poses[:10]))
    r = s.ranges.copy()
    r[3] = np.nan
    with pytest.raises(ValueError, match="scan.ranges holds 1 value"):
        hm.partial_fit(dataclasses.replace(s, ranges=r))
    with pytest.raises(ValueError, match="at least one scan"):
        hm.fit([])
    assert not hasattr(hm, "dual_coef_")  # nothing was learnt from the refused scans
    with pytest.raises(ValueError, match="max_nodes must be an integer >= 1"):
        IncrementalHilbertMap(max_nodes=0).partial_fit(s)
