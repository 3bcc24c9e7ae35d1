"""Acoustic levels in physical units: source level, echo level, noise, directivity, SNR and the
sonar-equation report, against closed forms (Urick 1983, eqs. 2.1, 2.2)."""
import math
import os
import re
from pathlib import Path

import numpy as np
import pytest

from conftest import acoustic_xml, frame_matrix, rectangle_xml, scene_xml, sonar_xml, sphere_xml
from mitsonar.sonar_equation import directivity_index, scan_echo_level, scan_levels, snr

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
DATA = os.path.join(ROOT, "tests", "data")
SINGLE = '<integrator type="sonar_tof"><integer name="max_depth" value="1"/></integrator>'
C = 1500.0


# ----------------------------------------------------------------------------- point targets

def sphere_scene(mitsonar, a, d, alpha, shininess, bin_width=0.01, pulse_bins=4):
    """A mirror-like Phong sphere (specular 1) of radius ``a`` whose front is at ``d`` on the axis
    of a uniform 3 x 3 deg beam (the sphere well inside it), a pulse ``pulse_bins`` bins long."""
    sensor = sonar_xml(frame_matrix((1, 0, 0), (0, 0, 1)), beam_pattern="uniform", beamwidth_h=3.0,
                       beamwidth_v=3.0, range_min=d - 0.2, range_max=d + 0.3, n_bins=int(round(0.5 / bin_width)),
                       n_pings=1, bearing_step=0.0, absorption=alpha,
                       pulse_length=2 * pulse_bins * bin_width / C)
    return mitsonar.load_scene(scene_xml(sensor, sphere_xml((d + a, 0, 0), a, acoustic_xml(0.0, 1.0, shininess)),
                                         integrator=SINGLE))


def test_phong_sphere_cross_section_tends_to_the_geometric_sphere():
    from mitsonar.sonar_equation import phong_sphere_cross_section

    # Exact quadrature against a direct one (scipy) at a moderate exponent ...
    from scipy.integrate import quad

    n = 50.0
    direct = (n + 2) * quad(lambda t: math.cos(2 * t) ** n * math.cos(t) ** 2 * math.sin(t), 0, math.pi / 4)[0]
    assert phong_sphere_cross_section(1.0, 1.0, n) == pytest.approx(direct, rel=1e-10)
    # ... and the mirror limit a^2 / 4 (TS = 20 log10(a / 2)).
    assert phong_sphere_cross_section(2.0, 1.0, 1e6) == pytest.approx(1.0, rel=1e-5)
    assert 10 * math.log10(phong_sphere_cross_section(0.1, 1.0, 300) / (0.1 ** 2 / 4)) < 0.02


@pytest.mark.parametrize("a,d,alpha", [(0.03, 2.0, 0.0), (0.05, 3.0, 0.0), (0.1, 5.0, 0.1)])
def test_sphere_echo_level_is_the_sonar_equation(mitsonar_mod, a, d, alpha):
    from mitsonar.sonar_equation import phong_sphere_cross_section

    n = 300.0
    scan = mitsonar_mod.render_scan(sphere_scene(mitsonar_mod, a, d, alpha, n), spp=1 << 16, seed=1)
    sl = scan.electronics.source_level
    assert sl == 200.0
    D = d + a
    ts = 10 * math.log10(phong_sphere_cross_section(a, 1.0, n))
    expect = sl - 10 * math.log10(d ** 2 * D ** 2) - 2 * alpha * d + ts
    el = scan_echo_level(scan)[0]
    assert el.dtype == np.float32 and el.shape == (scan.n_bins,)
    j = int((d - scan.range_min) / scan.bin_width)       # the bin of the sphere's front
    # The 4-bin pulse fills bins j+1..j+3 wholly: the echo keeps its level there.
    np.testing.assert_allclose(el[j + 1:j + 4], expect, atol=0.25)
    # Before the echo there is none; the half-filled edge bins are 3 dB down.
    assert np.all(np.isneginf(el[:j - 1]))
    assert el[j] == pytest.approx(expect - 3.0, abs=0.4)
    # The intensity itself is noise free and unchanged by the levels (one bin holds the echo).
    assert scan.intensity[0].sum() == pytest.approx(10 ** ((expect - sl) / 10), rel=0.06)


def test_echo_level_boxcar_of_ones():
    from mitsonar.sonar_equation import echo_level, pulse_boxcar

    np.testing.assert_allclose(pulse_boxcar(0.03, 0.01), [0.5, 1, 1, 0.5])
    np.testing.assert_allclose(pulse_boxcar(0.005, 0.01), [0.5])
    ranges = (np.arange(10) + 0.5) * 0.01
    inten = np.zeros(10)
    inten[2] = 1e-6
    el = echo_level(inten, ranges, 210.0, 2 * 0.03 / C, C)
    np.testing.assert_allclose(el[2:6], 210.0 - 60.0 + 10 * np.log10([0.5, 1, 1, 0.5]), atol=1e-4)
    assert np.all(np.isneginf(el[[0, 1, 6, 7, 8, 9]]))
    # No pulse: the echo fills its own bin.
    assert echo_level(inten, ranges, 210.0, 0.0, C)[2] == pytest.approx(150.0, abs=1e-4)


# ----------------------------------------------------------------------------- extended seabed

def lambert_footprint_level(rho, h, tilt, bw, alpha, rmin, bin_width, n_bins, pulse_bins, n=2400):
    """Echo level (dB re 1 uPa, SL 200) of a Lambert plane ``h`` below a uniform square beam of
    width ``bw`` tilted ``tilt`` from the vertical, as the sonar equation's footprint integral:
    per bin, the sum over plane patches dA of ``S_b dA r^-4 10^(-2 alpha r / 10)`` with Lambert's
    ``S_b = (rho / pi) cos^2 theta`` (the BSDF's backscatter per unit area), then the pulse's
    boxcar of ones (pulse_bins bins, echoes at bin centres: weights 1/2, 1, ..., 1, 1/2)."""
    zb = np.array([math.sin(tilt), 0.0, -math.cos(tilt)])
    yb = np.array([0.0, 1.0, 0.0])
    xb = np.cross(yb, zb)
    x = np.linspace(h * math.tan(tilt - bw), h * math.tan(tilt + bw), n)
    rmax = math.hypot(x[-1], h)
    y = np.linspace(-rmax * math.tan(bw), rmax * math.tan(bw), n)
    dA = (x[1] - x[0]) * (y[1] - y[0])
    X, Y = np.meshgrid(x, y)
    P = np.stack([X, Y, np.full_like(X, -h)], -1)
    r = np.linalg.norm(P, axis=-1)
    u = P / r[..., None]
    az = np.arctan2(u @ xb, u @ zb)
    el = np.arcsin(u @ yb)
    inside = (np.abs(az) <= bw / 2) & (np.abs(el) <= bw / 2)
    w = np.where(inside, rho / math.pi * (h / r) ** 2 / r ** 4 * 10 ** (-2 * alpha * r / 10) * dA, 0.0)
    k = np.floor((r - rmin) / bin_width).astype(int)
    ok = inside & (k >= 0) & (k < n_bins)
    hist = np.bincount(k[ok], w[ok], minlength=n_bins)
    ones = np.r_[0.5, np.ones(pulse_bins - 1), 0.5]
    boxed = np.convolve(hist, ones)[:n_bins]
    with np.errstate(divide="ignore"):
        return 200.0 + 10 * np.log10(boxed)


def test_lambert_seabed_echo_level_matches_the_footprint_integral(mitsonar_mod):
    rho, h, tilt, bw, alpha = 0.6, 2.0, math.radians(30.0), 6.0, 0.05
    rmin, bin_width, n_bins, pulse_bins = 2.0, 0.01, 60, 3
    boresight = (math.sin(tilt), 0.0, -math.cos(tilt))
    sensor = sonar_xml(frame_matrix(boresight, (0, 1, 0)), beam_pattern="uniform", beamwidth_h=bw, beamwidth_v=bw,
                       range_min=rmin, range_max=rmin + n_bins * bin_width, n_bins=n_bins, n_pings=1,
                       bearing_step=0.0, absorption=alpha, pulse_length=2 * pulse_bins * bin_width / C)
    plane = np.diag([20.0, 20.0, 1.0, 1.0])
    plane[2, 3] = -h
    scene = mitsonar_mod.load_scene(scene_xml(sensor, rectangle_xml(plane, acoustic_xml(rho)), integrator=SINGLE))
    scan = mitsonar_mod.render_scan(scene, spp=1 << 17, seed=2)
    ref = lambert_footprint_level(rho, h, tilt, math.radians(bw), alpha, rmin, bin_width, n_bins, pulse_bins)
    el = scan_echo_level(scan)[0].astype(np.float64)
    lit = ref > ref.max() - 6.0
    assert lit.sum() >= 8, "the echo should fill many bins"
    np.testing.assert_allclose(el[lit], ref[lit], atol=0.1)   # measured: within 0.01 dB
    assert np.all(np.isneginf(el[np.isneginf(ref)][:3]))


# ----------------------------------------------------------------------------- receiver side

def test_directivity_index_closed_forms(mitsonar_mod):
    from mitsonar.plugins.sensors.beam import BeamPattern

    bh, bv = math.radians(3.0), math.radians(35.0)
    uni = BeamPattern("uniform", 3.0, 35.0)
    assert uni.directivity_index() == pytest.approx(10 * math.log10(4 * math.pi / (bh * 2 * math.sin(bv / 2))), abs=1e-3)
    # gaussian B = 2^-((2 az / bh)^2 + (2 el / bv)^2): Int = sqrt(pi / p) sqrt(pi / q) exp(-1 / (4 q)),
    # p = 4 ln 2 / bh^2, q = 4 ln 2 / bv^2 (the cos(el) of the measure in closed form)
    p, q = 4 * math.log(2) / bh ** 2, 4 * math.log(2) / bv ** 2
    gauss = math.sqrt(math.pi / p) * math.sqrt(math.pi / q) * math.exp(-1 / (4 * q))
    assert BeamPattern("gaussian", 3.0, 35.0).directivity_index() == pytest.approx(
        10 * math.log10(4 * math.pi / gauss), abs=1e-3)
    # a large baffled piston: DI = 10 log10(4 pi A / lambda^2) (Urick 1983, Table 3.1)
    sinc = BeamPattern("sinc", 3.0, 3.0, frequency=500e3)
    lam = C / 500e3
    assert sinc.directivity_index() == pytest.approx(
        10 * math.log10(4 * math.pi * sinc.aperture_h * sinc.aperture_v / lam ** 2), abs=0.05)


def test_ambient_noise_is_thermal_at_high_frequency():
    from mitsonar.sonar_equation import DEFAULT_NOISE_LEVEL, ambient_noise_level

    # Mellen's thermal noise -15 + 20 log10 f_kHz dominates above ~100 kHz
    assert float(ambient_noise_level(700e3)) == pytest.approx(-15 + 20 * math.log10(700), abs=0.1)
    assert DEFAULT_NOISE_LEVEL == round(float(ambient_noise_level(700e3)))
    # and wind noise at a few kHz (Wenz): 50 + 7.5 sqrt(w) + 20 log f - 40 log(f + 0.4) dominates
    assert float(ambient_noise_level(5e3, wind_speed=10.0)) == pytest.approx(
        50 + 7.5 * math.sqrt(10) + 20 * math.log10(5) - 40 * math.log10(5.4), abs=0.5)


def test_snr_is_echo_level_minus_noise_in_band(mitsonar_mod):
    scan = mitsonar_mod.render_scan(sphere_scene(mitsonar_mod, 0.05, 3.0, 0.0, 300.0), spp=1 << 12, seed=0)
    tau = scan.electronics.pulse_length
    di = 10 * math.log10(4 * math.pi / (math.radians(3.0) * 2 * math.sin(math.radians(1.5))))
    assert directivity_index(scan) == pytest.approx(di, abs=1e-3)
    noise = 42.0 + 10 * math.log10(1 / tau) - di
    assert scan_levels(scan).noise_band_level == pytest.approx(noise, abs=1e-3)
    np.testing.assert_allclose(snr(scan), scan_echo_level(scan) - np.float32(noise), atol=1e-3)
    # an explicit receiver bandwidth and noise level, and DI recomputed from the fields without the record
    scan.electronics.receiver_bandwidth, scan.electronics.noise_level = 1e4, 50.0
    scan.meta.directivity_index = None
    assert scan_levels(scan).noise_band_level == pytest.approx(50.0 + 40.0 - di, abs=1e-3)


def test_receiver_bandwidth_is_the_noise_band_and_files_saved_as_bandwidth_still_load(mitsonar_mod, tmp_path):
    """The receiver's noise bandwidth is the electronics field ``receiver_bandwidth`` (the sensor's
    ``bandwidth`` is the transducer's band); scans saved while it was called ``bandwidth`` load with
    it under the new name, and settings dicts with the old key still build."""
    from mitsonar.receiver.electronics import Electronics

    e = Electronics(receiver_bandwidth=1e4, pulse_length=1e-4)
    assert e.noise_bandwidth() == 1e4 and Electronics(pulse_length=1e-4).noise_bandwidth() == pytest.approx(1e4)
    assert Electronics.from_dict({"bandwidth": 2e4}).receiver_bandwidth == 2e4
    scan = mitsonar_mod.render_scan(sphere_scene(mitsonar_mod, 0.05, 3.0, 0.0, 300.0), spp=64, seed=0)
    old = {k: v for k, v in scan.electronics.items() if k != "receiver_bandwidth"}
    scan.electronics = {**old, "bandwidth": 1e4, "noise_level": 50.0}          # as saved this morning
    for suffix in ("npz", "exr"):
        scan.save(tmp_path / f"old.{suffix}")
        back = mitsonar_mod.load_scan(tmp_path / f"old.{suffix}")
        assert back.electronics.receiver_bandwidth == 1e4 and "bandwidth" not in back.electronics
        assert scan_levels(back).noise_band_level == pytest.approx(50.0 + 40.0 - directivity_index(back), abs=1e-3)


# ----------------------------------------------------------------------------- electronics, files

def test_default_bytes_keep_the_old_calibration(mitsonar_mod):
    from mitsonar.receiver.electronics import Electronics, apply_to_scan

    e = Electronics()
    assert e.source_level + e.receiver_sensitivity == 52.0
    scan = mitsonar_mod.render_scan(mitsonar_mod.load_scene(os.path.join(ROOT, "scenes_xml", "box.xml")), spp=4)
    # Only the sum SL + sensitivity enters the bytes: the full default chain (speckle, noise,
    # ring-down) with another split of 52 dB gives the very same bytes.
    other = Electronics(source_level=230.0, receiver_sensitivity=-178.0)
    again = apply_to_scan(scan, other.to_dict())
    np.testing.assert_array_equal(again.data, scan.data)
    # The quiet chain is the old formula 10 log10(I) + 52 + gain + TVG, bit for bit.
    quiet = Electronics(speckle="off", noise_floor=-math.inf, ringdown=0.0, pulse_length=0.0, range_jitter=0.0)
    data = quiet.apply(scan.intensity, scan.ranges)
    with np.errstate(divide="ignore"):
        level = 10.0 * np.log10(scan.intensity.astype(np.float64)) + 52.0 + quiet.gain + quiet.tvg_db(scan.ranges)
    np.testing.assert_array_equal(data, quiet.quantise(level))


@pytest.mark.parametrize("name", ["old_levels_scan.npz", "old_levels_scan.exr"])
def test_files_from_before_levels_load_with_the_old_constant_split(mitsonar_mod, name):
    # Written by mitsonar 0.2 (source_level = 52, the calibration constant; no receiver_sensitivity).
    from mitsonar.receiver.electronics import apply_to_scan

    scan = mitsonar_mod.load_scan(os.path.join(DATA, name))
    assert scan.electronics.source_level == 200.0
    assert scan.electronics.receiver_sensitivity == -148.0
    # Re-applying the recorded electronics gives version 0.3's bytes (its noise is drawn by
    # another generator, issue 55): the same for the same seed, the echo in the file's bins
    again = apply_to_scan(scan).data
    np.testing.assert_array_equal(again, apply_to_scan(scan).data)
    assert again.shape == scan.data.shape
    assert (again[0, 21:23] > 120).all() and (scan.data[0, 21:23] > 120).all()
    # The echo level follows from the intensity: 1e-5 in one bin with a 7.5 cm pulse on 2.5 cm bins.
    el = scan_echo_level(scan)
    assert el[0, 21] == pytest.approx(200.0 - 50.0, abs=1e-4)
    assert np.isneginf(el[0, :20]).all()


def test_echo_level_round_trips_and_is_derived(mitsonar_mod, tmp_path):
    scan = mitsonar_mod.load_scan(os.path.join(DATA, "old_levels_scan.npz"))
    for ext in (".npz", ".exr"):
        path = tmp_path / ("s" + ext)
        scan.save(path)
        back = mitsonar_mod.load_scan(path)
        np.testing.assert_array_equal(scan_echo_level(back), scan_echo_level(scan))
        assert back.electronics == scan.electronics
    scan.electronics.source_level = 210.0
    np.testing.assert_allclose(scan_echo_level(scan)[np.isfinite(scan_echo_level(scan))],
                               scan_echo_level(mitsonar_mod.load_scan(tmp_path / "s.npz"))[np.isfinite(scan_echo_level(scan))] + 10,
                               atol=1e-4)


def test_a_source_level_below_150_db_is_explained(mitsonar_mod):
    from mitsonar.receiver.electronics import Electronics

    with pytest.raises(ValueError) as err:
        Electronics(source_level=52.0)
    msg = str(err.value)
    assert "\n" not in msg
    assert msg.startswith("sonar 'source_level': 52 dB is not allowed: it is the head's source level in dB re 1 uPa at 1 m")
    assert "receiver_sensitivity=-148" in msg
    # the release it names is one the changelog records, not a later one than this package
    quoted = re.search(r"up to mitsonar (\d+\.\d+(?:\.\d+)?)", msg).group(1)
    released = re.findall(r"^## \[(\d+\.\d+\.\d+)\]", (Path(ROOT) / "CHANGELOG.md").read_text(), flags=re.M)
    assert quoted in released, (quoted, released)
    version = tuple(int(x) for x in mitsonar_mod.__version__.split(".")[:3])
    assert tuple(int(x) for x in quoted.split(".")) <= version
    with pytest.raises(ValueError, match="'source_level': 270 dB is not allowed"):
        Electronics(source_level=270.0)


def test_xml_and_set_source_level_below_150_db_give_one_line(mitsonar_mod, tmp_path):
    scene = scene_xml(sonar_xml(source_level=52.0), sphere_xml((2, 0, 0), 0.1, acoustic_xml(0.5)))
    with pytest.raises(Exception, match="52 dB is not allowed: it is the head's source level"):
        mitsonar_mod.load_scene(scene)
    with pytest.raises(ValueError, match="source_level': 52 dB is not allowed"):
        mitsonar_mod.render_scan(mitsonar_mod.load_scene(os.path.join(ROOT, "scenes_xml", "box.xml")), spp=1,
                                 electronics={"source_level": 52.0})
    from test_cli import assert_one_line_error, run

    proc = run("render", os.path.join(ROOT, "scenes_xml", "box.xml"), "-o", str(tmp_path / "a.exr"),
               "--set", "source_level=52")
    assert_one_line_error(proc, "--set 'source_level': 52 dB is not allowed: it is the head's source level")
    assert not (tmp_path / "a.exr").exists()


def test_presets_carry_source_levels_and_keep_the_calibration(mitsonar_mod):
    from mitsonar.scenes import echosounders
    from mitsonar.presets.sidescan import PRESETS

    for p in PRESETS.values():
        assert 180 <= p["source_level"] <= 230
        assert p["source_level"] + p["receiver_sensitivity"] == 52.0
    head = echosounders.configure("r2sonic_2024")
    assert head.params["source_level"] + head.params["receiver_sensitivity"] == 52.0
    sensor = sonar_xml(kind="sidescan", preset="klein3000_100k", n_pings=1, range_max=20.0, n_bins=50)
    scene = mitsonar_mod.load_scene(scene_xml(sensor, sphere_xml((0, 5, -3), 1.0, acoustic_xml(0.5))))
    scan = mitsonar_mod.render_scan(scene, spp=1)
    assert scan.electronics.source_level == 220.0 and scan.electronics.noise_level == 29.0


# ----------------------------------------------------------------------------- the report

def test_report_recovers_the_target_strength_and_draws(mitsonar_mod, tmp_path):
    from mitsonar.sonar_equation import phong_sphere_cross_section, plot_levels

    a, d = 0.05, 3.0
    scan = mitsonar_mod.render_scan(sphere_scene(mitsonar_mod, a, d, 0.0, 300.0), spp=1 << 15, seed=3)
    rep = mitsonar_mod.sonar_equation_report(scan)
    row = rep.pings[0]
    assert d < row["range"] < d + 0.05
    # EL - SL + TL at the bin's centre range: TS up to the 40 log of where in the echo that bin lies
    ts = 10 * math.log10(phong_sphere_cross_section(a, 1.0, 300.0))
    assert row["target"] == pytest.approx(ts, abs=0.3)
    assert row["snr"] == pytest.approx(row["echo_level"] - rep.noise_band_level)
    assert rep.noise_band_level == pytest.approx(scan_levels(scan).noise_band_level)
    text = rep.table()
    for term in ("SL", "NL", "DI", "10 log B", "TS|Sb+10logA", "SNR"):
        assert term in text
    fig = plot_levels(rep, tmp_path / "levels.png")
    assert (tmp_path / "levels.png").stat().st_size > 1000
    ax = fig.axes[0]
    assert ax.get_xlabel() == "range (m)" and ax.get_ylabel() == "level (dB re 1 uPa)"
    # the command line on a scan file
    from test_cli import run

    scan.save(tmp_path / "s.npz")
    proc = run("levels", str(tmp_path / "s.npz"), "-o", str(tmp_path / "cli.png"))
    assert proc.returncode == 0, proc.stderr
    assert "noise in band" in proc.stdout and (tmp_path / "cli.png").exists()
    bad = run("levels", str(tmp_path / "s.npz"), "-o", str(tmp_path / "x.gif"))
    assert bad.returncode != 0 and "the extension must be one of .png, .pdf, .svg" in bad.stderr
