"""Issue "Survey speed": frozen render passes (plugins/integrators/paths/frozen_pass.py) give the traced passes'
histogram bit for bit whatever changes between renders (seed, pose, pass start), replay one
recording, and draw the emitted directions as the fused path kernel does; ``share_beams`` is the
default for multibeam heads that can share, with a silent fallback and an explicit opt-out."""
import gc

import numpy as np
import pytest

from conftest import acoustic_xml, frame_matrix, on_cuda, rectangle_xml, scene_xml, sonar_xml, sphere_xml


def small_scene(mitsonar_mod, kind="mechanical", pattern="gaussian", share=None, n_pings=12):
    """A head over a floor z = -2 with a sphere on it: single and multi-bounce echoes."""
    head = frame_matrix((1.0, 0.0, -0.4), (0.0, 0.0, 1.0))
    params = dict(kind=kind, range_min=0.5, range_max=8.0, n_bins=40, bearing_start=-11.0, n_pings=n_pings,
                  beam_pattern=pattern, beamwidth_h=3.0, beamwidth_v=20.0)
    params["bearing_step"] = 2.0
    floor = np.diag([8.0, 8.0, 1.0, 1.0])
    floor[:3, 3] = (2.0, 0.0, -2.0)
    bsdf = acoustic_xml(diffuse=0.6, specular=0.3, shininess=20.0)
    extra = "" if share is None else f'<boolean name="share_beams" value="{str(share).lower()}"/>'
    integ = f'<integrator type="sonar_tof"><integer name="max_depth" value="3"/>{extra}</integrator>'
    return mitsonar_mod.load_scene(scene_xml(sonar_xml(head, **params), rectangle_xml(floor, bsdf),
                                             sphere_xml((4.0, 0.5, -1.5), 0.5, bsdf), integrator=integ))


def render(scene, freeze, monkeypatch, **kw):
    from mitsonar.plugins.integrators.paths import frozen_pass

    monkeypatch.setattr(frozen_pass, "FREEZE", freeze)
    return scene.integrator().render_histogram(scene, 0, **kw)


@pytest.mark.parametrize("kind,share", [("mechanical", None), ("multibeam", False), ("multibeam", True)])
def test_frozen_passes_equal_traced_passes(mitsonar_mod, monkeypatch, kind, share):
    """Record (first call), then replay with another seed and another pose: each equals the
    traced pass bit for bit in the float32 of the scan (the float64 bins take atomic adds in
    thread order, so their last bits may differ: within 1e-12); one recording serves them all."""
    from mitsonar.plugins.integrators.paths import frozen_pass as fp
    scene = small_scene(mitsonar_mod, kind, share=share)
    head = scene.sensors()[0].head_pose()
    moved = head.copy()
    moved[:3, 3] += (0.3, -0.2, 0.1)
    fp.clear()   # past `MAX_RECORDINGS` (earlier tests' passes) all are dropped: the count would jump
    before = fp._frozen.n_recordings
    for seed, pose in ((3, None), (4, None), (4, moved), (5, head)):
        frozen = render(scene, True, monkeypatch, seed=seed, spp=32, pose=pose)
        traced = render(scene, False, monkeypatch, seed=seed, spp=32, pose=pose)
        np.testing.assert_array_equal(frozen.astype(np.float32), traced.astype(np.float32))
        np.testing.assert_allclose(frozen, traced, rtol=1e-12, atol=0)
        assert frozen.sum() > 0
    assert fp._frozen.n_recordings == before + 1   # recorded once, replayed three times
    assert not np.array_equal(render(scene, True, monkeypatch, seed=3, spp=32),
                              render(scene, True, monkeypatch, seed=4, spp=32))


def test_frozen_passes_split_into_passes_as_traced(mitsonar_mod, monkeypatch):
    """Several passes per render (pass start opaque, a last pass of another size): the frozen
    render equals the traced one and the one-pass render."""
    from mitsonar.plugins.integrators import sonar_tof

    scene = small_scene(mitsonar_mod)
    one = render(scene, True, monkeypatch, seed=7, spp=40)
    monkeypatch.setattr(sonar_tof, "MAX_SPP_PER_PASS", 16)   # passes of 16, 16, 8
    frozen = render(scene, True, monkeypatch, seed=7, spp=40)
    np.testing.assert_array_equal(frozen.astype(np.float32),
                                  render(scene, False, monkeypatch, seed=7, spp=40).astype(np.float32))
    np.testing.assert_allclose(frozen, one, rtol=1e-9, atol=0)


def test_emitted_directions_drawn_apart_equal_the_fused_path(mitsonar_mod, monkeypatch):
    """The pass draws the emitted directions in a kernel of their own (the beam's sampling table
    cannot be read inside a recording): the histogram equals that of the path function drawing
    them itself, bit for bit in float32."""
    import drjit as dr
    import mitsuba as mi

    scene = small_scene(mitsonar_mod)
    integ, sensor = scene.integrator(), scene.sensors()[0]
    setup = integ.setup(scene, sensor)
    ping, samples = integ.lanes(sensor.n_pings, 9, 0, 24)
    hist = dr.zeros(mi.Float64, sensor.n_pings * sensor.n_bins)

    def record(k, rng, energy, valid, hit):
        b, valid = setup.bins.index(rng, valid)
        dr.scatter_add(hist, mi.Float64(energy), setup.bins.flat(ping, b), valid)

    with dr.suspend_grad():
        integ.sample(setup, ping, samples, record)
    fused = hist.numpy().reshape(sensor.n_pings, sensor.n_bins) / 24
    frozen = render(scene, True, monkeypatch, seed=9, spp=24)
    if on_cuda():   # two kernels, fused differently by ptxas: float32 rounding apart (1e-4 on an H100)
        np.testing.assert_allclose(frozen, fused, rtol=1e-3, atol=0)
        return
    np.testing.assert_array_equal(frozen.astype(np.float32), fused.astype(np.float32))
    np.testing.assert_allclose(frozen, fused, rtol=1e-12, atol=0)


def test_multibeam_heads_share_beams_by_default(mitsonar_mod):
    """Unset ``share_beams``: a multibeam head that can share traces shared paths (the render of
    ``share_beams="true"``), a sinc receive beam falls back to per-row paths without a word (the
    render of ``"false"``), and ``"false"`` opts out."""
    def scan(pattern, share, kind="multibeam"):
        scene = small_scene(mitsonar_mod, kind, pattern, share=share)
        return scene.integrator().render_histogram(scene, 0, seed=2, spp=16).astype(np.float32)

    auto = scan("gaussian", None)
    np.testing.assert_array_equal(auto, scan("gaussian", True))
    assert not np.array_equal(auto, scan("gaussian", False))
    np.testing.assert_array_equal(scan("sinc", None), scan("sinc", False))
    np.testing.assert_array_equal(scan("gaussian", None, "mechanical"), scan("gaussian", False, "mechanical"))
    scene = small_scene(mitsonar_mod, "multibeam")
    assert "share_beams=auto" in str(scene.integrator())


def test_a_scene_loaded_between_renders_records_anew(mitsonar_mod, monkeypatch):
    """A recording's BSDF and shape calls are bound to Dr.Jit's registry of instances: after
    another scene is loaded the replay is refused by Dr.Jit and the pass is recorded anew, with
    the traced pass's result."""
    scene = small_scene(mitsonar_mod)
    first = render(scene, True, monkeypatch, seed=1, spp=16)
    other = small_scene(mitsonar_mod, n_pings=5)     # more BSDFs and shapes in the registry
    render(other, True, monkeypatch, seed=1, spp=16)
    again = render(scene, True, monkeypatch, seed=1, spp=16)
    np.testing.assert_array_equal(again.astype(np.float32), first.astype(np.float32))
    traced = render(scene, False, monkeypatch, seed=1, spp=16)
    np.testing.assert_array_equal(again.astype(np.float32), traced.astype(np.float32))


def test_a_changed_scene_parameter_reaches_the_replay(mitsonar_mod, monkeypatch):
    """A BSDF parameter changed through ``mi.traverse`` between renders is an input of the
    replay, not a value baked into the recording: the replay equals the traced render of the
    changed scene, and differs from the render before the change."""
    import mitsuba as mi

    scene = small_scene(mitsonar_mod)
    before = render(scene, True, monkeypatch, seed=1, spp=16)
    params = mi.traverse(scene)
    key = next(k for k in params.keys() if k.endswith("diffuse"))
    params[key] = mi.Float(0.2)
    params.update()
    after = render(scene, True, monkeypatch, seed=1, spp=16)
    traced = render(scene, False, monkeypatch, seed=1, spp=16)
    np.testing.assert_array_equal(after.astype(np.float32), traced.astype(np.float32))
    assert not np.allclose(after, before)


@pytest.mark.parametrize("nested", [False, True])
def test_textured_bsdf_follows_its_texels(mitsonar_mod, monkeypatch, tmp_path, nested):
    """A diffuse bitmap's texels changed through mi.traverse between frozen renders: each render
    equals the traced one of the changed scene (such scenes are traced: a replay was seen to read
    the texels before a change), also when the acoustic BSDF sits inside a twosided one (a C++
    BSDF, which the recording's walk over Python objects does not enter)."""
    import mitsuba as mi

    path = str(tmp_path / "reflectance.exr")
    mi.Bitmap(np.full((4, 4, 1), 0.3, np.float32)).write(path)
    tex = (f'<bsdf type="acoustic"><texture type="bitmap" name="diffuse"><string name="filename" value="{path}"/>'
           '<boolean name="raw" value="true"/><string name="filter_type" value="nearest"/></texture>'
           '<float name="specular" value="0"/></bsdf>')
    if nested:
        tex = f'<bsdf type="twosided">{tex}</bsdf>'

    floor = np.diag([4.0, 4.0, 1.0, 1.0])
    floor[:3, 3] = (0.0, 0.0, -2.0)
    scene = mitsonar_mod.load_scene(scene_xml(sonar_xml(frame_matrix((0.3, 0.0, -1.0), (0.0, 1.0, 0.0)), n_pings=4,
                                                        n_bins=30, beamwidth_h=30.0, beamwidth_v=30.0,
                                                        bearing_step=10.0), rectangle_xml(floor, tex)))
    params = mi.traverse(scene)
    key = next(k for k in params.keys() if k.endswith("diffuse.data"))
    totals = []
    for v in (0.65, 0.55, 0.6):
        params[key] = mi.TensorXf(np.full((4, 4, 1), v, np.float32))
        params.update()
        frozen = render(scene, True, monkeypatch, seed=1, spp=64)
        totals.append(frozen.sum())
        np.testing.assert_array_equal(frozen.astype(np.float32),
                                      render(scene, False, monkeypatch, seed=1, spp=64).astype(np.float32))
    assert totals[0] > totals[2] > totals[1] > 0


def test_integrators_with_the_same_settings_share_a_recording(mitsonar_mod, monkeypatch):
    """render_scan with an integrator dict makes a new integrator per call: equal settings replay
    the recording, other settings (sampling) record their own and render their own scan."""
    from mitsonar.plugins.integrators.paths import frozen_pass as fp
    monkeypatch.setattr(fp, "FREEZE", True)
    scene = small_scene(mitsonar_mod)
    scans, counts = {}, []
    # Objects freed in between (other tests' scenes) change Dr.Jit's registry, which makes the
    # next pass record anew (`frozen_pass.run`): collect them first and hold the collector off.
    gc.collect()
    # and start from no recording: past `MAX_RECORDINGS` (other tests' passes) all are dropped
    fp.clear()
    gc.disable()
    try:
        for sampling in ("sobol", "sobol", "independent"):
            counts.append(fp._frozen.n_recordings)
            scan = mitsonar_mod.render_scan(scene, spp=16, seed=2, integrator={"type": "sonar_tof", "max_depth": 3,
                                                                                "sampling": sampling})
            scans.setdefault(sampling, []).append(scan.intensity)
    finally:
        gc.enable()
    counts.append(fp._frozen.n_recordings)
    assert np.diff(counts).tolist()[1:] == [0, 1], counts    # the second sobol render replays
    np.testing.assert_array_equal(scans["sobol"][0], scans["sobol"][1])
    assert not np.array_equal(scans["sobol"][0], scans["independent"][0])
