"""Acoustic materials in physical units: the ``acoustic_material`` BSDF (specular reflection from
impedance, Lambert and APL-UW backscatter) and the sonar's water (``absorption`` and
``sound_speed`` ``auto``), against the NumPy acoustics they come from."""
import math

import numpy as np
import pytest

from conftest import frame_matrix, rectangle_xml, scene_xml, sonar_xml
from test_levels import SINGLE, C, lambert_footprint_level

from mitsonar.sonar_equation import scan_echo_level

N_MC = 1 << 17


@pytest.fixture(scope="module")
def mi():
    import mitsonar  # noqa: F401  (sets the variant and registers the plugins)
    import mitsuba

    return mitsuba


def bsdf(mi, **params):
    return mi.load_dict({"type": "acoustic_material", **params})


def local(grazing, phi=0.0):
    """Unit vectors in the surface's local frame (z the normal) at grazing angles and azimuths."""
    g, p = np.broadcast_arrays(np.asarray(grazing, float), np.asarray(phi, float))
    return np.stack([np.cos(g) * np.cos(p), np.cos(g) * np.sin(p), np.sin(g)], -1)


def interaction(mi, wi):
    si = mi.SurfaceInteraction3f()
    wi = np.asarray(wi, np.float32)
    si.wi = mi.Vector3f(wi[:, 0], wi[:, 1], wi[:, 2])
    return si


def evaluate(mi, b, wi, wo):
    """``f cos theta_o`` of every pair (rows of ``wi`` and ``wo``)."""
    wo = np.asarray(wo, np.float32)
    v = b.eval(mi.BSDFContext(), interaction(mi, wi), mi.Vector3f(wo[:, 0], wo[:, 1], wo[:, 2]))
    return np.array(v[0], dtype=np.float64)


def furnace(mi, b, grazing, n=N_MC, seed=1):
    """The white furnace: ``int f cos theta_o dw`` at one incident grazing angle by Monte Carlo with
    the BSDF's own sampling (the mean of the sample weights) and its standard error; also the
    samples, to check them against ``eval`` and ``pdf``."""
    rng = np.random.default_rng(seed)
    wi = np.repeat(local(grazing)[None], n, 0)
    u = rng.random((n, 3)).astype(np.float32)
    bs, w = b.sample(mi.BSDFContext(), interaction(mi, wi), mi.Float(u[:, 0]), mi.Point2f(u[:, 1], u[:, 2]))
    w = np.array(w[0], dtype=np.float64)
    wo = np.stack([np.array(c, dtype=np.float64) for c in (bs.wo.x, bs.wo.y, bs.wo.z)], -1)
    return w.mean(), w.std() / math.sqrt(n), wi, wo, w, np.array(bs.pdf, dtype=np.float64)


def expected_albedo(b, grazing):
    """What the construction says the albedo is: the specular weight plus the scattered fraction."""
    from mitsonar.plugins.bsdfs.acoustic_material import lerp_table

    return float(lerp_table(b.medium.w, grazing) + lerp_table(b.medium.scattered, grazing))


MATERIAL_CASES = {
    "sand": dict(material="sand"),
    "sand + Lambert -10 dB": dict(material="sand", mu=-10.0),
    "mud, its Lambert preset": dict(material="mud", backscatter="lambert"),
    "medium sand, APL-UW": dict(sediment="medium sand", frequency=100e3),
    "rock, APL-UW (scaled)": dict(material="rock", backscatter="apl_uw", frequency=100e3),
    "rough rock, APL-UW (scaled)": dict(sediment="rough rock", frequency=50e3),
    "steel": dict(material="steel"),
    "sea surface": dict(material="sea_surface"),
    "matched medium + Lambert": dict(density=1027.0, sound_speed=1528.0, mu=-10.0),
}
ANGLES = (5.0, 15.0, 30.0, 45.0, 70.0, 88.0)


@pytest.mark.parametrize("name", list(MATERIAL_CASES))
def test_every_material_conserves_energy(mi, name):
    """int f cos dw <= 1 at every incident angle, and equals the specular weight (|R|^2 where the
    scattered part leaves room for it) plus the scattered fraction, less what the horizon clips of
    the specular lobe (2 % at 5 deg grazing with n = 1000; 1 % where |R|^2 turns at sand's
    critical angle, 31.9 deg, inside the lobe)."""
    from mitsonar.acoustics import reflection_coefficient
    from mitsonar.plugins.bsdfs.acoustic_material import lerp_table

    b = bsdf(mi, **MATERIAL_CASES[name])
    for deg in ANGLES:
        g = math.radians(deg)
        e, err, wi, wo, w, pdf = furnace(mi, b, g)
        expect = expected_albedo(b, g)
        assert expect <= 1.0 + 1e-6
        # ... which is |R|^2 of mitsonar.acoustics plus the scattered fraction, where they fit in 1
        m = b.medium
        r2 = abs(reflection_coefficient(g, m.density / m.water_density, m.sound_speed / m.water_sound_speed,
                                        m.attenuation)) ** 2
        a = expect - float(lerp_table(m.w, g))
        assert expect == pytest.approx(min(r2 + a, 1.0), abs=2e-3), (name, deg)
        assert e <= 1.0 + 4 * err + 1e-4, (name, deg, e)
        # |R|^2 curves over the lobe's width: its average there may exceed its value at the centre
        # (measured: by 3e-4 at most, sand at 45 deg; mud near its angle of intromission)
        assert e <= expect + 1e-3 + 4 * err, (name, deg, e, expect)
        assert e >= expect - (0.03 if deg < 10 else 0.015) - 4 * err, (name, deg, e, expect)
        # the sample weights are eval / pdf of the sampled directions
        ok = pdf > 0
        np.testing.assert_allclose(w[ok][:2000], (evaluate(mi, b, wi[ok][:2000], wo[ok][:2000])
                                                  / pdf[ok][:2000]), rtol=2e-3, atol=1e-6)


def test_lambert_albedo_by_uniform_sampling(mi):
    """Independent of the BSDF's sampling: a matched medium (R = 0) with Lambert mu reflects
    pi 10^(mu/10) at every angle (uniform directions over the hemisphere, f cos / (1 / 2 pi))."""
    b = bsdf(mi, density=1027.0, sound_speed=1528.0, mu=-8.0)
    rng = np.random.default_rng(3)
    n = 1 << 16
    u = rng.random((n, 2))
    z = u[:, 0]
    r = np.sqrt(1 - z * z)
    wo = np.stack([r * np.cos(2 * np.pi * u[:, 1]), r * np.sin(2 * np.pi * u[:, 1]), z], -1)
    for deg in (3.0, 30.0, 80.0):
        wi = np.repeat(local(math.radians(deg))[None], n, 0)
        e = evaluate(mi, b, wi, wo).mean() * 2 * np.pi
        assert e == pytest.approx(math.pi * 10 ** (-0.8), rel=0.01)


@pytest.mark.parametrize("name", list(MATERIAL_CASES))
def test_every_material_is_reciprocal(mi, name):
    """f(wi, wo) = f(wo, wi): eval returns f cos(theta_o), so eval(wi, wo) / cos_o against
    eval(wo, wi) / cos_i, over random pairs and over pairs near the mirror direction."""
    b = bsdf(mi, **MATERIAL_CASES[name])
    rng = np.random.default_rng(7)
    n = 4096
    gi = rng.uniform(0.02, np.pi / 2, n)
    gi = np.r_[gi, gi]
    go = np.r_[rng.uniform(0.02, np.pi / 2, n), gi[:n] + rng.normal(0, 0.02, n)]
    go = np.clip(go, 0.02, np.pi / 2)
    pi_ = rng.uniform(0, 2 * np.pi, 2 * n)
    po = np.r_[rng.uniform(0, 2 * np.pi, n), pi_[n:] + np.pi + rng.normal(0, 0.02, n)]
    wi, wo = local(gi, pi_), local(go, po)
    wi32, wo32 = wi.astype(np.float32).astype(np.float64), wo.astype(np.float32).astype(np.float64)
    f_io = evaluate(mi, b, wi, wo) / wo32[:, 2]
    f_oi = evaluate(mi, b, wo, wi) / wi32[:, 2]
    assert np.count_nonzero(f_io) > n // 2
    np.testing.assert_allclose(f_io, f_oi, rtol=1e-4, atol=1e-7)


def test_the_critical_angle_shows(mi):
    """Sand without backscatter: the energy of the specular lobe follows |R(grazing)|^2 of
    mitsonar.acoustics.reflection_coefficient: nearly total (the sediment's loss) below the critical
    angle arccos(c_water / c_sand) = 31.9 deg, then down to the Rayleigh value at normal incidence."""
    from mitsonar.acoustics import critical_angle, material, reflection_coefficient

    sand = material("sand")
    m, nu = sand.density / 1027.0, sand.sound_speed / 1528.0
    theta_c = math.degrees(critical_angle(nu))
    assert theta_c == pytest.approx(31.9, abs=0.1)
    b = bsdf(mi, material="sand")
    energies = {}
    for deg in (10.0, 20.0, 27.0, 36.0, 45.0, 60.0, 85.0):
        e = furnace(mi, b, math.radians(deg))[0]
        r2 = abs(reflection_coefficient(math.radians(deg), m, nu, sand.attenuation)) ** 2
        energies[deg] = e
        assert e == pytest.approx(r2, abs=0.015), (deg, e, r2)
    assert energies[27.0] > 0.8 > 0.5 > energies[36.0]     # the drop across 31.9 deg
    # the Rayleigh value at normal incidence: ((Z2 - Z1) / (Z2 + Z1))^2
    z = m * nu
    assert energies[85.0] == pytest.approx(((z - 1) / (z + 1)) ** 2, abs=0.01)


def test_sea_surface_and_steel(mi):
    """Pressure release (R = -1) returns everything at every angle; steel (a fluid of
    7850 kg/m^3, 5900 m/s here) everything below its critical angle, 75 deg, and
    ((Z - 1)/(Z + 1))^2 = 87 % at normal incidence."""
    sea, steel = bsdf(mi, material="sea_surface"), bsdf(mi, material="steel")
    for deg in (20.0, 50.0, 88.0):
        assert furnace(mi, sea, math.radians(deg))[0] == pytest.approx(1.0, abs=0.005)
    assert furnace(mi, steel, math.radians(50.0))[0] == pytest.approx(1.0, abs=0.005)
    z = 7850.0 * 5900.0 / (1027.0 * 1528.0)
    assert furnace(mi, steel, math.radians(89.5))[0] == pytest.approx(((z - 1) / (z + 1)) ** 2, abs=0.005)


def test_monostatic_backscatter_is_the_model(mi):
    """In the backscatter direction (wo = wi) 10 log10(f cos^2) is Lambert's law and the APL-UW
    model (times the stated scale for rock, which is 1 for sand)."""
    from mitsonar.acoustics import apl_uw_backscatter, lambert

    deg = np.array([5.0, 10.0, 30.0, 60.0, 80.0])
    g = np.radians(deg)
    wi = local(g)
    lam = bsdf(mi, material="sand", mu=-20.0)
    s = 10 * np.log10(evaluate(mi, lam, wi, wi) * np.sin(g))       # eval is f cos_o
    np.testing.assert_allclose(s, lambert(g, -20.0), atol=0.01)
    for kw, sed, f in ((dict(sediment="medium sand", frequency=60e3), "medium sand", 60e3),
                       (dict(material="rock", backscatter="apl_uw", frequency=100e3), "rock", 100e3)):
        b = bsdf(mi, **kw)
        s = 10 * np.log10(evaluate(mi, b, wi, wi) * np.sin(g))
        ref = apl_uw_backscatter(g, f, sed, 1528.0) + 10 * np.log10(b.medium.backscatter_scale)
        np.testing.assert_allclose(s, ref, atol=0.05)
    assert b.medium.backscatter_scale == pytest.approx(1 / 1.67, rel=0.02)     # rock: -2.2 dB, stated
    assert bsdf(mi, sediment="medium sand", frequency=60e3).medium.backscatter_scale == 1.0


def test_rendered_lambert_seabed_echo_level_is_the_footprint_integral(mitsonar_mod):
    """A sand seabed with Lambert mu under a tilted uniform beam: its absolute echo level is the
    sonar equation's footprint integral with S_b = mu + 10 log10 sin^2 (test_levels' method, whose
    Lambert BSDF of albedo rho has mu = 10 log10(rho / pi)); the specular lobe points away."""
    mu = -9.0
    rho = math.pi * 10 ** (mu / 10)
    h, tilt, bw, alpha = 2.0, math.radians(30.0), 6.0, 0.05
    rmin, bin_width, n_bins, pulse_bins = 2.0, 0.01, 60, 3
    boresight = (math.sin(tilt), 0.0, -math.cos(tilt))
    sensor = sonar_xml(frame_matrix(boresight, (0, 1, 0)), beam_pattern="uniform", beamwidth_h=bw, beamwidth_v=bw,
                       range_min=rmin, range_max=rmin + n_bins * bin_width, n_bins=n_bins, n_pings=1,
                       bearing_step=0.0, absorption=alpha, pulse_length=2 * pulse_bins * bin_width / C)
    plane = np.diag([20.0, 20.0, 1.0, 1.0])
    plane[2, 3] = -h
    material = (f'<bsdf type="acoustic_material"><string name="material" value="sand"/>'
                f'<float name="mu" value="{mu}"/></bsdf>')
    scene = mitsonar_mod.load_scene(scene_xml(sensor, rectangle_xml(plane, material), integrator=SINGLE))
    scan = mitsonar_mod.render_scan(scene, spp=1 << 16, seed=2)
    ref = lambert_footprint_level(rho, h, tilt, math.radians(bw), alpha, rmin, bin_width, n_bins, pulse_bins)
    el = scan_echo_level(scan)[0].astype(np.float64)
    lit = ref > ref.max() - 6.0
    assert lit.sum() >= 8
    np.testing.assert_allclose(el[lit], ref[lit], atol=0.1)


@pytest.mark.parametrize("params, message", [
    (dict(material="wood"), "'material': 'wood' is not allowed (one of steel, concrete, rock, gravel, sand, silt, "
                            "mud, clay, sea_surface)"),
    (dict(sediment="pebbles"), "'sediment': 'pebbles' is not allowed (one of rough rock, rock"),
    (dict(density=-1.0, sound_speed=1600.0), "'density': -1.0 is not allowed (a density >= 0 kg/m^3"),
    (dict(density=1500.0, sound_speed=0.0), "'sound_speed': 0.0 is not allowed (a sound speed > 0 m/s)"),
    (dict(material="sand", attenuation=-0.1), "'attenuation': -0.1 is not allowed"),
    (dict(material="sand", mu=-3.0), "'mu': -3.0 is not allowed (a Lambert parameter <= -4.97 dB"),
    (dict(material="sand", backscatter="lambert"), "'mu': missing"),
    (dict(material="sand", backscatter="phong"), "'backscatter': 'phong' is not allowed (one of none, lambert, apl_uw)"),
    (dict(material="steel", backscatter="apl_uw", frequency=1e5), "'sediment': missing"),
    (dict(material="sand", backscatter="apl_uw"), "'frequency': missing"),
    (dict(sediment="clay", frequency=700e3), "'frequency': 700000.0 is not allowed (10000 to 100000 Hz"),
    (dict(material="sand", mu=-20.0, sediment="clay"), "'sediment': give 'mu' (backscatter 'lambert') or 'sediment'"),
    (dict(material="sand", mu=-20.0, backscatter="none"), "'mu': only used with backscatter 'lambert'"),
    (dict(material="sand", frequency=1e5), "'frequency': only used with backscatter 'apl_uw'"),
    (dict(), "'density': missing: give 'material'"),
])
def test_bad_materials_are_refused_in_one_line(mitsonar_mod, params, message):
    def xml_value(v):
        return f'<float name="{{}}" value="{v}"/>' if isinstance(v, float) else f'<string name="{{}}" value="{v}"/>'
    items = "".join(xml_value(v).format(k) for k, v in params.items())
    bad = f'<bsdf type="acoustic_material">{items}</bsdf>'
    plane = np.eye(4)
    sensor = sonar_xml(frame_matrix((0, 0, -1), (0, 1, 0), (0, 0, 1)), n_pings=1, n_bins=8)
    with pytest.raises(Exception) as err:
        mitsonar_mod.load_scene(scene_xml(sensor, rectangle_xml(plane, bad)))
    text = str(err.value)
    assert "acoustic_material " + message in text, text
    assert "\n" not in text


# ----------------------------------------------------------------------------- the water

def water_sensor(z=-20.0, **params):
    return sonar_xml(frame_matrix((1, 0, 0), (0, 0, 1), (0, 0, z)), n_pings=1, n_bins=8, **params)


def sensor_of(mitsonar_mod, xml):
    return mitsonar_mod.load_scene(scene_xml(xml)).sensors()[0]


def test_auto_water_falls_back_to_wide_range_equations_outside_the_default_ones(mitsonar_mod):
    from mitsonar.acoustics.seawater import ainslie_mccolm, sound_speed

    # tropical water (28 deg C) is outside Francois-Garrison's and, at 35 deg C, Mackenzie's range
    s = sensor_of(mitsonar_mod, water_sensor(-20.0, absorption="auto", frequency=200e3, temperature=28.0))
    assert s.absorption == pytest.approx(ainslie_mccolm(200e3, 28.0, 35.0, 20.0, 8.0), rel=1e-12)
    s = sensor_of(mitsonar_mod, water_sensor(-20.0, sound_speed="auto", temperature=35.0, salinity=5.0))
    assert s.sound_speed == pytest.approx(sound_speed(35.0, 5.0, 20.0, model="unesco"), rel=1e-12)


def test_auto_absorption_is_francois_garrison_at_the_heads_depth(mitsonar_mod):
    from mitsonar.acoustics import absorption

    s = sensor_of(mitsonar_mod, water_sensor(-20.0, absorption="auto", frequency=200e3, temperature=12.0,
                                             salinity=34.0, ph=7.9, surface_z=5.0))
    assert s.absorption == pytest.approx(absorption(200e3, 12.0, 34.0, 25.0, 7.9), rel=1e-12)
    assert s.sound_speed == 1500.0
    # the defaults: 700 kHz, 10 deg C, 35 ppt, pH 8, the surface at z = 0
    s = sensor_of(mitsonar_mod, water_sensor(-20.0, absorption="auto"))
    assert s.absorption == pytest.approx(absorption(700e3, 10.0, 35.0, 20.0, 8.0), rel=1e-12)
    assert 0.15 < s.absorption < 0.25          # dB/m at 700 kHz: 200 dB/km, not the old default 0


def test_auto_sound_speed_is_mackenzie_at_the_heads_depth(mitsonar_mod):
    from mitsonar.acoustics import sound_speed

    s = sensor_of(mitsonar_mod, water_sensor(-150.0, sound_speed="auto", temperature=25.0, salinity=38.0))
    assert s.sound_speed == pytest.approx(sound_speed(25.0, 38.0, 150.0), rel=1e-12)
    assert s.absorption == 0.0
    # the range window's timing follows: the default ping period is the two-way flight at that speed
    assert s.ping_period == pytest.approx(2 * 12.0 / s.sound_speed + 0.03)


@pytest.mark.parametrize("params, message", [
    (dict(absorption="auto", temperature=40.0),
     "sonar 'temperature': 40 deg C is outside Ainslie and McColm (1998)'s -6 to 35 deg C (absorption 'auto')"),
    (dict(sound_speed="auto", temperature=45.0),
     "sonar 'temperature': 45 deg C is outside Mackenzie (1981)'s -2 to 30 deg C and Chen and Millero (UNESCO 1983)'s "
     "0 to 40 deg C (sound_speed 'auto')"),
    (dict(absorption="auto", salinity=60.0), "sonar 'salinity': 60 ppt is outside Ainslie and McColm (1998)'s"),
    (dict(absorption="auto", ph=9.0), "sonar 'ph': 9 is outside Ainslie and McColm (1998)'s 7.7 to 8.3"),
    (dict(absorption="auto", frequency=2e6), "sonar 'frequency': 2e+06 Hz is outside Ainslie and McColm (1998)'s "
                                             "100 to 1e+06 Hz"),
    (dict(absorption="auto", surface_z=-30.0), "sonar 'surface_z': the head's depth -10 m (surface_z -30 - the "
                                               "head's z -20) is outside Ainslie and McColm (1998)'s 0 to 7000 m"),
    (dict(sound_speed="auto", surface_z=11000.0), "sonar 'surface_z': the head's depth 11020 m (surface_z 11000 - the "
                                                  "head's z -20) is outside Mackenzie (1981)'s 0 to 8000 m and Chen and "
                                                  "Millero (UNESCO 1983)'s 0 to 1000 bar"),
    (dict(absorption="lots"), "sonar 'absorption': 'lots' is not a number (expected <float> or <string value=\"auto\"/>)"),
    (dict(sound_speed="1500"), "sonar 'sound_speed': expected <float> or <string value=\"auto\"/>, got <string> '1500'"),
    (dict(temperature=12.0), "sonar 'temperature': only used with absorption or sound_speed 'auto'"),
    (dict(sound_speed="auto", ph=8.1), "sonar 'ph': only used with absorption 'auto'"),
])
def test_bad_water_is_refused_in_one_line(mitsonar_mod, params, message):
    with pytest.raises(Exception) as err:
        sensor_of(mitsonar_mod, water_sensor(-20.0, **params))
    text = str(err.value)
    assert message in text, text
    assert "\n" not in text


def test_auto_water_refuses_a_moving_head(mitsonar_mod):
    """'auto' is evaluated at to_world's depth; a render given a pose (a trajectory) is refused."""
    scene = mitsonar_mod.load_scene(scene_xml(water_sensor(-20.0, absorption="auto")))
    with pytest.raises(ValueError, match="sonar 'absorption': 'auto' is computed at the depth of the sensor's "
                                         "to_world"):
        mitsonar_mod.render_scan(scene, spp=4, pose=np.eye(4))


def test_the_parameter_tables_list_the_new_fields(mitsonar_mod):
    """The docstring tables are the documentation and the list of accepted names: a misspelling
    is refused with the nearest one."""
    from mitsonar.plugins import parameters
    from mitsonar.plugins.sensors.sonar import SonarSensor
    from mitsonar.plugins.bsdfs import acoustic_material

    assert {"temperature", "salinity", "ph", "surface_z"} <= set(parameters(SonarSensor))
    assert parameters(acoustic_material.AcousticMaterialBSDF) == [
        "material", "density", "sound_speed", "attenuation", "water_density", "water_sound_speed", "backscatter",
        "mu", "sediment", "frequency", "extrapolate", "shininess"]
    bad = '<bsdf type="acoustic_material"><string name="material" value="sand"/><float name="densty" value="2"/></bsdf>'
    sensor = sonar_xml(frame_matrix((0, 0, -1), (0, 1, 0), (0, 0, 1)), n_pings=1, n_bins=8)
    with pytest.raises(Exception, match='has no parameter "densty" \\(did you mean "density"\\?\\)'):
        mitsonar_mod.load_scene(scene_xml(sensor, rectangle_xml(np.eye(4), bad)))


def test_bistatic_pairs_take_the_mean_grazing_angle(mi):
    """Off the backscatter direction (and far from the mirror one) the scattered lobe is the
    monostatic f_mono = sigma / sin^2 at acoustics.bistatic_mean_grazing(incident, scattered)."""
    from mitsonar.acoustics import apl_uw_backscatter, bistatic_mean_grazing

    b = bsdf(mi, sediment="fine sand", frequency=40e3)
    gi = np.radians([10.0, 25.0, 40.0, 70.0])
    go = np.radians([50.0, 5.0, 80.0, 20.0])
    wi, wo = local(gi, 0.0), local(go, 0.5 * np.pi)          # 90 deg apart in azimuth: no mirror lobe
    f = evaluate(mi, b, wi, wo) / np.sin(go)
    gm = bistatic_mean_grazing(gi, go)
    ref = 10 ** (apl_uw_backscatter(gm, 40e3, "fine sand", 1528.0) / 10) / np.sin(gm) ** 2
    np.testing.assert_allclose(f, ref, rtol=0.01)
