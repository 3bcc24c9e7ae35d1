"""Surface evidence fed to a Hilbert map beside (or instead of) scans: hilbertmap.evidence."""
from __future__ import annotations

import numpy as np
import pytest

from hilbertmap import HilbertMap
from hilbertmap.embedding import Samples
from hilbertmap.evidence import surface_samples


def plane(z=-2.0, half=2.0, step=0.1):
    g = np.arange(-half, half + 1e-9, step)
    X, Y = np.meshgrid(g, g, indexing="ij")
    return np.stack([X.ravel(), Y.ravel(), np.full(X.size, z)], 1)


def test_points_become_groups_and_the_water_before_them_free():
    P = np.array([[3.0, 0.0, 0.0], [0.0, 0.0, -2.0]])
    s = surface_samples(P, [0.0, 0.0, 0.0], free_per_point=50, margin=0.2, rng=np.random.default_rng(1))
    np.testing.assert_array_equal(s.occupied[:, 0, :], P)
    assert s.occupied.shape == (2, 1, 3) and len(s.free) == 100
    a, b = s.free[:50], s.free[50:]
    # on the segments from the origin, never within the margin of the point
    assert np.allclose(a[:, 1:], 0) and a[:, 0].min() >= 0 and a[:, 0].max() <= 2.8
    assert np.allclose(b[:, :2], 0) and b[:, 2].max() <= 0 and b[:, 2].min() >= -1.8
    np.testing.assert_allclose(s.free_gap[:50], 3.0 - a[:, 0])
    # no ping of their own: concatenated after a scan's samples their groups keep ping -1
    other = Samples(free=np.zeros((0, 3)), occupied=np.zeros((1, 16, 3)), origins=np.zeros((1, 3)), info={},
                    frames=np.eye(4)[None], beams=np.zeros((1, 3)), spans=np.zeros((1, 3)),
                    occupied_ping=np.zeros(1, np.int64))
    both = Samples.concatenate([other, s])
    assert both.occupied.shape == (3, 16, 3) and list(both.occupied_ping) == [0, -1, -1]
    np.testing.assert_array_equal(both.occupied[1], np.repeat(P[:1], 16, axis=0))


def test_a_map_from_surface_evidence_holds_the_surface():
    P = plane()
    hm = HilbertMap(n_inducing=300, random_state=3).fit(None, samples=surface_samples(
        P, [0.0, 0.0, 0.0], rng=np.random.default_rng(3)))
    on = hm.predict_proba(plane(-2.0, 1.5, 0.25))
    above = hm.predict_proba(plane(-1.0, 1.5, 0.25))
    assert on.min() > 0.5, on.min()
    assert above.max() < 0.5, above.max()


def test_bad_points_are_refused_in_one_line():
    with pytest.raises(ValueError, match=r"HilbertMap: surface points must be a finite \(N, 3\) array, got shape \(4,\)"):
        surface_samples(np.zeros(4), np.zeros(3))
    with pytest.raises(ValueError, match=r"HilbertMap: free_per_point must be an integer >= 0, not -1"):
        surface_samples(np.zeros((2, 3)), np.zeros(3), free_per_point=-1)
