"""The multibeam (forward-looking) head of ``scenes_xml/box_fls.xml``: geometry of its rows, the
scan file, and mapping from its frames. The closed-form two-way gain of a row is ladder 3 in
test_physics.py (`test_multibeam_rows_follow_receive_beam_times_transmit_fan`)."""
import math
import os

import numpy as np
import pytest

from conftest import SCENES, frame_matrix

FLS = os.path.join(SCENES, "box_fls.xml")


def wall_range(bearings):
    """Range along a horizontal bearing from the origin to the box walls x = +-5, y = +-4."""
    c, s = np.abs(np.cos(bearings)), np.abs(np.sin(bearings))
    with np.errstate(divide="ignore"):
        return np.minimum(np.where(c > 1e-12, 5.0 / c, np.inf), np.where(s > 1e-12, 4.0 / s, np.inf))


def test_every_row_sees_the_wall_where_the_geometry_puts_it(mitsonar_mod, tmp_path):
    scene = mitsonar_mod.load_scene(FLS)
    scan = mitsonar_mod.render_scan(scene, spp=256, seed=3)
    assert scan.kind == "multibeam" and scan.n_pings == 256
    np.testing.assert_allclose(np.degrees(scan.bearings[[0, -1]]), [-65.0, 65.0], atol=1e-4)
    # one pose for the whole fan: every row starts at the head
    np.testing.assert_allclose(scan.poses[:, :3, 3], 0.0, atol=1e-12)
    first = scan.ranges[np.argmax(scan.intensity > 1e-3 * scan.intensity.max(), axis=1)]
    err = first - wall_range(scan.bearings)
    bin_w = scan.ranges[1] - scan.ranges[0]
    # Within 4 deg of a corner (+-38.7 deg) the corner reflector outshines the grazing wall, whose
    # return falls under the threshold: those rows first answer from the corner itself.
    corner = math.atan2(4.0, 5.0)
    away = np.abs(np.abs(scan.bearings) - corner) > math.radians(4.0)
    assert away.sum() > 200
    # the first echo of a 1 deg row comes from its near edge: at most r tan(incidence) x 0.5 deg early
    assert np.median(np.abs(err[away])) < 1.5 * bin_w
    assert err[away].max() < 1.5 * bin_w and err[away].min() > -0.12
    assert np.all(first[~away] <= math.hypot(5.0, 4.0) + bin_w)
    path = tmp_path / "fls.exr"
    scan.save(str(path))
    back = mitsonar_mod.load_scan(str(path))
    assert back.kind == "multibeam" and back.meta["tx_beamwidth_h"] == pytest.approx(131.0)
    np.testing.assert_array_equal(back.data, scan.data)


@pytest.mark.slow
def test_hilbert_map_from_forward_looking_frames(mitsonar_mod):
    from hilbertmap import HilbertMap, metrics

    scene = mitsonar_mod.load_scene(FLS)
    scans = []
    for i, (yaw, tilt) in enumerate((y, t) for y in (0, 90, 180, 270) for t in (0, 20)):
        a, b = math.radians(yaw), math.radians(tilt)
        fwd = (math.cos(a) * math.cos(b), math.sin(a) * math.cos(b), -math.sin(b))
        up = (math.cos(a) * math.sin(b), math.sin(a) * math.sin(b), math.cos(b))
        scans.append(mitsonar_mod.render_scan(scene, spp=1024, seed=i, pose=frame_matrix(fwd, up)))
    V, F = mitsonar_mod.scene_mesh(scene)
    hm = HilbertMap(n_inducing=1500, random_state=0).fit(scans)
    r = metrics.evaluate(hm, V, F, surfaces=("ridge",), n_surface=5000, n_free=50000)
    # the rows are narrow beams with their own frames: the mapper needs nothing multibeam-specific
    assert r["auc"] > 0.95 and r["auc_band_0.1_0.3"] > 0.85
    assert r["ridge_fscore@0.2"] > 0.75
