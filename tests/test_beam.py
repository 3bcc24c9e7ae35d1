"""Beam patterns: definitions, importance sampling, measured tables."""
import math

import drjit as dr
import numpy as np
import pytest


@pytest.fixture(scope="module")
def beam_mod(mitsonar_mod):
    from mitsonar.plugins import module

    return module("beam")


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
    assert scene.sensors()[0].beam.kind == "table"
