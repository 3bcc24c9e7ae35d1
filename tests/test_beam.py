"""Beam patterns: definitions, importance sampling, measured tables."""
import math
import os

import drjit as dr
import numpy as np
import pytest


@pytest.fixture(scope="module")
def beam_mod(mitsonar_mod):
    from mitsonar.plugins.sensors import beam

    return beam


def sample_weights(beam, n=1 << 18, seed=0):
    import mitsuba as mi

    rng = np.random.default_rng(seed)
    u = mi.Point2f(mi.Float(rng.random(n, dtype=np.float32)), mi.Float(rng.random(n, dtype=np.float32)))
    d, w = beam.sample(u)
    return np.array(d).reshape(3, -1).T if np.array(d).shape[0] == 3 else np.array(d), np.array(w)


@pytest.mark.parametrize("kind, bw", [("gaussian", (3.0, 35.0)), ("uniform", (20.0, 30.0)),
                                      ("sinc", (3.0, 35.0)), ("gaussian", (60.0, 60.0))])
def test_emission_weight_averages_to_the_beam_solid_angle(beam_mod, kind, bw):
    beam = beam_mod.BeamPattern(kind, *bw)
    _, w = sample_weights(beam)
    # E[B / pdf] = integral of B over the sphere, whatever the sampling density.
    assert w.mean() == pytest.approx(beam.solid_angle(), rel=0.01)
    # Importance sampling: the weight hardly varies (the estimator's variance comes from the scene).
    assert w.std() / w.mean() < 0.05


def test_gaussian_definition_and_half_power_points(beam_mod):
    beam = beam_mod.BeamPattern("gaussian", 3.0, 35.0)
    assert beam.eval_np(0.0, 0.0) == 1.0
    assert beam.eval_np(math.radians(1.5), 0.0) == pytest.approx(0.5)
    assert beam.eval_np(0.0, math.radians(17.5)) == pytest.approx(0.5)
    assert beam.eval_np(math.radians(1.5), math.radians(17.5)) == pytest.approx(0.25)


def test_sinc_piston_has_the_requested_width_and_side_lobes(beam_mod):
    beam = beam_mod.BeamPattern("sinc", 3.0, 35.0, frequency=700e3, sound_speed=1500.0)
    assert beam.eval_np(math.radians(1.5), 0.0) == pytest.approx(0.5, abs=1e-4)
    assert beam.eval_np(0.0, math.radians(17.5)) == pytest.approx(0.5, abs=1e-4)
    lam = 1500.0 / 700e3
    null = math.asin(lam / beam.aperture_h)
    assert beam.eval_np(null, 0.0) < 1e-8
    side = beam.eval_np(math.asin(1.4303 * lam / beam.aperture_h), 0.0)  # first side lobe of sinc^2
    assert side == pytest.approx(0.0472, rel=0.01)  # -13.3 dB
    assert beam.eval_np(math.radians(100), 0.0) == 0.0  # baffled: nothing behind


def test_explicit_apertures_override_the_widths(beam_mod):
    beam = beam_mod.BeamPattern("sinc", 3.0, 35.0, frequency=700e3, aperture_h=0.05, aperture_v=0.005)
    assert (beam.aperture_h, beam.aperture_v) == (0.05, 0.005)


def test_sin_over_x_from_float32_arithmetic_is_accurate_far_from_the_origin(beam_mod):
    """`sin_over_x` (what the sinc pattern uses on cuda, where Dr.Jit's float32 sin is the GPU's
    approximation) against float64 over +-80 rad (a piston's far side lobes), nulls and 0 included:
    within 2e-7 absolute (7.9e-8 on llvm, 1.1e-7 on an H100; Dr.Jit's own sin there: 6e-5), 5e-7
    relative wherever |sinc| > 1e-3."""
    import mitsuba as mi

    x = np.concatenate([np.linspace(-80.0, 80.0, 100001), np.pi * np.arange(-25, 26), [1e-7, -3e-7]])
    x = x.astype(np.float32)
    got = beam_mod.sin_over_x(mi.Float(x)).numpy()
    ref = np.sinc(x.astype(np.float64) / np.pi)
    assert np.abs(got - ref).max() < 2e-7
    big = np.abs(ref) > 1e-3
    assert np.abs(got[big] / ref[big] - 1).max() < 5e-7


@pytest.mark.parametrize("kind", ["gaussian", "sinc", "uniform"])
def test_kernel_and_numpy_evaluations_agree(beam_mod, kind):
    import mitsuba as mi

    beam = beam_mod.BeamPattern(kind, 10.0, 30.0)
    rng = np.random.default_rng(1)
    az = rng.uniform(-0.5, 0.5, 5000)
    el = rng.uniform(-0.8, 0.8, 5000)
    got = np.array(beam.eval(mi.Float(az.astype(np.float32)), mi.Float(el.astype(np.float32))))
    np.testing.assert_allclose(got, beam.eval_np(az.astype(np.float32), el.astype(np.float32)), atol=2e-5)


def test_sampled_directions_follow_the_pattern(beam_mod):
    beam = beam_mod.BeamPattern("gaussian", 10.0, 20.0)
    d, _ = sample_weights(beam, n=1 << 19, seed=3)
    az = np.arctan2(d[:, 0], d[:, 2])
    # Marginal in azimuth of B cos(el) for a separable gaussian is gaussian with the -3 dB
    # half width 5 deg: sigma = bw / (2 sqrt(2 ln 2)).
    sigma = math.radians(10.0) / (2 * math.sqrt(2 * math.log(2)))
    assert np.std(az) == pytest.approx(sigma, rel=0.01)
    assert abs(np.mean(az)) < 0.01 * sigma


def test_measured_table_pattern(beam_mod, tmp_path):
    path = tmp_path / "beam.csv"
    rows = ["axis,angle_deg,gain_db"]
    rows += [f"h,{a},{-3.0 * (a / 1.5) ** 2:.6f}" for a in np.linspace(-6, 6, 25)]
    rows += [f"v,{a},{-3.0 * (a / 17.5) ** 2:.6f}" for a in np.linspace(-60, 60, 41)]
    path.write_text("\n".join(rows) + "\n")
    table = beam_mod.read_beam_table(str(path))
    beam = beam_mod.BeamPattern("table", 3.0, 35.0, table=table)
    assert beam.eval_np(math.radians(1.5), 0.0) == pytest.approx(0.5, rel=0.01)
    assert beam.eval_np(0.0, 0.0) == pytest.approx(1.0)
    assert beam.eval_np(math.radians(7.0), 0.0) == 0.0  # outside the measured angles
    _, w = sample_weights(beam)
    assert w.mean() == pytest.approx(beam.solid_angle(), rel=0.01)


@pytest.mark.parametrize("content, message", [
    ("angle,gain\n0,0\n", "columns axis, angle_deg, gain_db"),
    ("axis,angle_deg,gain_db\nq,0,0\nh,1,-3\n", "line 2: axis 'q' is not one of h, v"),
    ("axis,angle_deg,gain_db\nh,0,zero\n", "line 2: angle_deg and gain_db must be numbers"),
    ("axis,angle_deg,gain_db\nh,-1,-3\nh,0,0\nh,1,-3\nv,0,0\n", "axis 'v' needs at least 2 rows"),
    ("axis,angle_deg,gain_db\nh,-1,-3\nh,0,3\nh,1,-3\nv,-1,0\nv,1,0\n", "gain_db 3.0 > 0"),
    ("axis,angle_deg,gain_db\nh,1,-3\nh,2,0\nv,-1,0\nv,1,0\n", "must cover the boresight"),
])
def test_bad_beam_tables_name_the_file_and_the_problem(beam_mod, tmp_path, content, message):
    path = tmp_path / "bad.csv"
    path.write_text(content)
    with pytest.raises(beam_mod.BeamPatternError, match=message) as info:
        beam_mod.read_beam_table(str(path))
    assert str(path) in str(info.value)


def test_table_pattern_from_xml(mitsonar_mod, tmp_path):
    from conftest import scene_xml, sonar_xml

    path = tmp_path / "beam.csv"
    path.write_text("axis,angle_deg,gain_db\nh,-5,-20\nh,0,0\nh,5,-20\nv,-30,-20\nv,0,0\nv,30,-20\n")
    scene = mitsonar_mod.load_scene(scene_xml(sonar_xml(beam_pattern="table", beam_table=str(path))))
    assert scene.sensors()[0].beam.pattern == "table"


@pytest.mark.parametrize("content, message", [
    (b"\x00\xff", "beam table is not UTF-8 text (expected CSV with columns axis,angle_deg,gain_db)"),
    (b"\x00\x00\x00\n", "beam table is not UTF-8 text"),
    (b"axis,angle_deg,gain_db\nh,0," + b"0" * 200000 + b"\n", "line 2: not CSV (field larger than field limit"),
    (b"", "beam table is empty (expected CSV with columns axis,angle_deg,gain_db)"),
])
def test_unreadable_beam_tables_name_the_file(beam_mod, tmp_path, content, message):
    path = tmp_path / "b.csv"
    path.write_bytes(content)
    with pytest.raises(beam_mod.BeamPatternError) as info:
        beam_mod.read_beam_table(str(path))
    assert str(info.value).startswith(f"{path}") and message in str(info.value)


def test_beam_table_that_is_a_directory_or_cannot_be_opened(beam_mod, tmp_path, monkeypatch):
    with pytest.raises(beam_mod.BeamPatternError, match=f"'beam_table': {tmp_path} is a directory"):
        beam_mod.read_beam_table(str(tmp_path))
    path = tmp_path / "beam.csv"
    path.write_text("axis,angle_deg,gain_db\n")

    def denied(file, *args, **kwargs):  # as root, chmod 000 would not stop the read
        raise PermissionError(13, "Permission denied", file)
    monkeypatch.setattr(beam_mod, "open", denied, raising=False)
    with pytest.raises(beam_mod.BeamPatternError, match="cannot read the beam table \\(Permission denied\\)") as info:
        beam_mod.read_beam_table(str(path))
    assert str(info.value).startswith(f"{path}: ")


def test_beam_table_with_a_byte_order_mark(beam_mod, tmp_path):
    path = tmp_path / "beam.csv"
    path.write_text("axis,angle_deg,gain_db\nh,-5,-20\nh,0,0\nh,5,-20\nv,-30,-20\nv,0,0\nv,30,-20\n",
                    encoding="utf-8-sig")
    assert set(beam_mod.read_beam_table(str(path))) == {"h", "v"}


def test_relative_beam_table_is_found_next_to_the_scene(mitsonar_mod, tmp_path, monkeypatch):
    """Like Mitsuba's own file names: relative to the scene file, wherever the program runs."""
    from conftest import scene_xml, sonar_xml

    (tmp_path / "scene").mkdir()
    (tmp_path / "elsewhere").mkdir()
    (tmp_path / "scene" / "beam.csv").write_text(
        "axis,angle_deg,gain_db\nh,-5,-20\nh,0,0\nh,5,-20\nv,-30,-20\nv,0,0\nv,30,-20\n")
    for name, table in (("good.xml", "beam.csv"), ("missing.xml", "nope.csv"), ("dir.xml", ".")):
        (tmp_path / "scene" / name).write_text(scene_xml(sonar_xml(beam_pattern="table", beam_table=table)))
    monkeypatch.chdir(tmp_path / "elsewhere")
    scene = mitsonar_mod.load_scene(str(tmp_path / "scene" / "good.xml"))
    assert scene.sensors()[0].beam.pattern == "table"
    scene = mitsonar_mod.load_scene(os.path.join("..", "scene", "good.xml"))  # a relative scene path too
    assert scene.sensors()[0].beam.pattern == "table"
    # Not found: the absolute paths tried, the scene's folder first.
    with pytest.raises(mitsonar_mod.SceneError, match="file 'nope.csv' does not exist") as info:
        mitsonar_mod.load_scene(str(tmp_path / "scene" / "missing.xml"))
    tried = str(info.value).split("(tried ")[1]
    assert tried.startswith(str(tmp_path / "scene" / "nope.csv"))
    assert str(tmp_path / "elsewhere" / "nope.csv") in tried
    with pytest.raises(mitsonar_mod.SceneError, match=f"'beam_table': {tmp_path / 'scene'} is a directory"):
        mitsonar_mod.load_scene(str(tmp_path / "scene" / "dir.xml"))


def test_binary_beam_table_from_xml_is_one_sentence(mitsonar_mod, tmp_path):
    from conftest import scene_xml, sonar_xml

    (tmp_path / "b.csv").write_bytes(b"\x00\xff")
    with pytest.raises(mitsonar_mod.SceneError) as info:
        mitsonar_mod.load_scene(scene_xml(sonar_xml(beam_pattern="table", beam_table=str(tmp_path / "b.csv"))))
    message = str(info.value)
    assert message.endswith(f"{tmp_path / 'b.csv'}: beam table is not UTF-8 text "
                            "(expected CSV with columns axis,angle_deg,gain_db)")
    assert "\n" not in message and "Traceback" not in message


@pytest.mark.parametrize("params, message", [
    (dict(frequency=-5.0), "'frequency': -5.0 Hz must be > 0"),
    (dict(frequency=float("nan")), "'frequency': nan Hz must be > 0"),
    (dict(aperture_h=-1.0), "'aperture_h': -1.0 m must be > 0"),
    (dict(aperture_v=0.05), "'aperture_v' is only used with beam_pattern 'sinc' \\(got 'gaussian'\\)"),
])
def test_impossible_or_unused_beam_parameters(beam_mod, params, message):
    with pytest.raises(beam_mod.BeamPatternError, match=message):
        beam_mod.BeamPattern("gaussian", 3.0, 35.0, **params)


def test_a_new_pattern_is_accepted_without_editing_other_modules(mitsonar_mod, beam_mod):
    """A toy pattern registered with the patterns' registry is a receive beam and a transmit fan of
    the ``sonar`` sensor, samples and renders, and shares transmit paths through its window:
    nothing outside its class names it."""
    import drjit as dr
    import mitsuba as mi

    from conftest import acoustic_xml, frame_matrix, rectangle_xml, scene_xml, sonar_xml

    class Tent(beam_mod.Pattern):
        name = "tent"

        def support(self, beam):
            bh, bv = math.radians(beam.beamwidth_h), math.radians(beam.beamwidth_v)
            return -bh, bh, -min(bv, math.pi / 2), min(bv, math.pi / 2)

        def eval_np(self, beam, az, el):
            bh, bv = math.radians(beam.beamwidth_h), math.radians(beam.beamwidth_v)
            return np.maximum(0.0, 1 - np.abs(az) / bh) * np.maximum(0.0, 1 - np.abs(el) / bv)

        def eval(self, beam, az, el):
            return dr.maximum(0.0, 1 - dr.abs(az) / beam._p_bh) * dr.maximum(0.0, 1 - dr.abs(el) / beam._p_bv)

    with pytest.raises(beam_mod.BeamPatternError, match="'beam_pattern': 'tent' is not one of gaussian, sinc"):
        beam_mod.BeamPattern("tent", 10.0, 20.0)
    beam_mod.register(Tent)
    try:
        beam = beam_mod.BeamPattern("tent", 10.0, 20.0)
        assert isinstance(beam.shape, Tent) and beam.pattern == "tent"
        # B at half the width is 1/2 on each axis; the emission weight averages to the solid angle
        assert beam.eval_np(math.radians(5.0), 0.0) == pytest.approx(0.5)
        _, w = sample_weights(beam)
        assert w.mean() == pytest.approx(beam.solid_angle(), rel=0.01)
        floor = np.diag([40.0, 40.0, 1.0, 1.0])
        floor[2, 3] = -2.0                              # 2 m below a head looking 40 deg down
        shapes = rectangle_xml(floor, acoustic_xml(diffuse=0.5))
        head = frame_matrix((math.sin(math.radians(40)), 0, -math.cos(math.radians(40))), (0, 1, 0))
        scan = mitsonar_mod.render_scan(mitsonar_mod.load_scene(scene_xml(
            sonar_xml(head, beam_pattern="tent", n_pings=3, bearing_start=-5.0, bearing_step=5.0, n_bins=50,
                      range_max=10.0), shapes)), spp=256, seed=1)
        assert scan.beam_pattern == "tent" and scan.intensity.max() > 0
        fan = mitsonar_mod.load_scene(scene_xml(
            sonar_xml(head, kind="multibeam", beam_pattern="tent", tx_pattern="tent", n_pings=5, bearing_start=-10.0,
                      bearing_step=5.0, n_bins=50, range_max=10.0),
            shapes, integrator='<integrator type="sonar_tof"><boolean name="share_beams" value="true"/></integrator>'))
        assert fan.sensors()[0].transmit.pattern == "tent"
        assert mitsonar_mod.render_scan(fan, spp=64, seed=1).meta.tx_pattern == "tent"
        assert isinstance(mi.load_dict({"type": "sonar", "beam_pattern": "tent"}).beam.shape, Tent)
    finally:
        beam_mod.unregister("tent")
    with pytest.raises(beam_mod.BeamPatternError, match="is not one of"):
        beam_mod.BeamPattern("tent", 10.0, 20.0)


def test_beam_kind_is_now_pattern(beam_mod):
    """``BeamPattern.kind`` (the pattern's name) is now ``pattern``; the old name reads it with a
    DeprecationWarning for one release."""
    beam = beam_mod.BeamPattern("uniform", 10.0, 20.0)
    assert beam.pattern == "uniform" and beam.shape is beam_mod.UNIFORM
    with pytest.warns(DeprecationWarning, match="BeamPattern.kind is now BeamPattern.pattern"):
        assert beam.kind == "uniform"
