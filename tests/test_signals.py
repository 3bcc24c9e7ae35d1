"""Pulses, matched filtering, beamforming and interferometry against their closed forms (numpy only)."""
import numpy as np
import pytest

from mitsonar import signals as S

C = 1500.0


def echo(pulse, fs, n, positions, amplitudes=None, elements=((0.0, 0.0, 0.0),), velocity=None, t_start=0.0):
    """Element data of point scatterers at ``positions`` (world = beam frame), transmitter at the origin."""
    x = np.atleast_2d(np.asarray(positions, float))
    a = np.ones(len(x)) if amplitudes is None else amplitudes
    return S.synthesize(a, x, np.linalg.norm(x, axis=1), np.asarray(elements, float), np.zeros(3), pulse, fs, n, C,
                        velocity=velocity, t_start=t_start)


def width_3db(power, step):
    """Full width at half power of the main lobe around the peak, with linear interpolation at the edges."""
    k = int(np.argmax(power))
    half = 0.5 * power[k]
    lo = k
    while power[lo - 1] > half:
        lo -= 1
    hi = k
    while power[hi + 1] > half:
        hi += 1
    left = lo - (power[lo] - half) / (power[lo] - power[lo - 1])
    right = hi + (power[hi] - half) / (power[hi] - power[hi + 1])
    return (right - left) * step


@pytest.mark.parametrize("window", [None, "hann"])
def test_pulse_fields_and_baseband(window):
    p = S.lfm(90e3, 110e3, 2e-3, window=window)
    assert p.carrier == 100e3 and p.bandwidth == 20e3 and p.duration == 2e-3
    s = p.samples(80e3)
    assert len(s) == 160 and s.dtype == np.complex128
    # instantaneous baseband frequency sweeps -B/2 .. +B/2
    f = np.diff(np.unwrap(np.angle(p.baseband(np.linspace(0, 2e-3, 4001, endpoint=False))))) / (2e-3 / 4000) / (2 * np.pi)
    assert f[0] == pytest.approx(-10e3, abs=20) and f[-1] == pytest.approx(10e3, abs=20)
    q = S.cw(100e3, 1e-3)
    assert q.carrier == 100e3 and q.bandwidth == pytest.approx(1e3) and q.default_sample_rate() == pytest.approx(4e3)


def test_lfm_compresses_to_0886_c_over_2b_at_the_target_range():
    p = S.lfm(90e3, 110e3, 2e-3)
    fs = 16 * p.bandwidth
    R = 3.0
    y = S.matched_filter(echo(p, fs, int(0.006 * fs), [(R, 0, 0)]), p, fs)[0]
    power = np.abs(y) ** 2
    k = int(np.argmax(power))
    assert abs(k - 2 * R / C * fs) <= 1                        # at the target's range, within one sample
    assert abs(y[k]) == pytest.approx(1.0, rel=1e-3)            # an echo a s(t - tau) compresses to a
    width = width_3db(power, C / (2 * fs))                      # m
    assert width == pytest.approx(0.886 * C / (2 * p.bandwidth), rel=0.10)


def test_cw_compresses_to_the_rectangles_triangle():
    T, fs = 1e-3, 64e3
    p = S.cw(100e3, T)
    y = S.matched_filter(echo(p, fs, 400, [(1.5, 0, 0)]), p, fs)[0]
    k0 = int(round(2 * 1.5 / C * fs))
    lag = (np.arange(len(y)) - k0) / fs
    tri = np.clip(1 - np.abs(lag) / T, 0, None)
    assert np.max(np.abs(np.abs(y) - tri)) < 0.02
    assert S.equivalent_duration(p, fs) == pytest.approx(2 * T / 3, rel=0.02)   # int (1 - |t|/T)^2 dt


@pytest.mark.parametrize("phi_deg", [0.0, 30.0])
def test_line_array_beam_peaks_at_the_target_with_0886_lambda_over_n_d_cos_phi(phi_deg):
    f, N = 100e3, 32
    lam = C / f
    e = S.line_array(N, frequency=f, sound_speed=C)
    d = lam / 2
    assert np.allclose(np.diff(e[:, 0]), d) and np.all(e[:, 1:] == 0)
    phi = np.radians(phi_deg)
    p, fs = S.cw(f, 1e-3), 40e3
    far = 1000.0
    x = echo(p, fs, 120, [far * S.look_directions(phi)], elements=e, t_start=2 * far / C - 5e-4)
    bw = 0.886 * lam / (N * d * np.cos(phi))
    b = phi + np.linspace(-3 * bw, 3 * bw, 1201)
    power = np.max(np.abs(S.delay_and_sum(x, e, S.look_directions(b), fs, f, C)) ** 2, axis=1)
    assert abs(b[np.argmax(power)] - phi) < 0.1 * bw
    assert width_3db(power, b[1] - b[0]) == pytest.approx(bw, rel=0.10)


def test_two_targets_a_few_beam_widths_apart_are_separated_at_their_azimuths():
    f, N = 100e3, 32
    e = S.line_array(N, frequency=f, sound_speed=C)
    bw = 0.886 * (C / f) / (N * C / f / 2)
    az = np.array([-2.0 * bw, 1.5 * bw])
    p, fs = S.lfm(95e3, 105e3, 1e-3), 40e3
    R = 20.0
    x = echo(p, fs, 1200, R * S.look_directions(az), amplitudes=np.array([1.0, 0.7j]), elements=e)
    y = S.matched_filter(x, p, fs)
    b = np.linspace(-5 * bw, 5 * bw, 401)
    k = int(round(2 * R / C * fs))
    prof = np.abs(S.delay_and_sum(y, e, S.look_directions(b), fs, f, C)[:, k]) ** 2
    from scipy.signal import find_peaks

    peaks, _ = find_peaks(prof, height=0.25 * prof.max())
    assert len(peaks) == 2
    assert np.allclose(b[peaks], az, atol=0.1 * bw)
    assert prof[(b > az[0] + bw * 0.9) & (b < az[1] - bw * 0.9)].max() < 0.25 * prof.max()   # a valley between


@pytest.mark.parametrize("psi_deg", [-40.0, -10.0, 5.0, 25.0, 50.0])
def test_interferometric_phase_is_2pi_b_sin_psi_over_lambda(psi_deg):
    f = 100e3
    lam = C / f
    b = 0.4 * lam
    e = S.interferometer(2, spacing=b, frequency=f, sound_speed=C)
    psi = np.radians(psi_deg)
    u = np.array([0.0, np.sin(psi), np.cos(psi)])
    p, fs = S.lfm(95e3, 105e3, 1e-3), 40e3
    x = S.matched_filter(echo(p, fs, 800, [5.0 * u], elements=e), p, fs)
    k = int(np.argmax(np.abs(x[0])))
    dphi = S.phase_difference(x[0, k], x[1, k])
    assert dphi == pytest.approx(2 * np.pi * b * np.sin(psi) / lam, abs=0.01)
    assert S.arrival_angle(x[0, k], x[1, k], b, lam) == pytest.approx(psi, abs=0.005)


def test_doppler_of_a_head_closing_on_a_point_is_2vf_over_c():
    f, v = 200e3, 3.0
    p, fs = S.cw(f, 4e-3), 20e3
    x = echo(p, fs, 1000, [(10.0, 0, 0)], velocity=(v, 0, 0))[0]
    on = np.abs(x) > 0.5
    shift = np.angle(np.sum((x[1:] * np.conj(x[:-1]))[on[1:] & on[:-1]])) * fs / (2 * np.pi)
    assert shift == pytest.approx(2 * v * f / C, rel=0.03)
    still = echo(p, fs, 1000, [(10.0, 0, 0)])[0]
    assert np.angle(np.sum(still[1:] * np.conj(still[:-1]))) == pytest.approx(0.0, abs=1e-9)


def test_mean_power_of_random_phase_scatterers_is_intensity_convolved_with_autocorrelation():
    rng = np.random.default_rng(4)
    p, fs = S.lfm(95e3, 105e3, 1e-3), 20e3
    r = rng.uniform(2.0, 2.5, 60)
    pos = np.stack([r, np.zeros_like(r), np.zeros_like(r)], axis=1)
    energy = rng.uniform(0.5, 1.5, 60)
    n = 300
    runs = []
    for _ in range(200):
        a = np.sqrt(energy) * np.exp(2j * np.pi * rng.uniform(size=60))
        runs.append(np.abs(S.matched_filter(echo(p, fs, n, pos, a), p, fs)[0]) ** 2)
    runs = np.array(runs)
    t = np.arange(n) / fs
    expected = S.expected_power(t, 2 * r / C, energy, p, fs)
    core = expected > 0.2 * expected.max()
    sem = runs.std(axis=0) / np.sqrt(len(runs))
    z = (runs.mean(axis=0) - expected)[core] / sem[core]
    assert np.mean(np.abs(z) < 3) > 0.95


def test_bad_pulses_and_element_layouts_are_refused_in_one_line():
    with pytest.raises(ValueError, match=r"pulse 'duration': -1 is not allowed \(a duration > 0 s\)"):
        S.cw(100e3, -1)
    with pytest.raises(ValueError, match="pulse 'window'"):
        S.lfm(90e3, 110e3, 1e-3, window="kaiser")
    with pytest.raises(ValueError, match="pulse 'f_stop'"):
        S.lfm(90e3, 90e3, 1e-3)
    with pytest.raises(ValueError, match=r"'elements': element 1 is \[nan, 0.0, 0.0\]"):
        S.check_elements([[0, 0, 0], [np.nan, 0, 0]])
    with pytest.raises(ValueError, match="elements 0 and 2 overlap"):
        S.check_elements([[0, 0, 0], [0.01, 0, 0], [0, 0, 0]])
    with pytest.raises(ValueError, match=r"shape \(3,\) is not allowed"):
        S.check_elements([0, 0, 0])


def test_elements_read_from_csv(tmp_path):
    path = tmp_path / "array.csv"
    path.write_text("x,y,z\n0,0,0\n0.001,0,0\n")
    assert S.read_elements(path).tolist() == [[0, 0, 0], [0.001, 0, 0]]
    path.write_text("x,y,z\n0,0,0\n0,0,0\n")
    with pytest.raises(ValueError, match="array.csv 'elements': elements 0 and 1 overlap"):
        S.read_elements(path)


@pytest.mark.parametrize("window", [None, "hann"])
def test_drjit_and_numpy_synthesis_agree(window, monkeypatch):
    from mitsonar.signals import synthesis

    rng = np.random.default_rng(2)
    pos = np.stack([rng.uniform(2, 4, 50), rng.uniform(-1, 1, 50), rng.uniform(-1, 1, 50)], axis=1)
    a = rng.normal(size=50) + 1j * rng.normal(size=50)
    p = S.lfm(95e3, 105e3, 1e-3, window=window)
    e = S.line_array(8, frequency=100e3)
    args = (a, pos, np.linalg.norm(pos, axis=1), e, np.zeros(3), p, 40e3, 400, C)
    fast = S.synthesize(*args, velocity=(1.0, 0.5, 0.0))
    monkeypatch.setattr(synthesis, "USE_DRJIT", False)
    slow = S.synthesize(*args, velocity=(1.0, 0.5, 0.0))
    assert np.abs(fast).max() > 1
    np.testing.assert_allclose(fast, slow, atol=1e-5 * np.abs(slow).max())
