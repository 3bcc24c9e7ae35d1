"""Eigenrays, arrivals and TL against Bellhop (M. B. Porter's ray/beam model, the Acoustics
Toolbox; issue 58): the environment written by `mitsonar.acoustics.bellhop.write_env`, Bellhop's
arrivals (run type A, its fan refined to 0.001 deg around each of mitsonar's eigenrays) and its
incoherent geometric-beam TL (run type I) read back, on a shallow thermocline and a Munk profile.

Bellhop's binary comes from the ``aubellhop`` wheel, fetched by ``scripts/setup.sh``
(``scripts/fetch_bellhop.py``) into ``.bellhop/``; these tests fail, not skip, without it.
"""
import math
import os
import subprocess

import numpy as np
import pytest

from mitsonar.acoustics import FluidBottom, SoundSpeedProfile, eigenrays, transmission_loss_field
from mitsonar.acoustics.bellhop import read_arrivals, read_shd, write_env

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))

THERMOCLINE = SoundSpeedProfile([0.0, 30.0, 100.0], [1520.0, 1480.0, 1480.0])
_MZ = np.linspace(0.0, 5000.0, 51)
_ETA = 2.0 * (_MZ - 1300.0) / 1300.0
#: Munk's canonical profile (Munk 1974, "Sound channel in an exponentially stratified ocean", JASA 55;
#: c = 1500 (1 + 0.00737 (eta - 1 + exp(-eta))), eta = 2 (z - 1300) / 1300), sampled every 100 m
MUNK = SoundSpeedProfile(_MZ, 1500.0 * (1.0 + 0.00737 * (_ETA - 1.0 + np.exp(-_ETA))))


@pytest.fixture(scope="session")
def bellhop():
    exe = os.environ.get("MITSONAR_BELLHOP") or os.path.join(ROOT, ".bellhop", "aubellhop", "bin", "bellhop.exe")
    if not (os.path.isfile(exe) and os.access(exe, os.X_OK)):
        pytest.fail(f"Bellhop is missing ({exe}): run scripts/setup.sh (scripts/fetch_bellhop.py fetches it "
                    "from the aubellhop wheel) or set MITSONAR_BELLHOP to a bellhop.exe")

    def run(folder, *args, **kwargs):
        path = write_env(os.path.join(folder, "case.env"), *args, **kwargs)
        done = subprocess.run([exe, "case"], cwd=folder, capture_output=True, text=True, timeout=120)
        assert done.returncode == 0, done.stdout[-2000:] + done.stderr[-2000:]
        return path[:-4]

    return run


CASES = [  # profile, source depth, receiver depth, range, water depth, bottom
    (THERMOCLINE, 10.0, 20.0, 500.0, 100.0, 1.0),
    (THERMOCLINE, 10.0, 20.0, 2000.0, 100.0, 1.0),
    (THERMOCLINE, 10.0, 50.0, 1000.0, 100.0, FluidBottom(1600.0, 1.5, 0.5)),
    (MUNK, 1000.0, 800.0, 2000.0, 5000.0, 1.0),
]


@pytest.mark.parametrize("case", range(len(CASES)))
def test_eigenrays_match_bellhops_arrivals_in_time_angle_and_level(case, bellhop, tmp_path):
    profile, zs, zr, R, D, bottom = CASES[case]
    table = eigenrays(profile, zs, zr, R, water_depth=D, bottom=bottom, max_bounces=3, angles=(-30.0, 30.0))
    assert table.size >= 1
    kinds = set()
    caustics = 0
    for k, row in enumerate(table):
        launch = math.degrees(row["launch"])
        folder = tmp_path / f"ray{k}"
        folder.mkdir()
        # Bellhop's fan refined to 0.001 deg around the ray
        base = bellhop(str(folder), profile, zs, zr, R, water_depth=D, bottom=bottom, run_type="A",
                       angles=(launch - 0.05, launch + 0.05), beams=101, step=D / 200.0)
        ref = read_arrivals(base + ".arr")
        ref = ref[(ref["surface_bounces"] == row["surface_bounces"]) & (ref["bottom_bounces"] == row["bottom_bounces"])]
        assert ref.size, f"Bellhop has no arrival like {row}"
        b = ref[np.argmin(np.abs(ref["time"] - row["time"]))]
        assert row["time"] == pytest.approx(b["time"], rel=1e-6)
        assert launch == pytest.approx(b["launch"], abs=0.01)
        assert math.degrees(row["arrival"]) == pytest.approx(b["arrival"], abs=0.05)
        assert row["transmission_loss"] == pytest.approx(-20.0 * math.log10(b["amplitude"]), abs=0.5)
        # phases (boundaries and caustics; Bellhop prints the opposite sign) to a degree
        turn = (math.degrees(row["phase"]) + b["phase"]) % 360.0
        assert min(turn, 360.0 - turn) < 1.0
        caustics += int(row["caustics"])
        kinds.add((row["surface_bounces"] > 0, row["bottom_bounces"] > 0))
    if profile is THERMOCLINE and R == 500.0:
        # surface- and bottom-reflected rays among them
        assert (True, True) in kinds and (False, True) in kinds
    if profile is THERMOCLINE and R == 2000.0:
        assert caustics >= 1          # a ray through a caustic: Bellhop's phase has its -pi/2


@pytest.mark.parametrize("profile, zs, D, depths, ranges", [
    (THERMOCLINE, 10.0, 100.0, [5.0, 20.0, 50.0, 80.0], [200.0, 500.0, 1000.0, 1500.0, 2000.0]),
    (MUNK, 1000.0, 5000.0, [800.0, 1000.0, 1500.0], [500.0, 1000.0, 1500.0, 2000.0]),
])
def test_the_tl_field_matches_bellhops_incoherent_geometric_beams(profile, zs, D, depths, ranges, bellhop, tmp_path):
    base = bellhop(str(tmp_path), profile, zs, depths, ranges, water_depth=D, run_type="I", angles=(-30.0, 30.0),
                   beams=4001, step=D / 200.0)
    bd, br, p = read_shd(base + ".shd")
    assert np.allclose(bd, depths) and np.allclose(br, ranges)
    with np.errstate(divide="ignore"):
        ref = -20.0 * np.log10(np.abs(p))
    field = transmission_loss_field(profile, zs, depths, ranges, water_depth=D, angles=(-30.0, 30.0), rays=4001,
                                    max_bounces=20)
    # outside the +-30 deg fan (steeper than it) both are silent; elsewhere within 0.5 dB
    assert np.isfinite(ref).sum() >= ref.size - 2
    np.testing.assert_array_equal(np.isfinite(field), np.isfinite(ref))
    np.testing.assert_allclose(field[np.isfinite(ref)], ref[np.isfinite(ref)], atol=0.5)
    # and the eigenrays' incoherent sum at a point of the field
    one = eigenrays(profile, zs, depths[1], ranges[2], water_depth=D, angles=(-30.0, 30.0), max_bounces=20)
    total = -10.0 * math.log10(np.sum(10.0 ** (-one["transmission_loss"] / 10.0)))
    assert total == pytest.approx(ref[1, 2], abs=0.5)


def test_a_rendered_echo_through_a_thermocline_follows_the_sonar_equation_with_bellhops_tl(mitsonar_mod, bellhop,
                                                                                          tmp_path):
    """A diffuse sphere 1 km away and 190 m below a head at 10 m in the thermocline, joined to it by
    one eigenray (launched 3.5 deg down; the rays focus there): the echo rendered through the
    profile, over the echo of the same sphere in uniform water, is ``-2 (TL - 20 log10 L)`` dB
    with TL Bellhop's one-way loss of the direct arrival and L the straight distance (the sonar
    equation, the sphere's target strength cancelling), within 1 dB. With ``1 / L^2`` on the way
    back (before the ray tube) it was 3.9 dB short."""
    import sys

    sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
    from conftest import acoustic_xml, frame_matrix, scene_xml, sonar_xml, sphere_xml

    head, X, zt = 10.0, 1000.0, 200.0
    ray = eigenrays(THERMOCLINE, head, zt, X, max_bounces=0)
    assert ray.size == 1
    launch = math.degrees(ray["launch"][0])
    base = bellhop(str(tmp_path), THERMOCLINE, head, zt, X, water_depth=300.0, run_type="A",
                   angles=(launch - 0.05, launch + 0.05), beams=101, step=1.5)
    ref = read_arrivals(base + ".arr")
    direct = ref[(ref["surface_bounces"] == 0) & (ref["bottom_bounces"] == 0)]
    assert direct.size >= 1
    tl = -20.0 * math.log10(direct["amplitude"][np.argmax(direct["amplitude"])])

    def render(grazing, profile):
        bore = (math.cos(grazing), 0.0, -math.sin(grazing))
        sensor = sonar_xml(frame_matrix(bore, (0.0, 0.0, 1.0), (0.0, 0.0, -head)), n_pings=1, beamwidth_h=2.0,
                           beamwidth_v=2.0, range_max=1100.0, n_bins=1100, sound_speed=1500.0)
        ball = sphere_xml((X, 0.0, -zt), 3.0, acoustic_xml(diffuse=0.8))
        scene = mitsonar_mod.load_scene(scene_xml(sensor, ball, integrator='<integrator type="sonar_tof">'
                                                  '<integer name="max_depth" value="1"/></integrator>'))
        scan = mitsonar_mod.render_scan(scene, spp=20000, seed=1, sound_speed_profile=profile)
        return float(scan.intensity.astype(float).sum())

    L = math.hypot(X, zt - head)
    rendered = 10.0 * math.log10(render(math.radians(launch), THERMOCLINE) / render(math.atan2(zt - head, X), None))
    assert rendered == pytest.approx(-2.0 * (tl - 20.0 * math.log10(L)), abs=1.0)


def test_a_sloping_bottom_matches_bellhop_with_its_bathymetry_file(bellhop, tmp_path):
    """The thermocline over a bottom deepening at 3 deg (Bellhop: a two-point .bty file): eigenrays
    in time, launch angle, TL and phase, and the incoherent TL field (a 2 deg upslope too)."""
    table = eigenrays(THERMOCLINE, 10.0, 20.0, 800.0, water_depth=100.0, bottom_slope=3.0, max_bounces=3,
                      angles=(-30.0, 30.0))
    assert np.any(table["bottom_bounces"] > 0)
    for k, row in enumerate(table):
        launch = math.degrees(row["launch"])
        folder = tmp_path / f"ray{k}"
        folder.mkdir()
        base = bellhop(str(folder), THERMOCLINE, 10.0, 20.0, 800.0, water_depth=100.0, bottom_slope=3.0,
                       run_type="A", angles=(launch - 0.05, launch + 0.05), beams=101, step=0.5)
        ref = read_arrivals(base + ".arr")
        ref = ref[(ref["surface_bounces"] == row["surface_bounces"]) & (ref["bottom_bounces"] == row["bottom_bounces"])]
        b = ref[np.argmin(np.abs(ref["time"] - row["time"]))]
        assert row["time"] == pytest.approx(b["time"], rel=1e-6)
        assert launch == pytest.approx(b["launch"], abs=0.01)
        assert row["transmission_loss"] == pytest.approx(-20.0 * math.log10(b["amplitude"]), abs=0.5)
    depths, ranges = np.array([10.0, 20.0, 50.0]), np.array([300.0, 600.0, 900.0])
    for slope in (3.0, -2.0):
        folder = tmp_path / f"field{slope:+g}"
        folder.mkdir()
        base = bellhop(str(folder), THERMOCLINE, 10.0, depths, ranges, water_depth=100.0, bottom_slope=slope,
                       run_type="I", angles=(-30.0, 30.0), beams=4001, step=0.5)
        p = read_shd(base + ".shd")[2]
        field = transmission_loss_field(THERMOCLINE, 10.0, depths, ranges, water_depth=100.0, bottom_slope=slope,
                                        angles=(-30.0, 30.0), rays=4001, max_bounces=20)
        np.testing.assert_allclose(field, -20.0 * np.log10(np.abs(p)), atol=0.5)
