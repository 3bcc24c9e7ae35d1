"""Issue "Frame overhead", the fixed cost of a frame: the recording key's walk
(`frozen_pass.jit_state`) takes most members without a call and must find the same values and
the same key as before; what a user changes between frames (a sensor parameter, a BSDF
parameter through ``mi.traverse``) reaches the next frame's render, never a stale recording or
emitter."""
import os

import numpy as np
import pytest

HERE = os.path.dirname(os.path.abspath(__file__))
SCENES = os.path.join(HERE, "..", "scenes_xml")


def _jit_state_before(obj):
    """`frozen_pass.jit_state` as it was before (every member through one recursive call)."""
    import drjit as dr
    import mitsuba as mi

    values, scalars, seen = [], [], set()

    def walk(o, path):
        if isinstance(o, (bool, int, float, str, type(None), np.generic)):
            scalars.append((path, o if not isinstance(o, np.generic) else o.item()))
            return
        if isinstance(o, np.ndarray):
            return
        if id(o) in seen:
            return
        seen.add(id(o))
        if isinstance(o, dr.ArrayBase):
            values.append(o)
            scalars.append((path, type(o).__name__, dr.width(o)))
            return
        if isinstance(o, (tuple, list)):
            for i, v in enumerate(o):
                walk(v, f"{path}[{i}]")
            return
        if isinstance(o, dict):
            for k in sorted(o, key=str):
                walk(o[k], f"{path}[{k!r}]")
            return
        if isinstance(o, dr.detail.TraversableBase):
            values.append(o)
            scalars.append((path, type(o).__name__, id(o)))
            if isinstance(o, mi.Scene):
                for i, shape in enumerate(o.shapes()):
                    walk(shape.bsdf(), f"{path}.shapes[{i}].bsdf")
            if not hasattr(o, "__dict__"):
                return
        elif not hasattr(o, "__dict__"):
            scalars.append((path, type(o).__name__, id(o)))
            return
        for k, v in sorted(vars(o).items()):
            walk(v, f"{path}.{k}")

    walk(obj, "")
    return values, tuple(scalars)


class _Members:
    """A context with members of every kind the walk tells apart."""

    def __init__(self, mi, shared):
        import enum

        self.flag, self.count, self.ratio, self.name, self.nothing = True, 3, 0.25, "gaussian", None
        self.np_scalar, self.np_float = np.int32(7), np.float64(0.5)
        self.mode = enum.IntEnum("Mode", "A B").B          # an int subclass: walked, not inlined
        self.host = np.arange(4.0)                           # host data: skipped
        self.nested = [1, (2.5, "x", None, [False, np.float32(1.5)]), {"b": 2, "a": mi.Float(1.0)}]
        self.shared = shared
        self.again = shared                                  # seen once (walked under .again)
        self.opaque = object()


@pytest.mark.parametrize("scene_file, share", [("quay_wall.xml", None), ("quay_wall.xml", False),
                                               ("box.xml", None), ("harbour.xml", None),
                                               ("pile_quay.xml", None)])
def test_key_walk_finds_what_it_found_before(mitsonar_mod, scene_file, share):
    """The walk with its leaves taken inline: the same JIT values (the same objects, in the same
    order) and the same key as the recursive walk, for the passes' contexts (shared frames,
    per-row setups, guided scenes) and for members of every kind."""
    import mitsuba as mi

    from mitsonar.plugins.integrators.paths import frozen_pass as fp, shared_beams as sb
    scene = mitsonar_mod.load_scene(os.path.join(SCENES, scene_file))
    integ, sensor = scene.integrator(), scene.sensors()[0]
    setup = integ.setup(scene, sensor)
    contexts = [setup]
    if share is None and sb.can_share(setup.sensor):
        contexts.append(sb.SharedFrame(setup))
    contexts.append(_Members(mi, contexts[-1]))
    for ctx in contexts:
        values, key = fp.jit_state(ctx)
        want_values, want_key = _jit_state_before(ctx)
        assert key == want_key
        assert [id(v) for v in values] == [id(v) for v in want_values]
        assert len(values) > 0
    _, key = fp.jit_state(contexts[-1])
    entries = dict((k[0], k[1:]) for k in key)
    assert entries[".mode"] == (2,) and entries[".np_scalar"] == (7,) and entries[".nested[1][3][1]"] == (1.5,)
    # host data skipped; the frame reached twice walked once, under the first name in sorted order
    assert ".host" not in entries and not any(k.startswith(".shared.") for k in entries)
    assert any(k.startswith(".again.") for k in entries)


def _render(mitsonar_mod, scene, seed=3):
    return mitsonar_mod.render_scan(scene, spp=2, seed=seed).intensity


def _cold(mitsonar_mod, monkeypatch, scene):
    """The same render as a process's first would make it: every pass traced afresh (no recording
    replayed), no receive-weighted emitter nor speckle field kept from an earlier frame."""
    from mitsonar.plugins.integrators.paths import frozen_pass, receive_emission
    from mitsonar.receiver import speckle

    frozen_pass.clear()
    receive_emission._cache.clear()
    with monkeypatch.context() as m:
        m.setattr(frozen_pass, "FREEZE", False)
        m.setattr(speckle, "CACHE_SIZE", 0)
        return _render(mitsonar_mod, scene)


@pytest.mark.parametrize("key, value", [("sonar.beamwidth_h", 0.8), ("sonar.absorption", 0.3),
                                        ("sonar.to_world", None)])
def test_sensor_changed_through_traverse_reaches_the_next_frame(mitsonar_mod, monkeypatch, key, value):
    """A multibeam frame replayed (its recording, receive-weighted emitter, range window and
    speckle field made for the first frame), then the sensor's beam width, absorption or pose
    changed through ``mi.traverse``: the next frame is the one a fresh process renders, bit for
    bit, not the old one."""
    import mitsuba as mi

    scene = mitsonar_mod.load_scene(os.path.join(SCENES, "quay_wall.xml"))
    before = _render(mitsonar_mod, scene)
    assert before.tobytes() == _render(mitsonar_mod, scene).tobytes()      # replayed: the same frame
    params = mi.traverse(scene)
    if value is None:       # the head moved 0.2 m along x
        m = np.array(params[key].matrix, dtype=np.float64).reshape(4, 4)
        m[0, 3] += 0.2
        value = mi.Transform4f(mi.Matrix4f(m))
    params[key] = value
    params.update()
    after = _render(mitsonar_mod, scene)
    assert not np.array_equal(after, before)
    assert after.tobytes() == _cold(mitsonar_mod, monkeypatch, scene).tobytes()


def test_bsdf_changed_through_traverse_reaches_the_next_frame(mitsonar_mod, monkeypatch):
    """The quay wall's seabed reflectance changed through ``mi.traverse`` between replayed
    frames: the next frame is the one a fresh process renders, and differs from the frame before."""
    import mitsuba as mi

    scene = mitsonar_mod.load_scene(os.path.join(SCENES, "quay_wall.xml"))
    before = _render(mitsonar_mod, scene)
    params = mi.traverse(scene)
    keys = [k for k in params.keys() if k.endswith(".diffuse")]
    assert keys
    for k in keys:
        params[k] = mi.Float(0.9 * float(params[k][0]))
    params.update()
    after = _render(mitsonar_mod, scene)
    assert not np.array_equal(after, before)
    assert after.tobytes() == _cold(mitsonar_mod, monkeypatch, scene).tobytes()


def test_traversed_beam_width_renders_as_the_xml_width(mitsonar_mod):
    """A multibeam's transmit fan follows the beam's widths unless the XML sets its own: the quay
    wall with ``beamwidth_h`` 0.8 deg set through ``mi.traverse`` renders the bytes of the scene
    loaded with 0.8 in its XML (the fan as wide as the swath plus one new beam width), not a fan
    kept from the 0.5 deg beam."""
    import mitsuba as mi

    path = os.path.join(SCENES, "quay_wall.xml")
    with open(path) as f:
        xml = f.read()
    old = '<float name="beamwidth_h" value="0.5"/>'
    assert old in xml
    loaded = mitsonar_mod.load_scene(xml.replace(old, '<float name="beamwidth_h" value="0.8"/>'))
    traversed = mitsonar_mod.load_scene(path)
    params = mi.traverse(traversed)
    params["sonar.beamwidth_h"] = 0.8
    params.update()
    tx_t, tx_l = traversed.sensors()[0].transmit, loaded.sensors()[0].transmit
    assert (tx_t.beamwidth_h, tx_t.beamwidth_v) == pytest.approx((tx_l.beamwidth_h, tx_l.beamwidth_v), rel=1e-6)
    assert _render(mitsonar_mod, traversed).tobytes() == _render(mitsonar_mod, loaded).tobytes()
