"""The `surface` option of survey scenes (issue 22): a flat specular sea surface at z = 0, off by
default, that puts a target's surface ghost at the image-source range in every kind of head."""
import math
import os

import numpy as np
import pytest

from conftest import SCENES, acoustic_xml, frame_matrix, scene_xml, sonar_xml, sphere_xml

H, D, A = 1.0, 6.0, 0.1      # head 1 m under the surface, a sphere of radius 0.1 m 6 m ahead
IMAGE = math.hypot(D, 2 * H)  # |t' - h|, t' the target's mirror image in the surface z = 0
MIXED = (D + IMAGE) / 2


def target_scene(kind):
    """A head at (0, 0, -1) looking along +x with a beam 60 deg tall, and the sphere at (6, 0, -1)."""
    head = frame_matrix((1, 0, 0), (0, 0, 1), (0.0, 0.0, -H))
    if kind == "mechanical":
        extra = dict(beamwidth_h=3.0, n_pings=1, bearing_step=0.0)
    else:
        extra = dict(beamwidth_h=2.0, n_pings=3, bearing_start=-2.0, bearing_step=2.0, tx_beamwidth_h=20.0,
                     tx_beamwidth_v=60.0)
    sensor = sonar_xml(head, kind=kind, beamwidth_v=60.0, range_min=5.0, range_max=7.0, n_bins=200, **extra)
    return scene_xml(sensor, sphere_xml((D, 0, -H), A, acoustic_xml(0.9)),
                     integrator='<integrator type="sonar_tof"><integer name="max_depth" value="3"/></integrator>')


@pytest.mark.parametrize("kind", ["mechanical", "multibeam"])
def test_surface_ghost_at_the_image_source_range_only_with_the_surface(mitsonar_mod, kind):
    """With the surface: echoes at the image-source constructions only: the direct one (from
    D - a), the mixed one (via the surface one way, from (D + |t' - h|) / 2 - a = 6.06 m) and the
    ghost (via the surface both ways, from |t' - h| - a = 6.22 m), with no echo between the direct
    and the mixed one, and the ghost's first bin where the image source puts it, after a gap.
    Without it: nothing beyond the sphere's limb (D, up to one bin). The ghost's paths need the
    mirror's narrow lobe twice (rare paths): four seeds of 2^18 paths are summed."""
    from mitsonar.scenes.sea_surface import load_survey_scene

    xml = target_scene(kind)
    out = {}
    for surface, seeds in ((False, (1,)), (True, (1, 2, 3, 4))):
        scene = load_survey_scene(xml, surface=surface)
        scans = [mitsonar_mod.render_scan(scene, spp=1 << 18, seed=s) for s in seeds]
        row = scans[0].n_pings // 2                        # the beam on the target
        out[surface] = np.mean([s.intensity[row].astype(np.float64) for s in scans], axis=0)
    r = scans[0].ranges
    bin_w = r[1] - r[0]
    band = lambda e, lo, hi: e[(r > lo) & (r < hi)].sum()  # noqa: E731
    off, on = out[False], out[True]
    direct = band(off, D - A - 0.02, D + 0.02)
    assert direct > 0 and band(on, D - A - 0.02, D + 0.02) == pytest.approx(direct, rel=0.05)
    assert off[r > D + bin_w].sum() == 0                                         # no surface: no ghost
    assert band(on, MIXED - A - 0.02, MIXED + 0.02) > 1e-2 * direct
    assert band(on, D + bin_w, MIXED - A - bin_w) <= 1e-12 * direct             # nothing earlier than the constructions
    ghost = band(on, IMAGE - A - bin_w, IMAGE + 0.02)
    assert ghost > 1e-3 * direct
    # "nothing" is below 1e-12 of the direct echo: a multibeam frame's shared paths score every echo
    # into the neighbouring beams by their gain, whose gaussian tail puts 1e-35 where a beam's own
    # paths put exactly 0
    late = r[(on > 1e-12 * direct) & (r > MIXED + bin_w)]
    assert abs(late[0] - (IMAGE - A)) <= bin_w                                   # the ghost's onset: the image range
    assert band(on, MIXED + bin_w, IMAGE - A - bin_w) <= 1e-12 * direct          # after a gap


def test_surface_option_is_off_by_default_and_adds_one_downward_mirror(mitsonar_mod, tmp_path, monkeypatch):
    from mitsonar.scenes.sea_surface import SURFACE_HALF_SIZE, edit_scene, load_survey_scene

    path = os.path.join(SCENES, "rocky_slope.xml")
    plain = mitsonar_mod.scene_mesh(load_survey_scene(path))
    np.testing.assert_allclose(plain[0].max(0)[2], -7.61, atol=0.01)       # as mitsonar.load_scene: no surface
    monkeypatch.chdir(tmp_path)                                              # its PLY found from anywhere
    scene = load_survey_scene(path, surface=True)
    V, F = mitsonar_mod.scene_mesh(scene)
    assert len(V) == len(plain[0]) + 4
    top = V[np.abs(V[:, 2]) < 1e-9]
    assert len(top) == 4
    np.testing.assert_allclose(np.abs(top[:, :2]), SURFACE_HALF_SIZE)
    import mitsuba as mi

    shape = [s for s in scene.shapes() if s.id() == "sea_surface"][0]
    si = scene.ray_intersect(mi.Ray3f(mi.Point3f(3, 2, -5), mi.Vector3f(0, 0, 1)))
    assert float(si.t[0]) == pytest.approx(5.0) and si.shape == shape
    assert float(si.n.z[0]) == pytest.approx(-1.0)                           # facing the water
    with pytest.raises(ValueError, match=r"scene option 'surface': 'yes' is not allowed \(True or False\)"):
        edit_scene(path, surface="yes")
    with pytest.raises(ValueError, match="already has a shape 'sea_surface'"):
        edit_scene(edit_scene(path, surface=True), surface=True)


def test_survey_cli_surface_option(tmp_path, mitsonar_mod):
    from mitsonar.cli import main

    out = tmp_path / "s"
    assert main(["survey", os.path.join(SCENES, "wreck.xml"), "--trajectory", os.path.join(SCENES, "wreck_survey.tum"),
                 "--surface", "--max-scans", "1", "--spp", "8", "-q", "-o", str(out)]) == 0
    scan = mitsonar_mod.load_scan(str(out / "scan_00000.npz"))
    assert scan.meta.scene == "wreck.xml +surface"
