"""`render_echoes`: element data rendered from the echo paths, against closed forms and the
incoherent renderer."""
import numpy as np
import pytest

from conftest import acoustic_xml, frame_matrix, rectangle_xml, scene_xml, sonar_xml, sphere_xml

C = 1500.0
FORWARD = frame_matrix((1, 0, 0), (0, 0, 1))   # boresight world +x, bearings turn towards world +y


def wall(x, half=5.0):
    """A rectangle at ``x`` facing the origin (normal -x), ``2 half`` m wide."""
    m = np.eye(4)
    m[:3, 0], m[:3, 1], m[:3, 2], m[:3, 3] = (0, 0, half), (0, half, 0), (-1, 0, 0), (x, 0, 0)
    return m


@pytest.fixture(scope="module")
def point_target(mitsonar_mod):
    sensor = sonar_xml(FORWARD, n_pings=1, n_bins=100, range_max=6.0, beamwidth_h=6.0, beamwidth_v=6.0)
    return mitsonar_mod.load_scene(scene_xml(sensor, sphere_xml((4.0, 0, 0), 0.005, acoustic_xml(0.9))))


def test_lfm_echo_of_a_point_target_compresses_to_0886_c_over_2b_at_its_range(mitsonar_mod, point_target):
    from mitsonar import signals as S
    from test_signals import width_3db

    p = S.lfm(690e3, 710e3, 1e-3)
    echoes = mitsonar_mod.render_echoes(point_target, p, spp=4096, sample_rate=16 * p.bandwidth)
    assert echoes.signal.dtype == np.complex64 and echoes.signal.shape[:2] == (1, 1)
    assert echoes.carrier == 700e3 and echoes.sound_speed == C
    assert echoes.n_samples == int(np.ceil((2 * 6.0 / C + 1e-3) * echoes.sample_rate))
    power = np.abs(S.matched_filter(echoes.signal[0, 0], p, echoes.sample_rate)) ** 2
    assert width_3db(power, C / (2 * echoes.sample_rate)) == pytest.approx(0.886 * C / (2 * p.bandwidth), rel=0.10)
    # at the default rate (twice the bandwidth) the peak is the sample of the target's range, within one
    echoes = mitsonar_mod.render_echoes(point_target, p, spp=4096)
    assert echoes.sample_rate == 2 * p.bandwidth
    k = int(np.argmax(np.abs(S.matched_filter(echoes.signal[0, 0], p, echoes.sample_rate))))
    assert abs(k - 2 * (4.0 - 0.005) / C * echoes.sample_rate) <= 1


def test_cw_echo_is_the_rectangles_triangle(mitsonar_mod, point_target):
    from mitsonar import signals as S

    T = 0.5e-3
    p = S.cw(700e3, T)
    echoes = mitsonar_mod.render_echoes(point_target, p, spp=1024, sample_rate=64 / T)
    y = np.abs(S.matched_filter(echoes.signal[0, 0], p, echoes.sample_rate))
    y /= y.max()
    lag = (np.arange(len(y)) - np.argmax(y)) / echoes.sample_rate
    assert np.max(np.abs(y - np.clip(1 - np.abs(lag) / T, 0, None))) < 0.05


def test_same_arguments_same_bytes_and_a_still_head_keeps_its_waveform_across_path_seeds(mitsonar_mod):
    from mitsonar import signals as S

    sensor = sonar_xml(FORWARD, n_pings=2, n_bins=100, range_max=6.0, beamwidth_h=4.0, beamwidth_v=4.0)
    scene = mitsonar_mod.load_scene(scene_xml(sensor, sphere_xml((4.0, 0, 0), 0.1, acoustic_xml(0.9))))
    p = S.lfm(690e3, 710e3, 1e-3)
    a = mitsonar_mod.render_echoes(scene, p, spp=8192, seed=1)
    b = mitsonar_mod.render_echoes(scene, p, spp=8192, seed=1)
    assert a.signal.tobytes() == b.signal.tobytes()
    assert a.meta["n_scatterers"] > 50
    c = mitsonar_mod.render_echoes(scene, p, spp=8192, seed=2)
    d = mitsonar_mod.render_echoes(scene, p, spp=8192, seed=1, speckle_seed=5)
    corr = lambda x, y: abs(np.vdot(x, y)) / np.linalg.norm(x) / np.linalg.norm(y)  # noqa: E731
    assert corr(a.signal.ravel(), c.signal.ravel()) > 0.9      # path seed: Monte-Carlo noise only
    assert corr(a.signal.ravel(), d.signal.ravel()) < 0.9      # speckle seed: other scatterers' phases


def test_head_closing_on_a_wall_hears_the_carrier_shifted_by_2vf_over_c(mitsonar_mod):
    from mitsonar import signals as S

    sensor = sonar_xml(FORWARD, n_pings=1, n_bins=100, range_max=10.0, beamwidth_h=2.0, beamwidth_v=2.0)
    scene = mitsonar_mod.load_scene(scene_xml(sensor, rectangle_xml(wall(8.0), acoustic_xml(0.5))))
    f, v = 700e3, 2.0
    p = S.cw(f, 2e-3)
    shifts = []
    for speed in (v, -v):
        traj = mitsonar_mod.Trajectory.straight(1.0, speed)
        x = mitsonar_mod.render_echoes(scene, p, spp=1024, sample_rate=20e3, trajectory=traj).signal[0, 0]
        on = np.abs(x) > 0.5 * np.abs(x).max()
        pairs = (x[1:] * np.conj(x[:-1]))[on[1:] & on[:-1]]
        shifts.append(np.angle(pairs.sum()) * 20e3 / (2 * np.pi))
    assert shifts[0] == pytest.approx(2 * v * f / C, rel=0.03)
    assert shifts[1] == pytest.approx(-2 * v * f / C, rel=0.03)


def test_line_array_beamforms_two_targets_at_their_azimuths(mitsonar_mod):
    from mitsonar import signals as S

    f = 700e3
    sensor = sonar_xml(FORWARD, kind="multibeam", n_pings=121, bearing_start=-15.0, bearing_step=0.25, n_bins=100,
                       range_max=6.0, beamwidth_h=1.0, beamwidth_v=10.0)
    az = np.radians([-6.0, 4.0])
    R = 5.0
    spheres = [sphere_xml((R * np.cos(a), R * np.sin(a), 0), 0.01, acoustic_xml(0.9)) for a in az]
    scene = mitsonar_mod.load_scene(scene_xml(sensor, *spheres))
    echoes = mitsonar_mod.render_echoes(scene, S.lfm(680e3, 720e3, 1e-3), elements=S.line_array(64, frequency=f),
                                        spp=1 << 14)
    assert echoes.signal.shape[:2] == (1, 64)              # one transmission per multibeam frame
    scan = S.beamform(echoes)
    assert scan.kind == "multibeam" and scan.intensity.shape == (121, 100) and scan.data.shape == (121, 100)
    assert scan.data.max() > scan.data.min()                       # the head's electronics made its bytes
    assert np.allclose(scan.bearings, np.radians(-15 + 0.25 * np.arange(121)))
    profile = scan.intensity.max(axis=1)
    from scipy.signal import find_peaks

    peaks, _ = find_peaks(profile, height=0.2 * profile.max())
    bw = 0.886 * (C / f) / (64 * C / f / 2)
    assert len(peaks) == 2
    assert np.allclose(scan.bearings[peaks], az, atol=0.25 * bw)
    bins = scan.intensity[peaks].argmax(axis=1)
    assert np.allclose(scan.ranges[bins], R - 0.01, atol=scan.ranges[1] - scan.ranges[0])


def test_mean_compressed_power_over_speckle_seeds_is_the_incoherent_intensity_convolved(mitsonar_mod):
    """Over a Lambert plane at an angle: E|y(t)|^2 over speckle seeds = sum_bins I_b |R(t - tau_b)|^2."""
    from mitsonar import signals as S

    # bins of 5 mm, a quarter of the range resolution c / (2 B) = 1.9 cm: the binned intensity is the
    # intensity density to well within the test's tolerance
    sensor = sonar_xml(FORWARD, n_pings=1, n_bins=200, range_min=3.5, range_max=4.5, beamwidth_h=4.0, beamwidth_v=4.0)
    plane = tilted_plane(4.0, 50.0)                                # echoes spread over range
    scene = mitsonar_mod.load_scene(scene_xml(sensor, rectangle_xml(plane, acoustic_xml(0.8))))
    p = S.lfm(680e3, 720e3, 1e-3)
    scan = mitsonar_mod.render_scan(scene, spp=1 << 15)
    powers = []
    for s in range(24):
        e = mitsonar_mod.render_echoes(scene, p, spp=4096, seed=s, speckle_seed=s, element_pattern="beam")
        y = S.matched_filter(e.signal[0, 0], p, e.sample_rate) / e.meta["pressure_scale"]
        powers.append(np.abs(y) ** 2)
    powers = np.array(powers)
    t = e.sample_times
    expected = S.expected_power(t, 2 * scan.ranges / C, scan.intensity[0], p, e.sample_rate)
    core = expected > 0.3 * expected.max()
    mean, sem = powers.mean(axis=0)[core], powers.std(axis=0)[core] / np.sqrt(len(powers))
    sums = powers[:, core].sum(axis=1)
    assert abs(sums.mean() - expected[core].sum()) < 3 * sums.std() / np.sqrt(len(sums)) + 0.02 * expected[core].sum()
    assert np.mean(np.abs(mean - expected[core]) < 3 * sem + 0.05 * expected[core]) > 0.9


def tilted_plane(x, incidence_deg, half=3.0):
    """A square through (x, 0, 0) whose normal is ``incidence_deg`` from -x, tilted towards +z."""
    a = np.radians(incidence_deg)
    n = np.array([-np.cos(a), 0.0, np.sin(a)])
    m = np.eye(4)
    m[:3, 0], m[:3, 1], m[:3, 2], m[:3, 3] = half * np.array([n[2], 0, -n[0]]), (0, half, 0), n, (x, 0, 0)
    return m


def test_speckle_of_a_lambert_plane_is_rayleigh(mitsonar_mod):
    from scipy import stats

    from mitsonar import signals as S

    sensor = sonar_xml(FORWARD, n_pings=1, n_bins=60, range_min=2.0, range_max=5.0, beamwidth_h=6.0, beamwidth_v=6.0)
    plane = tilted_plane(4.0, 60.0)
    scene = mitsonar_mod.load_scene(scene_xml(sensor, rectangle_xml(plane, acoustic_xml(0.8))))
    p = S.lfm(680e3, 720e3, 1e-3)
    amps = np.array([np.abs(S.matched_filter(mitsonar_mod.render_echoes(scene, p, spp=2048, speckle_seed=s).signal[0, 0],
                                             p, 2 * p.bandwidth)) for s in range(30)])
    rms = np.sqrt(np.mean(amps ** 2, axis=0))
    core = rms > 0.5 * rms.max()
    a = (amps[:, core] / rms[core]).ravel()                      # unit mean power per sample
    assert stats.kstest(a, stats.rayleigh(scale=np.sqrt(0.5)).cdf).pvalue > 0.01


def test_render_streams_paths_in_passes_with_the_same_echoes(mitsonar_mod, point_target, monkeypatch):
    from mitsonar import signals as S
    from mitsonar.signals import echoes as E

    p = S.lfm(690e3, 710e3, 1e-3)
    whole = mitsonar_mod.render_echoes(point_target, p, spp=4096, elements=S.line_array(4, frequency=700e3))
    calls = []
    original = E._Accumulator.add
    monkeypatch.setattr(E, "PASS_SLOTS", 1000)
    monkeypatch.setattr(E._Accumulator, "add", lambda self, rows, *a: calls.append(len(rows)) or original(self, rows, *a))
    streamed = mitsonar_mod.render_echoes(point_target, p, spp=4096, elements=S.line_array(4, frequency=700e3))
    assert len(calls) > 10                                       # many passes of at most 1000 slots
    np.testing.assert_allclose(streamed.signal, whole.signal, rtol=1e-4, atol=1e-6 * np.abs(whole.signal).max())


@pytest.mark.parametrize("kwargs, message", [
    (dict(elements=[[0, 0, 0], [np.inf, 0, 0]]), "render_echoes 'elements': element 1 is"),
    (dict(elements=[[0, 0, 0], [0, 0, 0]]), "render_echoes 'elements': elements 0 and 1 overlap"),
    (dict(sample_rate=10e3), r"render_echoes 'sample_rate': 10000.0 is not allowed \(a rate >= the pulse's bandwidth, 20000 Hz\)"),
    (dict(pulse="lfm"), "render_echoes 'pulse': str is not allowed"),
    (dict(pulse=("cw", 1e-3, 300e3)), r"render_echoes 'pulse': its carrier 300000 Hz is not allowed \(inside the head's band 525000 to 875000 Hz"),
    (dict(pulse=("cw", 0.02, 700e3)), r"render_echoes 'pulse': its duration 0.02 s is not allowed \(at most the two-way window"),
    (dict(spp=0), "render_echoes 'spp'"),
])
def test_bad_input_is_refused_in_one_line_before_rendering(mitsonar_mod, point_target, kwargs, message, monkeypatch):
    from mitsonar import signals as S
    from mitsonar.signals import echoes as E

    pulse = kwargs.pop("pulse", S.lfm(690e3, 710e3, 1e-3))
    if isinstance(pulse, tuple):
        pulse = S.cw(pulse[2], pulse[1])
    monkeypatch.setattr(E, "_trace", lambda *a, **k: pytest.fail("rendered before refusing"))
    with pytest.raises(mitsonar_mod.SceneError, match=message) as err:
        mitsonar_mod.render_echoes(point_target, pulse, **kwargs)
    assert "\n" not in str(err.value)


def test_interferometric_sidescan_bathymetry_of_a_flat_seabed_is_flat(mitsonar_mod):
    """Two rows stacked across the fan (the ``interferometer`` preset) at 5 m altitude over a flat
    Lambert seabed: between 20 and 60 deg grazing the depths are those of the seabed within 1 % of the
    altitude (95 % of the samples), unbiased."""
    from mitsonar import signals as S

    H = 5.0
    head = np.eye(4)
    head[2, 3] = H
    sensor = sonar_xml(head, kind="sidescan", side="port", n_pings=1, n_bins=400, range_max=16.0, depression=40.0,
                       beamwidth_h=1.0, beamwidth_v=50.0)
    floor = np.diag([30.0, 30.0, 1.0, 1.0])
    scene = mitsonar_mod.load_scene(scene_xml(sensor, rectangle_xml(floor, acoustic_xml(0.5))))
    echoes = mitsonar_mod.render_echoes(scene, S.lfm(680e3, 720e3, 1e-3), spp=1 << 16, elements="interferometer",
                                        scatterer_spacing=0.02)
    assert np.allclose(echoes.elements, [[0, 0, 0], [0, C / 700e3 / 2, 0]])
    b = S.sidescan_bathymetry(echoes, average=15)
    r = b["range"]
    grazing = (r > H / np.sin(np.radians(60))) & (r < H / np.sin(np.radians(20)))
    z = b["points"][0, grazing, 2]
    ok = np.isfinite(z)
    assert ok.mean() > 0.6
    assert np.percentile(np.abs(z[ok]), 95) < 0.01 * H
    assert abs(np.mean(z[ok])) < 0.002 * H
    across = b["points"][0, grazing, 1][ok]
    assert np.all(across > 0)                                    # the port side: world +y


def test_elements_from_a_csv_file(mitsonar_mod, point_target, tmp_path):
    from mitsonar import signals as S

    path = tmp_path / "array.csv"
    path.write_text("x,y,z\n-0.001,0,0\n0.001,0,0\n")
    echoes = mitsonar_mod.render_echoes(point_target, S.lfm(690e3, 710e3, 1e-3), spp=64, elements=str(path))
    assert echoes.elements.tolist() == [[-0.001, 0, 0], [0.001, 0, 0]] and echoes.signal.shape[1] == 2
    path.write_text("x,y,z\n0,0,0\n0,0,0\n")
    with pytest.raises(mitsonar_mod.SceneError, match=r"render_echoes \(elements file .*array.csv\) 'elements': "
                                                      "elements 0 and 1 overlap"):
        mitsonar_mod.render_echoes(point_target, S.lfm(690e3, 710e3, 1e-3), elements=str(path))
    with pytest.raises(mitsonar_mod.SceneError, match="render_echoes 'elements': 'nowhere.csv' is not allowed"):
        mitsonar_mod.render_echoes(point_target, S.lfm(690e3, 710e3, 1e-3), elements="nowhere.csv")


def test_mirror_like_plate_echoes_coherently_with_the_travel_time_phase(mitsonar_mod):
    """A mirror-like plate at normal incidence is a coherent glint: the same waveform for every speckle
    seed, and its compressed peak has the phase ``-2 pi f_c tau`` of its travel time; a Lambert plate's
    echo changes with the speckle seed."""
    from mitsonar import signals as S

    sensor = sonar_xml(FORWARD, n_pings=1, n_bins=100, range_max=6.0, beamwidth_h=3.0, beamwidth_v=3.0)
    p = S.lfm(690e3, 710e3, 1e-3)
    fs = 8 * p.bandwidth
    D = 4.0
    out = {}
    for name, bsdf in (("mirror", acoustic_xml(0.0, 1.0, 2000.0)), ("lambert", acoustic_xml(0.5))):
        scene = mitsonar_mod.load_scene(scene_xml(sensor, rectangle_xml(wall(D, 1.0), bsdf)))
        out[name] = [mitsonar_mod.render_echoes(scene, p, spp=4096, speckle_seed=s, sample_rate=fs) for s in (0, 1)]
    a, b = (e.signal[0, 0] for e in out["mirror"])
    assert np.abs(a).max() > 0 and a.tobytes() == b.tobytes()
    assert out["mirror"][0].meta["n_scatterers"] < 5                 # one glint (cells a range resolution wide)
    y = S.matched_filter(a, p, fs)
    tau = 2 * D / C
    k = int(round(tau * fs))
    assert abs(np.argmax(np.abs(y)) - k) <= 1
    # the compressed echo at the sample nearest tau: R(k / fs - tau) exp(-i 2 pi f_c tau)
    lags, r = S.compressed_autocorrelation(p, fs)
    expected = np.interp(k / fs - tau, lags, r.real) + 1j * np.interp(k / fs - tau, lags, r.imag)
    expected *= np.exp(-2j * np.pi * p.carrier * tau)
    assert np.angle(y[k] / expected) == pytest.approx(0.0, abs=0.05)
    c, d = (S.matched_filter(e.signal[0, 0], p, fs)[k] for e in out["lambert"])   # a sum of random phasors
    assert abs(c - d) > 0.2 * abs(c)


def test_rows_are_a_mechanical_heads_pings_with_their_times_and_poses(mitsonar_mod):
    from mitsonar import signals as S

    sensor = sonar_xml(FORWARD, n_pings=3, bearing_start=-4.0, bearing_step=4.0, n_bins=50, range_max=6.0,
                       beamwidth_h=3.0, beamwidth_v=3.0)
    scene = mitsonar_mod.load_scene(scene_xml(sensor, sphere_xml((4.0, 0, 0), 0.1, acoustic_xml(0.9))))
    echoes = mitsonar_mod.render_echoes(scene, S.cw(700e3, 1e-4), spp=512, elements="line_array")
    scan = mitsonar_mod.render_scan(scene, spp=16)
    assert echoes.signal.shape[:2] == (3, 64) and echoes.elements.shape == (64, 3)
    np.testing.assert_allclose(echoes.times, scan.times)
    np.testing.assert_allclose(echoes.poses, scan.poses)
    power = (np.abs(echoes.signal) ** 2).sum(axis=(1, 2))
    assert power[1] > 5 * max(power[0], power[2])                  # the middle ping looks at the sphere (one-way: transmit pattern only)


def test_waveform_over_a_rough_plane_converges_with_spp(mitsonar_mod):
    """The scatterers are frozen to the scene and only their energies are Monte-Carlo estimates: two
    path seeds' waveforms agree better and better as spp grows (a convergent estimator of one field)."""
    from mitsonar import signals as S

    sensor = sonar_xml(FORWARD, n_pings=1, n_bins=100, range_max=6.0, beamwidth_h=3.0, beamwidth_v=3.0)
    scene = mitsonar_mod.load_scene(scene_xml(sensor, rectangle_xml(tilted_plane(4.0, 40.0), acoustic_xml(0.8))))
    p = S.lfm(680e3, 720e3, 1e-3)

    def corr(spp):
        a, b = (mitsonar_mod.render_echoes(scene, p, spp=spp, seed=s).signal.ravel() for s in (0, 1))
        return abs(np.vdot(a, b)) / np.linalg.norm(a) / np.linalg.norm(b)

    low, high = corr(2048), corr(65536)
    assert low < 0.5 < 0.85 < high
