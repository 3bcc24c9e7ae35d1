"""Inverse problems solved with the physical renderer (issue "Inverse problems"): the examples'
fits converge from fixed wrong starts (examples/calibrate_mount.py, recover_reflectance.py,
recover_seabed.py)."""
import math

import numpy as np
import pytest

from conftest import example


def test_small_pose_is_a_rotation_by_the_rotation_vector(mitsonar_mod):
    """Rodrigues' formula against scipy-free closed forms: a rotation by r about axis r/|r|, and its
    derivative at r = 0 is the cross-product matrix."""
    import drjit as dr
    import mitsuba as mi

    inv = example("_inverse")
    r = [0.1, -0.2, 0.3]
    m = np.asarray(inv.small_pose(mi.Vector3f(1, 2, 3), mi.Vector3f(*r)).matrix).reshape(4, 4)
    ref = np.asarray(mi.Transform4f().rotate(mi.Vector3f(*[v / float(np.linalg.norm(r)) for v in r]),
                                             math.degrees(float(np.linalg.norm(r)))).matrix).reshape(4, 4)
    np.testing.assert_allclose(m[:3, :3], ref[:3, :3], atol=1e-6)
    np.testing.assert_allclose(m[:3, 3], [1, 2, 3])
    x = mi.Vector3f(0.0)
    dr.enable_grad(x)
    rot = inv.small_pose(mi.Vector3f(0.0), x).matrix
    dr.set_grad(x, mi.Vector3f(0, 0, 1))  # d R / d r_z at 0: [[0, -1, 0], [1, 0, 0], [0, 0, 0]]
    g = np.asarray(dr.forward_to(rot)).reshape(4, 4)
    np.testing.assert_allclose(g[:3, :3], [[0, -1, 0], [1, 0, 0], [0, 0, 0]], atol=1e-6)


def test_calibrate_mount_converges_within_1cm_and_0_2deg(mitsonar_mod):
    """From the nominal mount (7 cm and 3.9 deg off the true one) to within 1 cm / 0.2 deg in 70
    Adam steps on a 24-ping scan of the tank."""
    cal = example("calibrate_mount")
    res = cal.calibrate(iterations=70, spp=1024, seed=7, n_pings=24, n_bins=160)
    h = np.asarray(res["history"])
    assert h[0, 1] > 0.05 and h[0, 2] > 3.0  # the start is really off
    assert res["translation_error_m"] < 0.01, res
    assert res["rotation_error_deg"] < 0.2, res
    assert h[-1, 0] < 1e-2 * h[0, 0]


def test_calibrate_mount_refuses_bad_counts(mitsonar_mod):
    cal = example("calibrate_mount")
    with pytest.raises(SystemExit, match=r"iterations: 0 is not allowed \(a whole number from 1 to 100000\)"):
        cal.calibrate(iterations=0)


def test_recover_reflectance_within_5_percent(mitsonar_mod):
    """Six parameters (diffuse, specular, shininess of the walls and of the floor) from starts up
    to 2x off, to within 5 % of the truth in 100 Adam steps."""
    rr = example("recover_reflectance")
    res = rr.recover(iterations=100, spp=1024, seed=5)
    start_err = {k: abs(v - res["truth"][k]) / res["truth"][k] for k, v in zip(res["keys"], res["history"][0][1:])}
    assert min(start_err.values()) > 0.3  # every parameter starts well off
    assert max(res["relative_errors"].values()) < 0.05, res["relative_errors"]


def test_recover_reflectance_refuses_unphysical_values(mitsonar_mod):
    rr = example("recover_reflectance")
    with pytest.raises(SystemExit, match=r"start\['wall'\]: \(0\.8, 0\.5, 10\.0\) is not allowed .*diffuse \+ specular <= 1"):
        rr.recover(start={"wall": (0.8, 0.5, 10.0), "floor": (0.3, 0.2, 8.0)})


def test_recover_seabed_halves_the_height_error(mitsonar_mod):
    """Eight side-scan pings over a 4 x 12 m height map (0.5 m cells, mounds of +-25 cm): from the
    flat seabed, 30 Adam steps reduce the RMS height error over the cells the pings see by a factor
    of at least 2 (2.4 measured); the loss falls by a factor of at least 5."""
    rs = example("recover_seabed")
    res = rs.recover(iterations=30, spp=1024, seed=3)
    assert res["rms_start"] > 0.05
    assert res["rms_final"] < res["rms_start"] / 2, (res["rms_start"], res["rms_final"])
    h = np.asarray(res["history"])
    assert h[-1, 0] < h[0, 0] / 5


def test_recover_seabed_refuses_bad_geometry(mitsonar_mod):
    rs = example("recover_seabed")
    with pytest.raises(SystemExit, match=r"spacing, altitude: 0.5, -1.0 are not allowed \(lengths > 0 in metres\)"):
        rs.recover(altitude=-1.0)
