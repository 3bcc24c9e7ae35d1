"""mitsonar.acoustics: published check values, closed forms, limits and refused inputs.

Sources of the check values:

* Mackenzie (1981), J. Acoust. Soc. Am. 70, 807: 1550.744 m/s at 25 deg C, 35 ppt, 1000 m (the
  paper's own check value).
* Francois and Garrison (1982) total-absorption equation at pH 8 and the surface: nine values
  (0 and 10 deg C; 30 and 35 ppt; 1, 10, 100 kHz) as tabulated, three significant figures, in the
  check-value block of G. Jimenez Arranz's ``seawaterAbsorption_FrancoisGarrison1982.m`` (2017);
  the Acoustics Toolbox's ``franc_garr.m`` (D. Jackson, M. Porter) states the same equation was
  "verified using F-G Table IV".
* APL-UW TR 9407 (1994) Table 2 sediment rows (density ratio, sound speed ratio, loss parameter)
  as transcribed in UnderwaterAcoustics.jl (``# from APL-UW TR 9407 (1994), IV-6 Table 2``), and
  its spectral strengths w2 as used, converted to SI (``w2_SI = w2_cm4 * 100**gamma * 1e-8``), by
  hyo2_openbst's Jackson-model test sediments.
* The Kirchhoff term of the APL-UW model against a numerical quadrature of the handbook's own
  Kirchhoff integral.
"""
import math

import numpy as np
import pytest
from scipy.integrate import quad
from scipy.special import j0

import mitsonar.acoustics
from mitsonar import acoustics
from mitsonar.acoustics import (MATERIALS, SEDIMENTS, Material, Sediment, absorption, apl_uw_backscatter,
                                bistatic_mean_grazing, critical_angle, lambert, material, reflection_coefficient,
                                sediment, sound_speed)

DEG = math.pi / 180.0


def test_both_import_forms_reach_the_same_module():
    assert acoustics is mitsonar.acoustics
    assert acoustics.sound_speed is sound_speed


# ------------------------------------------------------------------------- sound speed (Mackenzie)

def test_mackenzie_check_value():
    # Mackenzie (1981): "c = 1550.744 m/s for T = 25 deg C, S = 35 ppt, D = 1000 m".
    assert sound_speed(25.0, 35.0, 1000.0) == pytest.approx(1550.744, abs=5e-4)


def test_sound_speed_is_vectorised_and_broadcasts():
    t = np.array([[0.0], [10.0], [25.0]])
    d = np.array([0.0, 1000.0])
    c = sound_speed(t, 35.0, d)
    assert c.shape == (3, 2)
    assert c[2, 1] == pytest.approx(1550.744, abs=5e-4)
    # the salinity and depth terms alone, at 0 deg C: 1448.96 + 1.340 (S - 35) + 0.01630 D + 1.675e-7 D^2
    assert sound_speed(0.0, 36.0, 100.0) == pytest.approx(1448.96 + 1.340 + 1.630 + 1.675e-3, abs=1e-9)
    assert isinstance(sound_speed(10.0, 35.0, 0.0), float)


@pytest.mark.parametrize("kwargs, text", [
    (dict(temperature=35.0), "sound_speed: temperature 35 deg C is outside Mackenzie (1981)'s -2 to 30 deg C"),
    (dict(temperature=-2.5), "temperature -2.5 deg C is outside Mackenzie (1981)'s -2 to 30 deg C"),
    (dict(salinity=20.0), "salinity 20 ppt is outside Mackenzie (1981)'s 25 to 40 ppt"),
    (dict(depth=-1.0), "depth -1 m is outside Mackenzie (1981)'s 0 to 8000 m"),
    (dict(depth=[10.0, 9000.0]), "depth 9000 m is outside"),
    (dict(temperature=float("nan")), "temperature nan is not a finite number"),
    (dict(salinity="salty"), "salinity 'salty' is not a number"),
])
def test_sound_speed_refuses_out_of_range_inputs_when_strict(kwargs, text):
    args = dict(temperature=10.0, salinity=35.0, depth=100.0) | kwargs
    with pytest.raises(ValueError) as err:
        sound_speed(**args, strict=True)
    assert text in str(err.value)
    assert "\n" not in str(err.value)


# ------------------------------------------------------------------------- absorption (F&G)

# (T deg C, S ppt, f kHz, alpha dB/km) at pH 8, depth 0: three significant figures.
FG_CHECK = [(0, 30, 1, 6.10e-2), (0, 35, 1, 6.40e-2), (10, 35, 1, 6.00e-2),
            (0, 30, 10, 1.12), (0, 35, 10, 1.29), (10, 35, 10, 9.63e-1),
            (0, 30, 100, 21.0), (0, 35, 100, 23.4), (10, 35, 100, 33.6)]


@pytest.mark.parametrize("t, s, f_khz, alpha_db_km", FG_CHECK)
def test_francois_garrison_check_values(t, s, f_khz, alpha_db_km):
    got = absorption(f_khz * 1e3, t, s, 0.0, ph=8.0) * 1000.0          # dB/m -> dB/km
    assert got == pytest.approx(alpha_db_km, rel=5e-3)
    if f_khz >= 10:   # MgSO4 and pure water: to the printed digit (1 kHz, boric acid: 0.06126 vs 0.0610 at 0 deg C, 30 ppt)
        half_unit = 0.5 * 10.0 ** (math.floor(math.log10(alpha_db_km)) - 2)
        assert abs(got - alpha_db_km) <= half_unit


def test_absorption_is_vectorised_in_hz_and_db_per_m():
    f = np.array([1e3, 10e3, 100e3])
    a = absorption(f, 10.0, 35.0, 0.0)
    assert a.shape == (3,)
    np.testing.assert_allclose(a * 1000.0, [6.00e-2, 9.63e-1, 33.6], rtol=5e-3)
    # the brief's orders of magnitude at 10 deg C, 35 ppt: ~200 dB/km at 700 kHz
    assert 150.0 < absorption(700e3, 10.0, 35.0, 0.0) * 1000.0 < 250.0
    # depth lowers the MgSO4 and pure-water terms (P2, P3 < 1)
    assert absorption(100e3, 10.0, 35.0, 3000.0) < absorption(100e3, 10.0, 35.0, 0.0)
    # pH raises only the boric-acid term, which matters at 1 kHz and not at 500 kHz
    low, high = absorption([1e3, 500e3], 10.0, 35.0, 0.0, ph=7.7), absorption([1e3, 500e3], 10.0, 35.0, 0.0, ph=8.3)
    assert high[0] > 1.5 * low[0] and high[1] == pytest.approx(low[1], rel=2e-3)


def test_pure_water_branches_meet_at_20_degrees():
    # F&G's two pure-water fits (T <= 20 and T > 20 deg C) join continuously; at 1 MHz the pure-water
    # term is most of the absorption, so a wrong coefficient in either branch shows as a step here.
    below = absorption(1e6, 20.0, 35.0, 0.0)
    above = absorption(1e6, 20.0 + 1e-9, 35.0, 0.0)
    assert above == pytest.approx(below, rel=2e-3)
    assert absorption(1e6, 22.0, 35.0, 0.0) > 0.0


@pytest.mark.parametrize("kwargs, text", [
    (dict(frequency=100.0), "absorption: frequency 100 Hz is outside Francois and Garrison (1982)'s 200 to 1e+06 Hz"),
    (dict(frequency=2e6), "frequency 2e+06 Hz is outside"),
    (dict(temperature=25.0), "temperature 25 deg C is outside Francois and Garrison (1982)'s -2 to 22 deg C"),
    (dict(salinity=36.0), "salinity 36 ppt is outside Francois and Garrison (1982)'s 30 to 35 ppt"),
    (dict(depth=4000.0), "depth 4000 m is outside Francois and Garrison (1982)'s 0 to 3500 m"),
    (dict(ph=9.0), "ph 9 is outside Francois and Garrison (1982)'s 7.7 to 8.3"),
])
def test_absorption_refuses_out_of_range_inputs_when_strict(kwargs, text):
    args = dict(frequency=10e3, temperature=10.0, salinity=35.0, depth=100.0) | kwargs
    with pytest.raises(ValueError, match="^absorption: ") as err:
        absorption(**args, strict=True)
    assert text in str(err.value)


# ------------------------------------------------------------------------- reflection coefficient

def test_total_reflection_below_the_critical_angle():
    theta_c = critical_angle(1.2)
    assert theta_c == pytest.approx(math.acos(1.0 / 1.2))
    below = np.linspace(0.0, theta_c, 20)[:-1]
    np.testing.assert_allclose(np.abs(reflection_coefficient(below, 1.8, 1.2)), 1.0, atol=1e-12)
    above = np.linspace(theta_c, np.pi / 2, 20)[1:]
    assert (np.abs(reflection_coefficient(above, 1.8, 1.2)) < 1.0 - 1e-6).all()


def test_normal_incidence_is_the_impedance_contrast():
    # R = (Z2 - Z1) / (Z2 + Z1), Z = rho c: lossless, and with a complex wavenumber k2 (1 + i delta)
    m, nu = 1.9, 1.15
    assert reflection_coefficient(np.pi / 2, m, nu) == pytest.approx((m * nu - 1) / (m * nu + 1), abs=1e-12)
    att = 0.8                                                   # dB per wavelength
    delta = att / (40.0 * math.pi * math.log10(math.e))
    kappa = (1 + 1j * delta) / nu                               # Z2/Z1 = m / kappa
    assert reflection_coefficient(np.pi / 2, m, nu, att) == pytest.approx((m - kappa) / (m + kappa), abs=1e-12)


def test_pressure_release_limit():
    theta = np.linspace(0.05, np.pi / 2, 7)
    np.testing.assert_allclose(reflection_coefficient(theta, 0.0, 1.1), -1.0, atol=1e-12)
    np.testing.assert_allclose(reflection_coefficient(theta, 1e-9, 1.1), -1.0, atol=1e-6)


def test_energy_is_conserved_above_the_critical_angle():
    # |R|^2 + (rho1 c1 / rho2 c2) |1 + R|^2 sin(theta2) / sin(theta1) = 1, cos(theta2) = nu cos(theta1)
    m, nu = 1.7, 1.1
    theta = np.linspace(critical_angle(nu) + 1e-3, np.pi / 2, 25)
    r = reflection_coefficient(theta, m, nu)
    sin2 = np.sqrt(1.0 - (nu * np.cos(theta)) ** 2)
    transmitted = np.abs(1.0 + r) ** 2 * sin2 / (m * nu * np.sin(theta))
    np.testing.assert_allclose(np.abs(r) ** 2 + transmitted, 1.0, atol=1e-12)
    # a slow seabed (nu < 1) has no critical angle and transmits at every angle
    theta = np.linspace(0.01, np.pi / 2, 25)
    r = reflection_coefficient(theta, 1.4, 0.98)
    sin2 = np.sqrt(1.0 - (0.98 * np.cos(theta)) ** 2)
    np.testing.assert_allclose(np.abs(r) ** 2 + np.abs(1 + r) ** 2 * sin2 / (1.4 * 0.98 * np.sin(theta)), 1.0,
                               atol=1e-12)


def test_attenuation_makes_the_reflection_partial_below_critical():
    theta = np.linspace(0.05, critical_angle(1.2) - 0.05, 9)
    r = np.abs(reflection_coefficient(theta, 1.8, 1.2, attenuation=0.5))
    assert ((r < 1.0) & (r > 0.8)).all()


def test_reflection_broadcasts_like_grazing():
    theta = np.full((3, 4), 0.7)
    r = reflection_coefficient(theta, 1.5, 1.1)
    assert r.shape == (3, 4) and np.iscomplexobj(r)
    assert reflection_coefficient(theta[:, :1], np.array([1.2, 1.5, 2.0]), 1.1).shape == (3, 3)
    assert isinstance(reflection_coefficient(0.3, 1.5, 1.1), complex)
    # grazing 0: -1, except the lossless matched-speed interface, whose limit is (m - 1)/(m + 1)
    assert reflection_coefficient(0.0, 1.5, 1.1) == pytest.approx(-1.0)
    assert reflection_coefficient(0.0, 1.5, 1.0) == pytest.approx(0.2)


def test_critical_angle_of_a_slow_seabed_is_nan():
    out = critical_angle(np.array([0.9, 1.0, 2.0]))
    assert np.isnan(out[0]) and np.isnan(out[1]) and out[2] == pytest.approx(math.pi / 3)
    with pytest.raises(ValueError, match="critical_angle: sound_speed_ratio 0 is not allowed"):
        critical_angle(0.0)


@pytest.mark.parametrize("args, text", [
    ((-0.1, 1.5, 1.1), "reflection_coefficient: grazing -0.1 rad is outside 0 to pi/2 rad"),
    ((2.0, 1.5, 1.1), "grazing 2 rad is outside 0 to pi/2 rad"),
    ((0.5, -1.0, 1.1), "reflection_coefficient: density_ratio -1 is not allowed (a value >= 0)"),
    ((0.5, 1.5, 0.0), "sound_speed_ratio 0 is not allowed (a value > 0)"),
    ((0.5, 1.5, 1.1, -0.2), "attenuation -0.2 dB/wavelength is not allowed"),
])
def test_reflection_refuses_bad_input(args, text):
    with pytest.raises(ValueError) as err:
        reflection_coefficient(*args)
    assert text in str(err.value)


# ------------------------------------------------------------------------- Lambert, bistatic helper

def test_lambert_is_mu_plus_twice_the_log_sine():
    theta = np.array([10.0, 30.0, 90.0]) * DEG
    np.testing.assert_allclose(lambert(theta, -27.0), -27.0 + 20.0 * np.log10(np.sin(theta)))
    assert lambert(np.pi / 2, -27.0) == pytest.approx(-27.0)
    assert lambert(30 * DEG, -27.0) == pytest.approx(-27.0 - 6.0206, abs=1e-4)
    assert lambert(0.0, -27.0) == -np.inf


def test_bistatic_mean_grazing():
    assert bistatic_mean_grazing(10 * DEG, 30 * DEG) == pytest.approx(20 * DEG)
    np.testing.assert_allclose(bistatic_mean_grazing([0.2, 0.4], 0.6), [0.4, 0.5])
    with pytest.raises(ValueError, match="bistatic_mean_grazing: grazing"):
        bistatic_mean_grazing(-0.1, 0.2)


# ------------------------------------------------------------------------- APL-UW sediments

# TR 9407 Table 2 (density ratio, sound speed ratio, delta) as transcribed in UnderwaterAcoustics.jl
TABLE2 = {"sandy gravel": (2.492, 1.3370, 0.01705), "coarse sand": (2.231, 1.2503, 0.01638),
          "medium sand": (1.845, 1.1782, 0.01624), "fine sand": (1.451, 1.1073, 0.01602),
          "very fine sand": (1.268, 1.0568, 0.01875), "clayey sand": (1.224, 1.0364, 0.02019),
          "coarse silt": (1.195, 1.0179, 0.02158), "sandy silt": (1.169, 0.9999, 0.01261),
          "sandy mud": (1.149, 0.9873, 0.00386), "fine silt": (1.148, 0.9861, 0.00306),
          "sandy clay": (1.147, 0.9849, 0.00242), "clay": (1.145, 0.98, 0.00148)}


@pytest.mark.parametrize("name", sorted(TABLE2))
def test_sediment_rows_reproduce_table_2(name):
    rho, nu, delta = TABLE2[name]
    s = SEDIMENTS[name]
    assert s.density_ratio == pytest.approx(rho, abs=6e-4)
    assert s.sound_speed_ratio == pytest.approx(nu, abs=6e-5)
    assert s.loss == pytest.approx(delta, abs=6e-6)
    assert s.spectral_exponent == 3.25
    assert s.volume == (0.002 if s.grain_size < 5.5 else 0.001)


@pytest.mark.parametrize("name, w2_si", [("coarse sand", 0.00022), ("medium sand", 0.0001406),
                                         ("fine sand", 0.000086), ("sandy mud", 0.0000164)])
def test_sediment_spectral_strength_matches_table_2(name, w2_si):
    # w2 in cm^4 with h0 = 1 cm; the SI strength of W(K) = w2_SI / K^gamma (K in 1/m) is w2 * 100**gamma * 1e-8
    assert SEDIMENTS[name].spectral_strength * 100.0 ** 3.25 * 1e-8 == pytest.approx(w2_si, rel=0.02)


def test_rock_rows_and_lookup():
    rock = sediment("Rock")
    assert (rock.density_ratio, rock.sound_speed_ratio, rock.loss, rock.spectral_strength) == (2.5, 2.5, 0.01374,
                                                                                                 0.01862)
    assert sediment("rough_rock").spectral_strength == 0.20693
    assert sediment("medium-sand") is SEDIMENTS["medium sand"]
    assert SEDIMENTS["medium sand"].attenuation == pytest.approx(0.886, abs=1e-3)   # dB/wavelength
    with pytest.raises(ValueError) as err:
        sediment("pudding")
    assert "sediment: unknown name 'pudding' (known: rough rock, rock, cobble, sandy gravel" in str(err.value)


def test_sediment_refuses_values_outside_the_handbook_limits():
    with pytest.raises(ValueError, match="Sediment 'x': density_ratio 0.5 is outside APL-UW TR 9407"):
        Sediment("x", 0.5, 1.1, 0.01, 0.002, 0.004)
    with pytest.raises(ValueError, match="Sediment 'x': spectral_strength 0 is not allowed"):
        Sediment("x", 1.5, 1.1, 0.01, 0.002, 0.0)
    with pytest.raises(ValueError, match="Sediment.from_grain_size: grain_size 10 phi is outside"):
        Sediment.from_grain_size(10.0)


# ------------------------------------------------------------------------- APL-UW backscatter

def _kirchhoff_only(name):
    """The sediment without volume scattering, so that near normal incidence only the Kirchhoff term is left."""
    s = SEDIMENTS[name]
    return Sediment(name, s.density_ratio, s.sound_speed_ratio, s.loss, 0.0, s.spectral_strength)


@pytest.mark.parametrize("name, f", [("medium sand", 30e3), ("fine sand", 30e3), ("coarse sand", 10e3),
                                     ("very fine sand", 100e3)])
def test_kirchhoff_term_matches_the_kirchhoff_integral(name, f):
    # TR 9407's Kirchhoff cross section |R(90)|^2 / (8 pi sin^2 cos^2) int exp(-q u^2a) J0(u) u du,
    # q = qc sin^2 / cos^2a, by quadrature; at normal incidence its limit |R|^2 Gamma(1/a) qc^(-1/a) / (16 pi a).
    sed = _kirchhoff_only(name)
    c = 1500.0
    k = 2 * math.pi * f / (100 * c)                                            # 1/cm
    a = sed.spectral_exponent / 2 - 1
    g = math.gamma
    ch2 = 2 * math.pi * sed.spectral_strength * g(2 - a) * 2 ** (-2 * a) / (a * (1 - a) * g(1 + a))
    qc = ch2 * 2 ** (1 - 2 * a) * k ** (2 * (1 - a))
    kappa = (1 + 1j * sed.loss) / sed.sound_speed_ratio
    r2 = abs((sed.density_ratio - kappa) / (sed.density_ratio + kappa)) ** 2
    assert r2 == pytest.approx(abs(reflection_coefficient(np.pi / 2, sed.density_ratio, sed.sound_speed_ratio,
                                                          sed.attenuation)) ** 2)
    normal = 10 * math.log10(r2 * g(1 / a) * qc ** (-1 / a) / (16 * math.pi * a))
    assert apl_uw_backscatter(np.pi / 2, f, sed, sound_speed=c) == pytest.approx(normal, abs=0.05)
    for deg in (89.0, 85.0, 80.0):   # the handbook's closed form approximates the integral to a fraction of a dB
        th = deg * DEG
        q = qc * math.sin(th) ** 2 / math.cos(th) ** (2 * a)
        integral = quad(lambda u: math.exp(-q * u ** (2 * a)) * j0(u) * u, 0, (40 / q) ** (1 / (2 * a)),
                        limit=2000)[0]
        exact = 10 * math.log10(r2 / (8 * math.pi * math.sin(th) ** 2 * math.cos(th) ** 2) * integral)
        assert apl_uw_backscatter(th, f, sed, sound_speed=c) == pytest.approx(exact, abs=0.6)


def test_volume_term_closed_form_on_a_smooth_seabed():
    # With almost no relief (tiny w2) the slopes vanish, shadowing is 1, and away from normal incidence
    # S_b is the volume term 5 delta sigma2 |1 - R^2|^2 sin^2 / (nu ln10 |P|^2 Im P) (TR 9407 Eqs. 65-66).
    s = SEDIMENTS["silty clay"]
    smooth = Sediment("smooth", s.density_ratio, s.sound_speed_ratio, s.loss, s.volume, 1e-9)
    theta = np.array([5.0, 20.0, 45.0, 70.0]) * DEG
    r = reflection_coefficient(theta, s.density_ratio, s.sound_speed_ratio, s.attenuation)
    kappa = (1 + 1j * s.loss) / s.sound_speed_ratio
    p = np.sqrt(kappa ** 2 - np.cos(theta) ** 2)
    sigma_v = (5 * s.loss * s.volume * np.abs(1 - r ** 2) ** 2 * np.sin(theta) ** 2
               / (s.sound_speed_ratio * math.log(10) * np.abs(p) ** 2 * p.imag))
    np.testing.assert_allclose(apl_uw_backscatter(theta, 30e3, smooth), 10 * np.log10(sigma_v), atol=0.01)


def test_frequency_enters_only_through_k_and_w2():
    # W ~ w2 k^-gamma, qc ~ w2 k^(4-gamma), s^2 ~ (w2 k^(4-gamma))^(1/alpha): scaling f by L and w2 by
    # L^(gamma-4) leaves every term unchanged.
    s = SEDIMENTS["fine sand"]
    scaled = Sediment("scaled", s.density_ratio, s.sound_speed_ratio, s.loss, s.volume,
                      s.spectral_strength * 3.0 ** (s.spectral_exponent - 4.0))
    theta = np.linspace(1.0, 90.0, 30) * DEG
    np.testing.assert_allclose(apl_uw_backscatter(theta, 90e3, scaled), apl_uw_backscatter(theta, 30e3, s),
                               atol=1e-9)
    # and at fixed w2, higher frequency scatters more from the sandy relief at 20 deg (k^(4-gamma) growth)
    assert apl_uw_backscatter(20 * DEG, 90e3, "medium sand") > apl_uw_backscatter(20 * DEG, 30e3, "medium sand")


@pytest.mark.parametrize("name", list(SEDIMENTS))
def test_backscatter_limits_for_every_sediment(name):
    theta = np.linspace(0.5, 60.0, 120) * DEG
    sb = apl_uw_backscatter(theta, 30e3, name)
    assert np.isfinite(sb).all()
    assert (np.diff(sb) > 0).all()                               # rises with grazing below 60 deg
    assert sb[0] < sb[-1] - 15.0                                 # steep, Lambert-like fall towards grazing
    full = apl_uw_backscatter(np.linspace(0.5, 90.0, 180) * DEG, 30e3, name)
    assert full.max() < 3.0                                      # no scattering strength above ~0 dB
    if SEDIMENTS[name].grain_size is not None:                   # sands, silts, clays: specular peak at 90 deg
        assert full[-1] == full.max()


def test_medium_sand_at_30_khz_in_the_published_range():
    # Handbook-scale magnitudes for medium sand at 30 kHz: about -25 to -30 dB at 30 deg, -35 to -40 dB at
    # 10 deg, a few dB below 0 at normal incidence (TR 9407 Fig. IV and Jackson et al. 1986's sand data).
    sb = apl_uw_backscatter(np.array([10.0, 30.0, 90.0]) * DEG, 30e3, "medium sand")
    assert -41.0 < sb[0] < -33.0
    assert -31.0 < sb[1] < -23.0
    assert -8.0 < sb[2] < 0.0
    # rock scatters more than sand, sand more than clay at low grazing
    at = 20 * DEG
    assert (apl_uw_backscatter(at, 30e3, "rock") > apl_uw_backscatter(at, 30e3, "medium sand")
            > apl_uw_backscatter(at, 30e3, "clay"))


def test_backscatter_broadcasts_and_refuses_bad_input():
    theta = np.full((2, 3), 30 * DEG)
    assert apl_uw_backscatter(theta, np.array([20e3, 40e3, 80e3]), "fine sand").shape == (2, 3)
    assert isinstance(apl_uw_backscatter(0.3, 30e3, "fine sand"), float)
    assert np.isfinite(apl_uw_backscatter(0.0, 30e3, "fine sand"))        # evaluated at 0.001 deg
    with pytest.raises(ValueError, match=r"apl_uw_backscatter: frequency 700000 Hz is outside APL-UW TR 9407 "
                                         r"\(pass extrapolate=True\)'s 10000 to 100000 Hz"):
        apl_uw_backscatter(0.3, 700e3, "fine sand")
    assert np.isfinite(apl_uw_backscatter(0.3, 700e3, "fine sand", extrapolate=True))
    with pytest.raises(ValueError, match="apl_uw_backscatter: grazing 3 rad is outside"):
        apl_uw_backscatter(3.0, 30e3, "fine sand")
    with pytest.raises(ValueError, match="sediment: unknown name 'lava'"):
        apl_uw_backscatter(0.3, 30e3, "lava")
    with pytest.raises(ValueError, match="sound_speed 340 m/s is outside"):
        apl_uw_backscatter(0.3, 30e3, "fine sand", sound_speed=340.0)


# ------------------------------------------------------------------------- materials

def test_material_presets():
    assert {"steel", "concrete", "rock", "gravel", "sand", "silt", "mud", "clay"} <= set(MATERIALS)
    steel = material("Steel")
    assert (steel.density, steel.sound_speed) == (7850.0, 5900.0)
    assert (material("concrete").density, material("concrete").sound_speed) == (2400.0, 3700.0)
    sand = material("sand")
    assert sand.density == pytest.approx(1.845 * 1027.0, rel=1e-3)
    assert sand.sound_speed == pytest.approx(1.1782 * 1528.0, rel=1e-4)
    assert sand.attenuation == pytest.approx(0.886, abs=2e-3)
    assert material("mud").lambert_mu == -27.0
    for m in MATERIALS.values():
        assert m.density > 0 and m.sound_speed > 0 and m.attenuation >= 0 and m.source
    # steel in water is nearly rigid: R at normal incidence = (Z - 1)/(Z + 1), Z = 7850 * 5900 / (1027 * 1528)
    z = 7850 * 5900 / (1027 * 1528)
    assert steel.reflection_coefficient(np.pi / 2) == pytest.approx((z - 1) / (z + 1))


def test_material_refuses_unknown_names_and_negative_densities():
    with pytest.raises(ValueError) as err:
        material("unobtainium")
    msg = str(err.value)
    assert msg.startswith("material: unknown name 'unobtainium' (known: steel, concrete, rock")
    assert "\n" not in msg
    with pytest.raises(ValueError, match="Material 'x': density -1000 kg/m\\^3 is not allowed"):
        Material("x", density=-1000.0, sound_speed=1500.0, attenuation=0.0)
    with pytest.raises(ValueError, match="Material 'x': attenuation -1 dB/wavelength is not allowed"):
        Material("x", density=1000.0, sound_speed=1500.0, attenuation=-1.0)
