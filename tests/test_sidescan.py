"""Side-scan sonar (issue "Side-scan sonar"): the ``sidescan`` kind's channels and rows against closed
forms over a flat Lambertian seabed (nadir gap, grazing falloff, channel separation), a box's
acoustic shadow, the ground-range correction, the waterfall and the mosaic's georeferencing."""
import math
import os

import numpy as np
import pytest

from conftest import SCENES, acoustic_xml, rectangle_xml, scene_xml, sonar_xml

SINGLE = '<integrator type="sonar_tof"><integer name="max_depth" value="1"/></integrator>'


def seabed(z, diffuse, half=200.0):
    m = np.diag([half, half, 1.0, 1.0])
    m[2, 3] = z
    return rectangle_xml(m, acoustic_xml(diffuse=diffuse))


def box_xml(lo, hi, diffuse=0.5):
    c = [(a + b) / 2 for a, b in zip(lo, hi)]
    s = [(b - a) / 2 for a, b in zip(lo, hi)]
    return (f'<shape type="cube"><transform name="to_world"><scale x="{s[0]}" y="{s[1]}" z="{s[2]}"/>'
            f'<translate x="{c[0]}" y="{c[1]}" z="{c[2]}"/></transform>{acoustic_xml(diffuse=diffuse)}</shape>')


def lambert_strip(h, depression, bw_h, bw_v, rho, edges, n_az=48, n_el=24000):
    """Closed form of the mean echo energy per bin of one channel over a flat Lambertian floor at
    depth h below the head, uniform beam: the integral over the beam's solid angle of
    B_tx B_rx (rho / pi) cos(theta) / r^2 (particle weight B / pdf, BSDF rho / pi times cos theta,
    receive gain B, spreading 1 / r^2), with r = h / cos(theta) the range of the direction, binned by
    r. Midpoint rule on (azimuth, elevation), d(omega) = cos(el) d(az) d(el)."""
    az = (np.arange(n_az) + 0.5) / n_az * math.radians(bw_h) - math.radians(bw_h) / 2
    el = (np.arange(n_el) + 0.5) / n_el * math.radians(bw_v) - math.radians(bw_v) / 2
    A, E = np.meshgrid(az, el, indexing="ij")
    d = math.radians(depression)
    # the port channel's beam frame in the head frame: x forward, y (0, -sin d, -cos d), z (0, cos d, -sin d)
    dz = np.sin(E) * -math.cos(d) + np.cos(E) * np.cos(A) * -math.sin(d)
    cos_t = np.clip(-dz, 1e-12, None)
    r = h / cos_t
    w = (rho / math.pi) * cos_t / r ** 2 * np.cos(E) * (math.radians(bw_h) / n_az) * (math.radians(bw_v) / n_el)
    k = np.searchsorted(edges, r, side="right") - 1
    ok = (dz < 0) & (k >= 0) & (k < len(edges) - 1)
    return np.bincount(k[ok], weights=w[ok], minlength=len(edges) - 1)


def test_flat_lambert_seabed_matches_the_closed_form_with_a_nadir_gap_and_separate_channels(mitsonar_mod):
    # Head 5 m above a Lambertian floor, uniform fan 90 deg tilted 45 deg down: from the horizontal
    # to nadir. A strong wall 8 m to starboard must not show in the port channel.
    h, rho, n_bins, rmax = 5.0, 0.5, 80, 20.0
    wall = np.eye(4)
    wall[:3, :3] = [[1, 0, 0], [0, 0, 1], [0, -1, 0]]       # rectangle's normal +z -> +y (faces the head)
    wall[:3, :3] = wall[:3, :3] @ np.diag([50.0, 50.0, 1.0])
    wall[:3, 3] = (0.0, -8.0, 0.0)
    sonar = sonar_xml(kind="sidescan", n_pings=2, n_bins=n_bins, range_max=rmax, beam_pattern="uniform",
                      beamwidth_h=2.0, beamwidth_v=90.0, depression=45.0)
    scene = mitsonar_mod.load_scene(scene_xml(sonar, seabed(-h, rho), rectangle_xml(wall, acoustic_xml(diffuse=0.9)),
                                              integrator=SINGLE))
    scan = mitsonar_mod.render_scan(scene, spp=1 << 16, seed=2)
    assert scan.kind == "sidescan" and scan.n_pings == 4
    np.testing.assert_array_equal(scan.channel, [0, 0, 1, 1])
    port, starboard = scan.intensity[scan.channel == 0].mean(0), scan.intensity[scan.channel == 1].mean(0)
    edges = np.linspace(0.0, rmax, n_bins + 1)
    ref = lambert_strip(h, 45.0, 2.0, 90.0, rho, edges)
    # nadir gap: nothing before the slant range h (the bin holding h is the first with energy)
    first = int(np.argmax(port > 0))
    assert edges[first] <= h < edges[first + 1] and np.all(port[:first] == 0)
    from mitsonar.products.sidescan import first_return
    np.testing.assert_allclose(first_return(scan), (edges[first] + edges[first + 1]) / 2)   # the altitude's bin
    # grazing falloff: the closed form, within 3 % on groups of 5 bins, from the nadir to 20 m
    groups = slice(first - first % 5, n_bins)
    got = port[groups].reshape(-1, 5).sum(1)
    want = ref[groups].reshape(-1, 5).sum(1)
    np.testing.assert_allclose(got, want, rtol=0.03)
    assert want[0] > 30 * want[-1]                          # the falloff is real, not flat
    # the wall (slant >= 8 m to starboard): absent from port, present (echo + occluded floor) to starboard
    far = edges[:-1] >= 8.0
    assert np.abs(starboard[far] - ref[far]).max() > 0.5 * ref[far].max()
    np.testing.assert_allclose(port[far].reshape(-1, 8).sum(1), ref[far].reshape(-1, 8).sum(1), rtol=0.03)


def shadow_edges(values, start, step):
    """(first empty sample, first non-empty sample after it) from ``start`` on."""
    v = np.nan_to_num(values)
    a = start + int(np.argmax(v[start:] == 0))
    b = a + int(np.argmax(v[a:] > 0))
    return a * step, b * step


def test_a_box_casts_the_shadow_the_geometry_gives_in_slant_and_ground_range(mitsonar_mod):
    from mitsonar.products.sidescan import ground_range

    h, y1, y2, H = 5.0, 4.0, 4.8, 1.2
    sonar = sonar_xml(kind="sidescan", side="port", n_pings=1, n_bins=400, range_max=16.0, beamwidth_h=1.0,
                      beamwidth_v=60.0, depression=30.0)
    scene = mitsonar_mod.load_scene(scene_xml(sonar, seabed(-h, 0.5), box_xml((-3, y1, -h - 0.5), (3, y2, -h + H)),
                                              integrator=SINGLE))
    scan = mitsonar_mod.render_scan(scene, spp=1 << 14, seed=1)
    bw = scan.bin_width
    # slant range: the last echo before the shadow is the floor at the box's foot or the box's far
    # top edge, whichever is farther; the floor reappears where the ray over that edge lands
    y_s = y2 * h / (h - H)
    start = max(math.hypot(y1, h), math.hypot(y2, h - H))
    end = math.hypot(y_s, h)
    a, b = shadow_edges(scan.intensity[0], int(5.2 / bw), bw)
    assert abs(a - start) <= 2 * bw and abs(b - end) <= 2 * bw, (a, b, start, end)
    assert end - start > 30 * bw                             # a long shadow, not a gap between bins
    # ground range over the flat floor at the altitude: the shadow runs from the box's foot to y_s
    for kwargs in (dict(altitude=h), dict(seabed=lambda x, y: np.full_like(x, -h)), dict()):
        gr = ground_range(scan, resolution=0.04, **kwargs)
        step = gr.ground[1] - gr.ground[0]
        a, b = shadow_edges(gr.values[0], int(3.0 / step), step)
        assert abs(a - y1) <= 2 * step + bw and abs(b - y_s) <= 2 * step + bw, (kwargs, a, b, y1, y_s)
    # ground range 0 is the nadir (slant h): the nadir gap has no ground position, and ground ranges
    # beyond the range window have no value
    gr = ground_range(scan, altitude=h)
    inside = np.hypot(gr.ground, h) < scan.range_max
    assert np.isfinite(gr.values[0, inside]).all() and np.isnan(gr.values[0, ~inside]).all()
    assert gr.values[0, 0] == scan.intensity[0, int(h / bw)]


def target_scene(mitsonar_mod, target):
    patch = np.diag([0.25, 0.25, 1.0, 1.0])
    patch[:3, 3] = (1.0, -6.0, -4.99)
    shapes = [seabed(-5.0, 0.05)] + ([rectangle_xml(patch, acoustic_xml(diffuse=0.9))] if target else [])
    sonar = sonar_xml(kind="sidescan", n_pings=150, n_bins=300, range_max=15.0, beamwidth_h=1.0, beamwidth_v=60.0,
                      depression=30.0)
    return mitsonar_mod.load_scene(scene_xml(sonar, *shapes, integrator=SINGLE))


def test_a_target_appears_at_its_pixel_of_the_waterfall_and_of_the_mosaic(mitsonar_mod, tmp_path):
    from mitsonar.products.mosaic import Mosaic, mosaic
    from mitsonar.products.sidescan import select_side, waterfall
    from mitsonar.geometry.trajectory import pose

    # a 0.5 m bright patch on a dim floor, 6 m to starboard of a straight track along +x at 2 m/s
    track = mitsonar_mod.Trajectory.straight(10.0, 2.0, start=pose((-2.0, 0.0, 0.0)))
    scans = [mitsonar_mod.render_scan(target_scene(mitsonar_mod, t), spp=256, seed=1, trajectory=track)
             for t in (True, False)]
    assert scans[0].meta.ping_period == pytest.approx(2 * 15.0 / 1500.0)
    # waterfall: the echo's rows are the pings abeam of the patch, its columns the starboard half
    diff = np.nan_to_num(waterfall(scans[0], use="intensity") - waterfall(scans[1], use="intensity"))
    r, c = np.unravel_index(np.argmax(diff), diff.shape)
    x = scans[0].positions[scans[0].channel == 1][::-1, 0][r]       # row 0 is the newest ping
    assert 0.75 - 0.05 <= x <= 1.25 + 0.05
    slant = scans[0].ranges[c - scans[0].n_bins]
    assert c >= scans[0].n_bins and math.hypot(5.75, 5.0) - 0.1 <= slant <= math.hypot(6.25, 5.0) + 0.1
    # the starboard rows alone give the same picture's right half
    star = select_side(scans[0], "starboard")
    assert star.meta.side == "starboard" and np.all(star.channel == 1) and star.n_pings == 150
    np.testing.assert_array_equal(waterfall(star, use="intensity")[:, 300:], waterfall(scans[0], use="intensity")[:, 300:])
    # mosaic: the brightest difference lies on the patch (x in [0.75, 1.25], y in [-6.25, -5.75])
    ms = [mosaic(s, resolution=0.1, bounds=(-3, 5, -8, 8), use="intensity", altitude=5.0) for s in scans]
    d = np.nan_to_num(ms[0].image - ms[1].image)
    r, c = np.unravel_index(np.argmax(d), d.shape)
    px, py = ms[0].pixel_to_world(r, c)
    assert 0.75 - 0.1 <= px <= 1.25 + 0.1 and -6.25 - 0.1 <= py <= -5.75 + 0.1, (px, py)
    assert ms[0].world_to_pixel(px, py) == (r, c)
    # the saved array and transform give the same pixel
    files = ms[0].save(str(tmp_path / "m.png"))
    assert [os.path.basename(f) for f in files] == ["m.png", "m.pgw", "m.npz"]
    back = Mosaic.load(tmp_path / "m.npz")
    assert back.transform == ms[0].transform and back.world_to_pixel(1.0, -6.0) == ms[0].world_to_pixel(1.0, -6.0)
    np.testing.assert_array_equal(back.image, ms[0].image)


def test_rows_poses_times_and_the_file_round_trip(mitsonar_mod, tmp_path):
    from mitsonar.geometry.frames import sidescan_rotation

    sonar = sonar_xml(kind="sidescan", n_pings=4, n_bins=50, range_max=30.0, depression=12.0)
    scene = mitsonar_mod.load_scene(scene_xml(sonar, seabed(-5.0, 0.5), integrator=SINGLE))
    track = mitsonar_mod.Trajectory.straight(3.0, 1.5)
    scan = mitsonar_mod.render_scan(scene, spp=64, seed=0, trajectory=track, start_time=0.5)
    period = 2 * 30.0 / 1500.0                           # default: two-way flight to range_max
    np.testing.assert_allclose(scan.times, np.tile(np.arange(4) * period, 2))
    np.testing.assert_array_equal(scan.channel, [0] * 4 + [1] * 4)
    for k in range(8):
        want = track.at(0.5 + scan.times[k]) @ sidescan_rotation(scan.channel[k], math.radians(12.0))
        np.testing.assert_allclose(scan.poses[k], want, atol=1e-12)
    b = scan.boresights
    np.testing.assert_allclose(b[0], [0, math.cos(math.radians(12)), -math.sin(math.radians(12))], atol=1e-12)
    np.testing.assert_allclose(b[4], [0, -math.cos(math.radians(12)), -math.sin(math.radians(12))], atol=1e-12)
    for ext in (".npz", ".exr"):
        scan.save(str(tmp_path / f"s{ext}"))
        back = mitsonar_mod.load_scan(str(tmp_path / f"s{ext}"))
        assert back.kind == "sidescan" and back.meta.depression == 12.0
        np.testing.assert_array_equal(back.channel, scan.channel)
        np.testing.assert_array_equal(back.times, scan.times)


def test_render_survey_splits_a_long_track_into_consecutive_scans(mitsonar_mod, tmp_path):
    sonar = sonar_xml(kind="sidescan", side="starboard", n_pings=10, n_bins=40, range_max=15.0)
    scene = mitsonar_mod.load_scene(scene_xml(sonar, seabed(-5.0, 0.5), integrator=SINGLE))
    track = mitsonar_mod.Trajectory.straight(1.0, 1.5)
    scans = list(mitsonar_mod.render_survey(scene, track, tmp_path / "survey", spp=16, progress=False))
    period = 0.02
    assert len(scans) == int((1.0 - 9 * period) / (10 * period) + 1e-9) + 1 == 5
    starts = [s.meta.start_time for s in scans]
    np.testing.assert_allclose(np.diff(starts), 10 * period)
    # one starboard ping every period, scan after scan, no gap and no overlap
    x = np.concatenate([s.positions[:, 0] for s in scans])
    np.testing.assert_allclose(np.diff(x), 1.5 * period, atol=1e-9)
    assert all(np.all(s.channel == 1) for s in scans)
    assert len(os.listdir(tmp_path / "survey")) == 6         # five scans and trajectory.tum


def test_presets_and_the_wreck_survey_scene(mitsonar_mod):
    from mitsonar.presets import sidescan as sidescan_heads

    presets = sidescan_heads.PRESETS
    scene = mitsonar_mod.load_scene(scene_xml(sonar_xml(kind="sidescan", preset="klein3000_500k", n_pings=2),
                                              seabed(-5.0, 0.5)))
    s = scene.sensors()[0]
    p = presets["klein3000_500k"]
    assert (s.beam.pattern, s.beam.frequency, s.beam.beamwidth_h, s.beam.beamwidth_v, s.range_max, s.depression) == (
        "sinc", p["frequency"], p["beamwidth_h"], p["beamwidth_v"], p["range_max"], p["depression"])
    s = mitsonar_mod.load_scene(scene_xml(sonar_xml(kind="sidescan", preset="starfish450", range_max=50.0,
                                                    depression=15.0), seabed(-5.0, 0.5))).sensors()[0]
    assert (s.range_max, s.depression, s.beam.beamwidth_v) == (50.0, 15.0, presets["starfish450"]["beamwidth_v"])
    # the wreck survey scene: a two-channel head whose survey fits its track
    scene = mitsonar_mod.load_scene(os.path.join(SCENES, "wreck_sidescan.xml"))
    sonar = scene.sensors()[0]
    track = mitsonar_mod.Trajectory.from_tum(os.path.join(SCENES, "wreck_sidescan_survey.tum"))
    assert sonar.kind == "sidescan" and sonar.side == "both" and sonar.n_bins == 1000
    assert sonar.ping_period == pytest.approx(2 * 12.0 / 1500.0)
    assert track.span[1] > 10 * sonar.scan_period
    z = track.positions[:, 2]
    np.testing.assert_allclose(z, -4.0)                        # 4 m above the sand at z = -8


@pytest.mark.parametrize("params, field, allowed", [
    (dict(depression=95.0), "depression", "0 to 90 deg"),
    (dict(depression=-1.0), "depression", "0 to 90 deg"),
    (dict(beamwidth_v=200.0), "beamwidth_v", "(0, 180]"),
    (dict(side="left"), "side", "port, starboard, both"),
    (dict(preset="edgetech"), "preset", "klein3000_100k"),
    (dict(bearing_step=1.0), "bearing_step", "side"),
])
def test_bad_input_is_one_line_naming_the_field_before_any_render(mitsonar_mod, params, field, allowed):
    with pytest.raises(ValueError) as exc:
        mitsonar_mod.load_scene(scene_xml(sonar_xml(kind="sidescan", **params), seabed(-5.0, 0.5)))
    msg = str(exc.value)
    assert f"'{field}'" in msg and allowed in msg and "\n" not in msg and "Traceback" not in msg


def test_sidescan_parameters_are_refused_on_other_kinds(mitsonar_mod):
    for kind in ("mechanical", "multibeam"):
        with pytest.raises(ValueError, match="'depression': only used with kind 'sidescan'"):
            mitsonar_mod.load_scene(scene_xml(sonar_xml(kind=kind, depression=10.0), seabed(-5.0, 0.5)))


def test_a_new_track_or_start_renders_without_compiling(mitsonar_mod):
    from conftest import jit_kernels
    from mitsonar.geometry.trajectory import pose

    sonar = sonar_xml(kind="sidescan", n_pings=20, n_bins=100, range_max=15.0)
    scene = mitsonar_mod.load_scene(scene_xml(sonar, seabed(-5.0, 0.5)))
    a = mitsonar_mod.Trajectory.straight(2.0, 1.5)
    b = mitsonar_mod.Trajectory.turn(3.0, 1.0, 10.0, start=pose((3.0, -1.0, 0.5), yaw=0.3))
    mitsonar_mod.render_scan(scene, spp=16, trajectory=a, start_time=0.2)
    _, fresh = jit_kernels(mitsonar_mod.render_scan, scene, spp=16, seed=5, trajectory=b, start_time=1.0)
    assert fresh == []


def test_the_wreck_survey_shows_the_nadir_gap_and_the_deckhouse_shadow_its_header_gives(mitsonar_mod):
    # First line (y = -5, heading +x, 4 m above the sand): port rows abeam of the deckhouse
    # (x in [-2, -1]) are empty from the deckhouse's far top edge (slant 6.17 m) to where the ray
    # over it lands on the sand (11.05 m across, slant 11.75 m); nothing comes before the nadir (4 m).
    scene = mitsonar_mod.load_scene(os.path.join(SCENES, "wreck_sidescan.xml"))
    track = mitsonar_mod.Trajectory.from_tum(os.path.join(SCENES, "wreck_sidescan_survey.tum"))
    scan = mitsonar_mod.render_scan(scene, spp=64, seed=0, trajectory=track, start_time=5.0, max_depth=1)
    x = scan.positions[:, 0]
    rows = (scan.channel == 0) & (x >= -2.0) & (x <= -1.0)
    assert rows.sum() > 30
    port = scan.intensity[rows].sum(0)
    r = scan.ranges
    edge, land = math.hypot(5.8, 2.1), math.hypot(5.8 * 4 / 2.1, 4.0)
    assert np.all(port[r < 3.9] == 0) and port[(r > 4.0) & (r < 4.3)].sum() > 0
    assert np.all(port[(r > edge + 0.15) & (r < land - 0.15)] == 0)
    assert port[(r > edge - 0.3) & (r < edge)].sum() > 0 and port[r > land + 0.15].sum() > 0


def test_survey_command_writes_the_waterfall_and_the_mosaic(tmp_path, capsys):
    from mitsonar.cli import main
    from mitsonar.products.mosaic import Mosaic

    scene = tmp_path / "ss.xml"
    scene.write_text(scene_xml(sonar_xml(kind="sidescan", n_pings=20, n_bins=60, range_max=12.0),
                               seabed(-4.0, 0.5), integrator=SINGLE))
    out = tmp_path / "out"
    rc = main(["survey", str(scene), "--lawnmower", "0", "3", "0", "0", "--speed", "1.5", "--depth", "0",
               "--spp", "8", "--max-scans", "2", "-q", "-o", str(out)])
    assert rc == 0, capsys.readouterr().err
    assert sorted(os.listdir(out)) == ["mosaic.npz", "mosaic.pgw", "mosaic.png", "scan_00000.npz",
                                       "scan_00000_waterfall.png", "scan_00001.npz", "track.png", "trajectory.tum"]
    m = Mosaic.load(out / "mosaic.npz")
    # the track (y = 0, x from 0 to 2 * 20 pings * 16 ms * 1.5 m/s) is covered, beyond the swath is not
    row, col = m.world_to_pixel(0.5, 5.0)
    assert m.count[row, col] > 0 and np.isfinite(m.image[row, col])
    row, col = m.world_to_pixel(0.5, 11.9)
    assert m.count[row, col] == 0 and np.isnan(m.image[row, col])


def test_long_range_survey_mosaic_is_sized_before_any_render(mitsonar_mod):
    """A 600 m head over a 1 km line: the mosaic's cell grows from the range bin so that the grid
    fits (at most 2e7 cells), decided before the first render; a mechanical head gets none."""
    from mitsonar.cli.survey import MOSAIC_CELLS, _mosaic_grid

    scene = mitsonar_mod.load_scene(scene_xml(sonar_xml(kind="sidescan", preset="klein3000_100k", n_bins=1000),
                                              seabed(-20.0, 0.5)))
    track = mitsonar_mod.Trajectory.lawnmower(0.0, 1000.0, 0.0, 0.0, 10.0, 2.0, depth=-5.0)
    grid = _mosaic_grid(scene, track)
    h, w = grid.shape
    assert h * w <= MOSAIC_CELLS and grid.transform[0] >= 0.6        # a bin: 600 m / 1000
    assert w * grid.transform[0] >= 1000.0 + 2 * 600.0
    mech = mitsonar_mod.load_scene(scene_xml(sonar_xml(), seabed(-5.0, 0.5)))
    assert _mosaic_grid(mech, track) is None
