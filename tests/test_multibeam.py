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
    assert back.kind == "multibeam" and back.meta.tx_beamwidth_h == pytest.approx(131.0)
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


@pytest.mark.slow
def test_transmit_and_receive_patterns_are_reciprocal_over_multipath(mitsonar_mod):
    # A target 6 m ahead under a calm water surface 1 m up (ladder 4's scene): the echo windows
    # are the direct path, the two mixed paths (via the surface out or back) and the path via the
    # surface both ways. Paths start from the receive beam and connect back through the transmit
    # fan, so swapping the two patterns must give the same expectation in every window (the mixed
    # window adds B_tx(surface) B_rx(target) + B_tx(target) B_rx(surface)). With a narrow beam both
    # ways (a rotating head) the mixed echo all but vanishes: the image direction is 18 deg up.
    from scipy import stats

    from conftest import acoustic_xml, rectangle_xml, scene_xml, sonar_xml, sphere_xml
    from test_physics import plane_matrix

    h, D, a = 1.0, 6.0, 0.1
    image = math.hypot(D, 2 * h)
    windows = [(D - a, D), ((D + image) / 2 - a, (D + image) / 2), (image - a, image)]
    to_world = frame_matrix((1, 0, 0), (0, 0, 1))
    water = rectangle_xml(plane_matrix(h, flip=True), acoustic_xml(0.0, 0.99, 300.0))
    target = sphere_xml((D, 0, 0), a, acoustic_xml(0.9))
    narrow, wide = (3.0, 10.0), (20.0, 60.0)

    def energies(rx, tx, kind="multibeam", seeds=range(8)):
        extra = dict(tx_beamwidth_h=tx[0], tx_beamwidth_v=tx[1]) if kind == "multibeam" else {}
        sensor = sonar_xml(to_world, kind=kind, beam_pattern="gaussian", beamwidth_h=rx[0], beamwidth_v=rx[1],
                           range_min=5.0, range_max=7.0, n_bins=200, n_pings=1, bearing_step=0.0, **extra)
        scene = mitsonar_mod.load_scene(scene_xml(sensor, water, target, integrator=(
            '<integrator type="sonar_tof"><integer name="max_depth" value="3"/></integrator>')))
        out = []
        for s in seeds:
            scan = mitsonar_mod.render_scan(scene, spp=1 << 18, seed=100 + s)
            r, e = scan.ranges, scan.intensity[0].astype(np.float64)
            out.append([e[(r > lo - 0.02) & (r < hi + 0.02)].sum() for lo, hi in windows])
        return np.array(out)

    fan_tx = energies(narrow, wide)
    fan_rx = energies(wide, narrow)
    t, p = stats.ttest_ind(fan_tx, fan_rx, equal_var=False)
    assert np.all(p > 1e-3 / 3), f"windows differ: p = {p}"
    mean = fan_tx.mean(0)
    assert mean[1] > 0.05 * mean[0] and mean[2] > 0  # the fan lights the target via the surface
    mech = energies(narrow, narrow, kind="mechanical", seeds=range(2)).mean(0)
    assert mech[1] < 0.01 * mean[1] and mech[0] == pytest.approx(mean[0], rel=0.1)
