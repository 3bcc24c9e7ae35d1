"""Plugins from XML, their errors, live parameters, determinism and the no-recompile guarantee."""
import math
import os

import drjit as dr
import numpy as np
import pytest

from conftest import SCENES, acoustic_xml, frame_matrix, jit_kernels, rectangle_xml, scene_xml, sonar_xml

BOX = os.path.join(SCENES, "box.xml")


def plane_scene(mitsonar, bsdf=None, max_depth=1, **sonar):
    """A single-ping sonar looking 40 deg down at a floor 2 m below."""
    t = math.radians(40)
    params = dict(beam_pattern="uniform", beamwidth_h=20.0, beamwidth_v=30.0, range_min=1.0,
                  range_max=5.0, n_bins=100, n_pings=1, bearing_step=0.0)
    params.update(sonar)
    floor = np.diag([20.0, 20.0, 1.0, 1.0])
    floor[2, 3] = -2.0
    return mitsonar.load_scene(scene_xml(
        sonar_xml(frame_matrix((math.sin(t), 0, -math.cos(t)), (0, 1, 0)), **params),
        rectangle_xml(floor, bsdf or acoustic_xml(0.5)),
        integrator=f'<integrator type="sonar_tof"><integer name="max_depth" value="{max_depth}"/></integrator>'))


def test_plain_mitsuba_loads_the_plugins_from_a_file(mitsonar_mod):
    import mitsuba as mi

    scene = mi.load_file(BOX, parallel=False)  # see load_scene: parallel loading is flaky
    sensor = scene.sensors()[0]
    assert type(sensor).__name__ == "SonarSensor"
    assert type(scene.integrator()).__name__ == "SonarTOFIntegrator"
    assert scene.integrator().max_depth == 5
    assert (sensor.n_pings, sensor.n_bins, sensor.range_max) == (200, 500, 12.0)
    image = mi.render(scene, spp=64)
    assert image.shape == (200, 500, 1)
    assert float(dr.sum(image.array)[0]) > 0


def test_load_from_string_equals_load_from_file(mitsonar_mod):
    with open(BOX) as fh:
        text = fh.read()
    a = mitsonar_mod.render_scan(mitsonar_mod.load_scene(BOX), spp=32, seed=3)
    b = mitsonar_mod.render_scan(mitsonar_mod.load_scene(text), spp=32, seed=3)
    np.testing.assert_array_equal(a.intensity, b.intensity)
    np.testing.assert_array_equal(a.data, b.data)


def test_scan_shapes_and_conventions(mitsonar_mod):
    scan = mitsonar_mod.render_scan(mitsonar_mod.load_scene(BOX), spp=16, seed=0)
    assert scan.intensity.shape == (200, 500) and scan.intensity.dtype == np.float32
    assert scan.data.shape == (200, 500) and scan.data.dtype == np.uint8
    np.testing.assert_allclose(scan.ranges, (np.arange(500) + 0.5) * 12 / 500)
    np.testing.assert_allclose(scan.bearings, np.radians(1.8 * np.arange(200)))
    assert scan.poses.shape == (200, 4, 4)
    for pose in scan.poses[::37]:
        np.testing.assert_allclose(pose[:3, :3].T @ pose[:3, :3], np.eye(3), atol=1e-12)
        np.testing.assert_allclose(pose[:3, 1], [0, 0, 1], atol=1e-12)  # scan axis up
    np.testing.assert_allclose(scan.poses[0][:3, 2], [1, 0, 0], atol=1e-12)
    np.testing.assert_allclose(scan.poses[50][:3, 2], [0, 1, 0], atol=1e-12)  # 90 deg: +y
    assert (scan.range_min, scan.range_max, scan.beam_pattern) == (0.0, 12.0, "gaussian")
    assert (scan.beamwidth_h, scan.beamwidth_v, scan.kind) == (3.0, 35.0, "mechanical")
    assert scan.meta.seed == 0 and scan.meta.spp == 16 and scan.meta.scene == "box.xml"


def test_misspelled_parameter_names_the_nearest_parameter(mitsonar_mod):
    bad = scene_xml(sonar_xml(n_binz=10))
    with pytest.raises(mitsonar_mod.SceneError,
                       match=r'the sensor "sonar" has no parameter "n_binz" \(did you mean "n_bins"\?\)'):
        mitsonar_mod.load_scene(bad)


def test_a_mitsuba_parse_error_is_one_line_naming_the_file(mitsonar_mod, tmp_path):
    """Mitsuba's own refusal (here a duplicate id: no plugin of ours raised) comes back as one
    line naming the file and both places; reducing it once failed with a NameError."""
    path = tmp_path / "dup.xml"
    path.write_text('<scene version="3.0.0"><integrator type="sonar_tof"/><sensor type="sonar"/>\n'
                    '<shape type="rectangle" id="a"/>\n<shape type="rectangle" id="a"/></scene>\n')
    with pytest.raises(mitsonar_mod.SceneError, match=r'duplicate ID: "a"') as info:
        mitsonar_mod.load_scene(str(path))
    assert "\n" not in str(info.value) and str(path) in str(info.value)


@pytest.mark.parametrize("params, message", [
    (dict(n_bins=0), r"sonar 'n_bins': 0 is not allowed \(1 to 65536\)"),
    (dict(range_min=5.0, range_max=2.0), r"sonar 'range_max'.*range_min"),
    (dict(kind="fanbeam"), r"sonar 'kind': 'fanbeam'.*mechanical, multibeam, sidescan"),
    (dict(tx_beamwidth_h=20.0), r"sonar 'tx_beamwidth_h': only used with kind 'multibeam'"),
    (dict(kind="multibeam", tx_pattern="table"), r"sonar 'tx_pattern': 'table'.*gaussian, sinc, uniform"),
    (dict(kind="multibeam", tx_beamwidth_v=0.0), r"sonar 'tx_beamwidth_v': 0.0 is not allowed"),
    (dict(beam_pattern="cone"), r"sonar 'beam_pattern': 'cone' is not one of gaussian, sinc, uniform, table"),
    (dict(beamwidth_h=-3.0), r"sonar 'beamwidth_h'"),
    (dict(sound_speed=340.0), r"sonar 'sound_speed'.*1000 to 2000"),
    (dict(absorption=-0.1), r"sonar 'absorption'"),
    (dict(beam_pattern="table"), r"beam_table"),
    (dict(beam_pattern="table", beam_table="/nonexistent/beam.csv"), r"does not exist"),
    (dict(tvg="35log"), r"sonar 'tvg': '35log' is not one of off, 20log, 30log, 40log"),
    (dict(bit_depth=6), r"sonar 'bit_depth'"),
    # Counts are <integer>: a fraction is refused, not truncated (8.7 pings once rendered 8).
    (dict(n_pings=8.7), r"sonar 'n_pings': 8.7 is not a whole number \(counts are <integer>\)"),
    (dict(n_bins=0.5), r"sonar 'n_bins': 0.5 is not a whole number"),
    (dict(bit_depth=8.5), r"sonar 'bit_depth': 8.5 is not a whole number"),
    # Wrong XML types name the field and the expected tag, for every numeric field.
    (dict(range_max="twelve"), r"sonar 'range_max': 'twelve' is not a number \(expected <float>\)"),
    (dict(n_bins="50"), r"sonar 'n_bins': expected <integer>, got <string> '50'"),
    (dict(beamwidth_v="35"), r"sonar 'beamwidth_v': expected <float>, got <string> '35'"),
    (dict(kind="multibeam", tx_beamwidth_v="wide"), r"sonar 'tx_beamwidth_v': 'wide' is not a number"),
    (dict(gain="loud"), r"sonar 'gain': 'loud' is not a number \(expected <float>\)"),
    (dict(beam_pattern="table", beam_table=7.0), r"sonar 'beam_table': expected <string>, got <float> 7.0"),
    # Impossible beam values whatever the pattern; parameters the pattern does not use.
    (dict(frequency=-5.0), r"sonar 'frequency': -5.0 Hz must be > 0"),
    (dict(beam_pattern="sinc", frequency=0.0), r"sonar 'frequency': 0.0 Hz must be > 0"),
    (dict(aperture_v=-1.0), r"sonar 'aperture_v': -1.0 m must be > 0"),
    (dict(beam_pattern="sinc", aperture_h=float("inf")), r"sonar 'aperture_h': inf m must be > 0"),
    (dict(aperture_h=0.05), r"sonar 'aperture_h' is only used with beam_pattern 'sinc' \(got 'gaussian'\)"),
    (dict(kind="multibeam", aperture_h=0.05), r"sonar 'aperture_h' is only used with beam_pattern 'sinc'"),
    (dict(kind="multibeam", tx_beamwidth_h=400.0), r"sonar 'tx_beamwidth_h': 400.0 is not allowed"),
    # Bearings are angles.
    (dict(bearing_step=1e30), r"sonar 'bearing_step': 1e\+30 is not allowed \(an angle in \[-360, 360\] deg\)"),
    (dict(bearing_start=-720.0), r"sonar 'bearing_start': -720.0 is not allowed"),
    (dict(kind="multibeam", n_pings=256, bearing_step=2.0),
     r"sonar 'bearing_step': 2.0 is not allowed \(for kind 'multibeam'.*<= 360 deg, here 510 deg\)"),
])
def test_impossible_sonar_settings_fail_with_our_message(mitsonar_mod, params, message):
    with pytest.raises(mitsonar_mod.SceneError, match=message) as info:
        mitsonar_mod.load_scene(scene_xml(sonar_xml(**params)))
    assert "Traceback" not in str(info.value)
    assert "\n" not in str(info.value)


@pytest.mark.parametrize("params", [
    dict(n_pings=8.0, n_bins=50.0),                             # whole floats are counts
    dict(beam_pattern="sinc", frequency=400e3, aperture_h=0.05, aperture_v=0.005),
    dict(kind="multibeam", tx_pattern="sinc", frequency=400e3),  # the transmit fan uses it
    dict(frequency=400e3), dict(kind="multibeam", frequency=400e3),   # the head's band (render_echoes) uses it
    dict(kind="multibeam", n_pings=256, bearing_step=130 / 255),
    dict(bearing_start=-360.0, bearing_step=-360.0, n_pings=3),
])
def test_possible_sonar_settings_load(mitsonar_mod, params):
    sensor = mitsonar_mod.load_scene(scene_xml(sonar_xml(**params))).sensors()[0]
    for name in ("n_pings", "n_bins", "bearing_step"):
        if name in params:
            assert getattr(sensor, name) == params[name]
    if "frequency" in params:
        assert sensor.beam.frequency == params["frequency"] and sensor.bandwidth == params["frequency"] / 2
        assert params["frequency"] in (sensor.beam.frequency, sensor.transmit and sensor.transmit.frequency)


def test_non_rigid_to_world_is_rejected(mitsonar_mod):
    with pytest.raises(mitsonar_mod.SceneError, match="rigid"):
        mitsonar_mod.load_scene(scene_xml(sonar_xml(np.diag([2.0, 1, 1, 1]))))
    scene = mitsonar_mod.load_scene(BOX)
    with pytest.raises(mitsonar_mod.SceneError, match="pose.*rigid"):
        mitsonar_mod.render_scan(scene, spp=4, pose=np.diag([1.0, 1, -1, 1]))


@pytest.mark.parametrize("bsdf, message", [
    (acoustic_xml(0.6, 0.6), r"'diffuse' \+ 'specular' = 1.2 > 1"),
    (acoustic_xml(-0.1, 0.2), r"acoustic 'diffuse': -0.1"),
    (acoustic_xml(0.1, 0.2, -3.0), r"acoustic 'shininess'"),
    ('<bsdf type="acoustic"><string name="preset" value="granite"/></bsdf>', r"'preset': 'granite' is not one of"),
    # A colour or a texture is not a reflection coefficient.
    ('<bsdf type="acoustic"><rgb name="diffuse" value="0.1,0.2,0.3"/></bsdf>',
     r"acoustic 'diffuse': expected a <float> in \[0, 1\], got <rgb>"),
    ('<bsdf type="acoustic"><texture type="checkerboard" name="specular"/></bsdf>',
     r"acoustic 'specular': expected a <float> in \[0, 1\], got <texture>"),
    ('<bsdf type="acoustic"><string name="shininess" value="thirty"/></bsdf>',
     r"acoustic 'shininess': 'thirty' is not a number \(expected a <float> >= 0\)"),
    ('<bsdf type="acoustic"><float name="preset" value="1"/></bsdf>',
     r"acoustic 'preset': expected <string>, got <float> 1.0"),
])
def test_invalid_materials_fail_with_our_message(mitsonar_mod, bsdf, message):
    with pytest.raises(mitsonar_mod.SceneError, match=message) as info:
        plane_scene(mitsonar_mod, bsdf)
    assert "Traceback" not in str(info.value) and "\n" not in str(info.value)


def test_invalid_max_depth_and_spp(mitsonar_mod):
    with pytest.raises(mitsonar_mod.SceneError, match=r"'max_depth': 0"):
        plane_scene(mitsonar_mod, max_depth=0)
    scene = plane_scene(mitsonar_mod)
    with pytest.raises(mitsonar_mod.SceneError, match="spp"):
        mitsonar_mod.render_scan(scene, spp=0)
    # max_depth is a count: a fraction is refused, not truncated; a whole float is taken.
    for prop, message in (('<float name="max_depth" value="2.5"/>',
                           r"sonar_tof 'max_depth': 2.5 is not a whole number \(counts are <integer>\)"),
                          ('<string name="max_depth" value="five"/>',
                           r"sonar_tof 'max_depth': 'five' is not a number \(expected <integer>\)")):
        integrator = f'<integrator type="sonar_tof">{prop}</integrator>'
        with pytest.raises(mitsonar_mod.SceneError, match=message):
            mitsonar_mod.load_scene(scene_xml(sonar_xml(), integrator=integrator))
    whole = '<integrator type="sonar_tof"><float name="max_depth" value="3.0"/></integrator>'
    assert mitsonar_mod.load_scene(scene_xml(sonar_xml(), integrator=whole)).integrator().max_depth == 3


def test_presets_by_name(mitsonar_mod):
    import mitsuba as mi
    from mitsonar.plugins.bsdfs import materials

    presets = materials.PRESETS
    for name in ("concrete_good", "water_calm", "sand", "rock"):
        scene = plane_scene(mitsonar_mod, f'<bsdf type="acoustic"><string name="preset" value="{name}"/></bsdf>')
        params = mi.traverse(scene)
        key = next(k for k in params.keys() if k.endswith("diffuse"))
        assert params[key][0] == pytest.approx(presets[name]["diffuse"])
        assert presets[name]["diffuse"] + presets[name]["specular"] <= 1
    # Thesis Table 2.2: a "good" concrete reflects 0.69 - 0.74, 80-95 % of it specular.
    good = presets["concrete_good"]
    assert 0.69 <= good["diffuse"] + good["specular"] <= 0.74
    assert 0.8 <= good["specular"] / (good["diffuse"] + good["specular"]) <= 0.95


def test_same_seed_same_scan_different_seed_different_scan(mitsonar_mod):
    scene = mitsonar_mod.load_scene(BOX)
    a = mitsonar_mod.render_scan(scene, spp=64, seed=11)
    b = mitsonar_mod.render_scan(scene, spp=64, seed=11)
    c = mitsonar_mod.render_scan(scene, spp=64, seed=12)
    np.testing.assert_array_equal(a.intensity, b.intensity)
    np.testing.assert_array_equal(a.data, b.data)
    assert not np.array_equal(a.intensity, c.intensity)


def test_diffuse_is_a_live_parameter_and_single_bounce_scales_with_it(mitsonar_mod):
    import mitsuba as mi

    scene = plane_scene(mitsonar_mod, acoustic_xml(0.2))
    before = mitsonar_mod.render_scan(scene, spp=4096, seed=1).intensity.astype(np.float64)
    params = mi.traverse(scene)
    key = next(k for k in params.keys() if k.endswith("diffuse"))
    params[key] = 0.6
    params.update()
    after = mitsonar_mod.render_scan(scene, spp=4096, seed=1).intensity.astype(np.float64)
    lit = before > 0
    assert lit.sum() > 20
    # The same paths: each bin exactly three times brighter.
    np.testing.assert_allclose(after[lit] / before[lit], 3.0, rtol=1e-5)
    params[key] = 0.7
    params[next(k for k in params.keys() if k.endswith("specular"))] = 0.5
    with pytest.raises(ValueError, match="> 1"):
        params.update()


def test_absorption_attenuates_each_bin_by_its_two_way_path(mitsonar_mod):
    a = mitsonar_mod.render_scan(plane_scene(mitsonar_mod), spp=8192, seed=2)
    b = mitsonar_mod.render_scan(plane_scene(mitsonar_mod, absorption=0.5), spp=8192, seed=2)
    lit = a.intensity[0] > 0
    ratio = b.intensity[0][lit] / a.intensity[0][lit]
    expected = 10 ** (-0.5 * 2 * a.ranges[lit] / 10)
    # Within a bin the range varies by half a bin width: 10^(-0.1 * 0.02) ~ 0.5 %.
    np.testing.assert_allclose(ratio, expected, rtol=6e-3)


def test_range_window_drops_echoes_outside_it(mitsonar_mod):
    full = mitsonar_mod.render_scan(plane_scene(mitsonar_mod, range_min=1.0, range_max=5.0, n_bins=100),
                                    spp=4096, seed=4)
    part = mitsonar_mod.render_scan(plane_scene(mitsonar_mod, range_min=2.6, range_max=3.0, n_bins=10),
                                    spp=4096, seed=4)
    # 4 cm bins in both: bins 40..49 of the full window are the partial window.
    np.testing.assert_allclose(part.intensity[0], full.intensity[0][40:50], rtol=1e-5)
    assert full.intensity[0][:40].sum() > 0 and full.intensity[0][50:].sum() > 0


@pytest.mark.parametrize("scene_file", ["box.xml", "box_fls.xml"])
def test_second_render_with_new_pose_seed_spp_and_material_does_not_recompile(mitsonar_mod, scene_file):
    import mitsuba as mi
    from mitsonar.plugins.integrators.paths import frozen_pass

    # start from no frozen-pass recording: past `MAX_RECORDINGS` (earlier tests' passes) all are
    # dropped, and a pass recorded anew between the two renders launches its traced kernels
    frozen_pass.clear()
    scene = mitsonar_mod.load_scene(os.path.join(SCENES, scene_file))
    mitsonar_mod.render_scan(scene, spp=64, seed=0)
    from mitsonar.receiver import speckle

    speckle._cache.clear()   # both renders compute their pose's speckle field (two kernels)
    first, _ = jit_kernels(mitsonar_mod.render_scan, scene, spp=64, seed=0)
    params = mi.traverse(scene)
    key = next(k for k in params.keys() if k.endswith("diffuse"))
    params[key] = 0.05
    params.update()
    pose = frame_matrix((0, 1, 0), (0, 0, 1), (1.0, -0.5, 0.3))
    second, compiled = jit_kernels(mitsonar_mod.render_scan, scene, spp=96, seed=7, pose=pose)
    assert second, "the render launched no kernel"
    assert not compiled, f"{len(compiled)} kernel(s) were compiled again"
    # The same kernels, not merely cached ones: nothing that changed is written into them
    # (the pose arrays' addresses included, whose alignment NumPy leaves to chance).
    assert set(second) == set(first)


def test_pose_moves_the_sonar(mitsonar_mod):
    scene = mitsonar_mod.load_scene(BOX)
    # 1 m closer to the x = +5 wall: the bearing-0 echo moves from 5 m to 4 m.
    pose = frame_matrix((1, 0, 0), (0, 0, 1), (1.0, 0.0, 0.0))
    scan = mitsonar_mod.render_scan(scene, spp=512, seed=0, pose=pose, max_depth=1)
    first = scan.ranges[np.nonzero(scan.intensity[0] > 0)[0][0]]
    assert first == pytest.approx(4.0, abs=0.03)
    np.testing.assert_allclose(scan.positions, np.tile([1.0, 0, 0], (200, 1)))


def test_scene_mesh_is_the_box_ground_truth(mitsonar_mod):
    v, f = mitsonar_mod.scene_mesh(mitsonar_mod.load_scene(BOX))
    assert f.shape[1] == 3 and v.shape[1] == 3
    np.testing.assert_allclose(v.min(0), [-5, -4, -3])
    np.testing.assert_allclose(v.max(0)[:2], [5, 4])
    tri = v[f]
    normals = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])
    area = 0.5 * np.linalg.norm(normals, axis=1)
    assert area.sum() == pytest.approx(80 + 2 * 33 * (10 + 8))
    # Every face looks into the water (towards the sonar at the origin).
    centres = tri.mean(1)
    assert np.all(np.einsum("ij,ij->i", normals, -centres) > 0)


def test_plugins_follow_a_variant_change():
    """Registered per variant (by `mitsonar.set_variant`: ``import mitsonar`` chooses none): after
    switching away and back the XML plugins still load."""
    import subprocess
    import sys

    code = f"""
import mitsonar, mitsuba as mi
active = mitsonar.set_variant()
mi.set_variant('scalar_rgb')
mi.set_variant(active)
scene = mi.load_file({BOX!r}, parallel=False)
print(type(scene.sensors()[0]).__name__, type(scene.integrator()).__name__)
print(mitsonar.render_scan(scene, spp=8).intensity.shape)
"""
    proc = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=300)
    assert proc.returncode == 0, proc.stderr
    assert "SonarSensor SonarTOFIntegrator" in proc.stdout and "(200, 500)" in proc.stdout


def test_a_new_variant_imports_every_module_of_the_families_again():
    """`register` for a new variant imports every module of the plugin families again (found by
    walking the packages), the path machinery's included: each holds the classes of the new
    variant, none of the old one's, and the way back renders. (The second variant is
    ``llvm_ad_rgb``, registered by hand: mitsonar follows only ``cuda_ad_mono``, which needs a GPU.)"""
    import json
    import subprocess
    import sys

    code = """
import json, mitsonar, mitsuba as mi
mitsonar.set_variant()
from mitsonar.plugins import register
from mitsonar.plugins.integrators import mlt_split
from mitsonar.plugins.integrators.paths import shared_beams
mi.set_variant('llvm_ad_rgb')
register()
from mitsonar.plugins.integrators import mlt_split, sonar_tof
from mitsonar.plugins.integrators.paths import shared_beams
from mitsonar.plugins.sensors import sonar
rgb = [issubclass(sonar.SonarSensor, mi.Sensor), issubclass(mlt_split.SonarTOFIntegrator, mi.SamplingIntegrator),
       mlt_split.SonarTOFIntegrator is sonar_tof.SonarTOFIntegrator, shared_beams.PingFrames is sonar.PingFrames]
mi.set_variant('llvm_ad_mono')
from mitsonar.plugins.integrators import mlt_split
mono = [issubclass(mlt_split.SonarTOFIntegrator, mi.SamplingIntegrator), type(mi.load_dict({'type': 'sonar_mlt'})).__name__,
        mitsonar.render_scan(mitsonar.load_scene(mitsonar.example_scene('box')), spp=8).intensity.shape[0]]
print(json.dumps([rgb, mono]))
"""
    proc = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=300)
    assert proc.returncode == 0, proc.stderr
    assert json.loads(proc.stdout.strip().splitlines()[-1]) == [[True] * 4, [True, "SonarMLTIntegrator", 200]]
