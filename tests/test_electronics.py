"""Device electronics: TVG laws, quantisation, noise statistics, range spreading, seeds, settings."""
import dataclasses
import math

import numpy as np
import pytest
from scipy import stats

from mitsonar.receiver.electronics import Electronics, apply_to_scan
from mitsonar.scan import Scan

# Everything random or spreading switched off: the level is the bare formula.
QUIET = dict(speckle="off", noise_floor=-math.inf, ringdown=0.0, pulse_length=0.0, range_jitter=0.0)
RANGES = (np.arange(500) + 0.5) * 0.024  # Micron: 500 bins to 12 m


def micron_like_scan(n_pings=8, intensity=None):
    inten = np.zeros((n_pings, RANGES.size), np.float32) if intensity is None else intensity
    poses = np.tile(np.eye(4), (n_pings, 1, 1))
    return Scan(intensity=inten, data=np.zeros(inten.shape, np.uint8), ranges=RANGES,
                bearings=np.radians(1.8 * np.arange(n_pings)), poses=poses, range_min=0.0, range_max=12.0,
                meta={"seed": 5})


# ------------------------------------------------------------------------------------------------
# TVG and level chain

@pytest.mark.parametrize("law,n", [("20log", 20), ("30log", 30), ("40log", 40)])
def test_tvg_law_matches_formula(law, n):
    r = np.linspace(0.05, 200.0, 4001)
    alpha = 0.05
    e = Electronics(tvg=law, tvg_cap=45.0)
    expect = np.minimum(n * np.log10(r) + 2 * alpha * r, 45.0)
    np.testing.assert_array_equal(e.tvg_db(r, alpha), expect)
    # Spot values: n dB per decade, and the cap.
    assert e.tvg_db([10.0])[0] == pytest.approx(n)
    assert e.tvg_db([1.0])[0] == 0.0
    assert e.tvg_db([1e6])[0] == 45.0


def test_tvg_off_is_zero_even_with_absorption():
    e = Electronics(tvg="off")
    np.testing.assert_array_equal(e.tvg_db(RANGES, absorption=0.3), np.zeros(RANGES.size))


@pytest.mark.parametrize("law", ["off", "20log", "30log", "40log"])
def test_apply_is_the_level_formula_when_quiet(law):
    rng = np.random.default_rng(1)
    inten = (10.0 ** rng.uniform(-9, -3, (4, RANGES.size))).astype(np.float32)
    inten[:, ::7] = 0.0  # open water
    e = Electronics(tvg=law, source_level=210.0, receiver_sensitivity=-160.0, gain=20.0, ad_low=0.0, ad_span=60.0,
                    tvg_cap=30.0, **QUIET)
    data = e.apply(inten, RANGES, absorption=0.02)
    with np.errstate(divide="ignore"):
        level = 10 * np.log10(inten.astype(np.float64)) + 50.0 + 20.0 + e.tvg_db(RANGES, 0.02)
    expect = np.floor(255 * np.clip((level - 0.0) / 60.0, 0, 1) + 0.5).astype(np.uint8)
    np.testing.assert_array_equal(data, expect)
    assert data.dtype == np.uint8 and data.shape == inten.shape
    assert np.all(data[:, ::7] == 0)


# ------------------------------------------------------------------------------------------------
# quantisation

def test_quantisation_edges_exact():
    e = Electronics(ad_low=-100.0, ad_span=255.0, **QUIET)  # one dB per byte: the edges are exact
    levels = [-np.inf, -101.0, -100.0, -99.5, np.nextafter(-99.5, -200), -89.5, np.nextafter(-89.5, -200),
              154.5, np.nextafter(154.5, -200), 155.0, 400.0]
    expect = [0, 0, 0, 1, 0, 11, 10, 255, 254, 255, 255]
    np.testing.assert_array_equal(e.quantise(levels), np.array(expect, np.uint8))


def test_every_half_way_edge_rounds_up():
    e = Electronics(ad_low=0.0, ad_span=255.0, **QUIET)
    k = np.arange(255)
    np.testing.assert_array_equal(e.quantise(k + 0.5), (k + 1).astype(np.uint8))
    # Just below: 1e-12 dB is far below a byte yet above the rounding of (level - low) / span * 255.
    np.testing.assert_array_equal(e.quantise(k + 0.5 - 1e-12), k.astype(np.uint8))


def test_window_ends_through_apply():
    # intensity 1e-3 -> -30 dB; source level + sensitivity = 30 puts it exactly at 0 dB.
    inten = np.full((1, 3), 1e-3)
    ranges = [1.0, 2.0, 3.0]
    at_low = Electronics(source_level=200.0, receiver_sensitivity=-170.0, gain=0.0, tvg="off", ad_low=0.0, ad_span=24.0, **QUIET)
    at_top = Electronics(source_level=200.0, receiver_sensitivity=-170.0, gain=0.0, tvg="off", ad_low=-24.0, ad_span=24.0, **QUIET)
    assert np.all(at_low.apply(inten, ranges) == 0)
    assert np.all(at_top.apply(inten, ranges) == 255)


def test_four_bit_output_is_multiples_of_17():
    e = Electronics(bit_depth=4, ad_low=0.0, ad_span=15.0, **QUIET)  # one dB per level
    levels = np.linspace(-5, 20, 10001)
    q = e.quantise(levels)
    assert set(np.unique(q)) == set(range(0, 256, 17))
    assert q[0] == 0 and q[-1] == 255
    assert list(e.quantise([0.0, 0.5, 1.5, np.nextafter(1.5, 0), 14.5, 15.0])) == [0, 17, 34, 17, 255, 255]
    noisy = Electronics(bit_depth=4).apply(np.full((20, RANGES.size), 1e-6), RANGES, seed=3)
    assert np.all(noisy % 17 == 0) and len(np.unique(noisy)) > 5


# ------------------------------------------------------------------------------------------------
# noise statistics

@pytest.mark.parametrize("shape", [0.8, 1.2, 2.0])
def test_weibull_speckle_fit_recovers_shape_and_scale(shape):
    e = Electronics(speckle="weibull", speckle_shape=shape)
    s = e.speckle_factors((1, 40000), np.random.default_rng(7)).ravel()
    k, loc, scale = stats.weibull_min.fit(s, floc=0)
    assert k == pytest.approx(shape, rel=0.03)
    assert scale == pytest.approx(1.0 / math.gamma(1.0 + 1.0 / shape), rel=0.03)
    assert s.mean() == pytest.approx(1.0, abs=0.02)


def test_rayleigh_speckle_is_unit_exponential():
    e = Electronics(speckle="rayleigh")
    s = e.speckle_factors((4, 25000), np.random.default_rng(11)).ravel()
    assert s.mean() == pytest.approx(1.0, abs=0.015)
    assert s.var() == pytest.approx(1.0, abs=0.04)  # exponential: variance = mean^2
    assert stats.kstest(s, "expon").pvalue > 1e-3
    amp = np.sqrt(s)  # Rayleigh amplitude: mean sqrt(pi)/2
    assert amp.mean() == pytest.approx(math.sqrt(math.pi) / 2, abs=0.01)


def test_speckle_correlated_over_the_pulse_keeps_its_law():
    e = Electronics(speckle="rayleigh", pulse_length=160e-6)
    pulse = Electronics(pulse_length=160e-6, range_jitter=0.0).range_kernel(0.024)
    s = e.speckle_factors((20, 5000), np.random.default_rng(2), pulse)
    assert s.mean() == pytest.approx(1.0, abs=0.02)
    assert s.var() == pytest.approx(1.0, abs=0.06)
    lag1 = np.corrcoef(s[:, :-1].ravel(), s[:, 1:].ravel())[0, 1]
    far = np.corrcoef(s[:, :-10].ravel(), s[:, 10:].ravel())[0, 1]
    assert lag1 > 0.4 and abs(far) < 0.03
    assert np.all(Electronics(speckle="off").speckle_factors((2, 3), np.random.default_rng(0)) == 1.0)


# ------------------------------------------------------------------------------------------------
# pulse and jitter spreading

def _moments(w, bin_width):
    x = np.arange(w.size) * bin_width
    mean = (w * x).sum() / w.sum()
    return mean, math.sqrt((w * (x - mean) ** 2).sum() / w.sum())


def test_pulse_spreads_a_delta_over_c_tau_over_two():
    bw = 0.024
    e = Electronics(pulse_length=2 * 5 * bw / 1500.0, range_jitter=0.0)  # c tau / 2 = 5 bins
    delta = np.zeros((1, 200))
    delta[0, 100] = 3.0
    out = e.spread(delta, (np.arange(200) + 0.5) * bw)[0]
    assert out.sum() == pytest.approx(3.0, rel=1e-12)
    # Boxcar [0, 5 bins) from the echo's bin centre: half bins at both ends.
    np.testing.assert_allclose(out[100:106], 3.0 * np.array([0.1, 0.2, 0.2, 0.2, 0.2, 0.1]), atol=1e-12)
    assert np.all(out[:100] == 0) and np.all(out[106:] == 0)


@pytest.mark.parametrize("tau,sigma", [(0.0, 0.05), (100e-6, 0.02), (300e-6, 0.1)])
def test_pulse_and_jitter_conserve_energy_and_spread_as_expected(tau, sigma):
    bw = 0.024
    ranges = (np.arange(500) + 0.5) * bw
    e = Electronics(pulse_length=tau, range_jitter=sigma)
    delta = np.zeros((2, 500))
    delta[:, 250] = [1e-5, 2.0]
    out = e.spread(delta, ranges)
    np.testing.assert_allclose(out.sum(axis=1), [1e-5, 2.0], rtol=1e-12)
    length = 1500.0 * tau / 2
    mean, std = _moments(out[1], bw)
    assert mean - ranges[250] + 0.5 * bw == pytest.approx(length / 2, abs=0.002)
    # Boxcar and Gaussian variances add; the bin discretisation adds about bw^2 / 12.
    assert std == pytest.approx(math.sqrt(length ** 2 / 12 + sigma ** 2 + bw ** 2 / 12), rel=0.03)


def test_energy_past_the_window_is_dropped_not_folded():
    e = Electronics(pulse_length=200e-6, range_jitter=0.0)
    inten = np.zeros((1, 50))
    inten[0, -1] = 1.0
    out = e.spread(inten, (np.arange(50) + 0.5) * 0.024)
    assert 0.0 < out.sum() < 0.2


# ------------------------------------------------------------------------------------------------
# seeds, inputs, defaults

def _box_like():
    inten = np.zeros((30, RANGES.size), np.float32)
    inten[:, 166:175] = 1e-5  # a wall at 4 m
    inten[:, 80:160] = 3e-7  # floor returns
    return inten


def test_same_seed_same_bytes_different_seed_different_bytes():
    e = Electronics()
    inten = _box_like()
    before = inten.copy()
    a, b, c = e.apply(inten, RANGES, seed=1), e.apply(inten, RANGES, seed=1), e.apply(inten, RANGES, seed=2)
    assert a.tobytes() == b.tobytes()
    assert a.tobytes() != c.tobytes()
    np.testing.assert_array_equal(inten, before)  # the input is never modified


def test_one_ping_and_input_checks():
    e = Electronics()
    one = e.apply(_box_like()[0], RANGES, seed=4)
    assert one.shape == (RANGES.size,) and one.dtype == np.uint8
    with pytest.raises(ValueError, match="finite and >= 0"):
        e.apply(-np.ones((1, 3)), [1.0, 2.0, 3.0])
    with pytest.raises(ValueError, match="do not match"):
        e.apply(np.ones((2, 4)), [1.0, 2.0, 3.0])
    with pytest.raises(ValueError, match="evenly spaced"):
        e.apply(np.ones((1, 3)), [1.0, 2.0, 5.0])


def test_defaults_look_like_a_micron():
    """Open water speckled with zeros and Weibull-like bytes, a short ring-down, walls saturated,
    floor returns in the window: inside the ranges measured on a real Micron's recordings
    (beyond 1.6 m 14-51 % zero bytes, Weibull shape of the others 1.05-1.54; 0.1-1.0 m mean byte 60-96)."""
    e = Electronics()
    inten = _box_like()
    data = e.apply(np.concatenate([np.zeros((170, RANGES.size), np.float32), inten]), RANGES, seed=0)
    water = data[:170, RANGES > 1.6].astype(float)
    assert 0.14 <= np.mean(water == 0) <= 0.51
    far = data[:, RANGES > 1.6].astype(float)   # open water and the box's echoes
    k, _, _ = stats.weibull_min.fit(far[far > 0], floc=0)
    assert 1.05 <= k <= 1.54
    profile = data[:170].mean(axis=0)
    background = profile[RANGES > 2.0].mean()

    def at(r):
        return profile[np.abs(RANGES - r) < 0.05].mean()

    assert 60 <= data[:170, (RANGES >= 0.1) & (RANGES <= 1.0)].mean() <= 96
    assert at(0.2) > background + 60 and at(0.4) > background + 15
    assert at(0.9) < background + 5
    wall = data[170:, 166:175]
    assert np.mean(wall == 255) > 0.6
    floor = data[170:, 80:160]
    assert 40 < floor.mean() < 200


def test_fields_are_the_xml_contract():
    types = {f.name: f.type for f in dataclasses.fields(Electronics)}
    for name in ("source_level", "receiver_sensitivity", "noise_level", "receiver_bandwidth", "tvg", "tvg_cap", "gain", "ad_low", "ad_span", "bit_depth", "pulse_length",
                 "range_jitter", "speckle", "speckle_shape", "noise_floor", "ringdown"):
        assert name in types
    for f in dataclasses.fields(Electronics):
        kind = {"float": float, "int": int, "str": str}[f.type if isinstance(f.type, str) else f.type.__name__]
        assert type(f.default) is kind, f.name


# ------------------------------------------------------------------------------------------------
# settings

@pytest.mark.parametrize("field,value,allowed", [
    ("tvg", "35log", "is not one of off, 20log, 30log, 40log"),
    ("speckle", "gamma", "is not one of off, rayleigh, weibull"),
    ("bit_depth", 6, "is not one of 8, 4"),
    ("bit_depth", 8.5, "is not an integer"),
    ("ad_span", 0.0, "is not a span > 0 dB"),
    ("speckle_shape", 0.0, "is not a Weibull shape"),
    ("pulse_length", -1e-6, "is not a duration"),
    ("range_jitter", -0.1, "is not a standard deviation"),
    ("ringdown", -1.0, "is not a range >= 0 m"),
    ("noise_floor", math.nan, "is not a finite level"),
    ("source_level", math.inf, "is not a finite number"),
    ("receiver_sensitivity", math.nan, "is not a finite number"),
    ("receiver_bandwidth", -1.0, "is not a bandwidth >= 0 Hz"),
    ("gain", "high", "is not a number"),
    ("tvg", 20, "is not a string"),
    ("ringdown_level", 0.0, "above ad_low"),
])
def test_invalid_settings_name_field_value_and_allowed(field, value, allowed):
    with pytest.raises(ValueError) as err:
        Electronics(**{field: value})
    msg = str(err.value)
    assert msg.startswith(f"sonar '{field}': {value!r} ")
    assert allowed in msg


def test_exact_message_and_source_prefix():
    with pytest.raises(ValueError, match=r"^sonar 'tvg': '35log' is not one of off, 20log, 30log, 40log$"):
        Electronics(tvg="35log")
    e = Electronics()
    e.bit_depth = 12
    with pytest.raises(ValueError, match=r"^box\.xml 'bit_depth': 12 "):
        e.validate(source="box.xml")
    with pytest.raises(ValueError, match="'gian' is not an electronics setting"):
        Electronics.from_dict({"gian": 3.0})


def test_lossless_coercions():
    e = Electronics(bit_depth=4.0, gain=3, noise_floor=-math.inf, speckle_shape=np.float32(2.0))
    assert type(e.bit_depth) is int and e.bit_depth == 4
    assert type(e.gain) is float and e.gain == 3.0
    assert type(e.speckle_shape) is float
    assert Electronics.from_dict({**e.to_dict(), "seed": 9}) == e


# ------------------------------------------------------------------------------------------------

def test_apply_to_scan_returns_a_recorded_copy():
    scan = micron_like_scan(30, _box_like())
    before = scan.intensity.copy()
    out = apply_to_scan(scan, {"gain": 20.0}, seed=3)
    assert out is not scan and np.all(scan.data == 0)
    np.testing.assert_array_equal(scan.intensity, before)
    np.testing.assert_array_equal(out.intensity, before)
    assert out.electronics.gain == 20.0 and out.electronics.seed == 3
    np.testing.assert_array_equal(out.data, Electronics(gain=20.0).apply(before, RANGES, seed=3))
    # Re-applying the recorded settings and seed reproduces the bytes.
    again = apply_to_scan(out)
    assert again.data.tobytes() == out.data.tobytes()
    # No seed anywhere but the meta's: it is used.
    assert apply_to_scan(scan).electronics.seed == 5
