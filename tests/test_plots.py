"""Pictures: files written at the expected size, echoes drawn where the geometry says, no crashes."""
import math
import warnings

import matplotlib.colors as mcolors
import matplotlib.image as mimage
import numpy as np
import pytest
from matplotlib import colormaps
from matplotlib.collections import LineCollection

from mitsonar.products import plots
from mitsonar.receiver.electronics import Electronics
from mitsonar.scan import Scan


def ring_scan(n_pings=36, n_bins=10, step_deg=10.0, rmax=10.0, bright=()):
    """Head at the origin, scan axis world +z, boresight at bearing 0 along world +x (box.xml)."""
    bearings = np.radians(step_deg * np.arange(n_pings))
    poses = np.tile(np.eye(4), (n_pings, 1, 1))
    for k, b in enumerate(bearings):
        z = np.array([math.cos(b), math.sin(b), 0.0])
        y = np.array([0.0, 0.0, 1.0])
        poses[k, :3, 0], poses[k, :3, 1], poses[k, :3, 2] = np.cross(y, z), y, z
    inten = np.zeros((n_pings, n_bins), np.float32)
    data = np.zeros((n_pings, n_bins), np.uint8)
    for k, j in bright:
        inten[k, j], data[k, j] = 1e-4, 255
    return Scan(intensity=inten, data=data, ranges=(np.arange(n_bins) + 0.5) * rmax / n_bins, bearings=bearings,
                poses=poses, range_min=0.0, range_max=rmax, beamwidth_h=step_deg,
                electronics=Electronics().to_dict(), meta={"scene": "synthetic", "seed": 0})


def pixel(fig, png, x, y):
    """RGB of the saved PNG's pixel that holds data point (x, y) of the figure's first axes."""
    img = mimage.imread(png)
    px, py = fig.axes[0].transData.transform((x, y))
    return img[int(math.floor(img.shape[0] - py)), int(math.floor(px)), :3]


def close(rgb, colour, tol=0.12):
    return np.abs(np.asarray(rgb) - np.asarray(mcolors.to_rgb(colour))).max() < tol


def test_polar_places_a_bright_bin_by_range_and_bearing(tmp_path):
    # Ping 9 = bearing 90 deg, bin 6 = 6.5 m; ping 0 = bearing 0, bin 3 = 3.5 m.
    scan = ring_scan(bright=[(9, 6), (0, 3)])
    png = str(tmp_path / "polar.png")
    fig = plots.plot_polar(scan, png, figsize=(6, 5), dpi=100, resolution=500)
    cmap = colormaps[plots.DEFAULT_CMAP]
    hot, cold = cmap(1.0), cmap(0.0)
    def at(r, deg):  # 3 deg off the bearing: clear of the grid's spokes
        a = math.radians(deg - 3.0)
        return pixel(fig, png, -r * math.sin(a), r * math.cos(a))

    # Bearing 0 is up, positive bearings counter-clockwise: 90 deg is on the left.
    assert close(at(6.5, 90), hot)
    assert close(at(3.5, 0), hot)
    for r, deg in [(6.5, 270), (6.5, 180), (3.5, 90), (6.5, 0), (6.5, 45), (5.5, 90), (7.5, 90)]:
        assert close(at(r, deg), cold), (r, deg)


def test_polar_wedges_overlap_in_ping_order(tmp_path):
    # 3 deg wedges at 1.8 deg steps: the later ping covers the earlier one's trailing part.
    scan = ring_scan(n_pings=200, n_bins=20, step_deg=1.8, bright=[(50, 10)])
    scan.beamwidth_h = 3.0
    png = str(tmp_path / "overlap.png")
    fig = plots.plot_polar(scan, png, figsize=(8, 8), dpi=100, resolution=800)
    r = 5.25
    cmap = colormaps[plots.DEFAULT_CMAP]

    def at(deg):
        a = math.radians(deg)
        return pixel(fig, png, -r * math.sin(a), r * math.cos(a))

    assert close(at(89.4), cmap(1.0))  # ping 50 (90 deg) is visible on [88.5, 90.3)
    assert close(at(91.0), cmap(0.0))  # ping 51 painted over it


def test_cartesian_places_bins_in_world_coordinates_and_cuts_the_mesh(tmp_path):
    scan = ring_scan(bright=[(9, 6)])  # bearing 90 deg: world +y at 6.5 m
    # A wall x = 4 from z = -3 to 3, two triangles: cut through z = 0 along x = 4.
    v = np.array([[4, -5, -3], [4, 5, -3], [4, 5, 3], [4, -5, 3]], float)
    f = np.array([[0, 1, 2], [0, 2, 3]])
    png = str(tmp_path / "cart.png")
    fig = plots.plot_cartesian(scan, mesh=(v, f), path=png, figsize=(6, 5), dpi=100)
    cmap = colormaps[plots.DEFAULT_CMAP]
    assert close(pixel(fig, png, 0.0, 6.5), cmap(1.0))
    assert close(pixel(fig, png, 0.0, -6.5), cmap(0.0))
    assert close(pixel(fig, png, 4.0, -2.0), "tab:green", tol=0.2)
    assert fig.axes[0].get_xlabel().startswith("world x")


def tilted(scan, tilt_deg, position=(0.0, 0.0, 0.0)):
    """The scan's head turned about world y so that bearing 0 (world +x) looks ``tilt_deg`` down
    (its scan axis leans forward as the harbour heads' do), then moved to ``position``."""
    a = math.radians(tilt_deg)
    R = np.array([[math.cos(a), 0.0, math.sin(a)], [0.0, 1.0, 0.0], [-math.sin(a), 0.0, math.cos(a)]])
    poses = scan.poses.copy()
    poses[:, :3, :] = np.einsum("ij,kjl->kil", R, poses[:, :3, :])
    poses[:, :3, 3] = position
    scan.poses = poses
    return scan


def wall_and_seabed():
    """A flat seabed z = -4 (100 m square) and a wall x = 6 from z = -4 to 2, y in [-20, 20]."""
    v = np.array([[-50, -50, -4], [50, -50, -4], [50, 50, -4], [-50, 50, -4],
                  [6, -20, -4], [6, 20, -4], [6, 20, 2], [6, -20, 2]], float)
    f = np.array([[0, 1, 2], [0, 2, 3], [4, 5, 6], [4, 6, 7]])
    return v, f


@pytest.mark.parametrize("tilt", [0.0, 30.0])
def test_cartesian_is_world_x_east_y_north_like_the_track(tmp_path, tilt):
    """Level or tilted, the head's pings are drawn at their world x (east, to the right) and y
    (north, up), equal aspect, with the labels of the track picture (a tilted head was drawn in
    an in-plane basis 'world u, v', turned 90 deg against the track)."""
    from mitsonar.geometry.trajectory import Trajectory

    # bearing 90 deg (world +y) bin 6 and bearing 0 (world +x, tilt down) bin 3
    scan = tilted(ring_scan(bright=[(9, 6), (0, 3)]), tilt, position=(3.0, -2.0, -1.0))
    png = str(tmp_path / "cart.png")
    fig = plots.plot_cartesian(scan, path=png, figsize=(6, 5), dpi=100)
    ax = fig.axes[0]
    hot, cold = colormaps[plots.DEFAULT_CMAP](1.0), colormaps[plots.DEFAULT_CMAP](0.0)
    c = math.cos(math.radians(tilt))
    assert close(pixel(fig, png, 3.0, -2.0 + 6.5), hot)            # 6.5 m north of the head
    assert close(pixel(fig, png, 3.0 + 3.5 * c, -2.0), hot)        # 3.5 m east, seen from above
    assert close(pixel(fig, png, 3.0, -2.0 - 6.5), cold) and close(pixel(fig, png, 3.0 - 3.5 * c, -2.0), cold)
    sonar = [ln for ln in ax.get_lines() if ln.get_label() == "sonar"][0]
    assert list(sonar.get_xdata()) == [3.0] and list(sonar.get_ydata()) == [-2.0]
    assert ax.get_aspect() == 1.0
    track = plots.plot_track(Trajectory(np.array([0.0, 1.0]), scan.poses[:2]), figsize=(6, 5), dpi=100)
    assert (ax.get_xlabel(), ax.get_ylabel()) == (track.axes[0].get_xlabel(), track.axes[0].get_ylabel())
    assert "east" in ax.get_xlabel() and "north" in ax.get_ylabel()
    assert not ax.xaxis_inverted() and not ax.yaxis_inverted()


def test_cartesian_ground_truth_only_where_the_beams_reach(tmp_path):
    """A head 30 deg down (fan 35 deg, range 10 m) over a seabed 4 m below, a wall 6 m east: the
    plane of its sweep cuts the seabed along x = 4 / tan 30 = 6.9 m, inside the range but where
    no beam looks (it was drawn as a green line: a misplaced wall). Drawn now: the wall only,
    where a beam holds it."""
    scan = tilted(ring_scan(), 30.0)
    v, f = wall_and_seabed()
    naive = plots.mesh_section(v, f, scan.positions.mean(axis=0), scan.poses[:, :3, 1].mean(axis=0))
    on_seabed = naive[np.isclose(naive[..., 2], -4.0).all(axis=1)]
    assert len(on_seabed) and np.allclose(on_seabed[..., 0], 4.0 / math.tan(math.radians(30.0)))
    fig = plots.plot_cartesian(scan, mesh=(v, f), path=str(tmp_path / "gt.png"), figsize=(6, 5), dpi=100)
    ax = fig.axes[0]
    truth = [c for c in ax.collections if isinstance(c, LineCollection)]
    assert len(truth) == 1
    seg = np.asarray(truth[0].get_segments())          # (S, 2, 2) world x, y
    assert len(seg) > 10
    assert np.allclose(seg[..., 0], 6.0)               # on the wall, nothing on the seabed
    assert "inside the beams (35\N{DEGREE SIGN} fan)" in truth[0].get_label()
    # every piece drawn is inside a beam at one of the depths cut, and the wall is drawn along
    # the stretch the beams reach (|y| up to sqrt(10^2 - 6^2 - dz^2) at the depth of the sweep)
    segments, dz = plots.beam_ground_truth(scan, v, f)
    assert np.allclose(segments[..., :2], seg)
    assert plots.in_beams(scan, segments.mean(axis=1)).all()
    assert seg[..., 1].max() > 5.0 and seg[..., 1].min() < -5.0 and np.abs(seg[..., 1]).max() <= 8.0


def test_track_frames_a_straight_run_and_draws_the_ground_truth_at_its_depth(tmp_path):
    """A straight 25 m run at z = -2 beside a wall x = 20 (z from -5 to 1): the view holds the wall's
    cut, its short side is at least TRACK_MIN_ASPECT of the long one (it was a strip 0.1 as high as
    wide), and the track's end is drawn where it is, not under the legend."""
    from mitsonar.geometry.trajectory import Trajectory

    t = np.linspace(0.0, 50.0, 51)
    poses = np.tile(np.eye(4), (len(t), 1, 1))
    poses[:, :3, 3] = np.stack([-10.0 + 0.5 * t, np.full_like(t, -14.0), np.full_like(t, -2.0)], 1)
    track = Trajectory(t, poses)
    v = np.array([[20, -20, -5], [20, 20, -5], [20, 20, 1], [20, -20, 1]], float)
    f = np.array([[0, 1, 2], [0, 2, 3]])
    png = str(tmp_path / "track.png")
    fig = plots.plot_track(track, png, mesh=(v, f), figsize=(6, 5), dpi=100)
    ax = fig.axes[0]
    (x0, x1), (y0, y1) = ax.get_xlim(), ax.get_ylim()
    assert x0 < -10.0 and x1 > 20.0 and y0 < -20.0 and y1 > 20.0   # track and the wall's cut x = 20
    assert min(x1 - x0, y1 - y0) >= plots.TRACK_MIN_ASPECT * max(x1 - x0, y1 - y0)
    assert close(pixel(fig, png, 20.0, 0.0), "tab:green", tol=0.2)
    assert close(pixel(fig, png, 15.0, -14.0), "tab:red", tol=0.2)
    legend = ax.get_legend() or fig.legends[0]     # below the axes, placed by the layout engine
    assert any("z = -2" in t.get_text() for t in legend.get_texts())


def test_mesh_section():
    v = np.array([[0, 0, -1], [1, 0, 1], [0, 1, 1], [5, 5, 2], [6, 5, 3], [5, 6, 4]], float)
    seg = plots.mesh_section(v, [[0, 1, 2], [3, 4, 5]], origin=(0, 0, 0), normal=(0, 0, 2))
    assert seg.shape == (1, 2, 3)
    np.testing.assert_allclose(sorted(map(tuple, seg[0])), [(0.0, 0.5, 0.0), (0.5, 0.0, 0.0)], atol=1e-12)
    assert plots.mesh_section(np.zeros((0, 3)), np.zeros((0, 3), int), (0, 0, 0), (0, 0, 1)).shape == (0, 2, 3)


@pytest.mark.parametrize("ext", ["png", "pdf"])
def test_files_written_with_expected_size(tmp_path, ext):
    scan = ring_scan(n_pings=100, n_bins=200, step_deg=3.6, rmax=12.0, bright=[(3, 120)])
    scan.beamwidth_h = 3.0
    for name, draw in [("polar", lambda p: plots.plot_polar(scan, p, figsize=(5, 4), dpi=80)),
                       ("cartesian", lambda p: plots.plot_cartesian(scan, path=p, figsize=(5, 4), dpi=80)),
                       ("ascan", lambda p: plots.plot_ascan(scan, 3, p, figsize=(5, 3), dpi=80))]:
        path = tmp_path / f"{name}.{ext}"
        draw(str(path))
        assert path.stat().st_size > 1000
        if ext == "png":
            h, w = mimage.imread(str(path)).shape[:2]
            assert (w, h) == ((400, 320) if name != "ascan" else (400, 240))
        else:
            assert path.read_bytes().startswith(b"%PDF")


def test_db_on_zero_intensity_and_all_modes_do_not_crash(tmp_path):
    scan = ring_scan()
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # no divide-by-zero or empty-range warnings either
        for use in ("data", "intensity"):
            for db in (False, True):
                plots.plot_polar(scan, None, use=use, db=db, figsize=(3, 3), dpi=50, resolution=100)
                plots.plot_cartesian(scan, use=use, db=db, figsize=(3, 3), dpi=50)
        plots.plot_ascan(scan, -1, str(tmp_path / "a.png"), db=True, figsize=(3, 2), dpi=50)
        plots.plot_ascan(scan, 0, None, db=False, figsize=(3, 2), dpi=50)


def test_title_has_key_settings_and_bad_arguments_raise(tmp_path):
    scan = ring_scan()
    fig = plots.plot_polar(scan, figsize=(3, 3), dpi=50, resolution=100)
    title = fig.axes[0].get_title()
    for word in ("mechanical", "TVG 20log", "gain 28 dB", "8-bit", "synthetic"):
        assert word in title
    assert "counter-clockwise" in fig.axes[0].get_xlabel()
    with pytest.raises(ValueError, match="extension"):
        plots.plot_polar(scan, str(tmp_path / "x.bmpx"), figsize=(3, 3), dpi=50, resolution=100)
    with pytest.raises(ValueError, match="use="):
        plots.plot_polar(scan, use="bytes")
    with pytest.raises(IndexError):
        plots.plot_ascan(scan, 36)


def fan_scan(n_beams=16, step_deg=1.0236, beamwidth=1.0, n_bins=20, rmax=20.0, upright=True):
    """A multibeam frame at the origin: beams ``step_deg`` apart (wider than ``beamwidth``, as the
    harbour head's 1.0236 deg steps of 1 deg beams), boresight world +x at the middle beam. With
    ``upright`` False the head keeps a driver's default identity mounting (scan axis world +y)."""
    bearings = np.radians(step_deg * (np.arange(n_beams) - (n_beams - 1) / 2.0))
    scan = ring_scan(n_pings=n_beams, n_bins=n_bins, rmax=rmax)
    poses = np.tile(np.eye(4), (n_beams, 1, 1))
    for k, b in enumerate(bearings):
        R = np.array([[math.cos(b), 0.0, math.sin(b)], [0.0, 1.0, 0.0], [-math.sin(b), 0.0, math.cos(b)]])
        mount = np.array([[0.0, 0.0, 1.0], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0]]) if upright else np.eye(3)
        poses[k, :3, :3] = mount @ R
    scan.poses, scan.bearings, scan.beamwidth_h = poses, bearings, beamwidth
    scan.data[:] = 200
    return scan


def test_cartesian_fan_beams_share_their_edges():
    """Adjacent beams of a frame share the edge half-way between them (their wedges were each
    ``beamwidth_h`` wide: 1 deg beams 1.0236 deg apart left gaps, drawn as white radial dashes):
    the meshes drawn hold n + 1 distinct edge bearings spaced one step apart; with an explicit
    ``ping_width`` every beam keeps its own two edges."""
    from matplotlib.collections import QuadMesh

    def edge_bearings(fig):
        far = [np.asarray(m.get_coordinates())[:, -1] for m in fig.axes[0].collections
               if isinstance(m, QuadMesh)]                          # corners at the far range, (x, y)
        return np.unique(np.round(np.degrees(np.arctan2(np.concatenate(far)[:, 1],
                                                        np.concatenate(far)[:, 0])), 9))

    scan = fan_scan()
    edges = edge_bearings(plots.plot_cartesian(scan, figsize=(4, 4), dpi=50))
    assert len(edges) == scan.n_pings + 1
    np.testing.assert_allclose(np.diff(edges), 1.0236, atol=1e-6)
    assert edges[0] == pytest.approx(-8 * 1.0236, abs=1e-6)
    own = edge_bearings(plots.plot_cartesian(scan, ping_width=1.0, figsize=(4, 4), dpi=50))
    assert len(own) == 2 * scan.n_pings


def test_polar_fan_has_no_gap_between_beams():
    """The polar display's fan is painted without gaps between beams 1.0236 deg apart whose beams
    are 1 deg wide (the gaps showed the background as radial lines)."""
    scan = fan_scan()
    fig = plots.plot_polar(scan, figsize=(4, 4), dpi=50, resolution=400)
    image = np.ma.filled(fig.axes[0].images[0].get_array(), np.nan)
    n = image.shape[0]
    mid = (np.arange(n) + 0.5) / n * 2.0 * scan.range_max - scan.range_max
    x, y = np.meshgrid(mid, mid[::-1])
    r, bearing = np.hypot(x, y), np.degrees(np.arctan2(-x, y))
    inner = (r > 2.0) & (r < scan.range_max - 1.0) & (np.abs(bearing) < 7.5 * 1.0236)
    assert inner.sum() > 1000 and np.isfinite(image[inner]).all()


def test_cartesian_warns_when_the_sweep_is_vertical():
    """A scan with a driver's default identity mounting sweeps a vertical plane: seen from above
    it has no width; the plot says so (it was an empty picture without a word)."""
    with pytest.warns(UserWarning, match=r"scan axis of every ping \(poses\[k\]\[:3, 1\]\) is horizontal.*pose"):
        plots.plot_cartesian(fan_scan(upright=False), figsize=(3, 3), dpi=50)
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        plots.plot_cartesian(fan_scan(), figsize=(3, 3), dpi=50)


def _overlaps(boxes):
    return [(a, b) for i, a in enumerate(boxes) for b in boxes[i + 1:] if a.overlaps(b)]


def test_polar_range_labels_sit_inside_their_rings():
    """Each range label lies inside its ring (the outer label sat on the rim of the fan, crossing
    it), measured on the drawn text's bounding box."""
    scan = ring_scan(rmax=12.0)
    from matplotlib.backends.backend_agg import FigureCanvasAgg

    fig = plots.plot_polar(scan, figsize=(7, 6.4), dpi=100, resolution=200)
    renderer = FigureCanvasAgg(fig).get_renderer()
    fig.draw(renderer)
    ax = fig.axes[0]
    labels = [t for t in ax.texts if t.get_text().endswith(" m")]
    assert [t.get_text() for t in labels][-1] == "12 m"
    for t in labels:
        ring = float(t.get_text()[:-2])
        box = ax.transData.inverted().transform(t.get_window_extent(renderer).corners())
        assert np.hypot(box[:, 0], box[:, 1]).max() < ring, t.get_text()
        assert np.hypot(box[:, 0], box[:, 1]).min() > ring - 2.0, t.get_text()


def convergence_result(seconds=(2.0, 5.0, 16.0)):
    """What `plot_convergence` reads of a comparison: two integrators, three budgets whose
    seconds span less than a decade (the labels of a short log axis ran into each other)."""
    runs = [{"integrator": lab, "budget_s": s, "seconds_mean": s * f, "spp": int(1000 * s),
             "rel_l2": 1e-3 / math.sqrt(s), "rel_l1": 2e-3 / math.sqrt(s),
             "regions": {"far": {"rel_l2": 1.5e-3 / math.sqrt(s)}}}
            for lab, f in (("sonar_tof", 1.0), ("sonar_mlt", 1.05)) for s in seconds]
    return {"settings": {"integrators": ["sonar_tof", "sonar_mlt"], "regions": {"far": [3.0, 8.0]},
                         "scene": "scenes_xml/slot_chamber.xml", "repeats": 2},
            "reference": {"self_rel_l2": 1e-4, "spp": 1 << 19}, "runs": runs}


def test_convergence_tick_labels_do_not_overlap(tmp_path):
    """No two tick labels of a panel's axis overlap, nor the panels' titles and labels (placed
    by the layout engine), in the picture of a comparison over less than a decade of seconds."""
    from mitsonar.jobs.compare.figures import plot_convergence

    fig = plot_convergence(convergence_result(), str(tmp_path / "convergence.png"))
    renderer = fig.canvas.get_renderer()
    for ax in fig.axes:
        for axis in (ax.xaxis, ax.yaxis):
            boxes = [t.get_window_extent(renderer) for t in axis.get_ticklabels(which="both")
                     if t.get_visible() and t.get_text()]
            assert len(boxes) >= 2
            assert not _overlaps(boxes), [t.get_text() for t in axis.get_ticklabels(which="both") if t.get_text()]
    titles = [ax.title.get_window_extent(renderer) for ax in fig.axes]
    assert not _overlaps(titles + [fig._suptitle.get_window_extent(renderer)])
