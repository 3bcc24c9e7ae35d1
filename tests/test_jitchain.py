"""The receiver chain as one Dr.Jit kernel (`mitsonar.receiver.jitchain`): the bytes of the NumPy
chain (`mitsonar.receiver.fastchain`) for every electronics setting, on the active variant."""
import numpy as np
import pytest

from conftest import jit_kernels
from test_frame_overhead import CONFIGS, QUAY, chain, chain_inputs


def both(model, inten, ranges, poses, monkeypatch, drawn):
    from mitsonar.receiver import jitchain

    out = []
    for mode in ("numpy", "jit"):
        monkeypatch.setattr(jitchain, "CHAIN", mode)
        out.append(chain(model, inten, ranges, poses, True, monkeypatch, drawn))
    return out


@pytest.mark.parametrize("settings", CONFIGS)
@pytest.mark.parametrize("drawn", [False, True])
def test_kernel_chain_gives_the_numpy_chain_bytes(mitsonar_mod, monkeypatch, settings, drawn):
    """Every setting (speckle drawn or the scene's, Weibull, no ring-down, no noise, 4 bits, no
    pulse, a fixed gain): the same bytes, for a scan and for one ping."""
    from mitsonar.receiver.electronics import Electronics

    model = Electronics.from_dict(settings)
    inten, ranges, poses = chain_inputs()
    ref, got = both(model, inten, ranges, poses, monkeypatch, drawn)
    assert got.dtype == np.uint8 and got.shape == ref.shape
    np.testing.assert_array_equal(got, ref)
    assert len(np.unique(ref)) > 3
    one_ref, one = both(model, inten[6], ranges, poses[6:7], monkeypatch, drawn)
    np.testing.assert_array_equal(one, one_ref)


def test_quay_frames_through_the_kernel_chain_keep_their_bytes(mitsonar_mod, monkeypatch):
    """render_scan's 512 x 500 frame at spp 2 and 64, three seeds: the kernel chain's bytes are
    the NumPy chain's (the intensities are the same render's)."""
    from mitsonar.receiver import jitchain

    scene = mitsonar_mod.load_scene(QUAY)
    for spp, seed in ((2, 1), (64, 2), (64, 3)):
        scans = []
        for mode in ("numpy", "jit"):
            monkeypatch.setattr(jitchain, "CHAIN", mode)
            scans.append(mitsonar_mod.render_scan(scene, spp=spp, seed=seed))
        np.testing.assert_array_equal(scans[0].intensity, scans[1].intensity)
        np.testing.assert_array_equal(scans[1].data, scans[0].data)
        assert (scans[0].data > 0).mean() > 0.1


def test_kernel_chain_compiles_once_for_new_frames(mitsonar_mod, monkeypatch):
    """A new seed or new intensities of the same shape replay the compiled kernel."""
    from mitsonar.receiver import jitchain
    from mitsonar.receiver.electronics import Electronics

    monkeypatch.setattr(jitchain, "CHAIN", "jit")
    model = Electronics.from_dict({})
    inten, ranges, poses = chain_inputs()
    sp = model.scene_speckle(poses, ranges, sound_speed=1500.0, beamwidth_h=1.0, aperture_h=0.03)
    model.apply(inten, ranges, seed=1, speckle=sp)
    first, _ = jit_kernels(lambda: model.apply(inten * 2.0, ranges, seed=2, speckle=sp))
    again, fresh = jit_kernels(lambda: model.apply(inten * 3.0, ranges, seed=3, speckle=sp))
    assert first and sorted(again) == sorted(first) and not fresh


def test_kernel_chain_compiles_one_way_whatever_the_host_alignment(mitsonar_mod):
    """Intensities, speckle, draws and per-bin arrays placed at every 8-byte offset from a 256-byte
    boundary (NumPy's allocations land anywhere; Dr.Jit maps host memory on llvm and would compile
    a contiguous read of it for its alignment): one kernel for all, and the same bytes."""
    from mitsonar.receiver import jitchain
    from mitsonar.receiver.electronics import Electronics

    model = Electronics.from_dict({})
    inten, ranges, poses = chain_inputs(n_rows=16, n_bins=300)
    inten = inten.astype(np.float64)
    rng = np.random.default_rng(3)
    g = rng.normal(size=inten.shape) + 1j * rng.normal(size=inten.shape)
    kernel = model.range_kernel(ranges[1] - ranges[0])
    taps = np.array([0.6, 0.8])
    z = rng.normal(size=(inten.shape[0], inten.shape[1] + 1, 2))
    f = np.full(inten.shape[1], 1e-5)
    ring = np.full(inten.shape[1], 1e-6)
    tvg = np.linspace(0.0, 30.0, inten.shape[1])

    def placed(a, k):
        """``a`` copied into memory ``8 k`` bytes past a 256-byte boundary."""
        raw = np.empty(a.nbytes + 512, dtype=np.uint8)
        start = -raw.ctypes.data % 256 + 8 * k
        out = raw[start:start + a.nbytes].view(a.dtype).reshape(a.shape)
        out[...] = a
        return out

    hashes, results = [], []
    for k in range(8):
        args = [placed(a, k) for a in (inten, g, z, f, ring, tvg)]
        run = lambda: results.append(jitchain.received_bytes(  # noqa: E731
            args[0], args[1], kernel, False, args[4], args[2], taps, args[3], (52.0, 10.0, args[5]),
            (model.ad_low, model.ad_span, model.bit_depth)))
        hashes.append(sorted(set(jit_kernels(run)[0])))
    assert hashes[0] and all(h == hashes[0] for h in hashes), hashes
    assert all(np.array_equal(r, results[0]) for r in results)


def test_one_bin_frames_do_not_bake_their_values_into_the_kernel(mitsonar_mod):
    """A frame of one bin a row (its per-bin TVG, noise and ring-down arrays hold one value): a
    new TVG value replays the compiled kernel (a one-element array would be a literal)."""
    from mitsonar.receiver import jitchain

    rng = np.random.default_rng(5)
    inten = rng.exponential(1e-9, (64, 1))
    g = rng.normal(size=inten.shape) + 1j * rng.normal(size=inten.shape)
    z = rng.normal(size=(64, 1, 2))
    hashes = []
    for tvg in (10.0, 20.0):
        run = lambda t=tvg: jitchain.received_bytes(  # noqa: E731
            inten, g, np.ones(1), False, np.full(1, 1e-6), z, np.ones(1), np.full(1, 1e-5),
            (52.0, 10.0, np.full(1, t)), (40.0, 60.0, 8))
        hashes.append(sorted(set(jit_kernels(run)[0])))
    assert hashes[0] and hashes[1] == hashes[0], hashes


def test_chain_choice(mitsonar_mod, monkeypatch):
    """``auto`` takes the kernel from JIT_MIN bins on (a frame, not a live ping); a bad choice is
    one line naming the setting."""
    from mitsonar.receiver import jitchain

    monkeypatch.setattr(jitchain, "CHAIN", "auto")
    assert jitchain.use_jit(512 * 500) and jitchain.use_jit(jitchain.JIT_MIN)
    assert not jitchain.use_jit(600) and not jitchain.use_jit(jitchain.JIT_MIN - 1)
    monkeypatch.setattr(jitchain, "CHAIN", "jit")
    assert jitchain.use_jit(600)
    monkeypatch.setattr(jitchain, "CHAIN", "numpy")
    assert not jitchain.use_jit(512 * 500)
    monkeypatch.setattr(jitchain, "CHAIN", "gpu")
    with pytest.raises(ValueError, match=r"^jitchain.CHAIN 'gpu' is not one of auto, jit, numpy$"):
        jitchain.use_jit()


def test_levels_on_a_quantisation_half_keep_the_numpy_byte(mitsonar_mod, monkeypatch):
    """The ring-down without noise, ranges on a 1 cm grid: in the empty bins the level is the
    ring-down's line ``40 - 50 r`` dB, which at r = 0.15 m is 32.5 dB, byte 212.5 of the default
    window (12.5 dB + 24 dB): exactly a half, where Dr.Jit's ``log`` and NumPy's ``log10`` may
    round to either side. NumPy's byte (213) it must be, as for every other bin."""
    from mitsonar.receiver import jitchain
    from mitsonar.receiver.electronics import Electronics

    model = Electronics.from_dict({"noise_floor": -np.inf})
    ranges = np.arange(1, 501) * 0.01
    inten = np.zeros((16, ranges.size))
    inten[:, 300:] = 1e-9 * np.arange(1, 201) / 200
    out = []
    for mode in ("numpy", "jit"):
        monkeypatch.setattr(jitchain, "CHAIN", mode)
        out.append(model.apply(inten, ranges, seed=4))
    assert (out[0][:, 14] == 213).all()
    np.testing.assert_array_equal(out[1], out[0])
