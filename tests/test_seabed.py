"""Seabed physics: the Lambert seabed presets give back their published Lambert parameter mu
(plugins/bsdfs/materials.py cites the values), and a pile standing on the seabed echoes its corner at
the range of the image-source construction."""
import math

import numpy as np
import pytest

from conftest import acoustic_xml, frame_matrix, rectangle_xml, scene_xml, sonar_xml

HEIGHT = 2.0
BEAM = 2.0  # deg, uniform, square


def seabed_scene(mitsonar, preset, grazing_deg):
    """A uniform 2 x 2 deg beam looking down at ``grazing_deg`` onto a plane 2 m below."""
    tilt = math.radians(90.0 - grazing_deg)  # from the downward vertical, in the x-z plane
    boresight = (math.sin(tilt), 0.0, -math.cos(tilt))
    r0 = HEIGHT / math.cos(tilt)
    sensor = sonar_xml(frame_matrix(boresight, (0, 1, 0)), beam_pattern="uniform", beamwidth_h=BEAM,
                       beamwidth_v=BEAM, range_min=0.7 * r0, range_max=1.3 * r0, n_bins=100, n_pings=1,
                       bearing_step=0.0)
    plane = np.diag([60.0, 60.0, 1.0, 1.0])
    plane[2, 3] = -HEIGHT
    bsdf = f'<bsdf type="acoustic"><string name="preset" value="{preset}"/></bsdf>'
    return mitsonar.load_scene(scene_xml(sensor, rectangle_xml(plane, bsdf),
                                         integrator='<integrator type="sonar_tof"><integer name="max_depth" value="1"/></integrator>'))


def footprint_factor(grazing_deg, n=2001):
    """K = integral over the beam of d(omega) / (r^2 cos theta): the echo of a seabed of uniform
    sigma is sigma K (the sonar equation E = integral sigma / r^4 dA, dA = r^2 d(omega) / cos theta).
    Beam directions (az, el) as in test_physics: r = h / (cos el cos a), cos theta = cos el cos a,
    a = tilt + az, d(omega) = cos el d(az) d(el); the integrand is cos^2(el) cos(a) / h^2."""
    tilt = math.radians(90.0 - grazing_deg)
    half = math.radians(BEAM) / 2
    t = (np.arange(n) + 0.5) / n * 2 * half - half
    az, el = np.meshgrid(t, t)
    w = (2 * half / n) ** 2
    return float(np.sum(np.cos(el) ** 2 * np.cos(tilt + az)) * w / HEIGHT ** 2)


def measured_strength(mitsonar, preset, grazing_deg):
    """10 log10 of the echo over K: the footprint-averaged backscattering strength, dB."""
    scan = mitsonar.render_scan(seabed_scene(mitsonar, preset, grazing_deg), spp=1 << 16, seed=3)
    return 10 * math.log10(float(scan.intensity.astype(np.float64).sum()) / footprint_factor(grazing_deg))


def test_seabed_presets_backscatter_follows_lambert_with_the_published_mu(mitsonar_mod):
    from mitsonar.plugins.bsdfs import materials

    # The presets' mu: representative values from APL-UW TR 9407 and Jackson & Richardson (2007).
    assert materials.LAMBERT_MU == {"seabed_sand": -27.0, "seabed_mud": -32.0, "seabed_clay": -35.0,
                                    "seabed_gravel": -20.0, "seabed_rock": -15.0}
    # Every preset at 30 deg grazing: S_b = mu + 10 log10(sin^2 30 deg) = mu - 6.02 dB.
    for name, mu in materials.LAMBERT_MU.items():
        expected = mu + 10 * math.log10(math.sin(math.radians(30.0)) ** 2)
        got = measured_strength(mitsonar_mod, name, 30.0)
        # 0.1 dB: the footprint average of sin^2 over a 2 deg beam (< 0.01 dB) plus Monte Carlo noise.
        assert got == pytest.approx(expected, abs=0.1), f"{name}: S_b(30 deg) {got:.2f} dB, Lambert {expected:.2f} dB"
    # The grazing-angle falloff of sand: 10 log10(sin^2) from 60 deg to 15 deg (-11.0 dB between them).
    for grazing in (15.0, 60.0):
        expected = -27.0 + 10 * math.log10(math.sin(math.radians(grazing)) ** 2)
        assert measured_strength(mitsonar_mod, "seabed_sand", grazing) == pytest.approx(expected, abs=0.1)


def test_seabed_preset_eval_is_the_lambert_cross_section(mitsonar_mod):
    """From the BSDF itself: f cos(theta_i) cos(theta_o) at the monostatic direction is
    (d / pi) sin^2(theta_g), so 10 log10 of it over sin^2 is mu."""
    import drjit as dr
    import mitsuba as mi

    from mitsonar.plugins.bsdfs import materials

    for name, mu in materials.LAMBERT_MU.items():
        bsdf = mi.load_dict({"type": "acoustic", "preset": name})
        for grazing in (10.0, 30.0, 70.0):
            g = math.radians(grazing)
            si = dr.zeros(mi.SurfaceInteraction3f)
            si.wi = mi.Vector3f(math.cos(g), 0.0, math.sin(g))  # local frame, normal +z
            value = bsdf.eval(mi.BSDFContext(), si, si.wi)  # f cos(theta_o), back towards the source
            sigma = float(value[0][0]) * math.sin(g)  # times cos(theta_i)
            assert 10 * math.log10(sigma / math.sin(g) ** 2) == pytest.approx(mu, abs=1e-4)


def test_pile_seabed_corner_echo_is_at_the_image_source_range(mitsonar_mod):
    """A concrete pile (radius 0.3 m, axis at x = 6 m) standing on a mirror-like seabed 3 m below a
    mechanical head looking at it 25 deg down. Paths sonar - pile - seabed - sonar (and back) are
    as long as sonar - pile - image of the sonar in the seabed, |SP| + |PS'|, whose minimum over the
    pile is at its foot: the corner echo starts at the range sqrt((6 - 0.3)^2 + 3^2) = 6.441 m, no
    earlier, and (the dihedral retro-reflects there) it is the strongest echo of the ping."""
    h, x, a = 3.0, 6.0, 0.3
    tilt = math.radians(25.0)
    sensor = sonar_xml(frame_matrix((math.cos(tilt), 0, -math.sin(tilt)), (0, 0, 1)), kind="mechanical",
                       beam_pattern="uniform", beamwidth_h=10.0, beamwidth_v=40.0, range_min=4.0,
                       range_max=9.0, n_bins=250, n_pings=1, bearing_step=0.0)
    plane = np.diag([20.0, 20.0, 1.0, 1.0])
    plane[2, 3] = -h
    # A glossy seabed (no diffuse part: it sends nothing back by itself, only via the pile).
    seabed = rectangle_xml(plane, acoustic_xml(0.0, 0.9, 300.0))
    pile = (f'<shape type="cylinder"><point name="p0" x="{x}" y="0" z="{-h}"/>'
            f'<point name="p1" x="{x}" y="0" z="2"/><float name="radius" value="{a}"/>'
            '<bsdf type="acoustic"><string name="preset" value="concrete_good"/></bsdf></shape>')

    def render(depth):
        integrator = f'<integrator type="sonar_tof"><integer name="max_depth" value="{depth}"/></integrator>'
        scan = mitsonar_mod.render_scan(mitsonar_mod.load_scene(scene_xml(sensor, seabed, pile, integrator=integrator)),
                                        spp=1 << 16, seed=1)
        return scan, scan.intensity[0].astype(np.float64)

    scan, direct = render(1)
    _, both = render(2)
    corner = math.hypot(x - a, h)
    k = int((corner - scan.range_min) / scan.bin_width)
    assert direct[:k].sum() > 0, "the pile's front face echoes before its foot"
    # Nothing arrives by the seabed before the image-source range ...
    assert both[:k].sum() == pytest.approx(direct[:k].sum(), rel=0.02)
    # ... and from its bin on the corner dominates: the strongest bin of the ping, far above the
    # direct echo of the pile's foot (measured: 200 times; 20 asserted).
    assert int(np.argmax(both)) == k, f"strongest echo at {scan.ranges[np.argmax(both)]:.3f} m, corner {corner:.3f} m"
    assert both[k] > 20 * direct[k]
