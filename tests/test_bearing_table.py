"""A multibeam head's own table of beam bearings (the sensor's ``bearings``): the scan's rows are
the table, a target's echo lands in the row whose table bearing points at it for an uneven
(sine-spaced) table with per-row and with shared paths, an even table renders as
``bearing_start``/``bearing_step`` do byte for byte, and bad tables are refused in one line."""
import numpy as np
import pytest

from conftest import acoustic_xml, frame_matrix, scene_xml, sonar_xml, sphere_xml

from mitsonar.presets.oculus import bearing_table

HEAD = frame_matrix((1.0, 0.0, 0.0), (0.0, 0.0, 1.0))
TARGET = np.array([4.0, -2.3, 0.0])          # about 30 deg off the boresight, 4.6 m away


def target_scene(mitsonar_mod, share=None, **params):
    base = dict(kind="multibeam", range_min=0.5, range_max=8.0, n_bins=60, beam_pattern="gaussian",
                beamwidth_h=1.0, beamwidth_v=20.0)
    base.update(params)
    extra = "" if share is None else f'<boolean name="share_beams" value="{str(share).lower()}"/>'
    integ = f'<integrator type="sonar_tof"><integer name="max_depth" value="1"/>{extra}</integrator>'
    return mitsonar_mod.load_scene(scene_xml(sonar_xml(HEAD, **base), sphere_xml(tuple(TARGET), 0.15,
                                             acoustic_xml(diffuse=0.8)), integrator=integ))


SINE = bearing_table(130.0, 64) / 100.0          # the Oculus's table: sine-spaced, 0.01 deg


@pytest.mark.parametrize("share", [False, True])
def test_the_echo_lands_in_the_row_whose_table_bearing_points_at_the_target(mitsonar_mod, share):
    table = " ".join(f"{b:.2f}" for b in SINE)
    scene = target_scene(mitsonar_mod, share=share, bearings=table)
    scan = mitsonar_mod.render_scan(scene, spp=256, seed=1)
    assert scan.n_pings == len(SINE)
    np.testing.assert_allclose(np.degrees(scan.bearings), SINE, atol=1e-9)
    # the row whose boresight (pose's z axis) is nearest the target's direction
    d = TARGET / np.linalg.norm(TARGET)
    aimed = int(np.argmax(scan.poses[:, :3, 2] @ d))
    assert abs(SINE[aimed]) > 20                  # off-axis, where the table's steps are uneven
    energy = scan.intensity.sum(axis=1)
    assert int(np.argmax(energy)) == aimed
    # the rows an even fan would have put there are not the ones that hear it
    assert energy[aimed] > 3 * np.delete(energy, [aimed - 1, aimed, aimed + 1]).max()


@pytest.mark.parametrize("share", [False, True])
def test_an_even_table_renders_as_bearing_start_and_step(mitsonar_mod, share):
    even = -20.0 + 0.5 * np.arange(81)
    a = mitsonar_mod.render_scan(target_scene(mitsonar_mod, share=share, bearings=",".join(f"{b:g}" for b in even)),
                                 spp=64, seed=2)
    b = mitsonar_mod.render_scan(target_scene(mitsonar_mod, share=share, bearing_start=-20.0, bearing_step=0.5,
                                              n_pings=81), spp=64, seed=2)
    np.testing.assert_array_equal(a.bearings, b.bearings)
    np.testing.assert_array_equal(a.intensity, b.intensity)
    np.testing.assert_array_equal(a.data, b.data)
    assert a.data.any()


@pytest.mark.parametrize("params, words", [
    (dict(bearings="1 2 2"), "strictly increasing"),
    (dict(bearings="-190 0 10"), "[-180, 180]"),
    (dict(bearings="1, x, 3"), "'bearings'"),
    (dict(bearings="1 2 3", bearing_step=1.0), "'bearing_step': not used with 'bearings'"),
    (dict(bearings="1 2 3", n_pings=3), "'n_pings': not used with 'bearings'"),
    (dict(bearings="1 2 3", kind="mechanical"), "only used with kind 'multibeam'"),
])
def test_a_bad_table_is_refused_in_one_line(mitsonar_mod, params, words):
    with pytest.raises(Exception) as err:
        target_scene(mitsonar_mod, **params)
    msg = str(err.value)
    assert "bearings" in msg or "bearing_step" in msg or "n_pings" in msg
    assert words in msg
