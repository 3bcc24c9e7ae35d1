"""Any ocean (issue 58): sound speed and absorption by named published equations, with their check
values; a value outside an equation's range warns once (refused with strict=True); the sensor's
``auto`` keeps Francois-Garrison inside its range and falls back to Ainslie-McColm outside it."""
import warnings

import numpy as np
import pytest

from mitsonar.acoustics import seawater
from mitsonar.acoustics.seawater import OutOfRangeWarning, absorption, ainslie_mccolm, depth_to_pressure, sound_speed


@pytest.fixture(autouse=True)
def fresh_warnings():
    seawater._WARNED.clear()
    yield
    seawater._WARNED.clear()


def test_unesco_check_value():
    # Fofonoff and Millard (1983): c(S=40, T68=40 deg C, P=1000 bar) = 1731.995 m/s. Wong and Zhu's
    # ITS-90 coefficients at T90 = 40 / 1.00024 reproduce it to their refit's 0.01 m/s.
    assert seawater._chen_millero(40.0 / 1.00024, 40.0, 1000.0) == pytest.approx(1731.995, abs=0.01)


@pytest.mark.parametrize("t, s, z, ref", [
    # EOS-80's svel (the `seawater` package 3.3.5, IPTS-68 coefficients; pressure at 45 deg N from
    # Saunders 1981), computed once for this table
    (10.0, 35.0, 0.0, 1489.8309),
    (10.0, 35.0, 1000.0, 1506.5231),
    (25.0, 35.0, 3000.0, 1585.2243),
    (2.0, 34.7, 5000.0, 1544.0289),
])
def test_unesco_sound_speed_matches_eos80_in_the_ocean(t, s, z, ref):
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        assert sound_speed(t, s, z, model="unesco") == pytest.approx(ref, abs=0.02)


def test_del_grosso_and_mackenzie_agree_with_unesco_where_all_three_hold():
    t, s, z = np.meshgrid([2.0, 10.0, 20.0], [33.0, 35.0, 38.0], [0.0, 500.0, 2000.0])
    un = sound_speed(t, s, z, model="unesco")
    dg = sound_speed(t, s, z, model="del_grosso")
    mk = sound_speed(t, s, z)
    # Dushaw et al. (1993): the equations differ by tenths of a m/s, up to about 1 m/s at depth
    assert np.max(np.abs(dg - un)) < 1.0 and np.max(np.abs(mk - un)) < 1.0
    assert np.max(np.abs((dg - un)[..., 0])) < 0.2


def test_depth_to_pressure_is_leroy_parthiot():
    # about 1.0106 MPa at 1000 m at 45 deg, more towards the poles (gravity)
    assert depth_to_pressure(1000.0, 45.0) == pytest.approx(1010.6, abs=0.3)
    assert depth_to_pressure(1000.0, 80.0) > depth_to_pressure(1000.0, 0.0)
    assert depth_to_pressure(0.0) == 0.0


def test_ainslie_mccolm_follows_francois_garrison_inside_its_range():
    f = np.array([1e3, 10e3, 100e3, 500e3])
    fg = absorption(f, 10.0, 35.0, 0.0)
    am = ainslie_mccolm(f, 10.0, 35.0, 0.0)
    assert np.all(np.abs(am / fg - 1.0) < 0.1)
    assert np.array_equal(absorption(f, 10.0, 35.0, 0.0, model="ainslie_mccolm"), am)


def test_fresh_water_is_the_pure_water_term_alone():
    fresh = absorption(100e3, 10.0, 0.0, 0.0, model="fresh_water")
    # F&G's A3 at 10 deg C: 4.937e-4 - 2.59e-5*10 + 9.11e-7*100 - 1.5e-8*1000 = 3.108e-4 dB/km/kHz^2
    assert fresh == pytest.approx(3.108e-4 * 100.0 ** 2 / 1000.0, rel=1e-9)
    assert fresh < absorption(100e3, 10.0, 35.0, 0.0) / 5


def test_outside_a_range_warns_once_and_strict_refuses():
    with pytest.warns(OutOfRangeWarning, match="temperature 28 deg C is outside Francois and Garrison"):
        tropical = absorption(100e3, 28.0, 35.0, 10.0)
    assert tropical > 0
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        absorption(100e3, 29.0, 35.0, 10.0)                    # warned once already
    with pytest.raises(ValueError, match="temperature 28 deg C is outside Francois and Garrison"):
        absorption(100e3, 28.0, 35.0, 10.0, strict=True)
    with pytest.warns(OutOfRangeWarning, match="salinity 7 ppt is outside Mackenzie"):
        sound_speed(10.0, 7.0, 10.0)                           # the Baltic
    # what no water has is refused whatever strict says
    with pytest.raises(ValueError, match="depth -5 m is not allowed"):
        sound_speed(10.0, 35.0, -5.0)
    with pytest.raises(ValueError, match="model 'wilson' is not one of mackenzie, unesco, del_grosso"):
        sound_speed(10.0, 35.0, 5.0, model="wilson")


def test_auto_absorption_keeps_francois_garrison_in_range_and_falls_back_to_ainslie_mccolm():
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        got = absorption(100e3, [10.0, 28.0, 10.0], [35.0, 35.0, 7.0], 10.0, model="auto")
    assert got[0] == absorption(100e3, 10.0, 35.0, 10.0)
    assert got[1] == ainslie_mccolm(100e3, 28.0, 35.0, 10.0)
    assert got[2] == ainslie_mccolm(100e3, 10.0, 7.0, 10.0)


def test_arlpys_published_values_of_the_same_equations():
    # arlpy 1.9 (uwa.absorption, uwa.soundspeed: Francois-Garrison and Mackenzie) documents
    # absorption(50000) = 0.2914 as the linear amplitude over 1 km at 27 deg C, 35 ppt, 10 m, pH
    # 8.1 (arlpy takes F&G beyond its 22 deg C), soundspeed() = 1539.1 m/s at 27 deg C, 35 ppt, 10 m
    # and soundspeed(temperature=25, depth=20) = 1534.6 m/s
    with pytest.warns(OutOfRangeWarning):
        alpha = absorption(50e3, 27.0, 35.0, 10.0, 8.1)
    assert 10.0 ** (-alpha * 1000.0 / 20.0) == pytest.approx(0.2914, abs=5e-5)
    assert sound_speed(27.0, 35.0, 10.0) == pytest.approx(1539.1, abs=0.05)
    assert sound_speed(25.0, 35.0, 20.0) == pytest.approx(1534.6, abs=0.05)
