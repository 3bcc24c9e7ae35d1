"""Issue "Frame overhead": the fast receiver chain (float64 parts, blocks of rows, reused buffers)
and the cached speckle field give the straightforward chain's bytes, kept in the same run as the
reference (``electronics.FAST = False``, ``speckle.CACHE_SIZE = 0``); frames replay their kernels
without compiling anew."""
import os

import numpy as np
import pytest

from mitsonar._compat import trapezoid

from conftest import jit_kernels

HERE = os.path.dirname(os.path.abspath(__file__))
QUAY = os.path.join(HERE, "..", "scenes_xml", "quay_wall.xml")

CONFIGS = [{}, {"speckle": "weibull", "speckle_shape": 1.5}, {"ringdown": 0.0}, {"noise_floor": -np.inf, "ringdown": 0.0},
           {"noise_floor": -np.inf}, {"bit_depth": 4}, {"pulse_length": 0.0, "range_jitter": 0.0},
           {"speckle": "off"}, {"tvg": "off", "gain": 30.0}]


@pytest.fixture(autouse=True)
def numpy_chain(monkeypatch):
    """These tests are about the NumPy chain (`fastchain`: its blocks, spreads, buffers); the
    kernel chain that `auto` takes for frames has its own (tests/test_jitchain.py)."""
    from mitsonar.receiver import jitchain

    monkeypatch.setattr(jitchain, "CHAIN", "numpy")


def chain_inputs(n_rows=45, n_bins=120, seed=1):
    rng = np.random.default_rng(seed)
    inten = rng.exponential(1e-9, (n_rows, n_bins)) * (rng.random((n_rows, n_bins)) < 0.3)
    inten[3] = 0.0                                   # a silent row
    inten[5, 7] = 1e3                                # a bin saturating the A/D
    ranges = np.linspace(0.5, 15.0, n_bins)
    poses = np.tile(np.eye(4), (n_rows, 1, 1))
    poses[:, 0, 3] = np.arange(n_rows) * 0.01
    return inten.astype(np.float32), ranges, poses


def chain(model, inten, ranges, poses, fast, monkeypatch, drawn=False):
    from mitsonar.receiver import electronics, speckle

    monkeypatch.setattr(electronics, "FAST", fast)
    monkeypatch.setattr(speckle, "CACHE_SIZE", 4 if fast else 0)
    sp = None
    if model.speckle != "off" and not drawn:
        sp = model.scene_speckle(poses, ranges, sound_speed=1500.0, beamwidth_h=1.0, aperture_h=0.03)
    return model.apply(inten, ranges, absorption=0.02, seed=11, speckle=sp)


@pytest.mark.parametrize("settings", CONFIGS)
@pytest.mark.parametrize("drawn", [False, True])
def test_fast_chain_gives_the_reference_bytes(mitsonar_mod, monkeypatch, settings, drawn):
    """Every setting, scene speckle or speckle drawn from the seed, a row count that is not a
    multiple of the block (several blocks): the same bytes as the straightforward chain."""
    from mitsonar.receiver import fastchain
    from mitsonar.receiver.electronics import Electronics

    monkeypatch.setattr(fastchain, "ROW_BLOCK", 8)
    model = Electronics.from_dict(settings)
    inten, ranges, poses = chain_inputs()
    ref = chain(model, inten, ranges, poses, False, monkeypatch, drawn)
    fast = chain(model, inten, ranges, poses, True, monkeypatch, drawn)
    again = chain(model, inten, ranges, poses, True, monkeypatch, drawn)   # a cached speckle field
    assert ref.dtype == fast.dtype == np.uint8
    np.testing.assert_array_equal(fast, ref)
    np.testing.assert_array_equal(again, ref)
    assert len(np.unique(ref)) > 3                  # not a blank scan
    one = chain(model, inten[6], ranges, poses[6:7], True, monkeypatch, drawn)   # one ping, 1-D
    np.testing.assert_array_equal(one, chain(model, inten[6], ranges, poses[6:7], False, monkeypatch, drawn))
    assert one.shape == (inten.shape[1],)


def test_fast_chain_leaves_its_inputs_alone(mitsonar_mod, monkeypatch):
    from mitsonar.receiver.electronics import Electronics

    inten, ranges, poses = chain_inputs()
    keep = inten.copy()
    chain(Electronics.from_dict({}), inten, ranges, poses, True, monkeypatch)
    np.testing.assert_array_equal(inten, keep)


def test_speckle_cache_returns_the_computed_field_read_only(mitsonar_mod, monkeypatch):
    from mitsonar.receiver import speckle

    _, ranges, poses = chain_inputs()
    kw = dict(seed=4, beamwidth_h=1.0, aperture_h=0.03, resolution=0.075)
    monkeypatch.setattr(speckle, "_cache", {})
    first = speckle.cell_speckle(poses, ranges, **kw)
    assert speckle.cell_speckle(poses, ranges, **kw) is first      # looked up, not recomputed
    np.testing.assert_array_equal(first, speckle._field(poses, ranges, 4, 1.0, 0.03, 0.075, speckle.N_FEATURES))
    with pytest.raises(ValueError):
        first[0, 0] = 0.0                           # shared: nobody may change it
    moved = poses.copy()
    moved[0, 1, 3] += 1e-9                          # one row moved by a nanometre: computed anew
    other = speckle.cell_speckle(moved, ranges, **kw)
    assert other is not first and not np.array_equal(other[0], first[0])
    np.testing.assert_array_equal(other[1:], first[1:])
    for i in range(speckle.CACHE_SIZE + 2):         # bounded
        speckle.cell_speckle(poses, ranges, **{**kw, "seed": 100 + i})
    assert len(speckle._cache) <= speckle.CACHE_SIZE


def test_quay_frames_equal_the_reference_chain(mitsonar_mod, monkeypatch):
    """The 512-beam frame through render_scan: a still head (the speckle field from the cache) and
    a moved head, fast and reference chains: the same intensity and the same bytes."""
    from mitsonar.receiver import electronics, speckle

    scene = mitsonar_mod.load_scene(QUAY)
    head = scene.sensors()[0].head_pose()
    moved = head.copy()
    moved[:3, 3] += (0.2, -0.1, 0.05)
    for seed, pose in ((1, None), (2, None), (2, moved), (3, None)):
        scans = []
        for fast in (True, False):
            monkeypatch.setattr(electronics, "FAST", fast)
            monkeypatch.setattr(speckle, "CACHE_SIZE", 4 if fast else 0)
            scans.append(mitsonar_mod.render_scan(scene, spp=2, seed=seed, pose=pose))
        np.testing.assert_array_equal(scans[0].intensity, scans[1].intensity)
        np.testing.assert_array_equal(scans[0].data, scans[1].data)
        assert scans[0].data.any()


def test_frames_replay_without_compiling(mitsonar_mod):
    """After the first frame, frames with other seeds and poses launch the same kernels, none
    compiled anew (Dr.Jit's kernel history), a fixed handful per frame."""
    scene = mitsonar_mod.load_scene(QUAY)
    head = scene.sensors()[0].head_pose()
    mitsonar_mod.render_scan(scene, spp=2, seed=0)
    runs = []
    for seed, shift in ((1, 0.0), (2, 0.3), (3, -0.2)):
        pose = head.copy()
        pose[0, 3] += shift
        runs.append(jit_kernels(mitsonar_mod.render_scan, scene, spp=2, seed=seed, pose=pose))
    for hashes, compiled in runs:
        assert compiled == []
        assert hashes == runs[0][0]
    assert 1 <= len(runs[0][0]) <= 4


def test_pass_sums_in_place_equal_the_straightforward_mean(mitsonar_mod):
    """`SonarTOFIntegrator.accumulate` sums its passes in place: the same bits as
    ``total = 0.0; total = total + pass ...; total / spp``, signed zeros included."""
    from mitsonar.plugins import module

    acc = module("sonar_tof").SonarTOFIntegrator.accumulate
    rng = np.random.default_rng(5)
    parts = {s: rng.exponential(1.0, 50) * (rng.random(50) < 0.5) for s in range(0, 10, 3)}
    for p in parts.values():
        p[:3] = (-0.0, 0.0, 1e-300)
    calls = []

    def one_pass(start, count):
        calls.append((start, count))
        return parts[start].copy()

    got = acc(10, 3, one_pass)
    want = 0.0
    for s in range(0, 10, 3):
        want = want + parts[s]
    want = want / 10
    assert calls == [(0, 3), (3, 3), (6, 3), (9, 1)]
    assert got.tobytes() == want.tobytes()
    one = acc(1, 3, lambda s, c: parts[0].copy())   # one pass: its -0.0 becomes +0.0 as 0.0 + x did
    assert one.tobytes() == ((0.0 + parts[0]) / 1).tobytes()


def _reference_words(values, index, n):
    """The module docstring's integer words of each bin, in exact Python integers (bin-major:
    ``words[i][k]``), and the count of non-finite values per bin."""
    words = [[0] * 9 for _ in range(n)]
    bad = [0] * n
    for v, i in zip(values.astype(np.float32), index):
        bits = int(v.view(np.uint32))
        e = (bits >> 23) & 0xFF
        if e == 255:
            bad[i] += 1
            continue
        if e == 0:                                  # zero or subnormal: adds nothing
            continue
        b = e - 1
        wide = ((bits & 0x7FFFFF) | 0x800000) << (b & 31)
        sign = -1 if bits >> 31 else 1
        words[i][b >> 5] += sign * (wide & 0xFFFFFFFF)
        words[i][(b >> 5) + 1] += sign * (wide >> 32)
    return words, bad


def test_exact_sums_are_stored_word_major_and_sum_as_the_reference(mitsonar_mod):
    """Word k of bin i at ``k n + i`` (one contiguous run per word for the conversion); every
    word is the exact integer sum of the docstring's pieces and the float64 totals are those
    words converted and added in the fixed order k = 0..8 (the bytes of the bin-major layout),
    within one rounding of the exact sum (``math.fsum``); a non-finite value makes its bin NaN."""
    import math

    import drjit as dr
    import mitsuba as mi

    from mitsonar.plugins import exact_sum

    rng = np.random.default_rng(46)
    n = 37
    big = np.float32(np.finfo(np.float32).max)
    values = np.concatenate([
        rng.normal(0.0, 1.0, 3000) * 10.0 ** rng.integers(-30, 30, 3000),   # both signs, all scales
        [big] * 6 + [-big] * 2,                       # into the top words; bin total above float32
        [1e30, 1.0, -1e30, 2.0 ** -126, -(2.0 ** -126)],   # cancellation, the smallest normal
        [1e-40, -1e-41, 0.0, -0.0],                   # subnormals and zeros: nothing
        [np.inf], [np.nan], [-np.inf],
        [np.float32(16777215.0)] * 500,               # carries well past 32 bits in a low word
    ]).astype(np.float32)
    index = rng.choice([i for i in range(n) if not 5 <= i <= 10], values.size).astype(np.uint32)
    index[3000:3008] = 5
    index[3008:3013] = 6
    index[3013:3017] = 7
    index[3017:3020] = (8, 9, 8)
    index[3020:] = 10
    active = np.ones(values.size, bool)
    active[rng.integers(0, 3000, 40)] = False          # inactive lanes add nothing
    hist = exact_sum.ExactBins(n)
    hist.add(mi.Float(values), mi.UInt32(index), mi.Bool(active))
    got = hist.numpy()
    words = hist.words.numpy().reshape(exact_sum.STRIDE, n)

    want_words, bad = _reference_words(values[active], index[active], n)
    np.testing.assert_array_equal(words[:exact_sum.WORDS].T, np.array(want_words, dtype=np.int64))
    np.testing.assert_array_equal(words[exact_sum.WORDS], bad)
    for i in range(n):
        if bad[i]:
            assert np.isnan(got[i])
            continue
        total = 0.0
        for k in range(exact_sum.WORDS):
            total += float(want_words[i][k]) * 2.0 ** (32 * k - 149)
        assert got[i].tobytes() == np.float64(total).tobytes()
        sel = active & (index == i) & (np.abs(values) >= np.finfo(np.float32).tiny)
        exact = math.fsum(float(v) for v in values[sel])
        assert abs(got[i] - exact) <= 4 * np.spacing(max(abs(exact), np.finfo(np.float64).tiny))
    assert got[6] == 1.0                                  # 1e30 + 1 - 1e30 + tiny - tiny, exactly
    assert got[5] == 4.0 * float(big)                     # beyond float32's range, finite
    assert np.isnan(got[8]) and np.isnan(got[9])

    # folding (`reserve` past MAX_ADDS) keeps the layout: the partial sums plus the new words
    hist.reserve(exact_sum.MAX_ADDS)
    hist.reserve(1)
    assert hist.partial is not None and not dr.any(hist.words != 0)
    hist.add(mi.Float(values[:3000]), mi.UInt32(index[:3000]), mi.Bool(active[:3000]))
    again = hist.numpy()
    more, _ = _reference_words(values[:3000][active[:3000]], index[:3000][active[:3000]], n)
    for i in range(n):
        if not bad[i]:
            part = 0.0
            for k in range(exact_sum.WORDS):
                part += float(more[i][k]) * 2.0 ** (32 * k - 149)
            assert again[i].tobytes() == np.float64(got[i] + part).tobytes()


def _emission_runs(scene, emission, seeds, spp, depth=2):
    import mitsuba as mi

    integ = mi.load_dict({"type": "sonar_tof", "max_depth": depth, "share_beams": True, "emission": emission})
    return np.array([integ.render_histogram(scene, scene.sensors()[0], seed=s, spp=spp) for s in seeds])


def test_receive_weighted_emission_agrees_with_the_transmit_fan_within_monte_carlo_error(mitsonar_mod):
    """``emission`` ``receive`` (plugins/receive_emission.py) against ``transmit`` (the fan's own
    density) on the small corner frame of tests/test_shared_beams.py (24 beams over 46 deg, the fan
    as wide: a quarter of its mass beyond the swath, two-bounce corner echoes): cells of 4 rows x
    5 bins holding > 1e-3 of the brightest, 16 seeds per side at spp 64, z = (mean_receive -
    mean_transmit) / sqrt(se_r^2 + se_t^2), about Student-t with ~30 degrees of freedom: |z| > 5
    has probability ~5e-4 for the worst of 24 cells. Dropping the paths beyond the swath
    (no defensive share) or a weight without the fan's own density would move whole cells by
    far more. The totals agree within 3 % (their standard error is about 1 %)."""
    from test_shared_beams import corner_scene

    scene = corner_scene(mitsonar_mod)
    out = {}
    for emission in ("transmit", "receive"):
        runs = _emission_runs(scene, emission, [10 * s + 3 for s in range(16)], 64)
        cells = runs[:, :, :30].reshape(16, 6, 4, 6, 5).sum(axis=(2, 4))
        out[emission] = (cells.mean(0), cells.std(0, ddof=1) / 4.0, runs.sum(axis=(1, 2)))
    (m0, s0, t0), (m1, s1, t1) = out["transmit"], out["receive"]
    lit = m0 > 1e-3 * m0.max()
    assert lit.sum() >= 12
    z = (m1 - m0)[lit] / np.sqrt(s0[lit] ** 2 + s1[lit] ** 2)
    assert np.abs(z).max() < 5.0, z
    assert t1.mean() == pytest.approx(t0.mean(), rel=0.03)


def wide_fan_scene(mitsonar_mod, tx_beamwidth_h):
    """24 gaussian receive beams of 3 deg stepping 2 deg (a 46 deg swath) over a floor and a
    sphere, the transmit fan ``tx_beamwidth_h`` wide."""
    from conftest import acoustic_xml, frame_matrix, rectangle_xml, scene_xml, sonar_xml, sphere_xml

    head = frame_matrix((1.0, 0.0, -0.3), (0.0, 0.0, 1.0))
    floor = np.diag([8.0, 8.0, 1.0, 1.0])
    floor[:3, 3] = (2.0, 0.0, -2.0)
    bsdf = acoustic_xml(diffuse=0.6, specular=0.3, shininess=20.0)
    sensor = sonar_xml(head, kind="multibeam", range_min=0.5, range_max=9.0, n_bins=34, bearing_start=-23.0,
                       bearing_step=2.0, n_pings=24, beam_pattern="gaussian", beamwidth_h=3.0, beamwidth_v=20.0,
                       tx_beamwidth_h=float(tx_beamwidth_h))
    return mitsonar_mod.load_scene(scene_xml(sensor, rectangle_xml(floor, bsdf),
                                             sphere_xml((4.0, -1.0, -1.5), 0.5, bsdf)))


def test_receive_weighted_emission_cuts_the_error_at_equal_paths(mitsonar_mod):
    """At equal spp the receive-weighted emission's relative L2 error against a high-spp reference
    is below the transmit fan's when the fan spends paths beyond the swath: a 120 deg fan over a
    46 deg swath (half its mass outside). Measured: 0.53-0.79x (4 sets of 6 seeds). With the fan as wide as the
    swath (the default) the gain depends on the scene: the 512-beam quay frame 0.82x
    (``max_depth`` 3, benchmarks/frame_targets.py), the small corner frame of
    tests/test_shared_beams.py within its noise (its two-bounce corner echoes dominate).
    Bound: < 0.85x with the mean of 6 seeds."""
    scene = wide_fan_scene(mitsonar_mod, 120.0)
    ref = _emission_runs(scene, "transmit", [99], 8192, depth=1)[0]

    def err(emission):
        runs = _emission_runs(scene, emission, range(6), 64, depth=1)
        return np.mean([np.linalg.norm(r - ref) for r in runs]) / np.linalg.norm(ref)

    e_t, e_r = err("transmit"), err("receive")
    print("errors", e_t, e_r, e_r / e_t)
    assert e_r < 0.85 * e_t


def test_emission_setting_is_checked_in_one_line(mitsonar_mod):
    import mitsuba as mi

    with pytest.raises(Exception, match="sonar_tof.*emission.*receive, transmit"):
        mi.load_dict({"type": "sonar_tof", "emission": "beams"})
    assert "emission=receive" in str(mi.load_dict({"type": "sonar_tof"}))   # the default


@pytest.mark.parametrize("tx_kind", ["gaussian", "uniform", "sinc"])
def test_receive_weighted_emission_weights_integrate_the_fan(mitsonar_mod, tx_kind):
    """``E_q[B_tx / q] = integral of B_tx`` and the same over a part of the sphere (importance
    sampling, Veach eq. 2.8), for a fan drawn as two 1-D inversions (gaussian, uniform) and one
    drawn from the 2-D table (sinc): 2^20 uniform samples against `BeamPattern.solid_angle`'s
    quadrature, within 1 % (the weights are bounded: standard error ~0.1 %); and the directions
    fall in the swath more often than the fan's own (the point of it)."""
    import math

    import drjit as dr
    import mitsuba as mi

    from mitsonar.plugins import module

    BeamPattern = module("beam").BeamPattern
    remit = module("receive_emission")
    tx = BeamPattern(kind=tx_kind, beamwidth_h=60.0, beamwidth_v=20.0, frequency=400e3)
    rx = BeamPattern(kind="gaussian", beamwidth_h=3.0, beamwidth_v=20.0, frequency=400e3)
    bearings = np.radians(np.arange(-20.0, 21.0, 2.0))          # a 40 deg swath inside the fan
    em = remit.ReceiveWeighted(tx, rx, bearings, math.radians(6.0))
    assert em.separable == (tx_kind != "sinc")
    n = 1 << 20
    rng = mi.PCG32(n, dr.arange(mi.UInt64, n))
    u = mi.Point2f(rng.next_float32(), rng.next_float32())
    d, w = em.sample(u)
    d_tx, _ = tx.sample(u)
    az = np.arctan2(d.x.numpy(), d.z.numpy())
    w = w.numpy().astype(np.float64)
    assert w.mean() == pytest.approx(tx.solid_angle(), rel=0.01)
    part = az > 0.3
    a = np.linspace(0.3, math.pi / 2, 4001)
    e = np.linspace(-math.pi / 2, math.pi / 2, 2001)
    A, E = np.meshgrid(a, e)
    want = trapezoid(trapezoid(tx.eval_np(A, E) * np.cos(E), a, axis=1), e)
    assert (w * part).mean() == pytest.approx(want, rel=0.01)
    swath = np.abs(az) <= math.radians(26.0)
    own = np.abs(np.arctan2(d_tx.x.numpy(), d_tx.z.numpy())) <= math.radians(26.0)
    assert swath.mean() > own.mean() + 0.05
    with pytest.raises(ValueError, match="defensive share"):
        remit.ReceiveWeighted(tx, rx, bearings, 0.1, beta=0.0)


def test_range_spread_over_the_echoes_span_gives_the_same_bytes(mitsonar_mod, monkeypatch):
    """`fastchain.convolve_span` (only the columns within a kernel of an echo) against
    `convolve_range` (every column): the same bytes for blocks with echoes in a middle span, at
    either end, a lone echo, none at all, signed zeros; and the whole chain on such a frame gives
    the straightforward chain's bytes."""
    from mitsonar.receiver import fastchain
    from mitsonar.receiver.electronics import Electronics

    rng = np.random.default_rng(3)
    kernel = fastchain.cached((0.3, 0.0, 0.03), lambda *k: np.array([0.05, 0.2, 0.5, 0.2, 0.05]))
    blocks = []
    for lo, hi in ((60, 100), (0, 7), (113, 120), (50, 51), (0, 0), (0, 120)):
        b = np.zeros((6, 120))
        b[:, lo:hi] = rng.exponential(1e-9, (6, hi - lo)) * (rng.random((6, hi - lo)) < 0.5)
        b[0, lo:hi] = 1e-9 if hi > lo else 0.0
        blocks.append(b)
    blocks[0][2, 30] = -0.0
    for b in blocks:
        got, want = fastchain.convolve_span(b, kernel), fastchain.convolve_range(b, kernel)
        assert got.tobytes() == want.tobytes()
    monkeypatch.setattr(fastchain, "ROW_BLOCK", 6)
    inten = np.concatenate(blocks).astype(np.float32)
    ranges = np.linspace(0.5, 15.0, 120)
    poses = np.tile(np.eye(4), (len(inten), 1, 1))
    for settings in ({}, {"noise_floor": -np.inf, "ringdown": 0.0}):
        model = Electronics.from_dict(settings)
        ref = chain(model, inten, ranges, poses, False, monkeypatch)
        np.testing.assert_array_equal(chain(model, inten, ranges, poses, True, monkeypatch), ref)


def test_sparse_spread_gives_the_dense_spread_bit_for_bit(mitsonar_mod):
    """`fastchain.convolve_sparse` (few echoes: a frame at few paths) equals `convolve_range` bit
    for bit: neighbouring echoes whose spreads overlap (sums of several products, in tap order),
    echoes at both ends (spread off the ends dropped), zero weights, a silent row."""
    from mitsonar.receiver import fastchain

    rng = np.random.default_rng(3)
    inten = rng.exponential(1.0, (9, 64)) * (rng.random((9, 64)) < 0.05)
    inten[1, 10:14] = rng.exponential(1e-6, 4)          # overlapping spreads
    inten[2, 0], inten[2, -1] = 3.0, 7.0                 # both ends
    inten[4] = 0.0
    for kernel in (rng.random(17), np.array([0.2, 0.0, 0.5, 0.0, 0.3]), rng.random(3) * 1e-3, rng.random(201)):
        dense = fastchain.convolve_range(inten, kernel)
        sparse = fastchain.convolve_sparse(inten, kernel)
        assert sparse.dtype == dense.dtype and sparse.shape == dense.shape
        np.testing.assert_array_equal(sparse.view(np.uint64), dense.view(np.uint64))
    assert not fastchain.convolve_sparse(np.zeros((2, 5)), np.ones(3)).any()


def test_sparse_scans_take_the_sparse_spread_and_keep_the_bytes(mitsonar_mod, monkeypatch):
    """A scan with echoes in under 1/16 of its bins goes through `convolve_sparse` (not the dense
    spread) and gives the straightforward chain's bytes, for every setting."""
    from mitsonar.receiver import fastchain
    from mitsonar.receiver.electronics import Electronics

    inten, ranges, poses = chain_inputs()
    inten = inten * (np.random.default_rng(8).random(inten.shape) < 0.15)   # about 5 % of bins
    assert 0 < np.count_nonzero(inten) * fastchain.SPARSE_RATIO <= inten.size
    calls = []
    sparse = fastchain.convolve_sparse
    monkeypatch.setattr(fastchain, "convolve_sparse", lambda *a: calls.append(1) or sparse(*a))
    for settings in CONFIGS:
        model = Electronics.from_dict(settings)
        before = len(calls)
        ref = chain(model, inten, ranges, poses, False, monkeypatch)
        fast = chain(model, inten, ranges, poses, True, monkeypatch)
        np.testing.assert_array_equal(fast, ref)
        if model.speckle != "off" and model.range_kernel(ranges[1] - ranges[0]).size > 1:
            assert len(calls) == before + 1


def test_speckle_tables_are_shared_by_a_turning_head(mitsonar_mod, monkeypatch):
    """A head turning ping after ping (a new field each ping) computes the field's pose-free
    tables once: the same bytes as computing everything afresh (``CACHE_SIZE = 0``), the tables
    kept read-only and bounded."""
    from mitsonar.geometry.frames import bearing_rotation
    from mitsonar.receiver import speckle

    monkeypatch.setattr(speckle, "_cache", {})
    monkeypatch.setattr(speckle, "_tables_cache", {})
    ranges = np.linspace(0.5, 30.5, 600)
    kw = dict(seed=9, beamwidth_h=3.0, aperture_h=0.04, resolution=0.05)
    fields = [speckle.cell_speckle(bearing_rotation(np.radians(1.8 * k))[None], ranges, **kw) for k in range(3)]
    assert len(speckle._tables_cache) == 1
    tables = next(iter(speckle._tables_cache.values()))
    assert all(not t.flags.writeable for t in tables)
    monkeypatch.setattr(speckle, "CACHE_SIZE", 0)
    for k, field in enumerate(fields):
        fresh = speckle.cell_speckle(bearing_rotation(np.radians(1.8 * k))[None], ranges, **kw)
        np.testing.assert_array_equal(fresh.view(np.uint64), field.view(np.uint64))
    monkeypatch.setattr(speckle, "CACHE_SIZE", 2)
    for seed in range(5):
        speckle.cell_speckle(np.eye(4)[None], ranges, **{**kw, "seed": seed})
    assert len(speckle._tables_cache) <= 2


def test_speckle_products_run_on_one_blas_thread(mitsonar_mod):
    """`speckle.one_blas_thread` holds NumPy's BLAS to one thread (no threads woken to spin on
    the renderer's cores) and gives the previous count back."""
    threadpoolctl = pytest.importorskip("threadpoolctl")
    from mitsonar.receiver import speckle

    def counts():
        return [lib["num_threads"] for lib in threadpoolctl.threadpool_info() if lib["user_api"] == "blas"]

    before = counts()
    with speckle.one_blas_thread():
        inside = counts()
    assert inside and all(n == 1 for n in inside)
    assert counts() == before


def test_live_pings_equal_the_reference_chain(mitsonar_mod, monkeypatch):
    """One-row pings of the live harbour head (`mitsonar.devices.live.live_scene`) turning 1.8 deg
    a ping, as `PingRenderer.render` renders them: the fast chain with its caches gives the
    reference chain's bytes."""
    from mitsonar.devices.live import live_scene
    from mitsonar.geometry.frames import bearing_rotation
    from mitsonar.receiver import electronics, speckle

    scene = live_scene(os.path.join(HERE, "..", "scenes_xml", "harbour.xml"))
    sonar = scene.sensors()[0]
    mount = np.array(sonar.to_world_np, dtype=np.float64)
    for k in range(3):
        pose = mount @ bearing_rotation(np.radians(1.8 * k))
        scans = []
        for fast in (True, False):
            monkeypatch.setattr(electronics, "FAST", fast)
            monkeypatch.setattr(speckle, "CACHE_SIZE", 4 if fast else 0)
            scans.append(mitsonar_mod.render_scan(scene, spp=16, seed=k, pose=pose, sensor=sonar))
        assert scans[0].data.shape == (1, sonar.n_bins)
        np.testing.assert_array_equal(scans[0].intensity, scans[1].intensity)
        np.testing.assert_array_equal(scans[0].data, scans[1].data)
        assert scans[0].data.any()


def test_prefetched_noise_gives_the_same_bytes(mitsonar_mod, monkeypatch):
    """`render_scan` draws the receiver noise on a worker thread during the render
    (`fastchain.prefetch_draws`): every frame takes the prefetched draws (same seed and shape)
    and its bytes are those drawn by `Electronics.apply` itself; another seed or shape is not
    taken."""
    from mitsonar.receiver import fastchain
    from mitsonar.receiver.electronics import Electronics

    scene = mitsonar_mod.load_scene(QUAY)
    taken = []
    take = fastchain.take_draws

    def spy(*args):
        drawn = take(*args)
        taken.append(drawn is not None)
        return drawn

    monkeypatch.setattr(fastchain, "take_draws", spy)
    scans = {}
    for prefetch in (True, False):
        monkeypatch.setattr(fastchain, "PREFETCH", prefetch)
        scans[prefetch] = [mitsonar_mod.render_scan(scene, spp=1, seed=s, electronics_seed=e)
                           for s, e in ((4, None), (4, 9))]
    assert taken == [True, True, False, False]
    for a, b in zip(scans[True], scans[False]):
        np.testing.assert_array_equal(a.data, b.data)
    assert not np.array_equal(scans[True][0].data, scans[True][1].data)
    model = Electronics.from_dict({})
    ranges = np.linspace(0.5, 10.0, 50)
    monkeypatch.setattr(fastchain, "PREFETCH", True)
    model.prefetch_noise((1, 600), np.linspace(0.5, 30.5, 600), 1500.0, 7)    # a one-row ping: drawn by apply
    assert fastchain.take_draws((1, 600), 7) is None
    monkeypatch.setattr(fastchain, "PREFETCH_MIN", 0)
    model.prefetch_noise((3, 50), ranges, 1500.0, 7)
    assert fastchain.take_draws((3, 50), 7) is not None
    assert fastchain.take_draws((3, 50), 8) is None        # another seed: drawn by apply
    model.prefetch_noise((3, 50), ranges, 1500.0, 7)
    assert fastchain.take_draws((4, 50), 7) is None        # another shape


def _draws_in_child(queue):
    from mitsonar.receiver import fastchain

    fastchain.prefetch_draws((2, 30), 5)
    queue.put(float(fastchain.take_draws((2, 30), 5)[0].sum()))


def test_prefetch_works_in_a_forked_child(mitsonar_mod, monkeypatch):
    """A process forked after a prefetch (a dataset's workers) has no worker thread: its own
    prefetch starts one instead of waiting forever on the parent's."""
    import multiprocessing

    from mitsonar.receiver import fastchain

    monkeypatch.setattr(fastchain, "PREFETCH_MIN", 0)
    fastchain.prefetch_draws((2, 30), 5)
    want = float(fastchain.take_draws((2, 30), 5)[0].sum())
    ctx = multiprocessing.get_context("fork")
    queue = ctx.Queue()
    child = ctx.Process(target=_draws_in_child, args=(queue,))
    child.start()
    child.join(30)
    alive = child.is_alive()
    if alive:
        child.kill()
    assert not alive and queue.get(timeout=5) == want
