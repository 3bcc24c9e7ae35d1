"""Multi-echo free space (hilbertmap.multiecho): the water between a ping's echoes is labelled free
where the beam can be shown to have reached it, and not in the shadow of its first echo.

A hand-made scene, no renderer: a wide-fan ping (3 x 40 deg) looks along +x at a reflector that
fills the upper half of its fan at 3.0-3.2 m and a wall at 6.0 m that only the lower half reaches:
two echo runs. Narrow pings (3 x 3 deg) from the same place show the lower water empty up to the
wall and see the reflector in front of the upper water. The candidates between the wide ping's
echoes fill its whole fan from 3.2 to 6.0 m; the lower ones are visible, the upper ones lie in the
reflector's shadow.
"""
from __future__ import annotations

import numpy as np
import pytest

from hilbertmap import HilbertMap
from hilbertmap.testing import SyntheticScan, frame

N_BINS, R_MAX = 200, 8.0
BW = R_MAX / N_BINS


def _scan(poses, runs, bw_v):
    """A scan whose ping k has full bins (data 255) over the ranges ``runs[k]`` (list of (r0, r1))."""
    data = np.zeros((len(poses), N_BINS), dtype=np.uint8)
    for k, rr in enumerate(runs):
        for r0, r1 in rr:
            data[k, int(round(r0 / BW)):int(round(r1 / BW))] = 255
    return SyntheticScan(intensity=data.astype(np.float32), data=data, ranges=(np.arange(N_BINS) + 0.5) * BW,
                         bearings=np.zeros(len(poses)), poses=np.asarray(poses), range_min=0.0, range_max=R_MAX,
                         beamwidth_h=3.0, beamwidth_v=bw_v)


def scene_scans():
    wide = _scan([frame((1, 0, 0), (0, 0, 1))] * 40, [[(3.0, 3.2), (6.0, 6.2)]] * 40, 40.0)
    poses, runs = [], []
    for el in np.radians(np.arange(-25.0, 25.5, 1.5)):
        for az in np.radians(np.arange(-6.0, 6.5, 1.5)):
            d = np.array([np.cos(el) * np.cos(az), np.cos(el) * np.sin(az), np.sin(el)])
            poses.append(frame(d, (0, 0, 1)))
            r = 3.0 / d[0] if el > 0 else 6.0 / d[0]  # the reflector above z = 0, the wall below
            runs.append([(r, r + 0.2)])
    return [wide, _scan(poses, runs, 3.0)]


PARAMS = dict(n_inducing=400, bin_rule="threshold", threshold=128, blanking=0.3, min_echo_bins=1, free_density=2000.0,
              random_state=5)


@pytest.fixture(scope="module")
def maps():
    scans = scene_scans()
    return scans, HilbertMap(multi_echo=True, **PARAMS).fit(scans)


def test_candidates_lie_between_the_echoes_only():
    hm = HilbertMap(multi_echo=True, **PARAMS)
    s = hm.embed(scene_scans()[0], np.random.default_rng(0))
    r = np.linalg.norm(s.between, axis=1)
    assert len(r) > 100
    assert r.min() >= 3.2 - 1e-9 and r.max() <= 6.0 + 1e-9
    # each candidate knows its metres to the next echo (the wall's run at 6.0 m)
    np.testing.assert_allclose(s.between_gap, 6.0 - r, atol=1e-9)
    # without the option: no candidates, and the first-echo samples are the same draws
    s0 = HilbertMap(**PARAMS).embed(scene_scans()[0], np.random.default_rng(0))
    assert len(s0.between) == 0
    np.testing.assert_array_equal(s0.free, s.free)


def test_between_echo_water_is_free_where_visible_and_not_in_the_shadow(maps):
    scans, hm = maps
    kept = hm.multi_echo_free_
    assert hm.n_between_candidates_ > 100
    # visible: below the reflector, where the narrow pings saw the water empty up to the wall
    assert (kept[:, 2] < -0.3).sum() > 20, kept
    # shadowed: above z = 0 the straight path from the head crosses the reflector. (Within about
    # a length-scale behind its face the map's p < 0.5 at the fan's edge lets a few through.)
    behind = (kept[:, 2] > 0.3) & (np.linalg.norm(kept, axis=1) > 3.6)
    assert behind.sum() == 0, kept[behind]
    from hilbertmap.multiecho import visibility

    pts = np.array([[4.5, 0.0, -0.9], [4.5, 0.0, 0.9]])
    vis = visibility(hm, pts, np.zeros((2, 3)), np.full(2, 0.3), margin=hm.near_depth)
    assert vis[0] > 0.5 and vis[1] == 0.0, vis


def test_multi_echo_refit_is_deterministic_per_seed(maps):
    scans, hm = maps
    again = HilbertMap(multi_echo=True, **PARAMS).fit(scans)
    np.testing.assert_array_equal(again.weights_, hm.weights_)
    np.testing.assert_array_equal(again.multi_echo_free_, hm.multi_echo_free_)


def test_multi_echo_must_be_a_bool():
    with pytest.raises(ValueError, match=r"HilbertMap: multi_echo must be True or False, not 'yes'"):
        HilbertMap(multi_echo="yes", **PARAMS).fit(scene_scans())
