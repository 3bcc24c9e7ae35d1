"""The size bounds of a scene's settings (`mitsonar._limits`, issue 56 item 6): every bounded XML
parameter is refused past its bound in one line naming the file, the plugin, the parameter and
the interval from the one table; ``range_max`` 1e30 once rendered bins 2e27 m wide, pings 2.6e29 s
apart and an all-zero scan. The shipped scenes stay inside (tests/test_example_scenes.py)."""
import pytest
from conftest import scene_xml, sonar_xml

from mitsonar._limits import LIMITS, RANGE_MAX_M

BIG = 3_000_000_000   # past a signed 32-bit count
SAMPLER = '<sampler type="independent"><integer name="sample_count" value="{}"/></sampler></sensor>'


def _integrator(kind, **params):
    body = "".join(f'<integer name="{k}" value="{v}"/>' for k, v in params.items())
    return f'<integrator type="{kind}">{body}</integrator>'


# (plugin, parameter, table key, the scene's XML): one case per bounded parameter, each just
# past its upper bound (the lower ends were refused before; they still are).
CASES = [
    ("sonar", "range_max", "range_max", scene_xml(sonar_xml(range_max=1e30))),
    ("sonar", "range_max", "range_max", scene_xml(sonar_xml(range_max=RANGE_MAX_M * 1.01))),
    ("sonar", "range_min", "range_min", scene_xml(sonar_xml(range_min=2e5, range_max=3e5))),
    ("sonar", "n_bins", "n_bins", scene_xml(sonar_xml(n_bins=70000))),
    ("sonar", "n_pings", "n_pings", scene_xml(sonar_xml(n_pings=200000))),
    ("sonar", "n_pings", "n_beams", scene_xml(sonar_xml(kind="multibeam", n_pings=5000, bearing_step=0.01))),
    ("sonar", "ping_period", "ping_period", scene_xml(sonar_xml(ping_period=4000.0))),
    ("sonar", "sample_count", "spp", scene_xml(sonar_xml()).replace("</sensor>", SAMPLER.format(BIG))),
    ("sonar_tof", "max_depth", "max_depth", scene_xml(sonar_xml(), integrator=_integrator("sonar_tof", max_depth=65))),
    ("sonar_tof", "svp_chords", "svp_chords",
     scene_xml(sonar_xml(), integrator=_integrator("sonar_tof", svp_chords=2000))),
    ("sonar_mlt", "chains", "chains", scene_xml(sonar_xml(), integrator=_integrator("sonar_mlt", chains=BIG))),
    ("sonar_mlt", "mutations", "mutations",
     scene_xml(sonar_xml(), integrator=_integrator("sonar_mlt", mutations=BIG))),
    ("sonar_mlt", "bootstrap", "bootstrap",
     scene_xml(sonar_xml(), integrator=_integrator("sonar_mlt", bootstrap=BIG))),
]


@pytest.mark.parametrize("plugin, name, key, xml", CASES, ids=[f"{c[0]}.{c[1]}:{c[2]}" for c in CASES])
def test_a_size_past_its_bound_is_refused_naming_the_file_and_the_bound(mitsonar_mod, tmp_path, plugin, name,
                                                                          key, xml):
    path = tmp_path / "big.xml"
    path.write_text(xml)
    with pytest.raises(mitsonar_mod.SceneError) as err:
        mitsonar_mod.load_scene(str(path))
    line = str(err.value)
    top = LIMITS[key].hi
    assert "\n" not in line and str(path) in line, line
    assert f"{plugin} '{name}':" in line and "is not allowed" in line, line
    # the interval, its upper end the table's
    assert f"to {int(top)}{LIMITS[key].unit}" in line or f"at most {int(top)}{LIMITS[key].unit}" in line, line


def test_the_echo_sounders_use_the_same_bounds(mitsonar_mod):
    from mitsonar.scenes import echosounders

    for kwargs, message in ((dict(range_max=2e5), "echosounder 'range_max': 200000.0 is not allowed (a range > "
                                                  "range_min = 0.5 m, at most 100000 m)"),
                            (dict(n_beams=5000), "echosounder 'n_beams': 5000 is not allowed (a whole number of "
                                                 "receive beams from 2 to 4096)"),
                            (dict(n_bins=70000), "echosounder 'n_bins': 70000 is not allowed (1 to 65536)")):
        with pytest.raises(ValueError) as err:
            echosounders.configure("r2sonic_2024", **kwargs)
        assert str(err.value) == message


def test_sizes_at_their_bounds_load(mitsonar_mod):
    """The bounds are inclusive: a 100 km window, 65536 bins, 4096 beams load."""
    scene = mitsonar_mod.load_scene(scene_xml(sonar_xml(range_max=RANGE_MAX_M, n_bins=65536, n_pings=1)))
    assert scene.sensors()[0].range_max == RANGE_MAX_M
    scene = mitsonar_mod.load_scene(scene_xml(sonar_xml(kind="multibeam", n_pings=4096, bearing_step=0.01,
                                                        n_bins=8)))
    assert scene.sensors()[0].n_pings == 4096
