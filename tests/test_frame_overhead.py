"""Issue "Frame overhead": the cached speckle field is the computed one; frames replay their
kernels without compiling anew; pass sums and exact sums; the receive-weighted emission. (The
NumPy receiver chain these tests once compared is now the oracle of tests/test_devicechain.py.)"""
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


def chain_inputs(n_rows=45, n_bins=120, seed=1):
    rng = np.random.default_rng(seed)
    inten = rng.exponential(1e-9, (n_rows, n_bins)) * (rng.random((n_rows, n_bins)) < 0.3)
    inten[3] = 0.0                                   # a silent row
    inten[5, 7] = 1e3                                # a bin saturating the A/D
    ranges = np.linspace(0.5, 15.0, n_bins)
    poses = np.tile(np.eye(4), (n_rows, 1, 1))
    poses[:, 0, 3] = np.arange(n_rows) * 0.01
    return inten.astype(np.float32), ranges, poses


def chain(model, inten, ranges, poses, drawn=False):
    sp = None
    if model.speckle != "off" and not drawn:
        sp = model.scene_speckle(poses, ranges, sound_speed=1500.0, beamwidth_h=1.0, aperture_h=0.03)
    return model.apply(inten, ranges, absorption=0.02, seed=11, speckle=sp)


def test_chain_leaves_its_inputs_alone(mitsonar_mod, monkeypatch):
    from mitsonar.receiver.electronics import Electronics

    inten, ranges, poses = chain_inputs()
    keep = inten.copy()
    chain(Electronics.from_dict({}), inten, ranges, poses)
    np.testing.assert_array_equal(inten, keep)


def test_speckle_cache_returns_the_computed_field_read_only(mitsonar_mod, monkeypatch):
    from mitsonar.receiver import speckle

    _, ranges, poses = chain_inputs()
    kw = dict(seed=4, beamwidth_h=1.0, aperture_h=0.03, resolution=0.075)
    monkeypatch.setattr(speckle, "_cache", {})
    first = speckle.cell_speckle(poses, ranges, **kw)
    assert speckle.cell_speckle(poses, ranges, **kw) is first      # looked up, not recomputed
    np.testing.assert_array_equal(first, speckle._field(poses, ranges, 4, 1.0, 0.03, 0.075, speckle.N_FEATURES).numpy())
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
    # a moved head computes its speckle field (two kernels more than a still head's frame)
    assert runs[2][0] == runs[1][0] and set(runs[0][0]) < set(runs[1][0])
    assert 1 <= len(runs[0][0]) <= 6 and len(runs[1][0]) == len(runs[0][0]) + 2


def test_pass_sums_in_place_equal_the_straightforward_mean(mitsonar_mod):
    """`SonarTOFIntegrator.accumulate` sums its passes in place: the same bits as
    ``total = 0.0; total = total + pass ...; total / spp``, signed zeros included."""
    from mitsonar.plugins.integrators import sonar_tof

    acc = sonar_tof.SonarTOFIntegrator.accumulate
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

    from mitsonar.plugins.integrators.paths import exact_sum

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
    """``emission`` ``receive`` (plugins/integrators/paths/receive_emission.py) against ``transmit`` (the fan's own
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

    from mitsonar.plugins.sensors import beam
    from mitsonar.plugins.integrators.paths import receive_emission

    BeamPattern = beam.BeamPattern
    remit = receive_emission
    tx = BeamPattern(pattern=tx_kind, beamwidth_h=60.0, beamwidth_v=20.0, frequency=400e3)
    rx = BeamPattern(pattern="gaussian", beamwidth_h=3.0, beamwidth_v=20.0, frequency=400e3)
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
