"""render_scan's arguments: checked before the render, in one sentence naming the argument."""
import os
import warnings

import numpy as np
import pytest

from conftest import SCENES, frame_matrix

BOX = os.path.join(SCENES, "box.xml")


@pytest.fixture(scope="module")
def box(mitsonar_mod):
    return mitsonar_mod.load_scene(BOX)


@pytest.mark.parametrize("kwargs, message", [
    ({"spp": 1.5}, "'spp': 1.5 is not allowed (a whole number of paths per ping from 1 to 2147483647)"),
    ({"spp": 0}, "'spp': 0 is not allowed"),
    ({"spp": None}, "'spp': None is not allowed"),
    ({"spp": float("nan")}, "'spp': nan is not allowed"),
    ({"spp": True}, "'spp': True is not allowed"),
    ({"spp": "64"}, "'spp': '64' is not allowed"),
    ({"seed": -1}, "'seed': -1 is not allowed (a whole number from 0 to 4294967295)"),
    # The path seed is 32 bits: 2^32 would render the same scan as seed 0.
    ({"seed": 2 ** 32}, "'seed': 4294967296 is not allowed"),
    ({"seed": "x"}, "'seed': 'x' is not allowed"),
    ({"electronics_seed": -2}, "'electronics_seed': -2 is not allowed"),
    ({"max_depth": 2.7}, "'max_depth': 2.7 is not allowed (a whole number of surface bounces from 1 to 64)"),
    ({"max_depth": 0}, "'max_depth': 0 is not allowed"),
    ({"pose": "identity"}, "'pose': expected a 4x4 rigid transform (array-like), got str 'identity'"),
    ({"pose": np.eye(3)}, "'pose': expected a 4x4 matrix, got shape (3, 3)"),
    ({"pose": np.where(np.eye(4) > 0, np.nan, 0.0)}, "'pose': entry [0, 0] is nan (a pose must be finite)"),
    ({"pose": np.diag([2.0, 1, 1, 1])}, "'pose': must be a rigid transform"),
    ({"integrator": "sonar_tofx"}, "'integrator': 'sonar_tofx' is not a sonar integrator (one of sonar_bdpt, sonar_mlt, sonar_tof)"),
    ({"integrator": {"type": "sonar_mlt", "chainz": 4}},
     "the integrator \"sonar_mlt\" has no parameter \"chainz\" (did you mean \"chains\"?)"),
    ({"electronics": [("gain", 3)]}, "'electronics': expected a dict of electronics fields, got list"),
    ({"electronics": {"gian": 3}}, "'gian' is not an electronics setting"),
])
def test_bad_arguments_fail_before_rendering(mitsonar_mod, box, monkeypatch, kwargs, message):
    from mitsonar.plugins.integrators import sonar_mlt, sonar_tof

    def no_render(*a, **k):
        raise AssertionError("rendered before the arguments were checked")
    for cls in (sonar_tof.SonarTOFIntegrator, sonar_mlt.SonarMLTIntegrator):
        monkeypatch.setattr(cls, "render_histogram", no_render)
    with pytest.raises(mitsonar_mod.SceneError) as err:
        mitsonar_mod.render_scan(box, **kwargs)
    assert message in str(err.value)
    assert "\n" not in str(err.value)


def test_whole_floats_count_as_counts(mitsonar_mod, box):
    a = mitsonar_mod.render_scan(box, spp=32.0, seed=np.uint32(3), max_depth=np.int64(2))
    b = mitsonar_mod.render_scan(box, spp=32, seed=3, max_depth=2)
    np.testing.assert_array_equal(a.intensity, b.intensity)
    assert a.meta.spp == 32 and isinstance(a.meta.spp, int)


def test_largest_seed_is_allowed_and_differs_from_zero(mitsonar_mod, box):
    top = mitsonar_mod.render_scan(box, spp=16, seed=2 ** 32 - 1)
    zero = mitsonar_mod.render_scan(box, spp=16, seed=0)
    assert not np.array_equal(top.intensity, zero.intensity)


def _with(text, old, new):
    assert old in text
    return text.replace(old, new)


def test_a_chosen_non_sonar_integrator_is_replaced_with_a_warning(mitsonar_mod, tmp_path):
    text = open(BOX).read()
    start, end = text.index("<integrator"), text.index("</integrator>") + len("</integrator>")
    path_xml = text[:start] + '<integrator type="path"/>' + text[end:]
    scene = mitsonar_mod.load_scene(path_xml)
    with pytest.warns(UserWarning, match="its integrator PathIntegrator is not a sonar integrator; rendering with sonar_tof"):
        scan = mitsonar_mod.render_scan(scene, spp=4)
    assert scan.meta.integrator == "SonarTOFIntegrator"
    # No <integrator> at all: sonar_tof is the documented default, nothing to warn about.
    scene = mitsonar_mod.load_scene(text[:start] + text[end:])
    with warnings.catch_warnings():
        warnings.simplefilter("error", UserWarning)
        mitsonar_mod.render_scan(scene, spp=4)


def test_second_sonar_is_named_in_a_warning(mitsonar_mod):
    text = open(BOX).read()
    start, end = text.index('<sensor type="sonar"'), text.index("</sensor>") + len("</sensor>")
    sensor = text[start:end]
    second = _with(sensor, 'id="sonar"', 'id="sonar2"') if 'id="sonar"' in sensor else sensor
    scene = mitsonar_mod.load_scene(text[:end] + second + text[end:])
    with pytest.warns(UserWarning, match="has 2 sonar sensors; rendering sensor 0"):
        mitsonar_mod.render_scan(scene, spp=4)
    with warnings.catch_warnings():
        warnings.simplefilter("error", UserWarning)
        mitsonar_mod.render_scan(scene, spp=4, sensor=scene.sensors()[1])


def test_pose_checks_keep_good_poses(mitsonar_mod, box):
    pose = frame_matrix((1, 0, 0), (0, 0, 1), (1.0, 0.0, 0.0))
    scan = mitsonar_mod.render_scan(box, spp=8, pose=pose.tolist())
    np.testing.assert_allclose(scan.positions[0], [1.0, 0.0, 0.0])
