"""The water as one value (mitsonar.acoustics.water.Water) and the one nominal sound speed
(SOUND_SPEED) that every ``sound_speed`` default takes."""
import ast
import math
import os

import pytest

from conftest import frame_matrix, scene_xml, sonar_xml

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))


def test_water_defaults_are_the_sensors_and_map_onto_its_parameters(mitsonar_mod):
    from mitsonar.acoustics import Water
    from mitsonar.plugins import water

    assert water.WATER_DEFAULTS == Water().sensor_parameters() == \
        {"temperature": 10.0, "salinity": 35.0, "ph": 8.0, "surface_z": 0.0}
    w = Water(temperature=12.0, salinity=34.0, ph=7.9, surface_z=5.0)
    assert Water.from_sensor_parameters(w.sensor_parameters()) == w
    # the sensor given this water's parameters computes what the water computes at the head's depth
    xml = sonar_xml(frame_matrix((1, 0, 0), (0, 0, 1), (0, 0, -20.0)), n_pings=1, n_bins=8,
                    absorption="auto", sound_speed="auto", frequency=200e3, **w.sensor_parameters())
    s = mitsonar_mod.load_scene(scene_xml(xml)).sensors()[0]
    assert w.depth(-20.0) == 25.0
    assert s.sound_speed == pytest.approx(float(w.sound_speed(25.0)), rel=1e-12)
    assert s.absorption == pytest.approx(float(w.absorption(200e3, 25.0)), rel=1e-12)


def test_water_names_its_equations():
    from mitsonar.acoustics import Water, absorption, sound_speed

    w = Water(temperature=4.0, salinity=34.5, latitude=60.0, sound_speed_model="unesco",
              absorption_model="francois_garrison")
    assert w.sound_speed(800.0) == sound_speed(4.0, 34.5, 800.0, model="unesco", latitude=60.0)
    assert w.sound_speed(800.0) != sound_speed(4.0, 34.5, 800.0, model="unesco", latitude=0.0)
    assert w.absorption(100e3, 800.0) == absorption(100e3, 4.0, 34.5, 800.0, 8.0, model="francois_garrison")


@pytest.mark.parametrize("field, value, words", [
    ("sound_speed_model", "wilson", "one of mackenzie, unesco, del_grosso"),
    ("absorption_model", "thorp", "one of francois_garrison, ainslie_mccolm, fresh_water, auto"),
    ("temperature", math.nan, "a finite number"),
    ("surface_z", "0", "a finite number"),
    ("salinity", -1.0, "a salinity >= 0 ppt"),
    ("latitude", 91.0, "-90 to 90 deg"),
])
def test_water_refuses_a_field_in_one_line(field, value, words):
    from mitsonar.acoustics import Water

    with pytest.raises(ValueError) as e:
        Water(**{field: value})
    assert str(e.value) == f"Water '{field}': {value!r} is not allowed ({words})"


def _literal_sound_speeds(path):
    """(line, name) of each default of 1500 (a parameter's, a field's) in the code at ``path``."""
    with open(path, encoding="utf-8") as fh:
        tree = ast.parse(fh.read(), path)
    out = []
    for node in ast.walk(tree):
        if isinstance(node, (ast.FunctionDef, ast.AsyncFunctionDef)):
            a = node.args
            pos = a.posonlyargs + a.args
            pairs = list(zip(pos[len(pos) - len(a.defaults):], a.defaults)) + \
                [(k, d) for k, d in zip(a.kwonlyargs, a.kw_defaults) if d is not None]
            out += [(d.lineno, k.arg) for k, d in pairs if isinstance(d, ast.Constant) and d.value == 1500]
        elif isinstance(node, ast.AnnAssign) and isinstance(node.value, ast.Constant) and node.value.value == 1500:
            out.append((node.lineno, ast.unparse(node.target)))
    return out


# The Scan's own field default is the scan room's (reworked beside this change; it joins at the merge).
NOT_YET = {os.path.join(ROOT, "mitsonar", "scan", "model.py")}


def test_every_sound_speed_default_is_the_one_named_default():
    """No signature or field writes 1500 m/s itself: they take `SOUND_SPEED` (one place to read
    or change the nominal water)."""
    bad = []
    for folder in ("mitsonar", "plugins"):
        for root, _, files in os.walk(os.path.join(ROOT, folder)):
            for f in files:
                path = os.path.join(root, f)
                if f.endswith(".py") and path not in NOT_YET:
                    bad += [(os.path.relpath(path, ROOT), line, name) for line, name in _literal_sound_speeds(path)]
    assert bad == []
