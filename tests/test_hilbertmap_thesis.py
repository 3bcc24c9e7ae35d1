"""The thesis setting mapped with the defaults (issue #31: maps from surveys, surface accuracy).

Soares 2017, 5.1 (Figs. 5.1, 5.2): one sonar position in the box of ``scenes_xml/box.xml``, three
orthogonal mechanical scans rendered with the renderer's defaults, mapped by ``HilbertMap()``. The
map's surface is the ridge (``hm.surface()``); the issue's target: cut by the horizontal plane
through the sonar it lies within 0.12 m of the walls both ways (the thesis reports about 0.45 m),
with the mean probability on the insonified walls above 0.5 (the thesis: about 0.35), AUC > 0.95
and AUC > 0.85 against the water 0.1-0.3 m from the walls. The map alone does not reach 0.12 m (its
ridge rounds the concave corners); the map with its walls refined by the renderer and fed back as
evidence (``mitsonar.inverse.room.room_feedback``) does, and is asserted.

The defaults were chosen on the render seeds 0 and 3 of this box and checked on a 9 x 7 m box
with the sonar off-centre (``benchmarks/thesis_mapping.py``); seed 11 is used nowhere else.
"""
from __future__ import annotations

import os

import numpy as np
import pytest

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
SEED = 11


@pytest.fixture(scope="module")
def thesis_map():
    import mitsonar
    from hilbertmap import HilbertMap
    from hilbertmap.testing import orthogonal_frames

    scene = mitsonar.load_scene(os.path.join(ROOT, "scenes_xml", "box.xml"))
    scans = [mitsonar.render_scan(scene, seed=SEED + j, pose=T) for j, T in enumerate(orthogonal_frames())]
    V, F = mitsonar.scene_mesh(scene)
    hm = HilbertMap(random_state=SEED).fit(scans)
    return hm, np.asarray(V, dtype=np.float64), np.asarray(F, dtype=np.int64), scans


def _report(hm, V, F):
    from hilbertmap.metrics import evaluate

    # the surface is extracted in a slab around the plane through the sonar (z = 0), the part the
    # cut needs: the same ridge there, a fifteenth of the grid
    lo, hi = hm.coverage_.bounds()
    slab = ([lo[0], lo[1], -0.5], [hi[0], hi[1], 0.5])
    return evaluate(hm, V, F, surfaces=("ridge",), n_surface=3000, n_free=20000, contours=False,
                    surface_bounds=slab, random_state=SEED)


@pytest.fixture(scope="module")
def thesis_report(thesis_map):
    hm, V, F, _ = thesis_map
    return _report(hm, V, F)


@pytest.fixture(scope="module")
def feedback_report(thesis_map):
    """The same scans mapped again with the first map's walls refined by the renderer and fed back
    as occupied evidence (:func:`mitsonar.inverse.room.room_feedback`)."""
    from mitsonar.inverse.room import room_feedback

    hm, V, F, scans = thesis_map
    fb = room_feedback(scans, hm, seed=SEED)
    return fb, _report(fb["map"], V, F)


def test_thesis_setting_map_quality(thesis_report):
    r = thesis_report
    assert r["n_surface_points"] > 1000
    assert r["surface_p_mean"] > 0.5, r
    assert r["auc"] > 0.95, r
    assert r["auc_band_0.1_0.3"] > 0.85, r
    # the horizontal plane through the sonar, both ways: 0.23-0.45 m on seeds 0, 3 and 11 (before
    # min_echo_bins=4 and the frustum front test: 0.63-0.67 m on seeds 0 and 3), the worst points at
    # concave corners and at oblique walls next to them
    assert r["ridge_slice_hausdorff"] == max(r["ridge_slice_max"], r["ridge_slice_comp_max"])
    assert r["ridge_slice_max"] < 0.25, r
    assert r["ridge_slice_hausdorff"] < 0.5, r


def test_ridge_within_012_m_of_the_walls_in_the_thesis_setting(thesis_report, feedback_report):
    """The map alone rounds the concave corners 0.2-0.25 m inside (the corner's last 0.2 m is never
    seen empty: the first echo comes from the beam's skirt); with its walls refined by analysis by
    synthesis and fed back, the map's own ridge lies within 0.12 m of the walls both ways."""
    assert thesis_report["ridge_slice_hausdorff"] > 0.15, thesis_report
    fb, r = feedback_report
    # the refined polygon: the box's four corners (x = +-5, y = +-4) and floor (z = -3), within 2 cm
    truth = np.array([[5.0, -4.0], [5.0, 4.0], [-5.0, 4.0], [-5.0, -4.0]])
    C = fb["corners"]
    assert len(C) == 4 and np.linalg.norm(C[:, None] - truth[None], axis=2).min(axis=1).max() < 0.02, C
    assert abs(fb["floor"] + 3.0) < 0.02, fb["floor"]
    assert r["ridge_slice_hausdorff"] < 0.12, r
    assert r["auc"] > 0.95 and r["auc_band_0.1_0.3"] > 0.85 and r["surface_p_mean"] > 0.5, r


def test_mesh_slice_metrics_measure_both_ways():
    """A closed-form check of the two-sided cut: a square's walls against a copy moved 0.05 m along
    x and cut short by 0.3 m at one end."""
    from hilbertmap import geometry as geo
    from hilbertmap.metrics import mesh_slice_metrics

    class Seen:  # every point insonified, the sonar at z = 0
        sensor_positions_ = np.zeros((1, 3))

        def insonified(self, P, part="any"):
            return np.ones(len(P), dtype=bool)

    def wall(x0, y0, x1, y1):
        v = np.array([[x0, y0, -1], [x1, y1, -1], [x1, y1, 1], [x0, y0, 1]], dtype=np.float64)
        return v, np.array([[0, 1, 2], [0, 2, 3]])

    tv, tf = wall(1.0, -1.0, 1.0, 1.0)
    mv, mf = wall(1.05, -1.0, 1.05, 0.7)
    r = mesh_slice_metrics(Seen(), mv, mf, tv, tf, step=0.01)
    assert r["ridge_slice_max"] == pytest.approx(0.05, abs=1e-9)
    assert set(r) == {"ridge_slice_max", "ridge_slice_comp_max", "ridge_slice_hausdorff"}
    # the true line's far end (1, 1) is 0.3 m along y and 0.05 m along x from the cut's end
    assert r["ridge_slice_comp_max"] == pytest.approx(np.hypot(0.3, 0.05), abs=0.01)
    assert r["ridge_slice_hausdorff"] == r["ridge_slice_comp_max"]
    # no surface in the plane: completeness is infinite, not silently zero
    r = mesh_slice_metrics(Seen(), mv + [0, 0, 5], mf, tv, tf, step=0.01)
    assert r["ridge_slice_comp_max"] == np.inf
    assert geo.plane_section(mv + [0, 0, 5], mf, 2, 0.0).shape == (0, 2, 3)
