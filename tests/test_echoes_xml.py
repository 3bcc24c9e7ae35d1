"""The head's band (``frequency`` +- ``bandwidth`` / 2) and receive elements (an ``elements`` CSV)
in a scene's XML, used by `render_echoes`, and the example scenes that carry them: a forward-looking
line array (``fls_array``) and an interferometric side-scan (``interferometric_sidescan``); moving
objects' Doppler (`render_echoes`'s ``velocities``)."""
import os

import numpy as np
import pytest

from conftest import acoustic_xml, frame_matrix, scene_xml, sonar_xml, sphere_xml

C = 1500.0
FORWARD = frame_matrix((1, 0, 0), (0, 0, 1))
TARGET = sphere_xml((4.0, 0, 0), 0.005, acoustic_xml(0.9))


def head(mitsonar_mod, **params):
    from mitsonar.sim.scene import sonar_of

    base = dict(n_pings=1, n_bins=100, range_max=6.0, beamwidth_h=6.0, beamwidth_v=6.0)
    return sonar_of(mitsonar_mod.load_scene(scene_xml(sonar_xml(FORWARD, **{**base, **params}), TARGET)))


def test_the_band_is_frequency_over_q_unless_the_xml_or_a_preset_gives_it(mitsonar_mod):
    from mitsonar.signals.echoes import head_band

    assert head(mitsonar_mod).bandwidth == 350e3                       # 700 kHz / Q, Q = 2
    assert head_band(head(mitsonar_mod, frequency=400e3)) == (300e3, 500e3)   # a gaussian beam takes a frequency
    assert head_band(head(mitsonar_mod, bandwidth=20e3)) == (690e3, 710e3)
    side = dict(kind="sidescan", n_pings=1, range_max=20.0, n_bins=50)
    assert head(mitsonar_mod, preset="starfish450", **side).bandwidth == 50e3          # published: 425-475 kHz
    klein = head(mitsonar_mod, preset="klein3000_100k", **side)
    assert klein.beam.frequency == 100e3 and klein.bandwidth == 50e3                   # not published: the rule
    klein = head(mitsonar_mod, preset="klein3000_100k", beam_pattern="gaussian", **side)
    assert klein.beam.frequency == 100e3                       # the preset's frequency whatever the pattern


@pytest.mark.parametrize("value", [0.0, -1e3, float("nan"), 1.4e6, float("inf")])
def test_a_bad_bandwidth_is_refused_in_one_line(mitsonar_mod, value):
    with pytest.raises(mitsonar_mod.SceneError, match=r"sonar 'bandwidth': .* (is not|not allowed).*band > 0 Hz "
                                                      r"and below 2 frequency = 1400000 Hz") as err:
        head(mitsonar_mod, bandwidth=value)
    assert "\n" not in str(err.value)


def test_render_echoes_holds_the_carrier_to_the_xml_band(mitsonar_mod, monkeypatch):
    from mitsonar import signals as S
    from mitsonar.signals import echoes as E

    scene = mitsonar_mod.load_scene(scene_xml(sonar_xml(FORWARD, n_pings=1, n_bins=100, range_max=6.0,
                                                        bandwidth=20e3), TARGET))
    monkeypatch.setattr(E, "_trace", lambda *a, **k: pytest.fail("rendered before refusing"))
    with pytest.raises(mitsonar_mod.SceneError, match=r"render_echoes 'pulse': its carrier 720000 Hz is not allowed "
                                                      r"\(inside the head's band 690000 to 710000 Hz") as err:
        mitsonar_mod.render_echoes(scene, S.lfm(710e3, 730e3, 1e-3))
    assert "\n" not in str(err.value)


def write_scene(folder, csv_text, name="array.csv"):
    os.makedirs(folder, exist_ok=True)
    with open(os.path.join(folder, name), "w") as fh:
        fh.write(csv_text)
    path = os.path.join(folder, "scene.xml")
    with open(path, "w") as fh:
        fh.write(scene_xml(sonar_xml(FORWARD, n_pings=1, n_bins=100, range_max=6.0, beamwidth_h=6.0,
                                     beamwidth_v=6.0, elements=name), TARGET))
    return path


def test_elements_csv_next_to_the_scene_file_are_the_default_elements(mitsonar_mod, tmp_path, monkeypatch):
    from mitsonar import signals as S
    from mitsonar.sim.scene import sonar_of

    path = write_scene(tmp_path / "scenes", "x,y,z\n-0.001,0,0\n0.001,0,0\n0,0.001,0\n")
    monkeypatch.chdir(tmp_path)                                  # found from the scene's folder, not the cwd
    scene = mitsonar_mod.load_scene(str(path))
    assert sonar_of(scene).elements.tolist() == [[-0.001, 0, 0], [0.001, 0, 0], [0, 0.001, 0]]
    p = S.lfm(690e3, 710e3, 1e-3)
    echoes = mitsonar_mod.render_echoes(scene, p, spp=4096)
    assert echoes.signal.shape[1] == 3 and echoes.elements.tolist() == sonar_of(scene).elements.tolist()
    # the element at +x hears the target (on the axis) at the same time as the one at -x
    y = np.abs(S.matched_filter(echoes.signal[0], p, echoes.sample_rate))
    assert np.argmax(y[0]) == np.argmax(y[1]) and y[0].max() > 0
    given = mitsonar_mod.render_echoes(scene, p, spp=256, elements=[[0, 0, 0]])      # an argument wins
    assert given.signal.shape[1] == 1


@pytest.mark.parametrize("csv_text, message", [
    ("x,y,z\n0,0,0\n0,0,0\n", r"sonar \(elements file .*array.csv\) 'elements': elements 0 and 1 overlap"),
    ("x,y,z\n0,0,0\n0,nan,0\n", r"sonar \(elements file .*array.csv\) 'elements': element 1 is"),
    ("x,y,z\n0,0,0\n1,2\n", r"sonar \(elements file .*array.csv\): line 3 .* is not allowed \(x,y,z in m"),
    ("x,y,z\n0,0,0\n0,a,0\n", r"sonar \(elements file .*array.csv\): line 3 .* is not allowed \(x,y,z in m\)"),
    ("x,y,z\n", r"sonar \(elements file .*array.csv\): no element"),
])
def test_a_bad_elements_csv_is_refused_when_the_scene_loads(mitsonar_mod, tmp_path, csv_text, message):
    path = write_scene(tmp_path, csv_text)
    with pytest.raises(mitsonar_mod.SceneError, match=message) as err:
        mitsonar_mod.load_scene(str(path))
    assert "\n" not in str(err.value)


def test_a_missing_elements_file_is_refused_naming_where_it_looked(mitsonar_mod, tmp_path):
    path = write_scene(tmp_path, "0,0,0\n")
    os.remove(tmp_path / "array.csv")
    with pytest.raises(mitsonar_mod.SceneError, match=r"sonar 'elements': 'array.csv' is not allowed \(a CSV file "
                                                      r"of x,y,z rows in m; tried .*array.csv") as err:
        mitsonar_mod.load_scene(str(path))
    assert "\n" not in str(err.value)


def test_fls_array_scene_beamforms_its_two_targets(mitsonar_mod):
    """The example FLS head: its 64 XML elements are the line-array preset at half a wavelength, and
    the beamformed frame shows the two spheres at their bearings (-8 and +10 deg, within a quarter
    of the -3 dB beam width 0.886 lambda / (N d)) and range (6 m less the radius, within a bin)."""
    from scipy.signal import find_peaks

    from mitsonar import signals as S
    from mitsonar.sim.scene import sonar_of

    scene = mitsonar_mod.load_scene(mitsonar_mod.example_scene("fls_array"))
    np.testing.assert_allclose(sonar_of(scene).elements, S.line_array(64, frequency=700e3), atol=1e-10)
    echoes = mitsonar_mod.render_echoes(scene, S.lfm(680e3, 720e3, 1e-3), spp=1 << 14)
    assert echoes.signal.shape[:2] == (1, 64)
    scan = S.beamform(echoes)
    assert scan.intensity.shape == (121, 200)
    near = (scan.ranges > 5.7) & (scan.ranges < 6.3)
    profile = scan.intensity[:, near].max(axis=1)
    peaks, _ = find_peaks(profile, height=0.2 * profile.max())
    width = 0.886 * 2 / 64                                       # rad: lambda / (N lambda / 2)
    assert len(peaks) == 2
    np.testing.assert_allclose(scan.bearings[peaks], np.radians([-8.0, 10.0]), atol=0.25 * width)
    bins = scan.intensity[peaks].argmax(axis=1)
    np.testing.assert_allclose(scan.ranges[bins], 6.0 - 0.05, atol=scan.ranges[1] - scan.ranges[0])


def test_interferometric_sidescan_scene_maps_its_flat_seabed_flat(mitsonar_mod):
    """The example interferometric side-scan (two rows across the port fan from its XML, 5 m over a
    flat seabed): between 20 and 60 deg grazing the depths are the seabed's within 1 % of the
    altitude (95 % of the samples), unbiased, on the port side."""
    from mitsonar import signals as S

    H = 5.0
    scene = mitsonar_mod.load_scene(mitsonar_mod.example_scene("interferometric_sidescan"))
    echoes = mitsonar_mod.render_echoes(scene, S.lfm(680e3, 720e3, 1e-3), spp=1 << 16, scatterer_spacing=0.02)
    np.testing.assert_allclose(echoes.elements, [[0, 0, 0], [0, C / 700e3 / 2, 0]], atol=1e-11)
    b = S.sidescan_bathymetry(echoes, average=15)
    r = b["range"]
    grazing = (r > H / np.sin(np.radians(60))) & (r < H / np.sin(np.radians(20)))
    z = b["points"][0, grazing, 2]
    ok = np.isfinite(z)
    assert ok.mean() > 0.6
    assert np.percentile(np.abs(z[ok]), 95) < 0.01 * H
    assert abs(np.mean(z[ok])) < 0.002 * H
    assert np.all(b["points"][0, grazing, 1][ok] > 0)            # the port side: world +y


def moving_wall_scene(mitsonar_mod):
    from conftest import matrix_attr

    m = np.eye(4)
    m[:3, 0], m[:3, 1], m[:3, 2], m[:3, 3] = (0, 0, 5.0), (0, 5.0, 0), (-1, 0, 0), (8.0, 0, 0)
    wall = (f'<shape type="rectangle" id="wall"><transform name="to_world"><matrix value="{matrix_attr(m)}"/>'
            f"</transform>{acoustic_xml(0.5)}</shape>")
    sensor = sonar_xml(FORWARD, n_pings=1, n_bins=100, range_max=10.0, beamwidth_h=2.0, beamwidth_v=2.0)
    return mitsonar_mod.load_scene(scene_xml(sensor, wall, sphere_xml((3.0, 3.0, 0), 0.1, acoustic_xml(0.5))))


def test_a_wall_closing_on_a_still_head_shifts_the_carrier_by_2vf_over_c(mitsonar_mod):
    """Objects' velocities: a Lambert wall moving at v towards (away from) a still head returns the
    carrier shifted by +2 v f / c (-2 v f / c), within 3 %; still, by nothing."""
    from mitsonar import signals as S

    scene = moving_wall_scene(mitsonar_mod)
    f, v, fs = 700e3, 2.0, 20e3
    p = S.cw(f, 2e-3)

    def shift(velocities):
        x = mitsonar_mod.render_echoes(scene, p, spp=1024, sample_rate=fs, velocities=velocities).signal[0, 0]
        on = np.abs(x) > 0.5 * np.abs(x).max()
        pairs = (x[1:] * np.conj(x[:-1]))[on[1:] & on[:-1]]
        return np.angle(pairs.sum()) * fs / (2 * np.pi)

    assert shift({"wall": (-v, 0, 0)}) == pytest.approx(2 * v * f / C, rel=0.03)
    assert shift({"wall": (v, 0, 0)}) == pytest.approx(-2 * v * f / C, rel=0.03)
    assert abs(shift(None)) < 0.01 * 2 * v * f / C
    assert abs(shift({"wall": (0, v, 0)})) < 0.05 * 2 * v * f / C        # across the line of sight: none


@pytest.mark.parametrize("velocities, message", [
    ({"ship": (1, 0, 0)}, r"render_echoes 'velocities': 'ship' is not allowed \(a shape id of the scene: 'wall'\)$"),
    ({"wall": (1, 0)}, r"render_echoes 'velocities': 'wall': \(1, 0\) is not allowed \(a finite \(vx, vy, vz\)"),
    ({"wall": (np.nan, 0, 0)}, r"render_echoes 'velocities': 'wall': .* is not allowed"),
    ({"wall": (200.0, 0, 0)}, r"slower than a tenth of the sound speed, 150 m/s"),
    ([(1, 0, 0)], r"render_echoes 'velocities': list is not allowed \(a dict of shape id"),
])
def test_bad_velocities_are_refused_before_rendering(mitsonar_mod, monkeypatch, velocities, message):
    from mitsonar import signals as S
    from mitsonar.signals import echoes as E

    scene = moving_wall_scene(mitsonar_mod)
    monkeypatch.setattr(E, "_trace", lambda *a, **k: pytest.fail("rendered before refusing"))
    with pytest.raises(mitsonar_mod.SceneError, match=message) as err:
        mitsonar_mod.render_echoes(scene, S.cw(700e3, 2e-3), velocities=velocities)
    assert "\n" not in str(err.value)
