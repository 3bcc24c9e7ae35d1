"""Issue 55 item 1: `render_frame` keeps the frame on the device from the exact sums to the bytes
(no NumPy array on the way), with `render_scan`'s bits."""
import os

import numpy as np
import pytest

HERE = os.path.dirname(os.path.abspath(__file__))
SCENES = os.path.join(HERE, "..", "scenes_xml")


@pytest.fixture(autouse=True)
def own_speckle_cache(mitsonar_mod, monkeypatch):
    """The scene speckle fields these renders cache are dropped after each test (a quay field
    cached by an earlier test changes the kernels tests/test_frame_overhead.py counts)."""
    from mitsonar.receiver import speckle

    monkeypatch.setattr(speckle, "_cache", {})


@pytest.fixture
def host_copies(monkeypatch):
    """The Dr.Jit arrays brought to NumPy (``.numpy()``, ``np.asarray``) while it is on: (type,
    width)."""
    import drjit as dr

    seen = []
    numpy, array = dr.ArrayBase.numpy, dr.ArrayBase.__array__

    def spy_numpy(self, *args, **kwargs):
        seen.append((type(self).__name__, dr.width(self)))
        return numpy(self, *args, **kwargs)

    def spy_array(self, *args, **kwargs):
        seen.append((type(self).__name__, dr.width(self)))
        return array(self, *args, **kwargs)

    monkeypatch.setattr(dr.ArrayBase, "numpy", spy_numpy)
    monkeypatch.setattr(dr.ArrayBase, "__array__", spy_array)
    return seen


@pytest.mark.parametrize("name,spp", [("quay_wall.xml", 2), ("box.xml", 32)])
def test_render_frame_brings_nothing_to_the_host(mitsonar_mod, host_copies, name, spp):
    """The quay frame (shared beams) and the box scan (per-row paths): after a first frame,
    `render_frame` converts no array of the frame to NumPy (the histogram was summed on the host
    and uploaded before); its arrays are Dr.Jit arrays with `render_scan`'s bits. (The set-up
    may read single values of the scene: the plane guide reads a rectangle's ``to_world``.)"""
    import mitsuba as mi

    from mitsonar.sim.render import render_frame

    scene = mitsonar_mod.load_scene(os.path.join(SCENES, name))
    scan = mitsonar_mod.render_scan(scene, spp=spp, seed=3)
    host_copies.clear()
    frame = render_frame(scene, spp=spp, seed=3)
    assert [(kind, width) for kind, width in host_copies if width > 1] == []
    assert isinstance(frame.intensity, mi.Float32) and isinstance(frame.data, mi.UInt8)
    intensity, data = frame.numpy()
    assert intensity.tobytes() == scan.intensity.tobytes() and data.tobytes() == scan.data.tobytes()


def test_frame_intensity_is_the_histogram_rounded_as_numpy_rounds(mitsonar_mod):
    """`render_scan`'s intensity is `render_histogram`'s float64 mean cast to float32 by NumPy, bit
    for bit, its float32 subnormals included: the box at spp 32 has means below 2^-126, which
    Dr.Jit's pool threads (FTZ) would flush to 0 in a plain conversion."""
    scene = mitsonar_mod.load_scene(os.path.join(SCENES, "box.xml"))
    hist = scene.integrator().render_histogram(scene, 0, seed=3, spp=32)
    want = hist.astype(np.float32)
    tiny = np.finfo(np.float32).tiny
    assert ((want != 0) & (np.abs(want) < tiny)).any()
    got = mitsonar_mod.render_scan(scene, spp=32, seed=3).intensity
    assert got.tobytes() == want.tobytes()


def test_to_float32_rounds_as_numpy(mitsonar_mod):
    """`exact_sum.to_float32` against ``astype(np.float32)``: subnormals, ties at the subnormals'
    spacing, the least normal and the values rounding up to it, zeros, infinities, NaN, overflow."""
    import mitsuba as mi

    from mitsonar.plugins.integrators.paths.exact_sum import to_float32

    rng = np.random.default_rng(4)
    unit = 2.0 ** -149
    x = np.concatenate([rng.exponential(1.0, 20000) * 2.0 ** rng.integers(-160, -100, 20000),
                        -rng.exponential(1.0, 500) * 2.0 ** -140,
                        [0.0, -0.0, np.inf, -np.inf, np.nan, 2.0 ** -126, 2.0 ** -126 * (1 - 2.0 ** -30),
                         0.5 * unit, 1.5 * unit, 2.5 * unit, -2.5 * unit, 0.5 * unit * (1 + 1e-12), 1e-300,
                         3.5e38, 1.0 / 3.0]])
    with np.errstate(over="ignore"):
        want = x.astype(np.float32)
    assert to_float32(mi.Float64(x)).numpy().tobytes() == want.tobytes()


def test_accumulate_on_the_device_gives_the_host_bits(mitsonar_mod):
    """`SonarTOFIntegrator.accumulate` of ``mi.Float64`` passes: a ``mi.Float64`` with the bits of
    the NumPy passes' mean (``0.0 + x`` turns -0.0 into +0.0; ``/ spp`` a division, not a
    product by ``1 / spp``)."""
    import mitsuba as mi

    from mitsonar.plugins.integrators import sonar_tof

    acc = sonar_tof.SonarTOFIntegrator.accumulate
    rng = np.random.default_rng(6)
    parts = {s: rng.exponential(1.0, 4000) * (rng.random(4000) < 0.5) for s in range(0, 10, 3)}
    for p in parts.values():
        p[:3] = (-0.0, 0.0, 1e-300)
    for spp, per in ((10, 3), (1, 3), (7, 7)):
        host = acc(spp, per, lambda s, c: parts[s].copy())
        device = acc(spp, per, lambda s, c: mi.Float64(parts[s]))
        assert isinstance(device, mi.Float64)
        assert device.numpy().tobytes() == host.tobytes()
        mean, single = acc(spp, per, lambda s, c: mi.Float64(parts[s]), float32=True)
        assert mean.numpy().tobytes() == host.tobytes()
        assert single.numpy().tobytes() == host.astype(np.float32).tobytes()


def test_a_frame_of_any_number_of_passes_launches_the_same_kernels(mitsonar_mod):
    """The quay frame in one pass and in three (passes of at most 2 paths per beam): the same
    Dr.Jit kernels (each pass evaluates the running sum, the mean and its float32 in the kernel
    the last pass launches too), none compiled anew, and the bits of the passes summed on the
    host."""
    from conftest import jit_kernels

    from mitsonar.plugins.integrators import sonar_tof

    scene = mitsonar_mod.load_scene(os.path.join(SCENES, "quay_wall.xml"))
    n_rows = scene.sensors()[0].n_pings
    mitsonar_mod.render_scan(scene, spp=2, seed=1)
    one, compiled = jit_kernels(mitsonar_mod.render_scan, scene, spp=2, seed=2)
    assert compiled == []
    lanes = sonar_tof.MAX_LANES_PER_PASS
    try:
        sonar_tof.MAX_LANES_PER_PASS = 2 * n_rows
        mitsonar_mod.render_scan(scene, spp=5, seed=1)
        scan = [None]
        many, compiled = jit_kernels(lambda: scan.__setitem__(0, mitsonar_mod.render_scan(scene, spp=5, seed=2)))
        integ = scene.integrator()
        hist = integ.accumulate(5, 2, lambda start, count: integ._shared_pass(
            _shared(integ, scene), 2, start, count).numpy())
    finally:
        sonar_tof.MAX_LANES_PER_PASS = lanes
    assert compiled == [] and len(many) > len(one) and set(many) == set(one)
    assert scan[0].intensity.tobytes() == hist.astype(np.float32).reshape(scan[0].intensity.shape).tobytes()


def _shared(integ, scene):
    from mitsonar.plugins.integrators.paths.shared_beams import SharedFrame

    return SharedFrame(integ.setup(scene, 0, None, None), None)
