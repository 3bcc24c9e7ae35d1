"""The receiver chain as Dr.Jit kernels (`mitsonar.receiver.devicechain`, issue 55): its bytes are
the NumPy oracle's (tests/numpy_chain.py, the chain before version 0.3) given the same draws and
speckle; its counter-based noise is a unit circular complex Gaussian, the same for any thread
count; a new seed or frame replays the compiled kernels."""
import math
import os

import numpy as np
import pytest

import numpy_chain
from conftest import jit_kernels
from test_frame_overhead import CONFIGS, QUAY, chain_inputs


def oracle(model, inten, ranges, seed, speckle=None, absorption=0.02, sound_speed=1500.0):
    """`Electronics.apply`'s bytes computed by the NumPy oracle from the device's own draws."""
    from mitsonar.receiver import devicechain
    from mitsonar.receiver.electronics import _bin_width

    inten = np.array(inten, dtype=np.float64, ndmin=2)
    n_rows, n_bins = inten.shape
    bw = _bin_width(ranges)
    corr = model._noise_corr(bw, sound_speed)
    kernel = model.range_kernel(bw, sound_speed) if bw > 0 else np.ones(1)
    h = devicechain.taps(corr)
    width = n_bins + h.size - 1

    def drawn(stream):
        re, im = devicechain.draws(seed, stream, n_rows, width)
        return np.stack([re.numpy(), im.numpy()], axis=-1).reshape(n_rows, width, 2)

    if model.speckle == "off":
        g = np.ones(inten.shape, dtype=np.complex128)
    else:
        if speckle is None:
            re, im = numpy_chain.filtered(drawn(devicechain.STREAM_SPECKLE), h, n_bins)
            g = re + 1j * im
        else:
            g = np.array(speckle, dtype=np.complex128).reshape(inten.shape)
        if model.speckle == "weibull":
            k = model.speckle_shape
            p = g.real ** 2 + g.imag ** 2
            with np.errstate(divide="ignore", invalid="ignore"):
                g = g * np.where(p > 0, p ** (0.5 / k - 0.5), 0.0) / math.sqrt(math.gamma(1.0 + 1.0 / k))
    calibration = model.source_level + model.receiver_sensitivity
    tvg = model.tvg_db(ranges, absorption)
    chain = calibration + model.gain + tvg
    ring = np.sqrt(10.0 ** ((model.ringdown_db(ranges) - chain) / 10.0)) if model.ringdown > 0 else None
    z = f = None
    if model.noise_floor > -math.inf:
        z = drawn(devicechain.STREAM_NOISE)
        f = math.sqrt(10.0 ** (model.noise_floor / 10.0)) * 10.0 ** (-chain / 20.0)
    quiet = ring is None and z is None
    return numpy_chain.received_bytes(inten, g, kernel, quiet, ring, z, h, f, (calibration, model.gain, tvg),
                                      (model.ad_low, model.ad_span, model.bit_depth))


def agree(got, want):
    """The kernel's bytes are the oracle's but where a level lies within rounding of a step's
    half (the kernel's log2 against NumPy's log10): at most one step apart, in under 1e-3 of
    the bins."""
    assert got.dtype == np.uint8 and got.shape == want.shape
    diff = np.abs(got.astype(np.int32) - want.astype(np.int32))
    assert np.all((diff == 0) | (diff == 1) | (diff == 17))
    assert np.count_nonzero(diff) <= max(1, 1e-3 * diff.size)


@pytest.mark.parametrize("settings", CONFIGS)
@pytest.mark.parametrize("drawn", [False, True])
def test_kernel_chain_gives_the_numpy_oracle_bytes(mitsonar_mod, settings, drawn):
    """Every setting (speckle drawn or the scene's, Weibull, no ring-down, no noise, 4 bits, no
    pulse, a fixed gain), a scan and one ping: the oracle's bytes from the same draws."""
    from mitsonar.receiver.electronics import Electronics

    model = Electronics.from_dict(settings)
    inten, ranges, poses = chain_inputs()
    sp = None
    if not drawn and model.speckle != "off":
        sp = model.scene_speckle(poses, ranges, sound_speed=1500.0, beamwidth_h=1.0, aperture_h=0.03)
    got = model.apply(inten, ranges, absorption=0.02, seed=11, speckle=sp)
    agree(got, oracle(model, inten, ranges, 11, sp))
    assert len(np.unique(got)) > 3
    one = model.apply(inten[6], ranges, absorption=0.02, seed=11, speckle=None if sp is None else sp[6])
    agree(one[None], oracle(model, inten[6], ranges, 11, None if sp is None else sp[6]))


def test_counter_based_noise_is_a_unit_circular_complex_gaussian(mitsonar_mod):
    """The noise draws: power exponential of mean 1 (P(>1) = e^-1, P(>4) = e^-4), real and
    imaginary parts uncorrelated with variance 1/2, neighbours independent; another seed or
    stream other numbers."""
    from mitsonar.receiver import devicechain

    re, im = (a.numpy() for a in devicechain.draws(7, devicechain.STREAM_NOISE, 200, 1000))
    p = re ** 2 + im ** 2
    assert abs(p.mean() - 1) < 0.01
    assert abs(np.mean(p > 1) - math.exp(-1)) < 0.004 and abs(np.mean(p > 4) - math.exp(-4)) < 0.001
    assert abs(re.var() - 0.5) < 0.01 and abs(im.var() - 0.5) < 0.01
    assert abs(np.corrcoef(re, im)[0, 1]) < 0.01 and abs(np.corrcoef(re[:-1], re[1:])[0, 1]) < 0.01
    other = devicechain.draws(8, devicechain.STREAM_NOISE, 200, 1000)[0].numpy()
    stream = devicechain.draws(7, devicechain.STREAM_SPECKLE, 200, 1000)[0].numpy()
    assert abs(np.corrcoef(re, other)[0, 1]) < 0.01 and abs(np.corrcoef(re, stream)[0, 1]) < 0.01
    # a bin's draw depends on its counter only: a wider frame holds the narrower one's numbers
    wide = devicechain.draws(7, devicechain.STREAM_NOISE, 3, 1500)[0].numpy().reshape(3, 1500)
    np.testing.assert_array_equal(wide[:, :1000], re.reshape(200, 1000)[:3])


@pytest.mark.parametrize("threads", [1, 2, 4])
def test_chain_bytes_are_the_same_with_any_thread_count(mitsonar_mod, threads):
    """The same seed and intensity give the same bytes, scene speckle field included, whatever
    Dr.Jit's thread count."""
    import drjit as dr

    from mitsonar.receiver import speckle
    from mitsonar.receiver.electronics import Electronics

    model = Electronics()
    inten, ranges, poses = chain_inputs(n_rows=64, n_bins=700)
    before = dr.thread_count()
    speckle._cache.clear()
    try:
        dr.set_thread_count(threads)
        sp = model.scene_speckle_field(poses, ranges, sound_speed=1500.0, beamwidth_h=1.0, aperture_h=0.03)
        got = (model.apply(inten, ranges, seed=5, speckle=sp), sp.numpy().copy())
    finally:
        dr.set_thread_count(before)
        speckle._cache.clear()
    sp = model.scene_speckle_field(poses, ranges, sound_speed=1500.0, beamwidth_h=1.0, aperture_h=0.03)
    np.testing.assert_array_equal(got[1].view(np.uint64), sp.numpy().view(np.uint64))
    np.testing.assert_array_equal(got[0], model.apply(inten, ranges, seed=5, speckle=sp))


def test_kernel_chain_compiles_once_for_new_frames(mitsonar_mod):
    """A new seed or new intensities of the same shape replay the compiled kernels."""
    from mitsonar.receiver.electronics import Electronics

    model = Electronics.from_dict({})
    inten, ranges, poses = chain_inputs()
    sp = model.scene_speckle(poses, ranges, sound_speed=1500.0, beamwidth_h=1.0, aperture_h=0.03)
    model.apply(inten, ranges, seed=1, speckle=sp)
    first, _ = jit_kernels(lambda: model.apply(inten * 2.0, ranges, seed=2, speckle=sp))
    again, fresh = jit_kernels(lambda: model.apply(inten * 3.0, ranges, seed=3, speckle=sp))
    assert first and sorted(again) == sorted(first) and not fresh


def test_kernel_chain_compiles_one_way_whatever_the_host_alignment(mitsonar_mod):
    """Intensities and speckle placed at every 8-byte offset from a 256-byte boundary (NumPy's
    allocations land anywhere; Dr.Jit may map host memory on llvm): one set of kernels for all,
    and the same bytes."""
    from mitsonar.receiver.electronics import Electronics

    model = Electronics.from_dict({})
    inten, ranges, poses = chain_inputs(n_rows=16, n_bins=300)
    rng = np.random.default_rng(3)
    g = rng.normal(size=inten.shape) + 1j * rng.normal(size=inten.shape)

    def placed(a, k):
        raw = np.empty(a.nbytes + 512, dtype=np.uint8)
        start = -raw.ctypes.data % 256 + 8 * k
        out = raw[start:start + a.nbytes].view(a.dtype).reshape(a.shape)
        out[...] = a
        return out

    model.apply(placed(inten, 0), ranges, seed=1, speckle=placed(g, 0))
    hashes, results = [], []
    for k in range(8):
        args = placed(inten, k), placed(g, k)
        h, _ = jit_kernels(lambda: results.append(model.apply(args[0], ranges, seed=1, speckle=args[1])))
        hashes.append(sorted(h))
    assert all(h == hashes[0] for h in hashes)
    assert all(np.array_equal(r, results[0]) for r in results)


def test_speckle_drawn_from_the_seed_keeps_its_law(mitsonar_mod):
    """``speckle_factors`` (the speckle `apply` draws without a scene field) has mean 1 and the
    exponential or Weibull law, correlated over the pulse like the noise."""
    from mitsonar.receiver.electronics import Electronics

    s = Electronics(speckle="rayleigh").speckle_factors((10, 20000), 4).ravel()
    assert abs(s.mean() - 1) < 0.02 and abs(np.mean(s > 1) - math.exp(-1)) < 0.005
    assert np.array_equal(s, Electronics(speckle="rayleigh").speckle_factors((10, 20000), 4).ravel())
    assert not np.array_equal(s, Electronics(speckle="rayleigh").speckle_factors((10, 20000), 5).ravel())


@pytest.mark.parametrize("shape", [(1, 1), (1, 500), (3, 1), (2, 20000)])
def test_frames_of_one_bin_one_beam_or_many_bins(mitsonar_mod, shape):
    """Edge shapes render: one bin (no spread, no correlation), one row, 20 000 bins."""
    from mitsonar.receiver.electronics import Electronics

    n_rows, n_bins = shape
    ranges = np.linspace(0.5, 20.0, n_bins) if n_bins > 1 else np.array([3.0])
    inten = np.full(shape, 1e-6, dtype=np.float32)
    data = Electronics().apply(inten, ranges, seed=2)
    assert data.shape == shape and data.dtype == np.uint8 and data.max() > 0
    np.testing.assert_array_equal(data, Electronics().apply(inten, ranges, seed=2))


def test_bad_seeds_and_variants_are_refused_in_one_line(mitsonar_mod, monkeypatch):
    from mitsonar.receiver import devicechain
    from mitsonar.receiver.electronics import Electronics

    inten, ranges = np.zeros((2, 5)), np.linspace(1, 2, 5)
    for bad in (-1, 2 ** 64, 1.5, True, "3"):
        with pytest.raises(ValueError, match=r"^electronics: seed .* is not allowed \(a whole number from 0 to "
                                             r"2\^64 - 1, or None\)$"):
            Electronics().apply(inten, ranges, seed=bad)
    a, b = Electronics().apply(inten, ranges, seed=None), Electronics().apply(inten, ranges, seed=2 ** 64 - 1)
    assert a.shape == b.shape == (2, 5)
    monkeypatch.setattr(devicechain, "variant", lambda: "scalar_rgb")
    with pytest.raises(ValueError, match=r"^electronics: the receiver chain runs as Dr.Jit kernels of an llvm or "
                                         r"cuda variant; the active Mitsuba variant is scalar_rgb$"):
        Electronics().apply(inten, ranges)


def test_render_frame_keeps_the_frame_on_the_device_and_is_render_scans_scan(mitsonar_mod):
    """`render_frame` hands Dr.Jit arrays of the active variant (intensity float32, bytes uint8)
    that are, brought to the host, `render_scan`'s intensity and bytes bit for bit."""
    import drjit as dr
    import mitsuba as mi

    from mitsonar.sim.render import render_frame

    scene = mitsonar_mod.load_scene(QUAY)
    frame = render_frame(scene, spp=4, seed=3)
    assert isinstance(frame.intensity, mi.Float32) and isinstance(frame.data, mi.UInt8)
    assert dr.width(frame.data) == frame.shape[0] * frame.shape[1]
    scan = mitsonar_mod.render_scan(scene, spp=4, seed=3)
    inten, data = frame.numpy()
    assert frame.shape == scan.intensity.shape
    np.testing.assert_array_equal(inten.view(np.uint32), scan.intensity.view(np.uint32))
    np.testing.assert_array_equal(data, scan.data)
    assert data.any()


@pytest.mark.parametrize("kw", [dict(n_bins=1, n_pings=3), dict(kind="multibeam", n_pings=1, n_bins=300),
                                dict(n_bins=20000, n_pings=2)])
def test_edge_frames_render_on_the_device(mitsonar_mod, kw):
    """A frame of one bin, of one beam, of 20 000 bins renders through the device chain."""
    from conftest import scene_xml, sonar_xml

    from mitsonar.sim.render import render_frame

    scene = mitsonar_mod.load_scene(scene_xml(sonar_xml(**kw)))
    frame = render_frame(scene, spp=2, seed=1)
    inten, data = frame.numpy()
    assert data.shape == inten.shape == frame.shape and frame.shape[1] == kw["n_bins"]
    np.testing.assert_array_equal(data, render_frame(scene, spp=2, seed=1).numpy()[1])


def test_16384_beams_are_refused_in_one_line_before_any_work(mitsonar_mod):
    from conftest import scene_xml, sonar_xml

    with pytest.raises(Exception) as err:
        mitsonar_mod.load_scene(scene_xml(sonar_xml(kind="multibeam", n_pings=16384, bearing_step=0.005)))
    msg = str(err.value)
    assert "\n" not in msg and "'n_pings': 16384 is not allowed (a whole number of receive beams from 1 to 4096" in msg


def test_an_empty_frame_gives_empty_bytes(mitsonar_mod):
    from mitsonar.receiver.electronics import Electronics

    data = Electronics().apply(np.zeros((0, 5)), np.linspace(1.0, 2.0, 5), seed=1)
    assert data.shape == (0, 5) and data.dtype == np.uint8


def test_a_scene_without_shapes_renders_after_another_scene(mitsonar_mod):
    """An empty scene's frozen pass, recorded after another scene's render, dispatched its ray
    casts over that scene's shapes, which Dr.Jit refused to record: such a scene is traced."""
    from conftest import scene_xml, sonar_xml

    box = mitsonar_mod.load_scene(os.path.join(os.path.dirname(QUAY), "box.xml"))
    mitsonar_mod.render_scan(box, spp=4, seed=3)
    empty = mitsonar_mod.load_scene(scene_xml(sonar_xml(n_bins=50, n_pings=3)))
    scan = mitsonar_mod.render_scan(empty, spp=2, seed=1)
    assert scan.data.shape == (3, 50) and not scan.intensity.any()
