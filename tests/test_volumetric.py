"""3D imaging sonar (`mitsonar.signals.volumetric`): a 24 x 24 planar array at half a wavelength
(200 kHz, 20 kHz band; aperture 9 cm, Fraunhofer distance 2.16 m), focused near-field delay-and-sum
against the closed forms: the peak voxel of a point target, the -3 dB beam widths, a plane's
point cloud."""
import math

import numpy as np
import pytest

from conftest import acoustic_xml, rectangle_xml, scene_xml


def head(**kw):
    from mitsonar.signals.volumetric import Volumetric

    args = dict(rows=24, columns=24, frequency=200e3, bandwidth=20e3, n_azimuth=31, n_elevation=21,
                fov_azimuth=60.0, fov_elevation=40.0, range_max=4.0, n_bins=370, range_min=0.3)
    args.update(kw)
    return Volumetric(**args)


def target(r, az, el):
    from mitsonar.signals import PointTarget
    from mitsonar.signals.volumetric import directions

    return PointTarget(tuple(r * directions([az], [el])[0, 0]), 0.0)


@pytest.fixture(scope="module")
def point_scene(mitsonar_mod):
    return mitsonar_mod.load_scene(scene_xml(head().sensor_xml()))


@pytest.mark.parametrize("r, az_deg, el_deg", [(0.6, 10.0, -6.0), (1.5, -4.0, 14.0), (3.0, -20.0, 10.0)])
def test_point_target_peaks_in_its_cell_near_and_far(mitsonar_mod, point_scene, r, az_deg, el_deg):
    """The strongest voxel of a 31 x 21 x 370 volume is the target's (range, azimuth, elevation) cell,
    in the array's near field (0.6 and 1.5 m < 2.16 m) as beyond it."""
    from mitsonar.signals.volumetric import beamform_3d

    cfg = head()
    az, el = math.radians(az_deg), math.radians(el_deg)
    e = mitsonar_mod.render_echoes(point_scene, cfg.pulse(), elements=cfg.elements(), spp=1,
                                   targets=[target(r, az, el)])
    vol = beamform_3d(e, cfg.azimuths(), cfg.elevations(), cfg.ranges())
    assert vol.intensity.shape == (21, 31, 370) and vol.intensity.dtype == np.float32
    k = np.unravel_index(int(np.argmax(vol.intensity)), vol.intensity.shape)
    assert k[0] == int(np.argmin(np.abs(cfg.elevations() - el)))
    assert k[1] == int(np.argmin(np.abs(cfg.azimuths() - az)))
    assert abs(cfg.ranges()[k[2]] - r) <= (cfg.range_max - cfg.range_min) / cfg.n_bins


@pytest.mark.parametrize("r, az_deg, el_deg", [(3.0, 0.0, 0.0), (3.0, 30.0, 0.0), (0.6, 10.0, -6.0)])
def test_beam_widths_are_0886_lambda_over_nd_widening_as_one_over_cos_steer(mitsonar_mod, point_scene, r, az_deg,
                                                                             el_deg):
    """Cuts through the target in azimuth and in elevation: -3 dB widths within 5 % of
    0.886 lambda / (N d cos steer), at broadside, steered 30 deg (15 % wider), and in the near field."""
    from mitsonar.sas.quality import _cut
    from mitsonar.signals.volumetric import beamform_3d

    cfg = head()
    az, el = math.radians(az_deg), math.radians(el_deg)
    e = mitsonar_mod.render_echoes(point_scene, cfg.pulse(), elements=cfg.elements(), spp=1,
                                   targets=[target(r, az, el)])
    step = math.radians(0.1)
    fine = np.arange(-120, 121) * step
    along_az = beamform_3d(e, az + fine, [el], [r]).intensity[0, :, 0]
    along_el = beamform_3d(e, [az], el + fine, [r]).intensity[:, 0, 0]
    w_az, w_el = cfg.beamwidths(az, el)
    assert _cut(along_az, int(np.argmax(along_az)), step)[0] == pytest.approx(w_az, rel=0.05)
    assert _cut(along_el, int(np.argmax(along_el)), step)[0] == pytest.approx(w_el, rel=0.05)
    assert abs(int(np.argmax(along_az)) - 120) <= 1 and abs(int(np.argmax(along_el)) - 120) <= 1
    if az_deg == 30.0:
        assert w_az == pytest.approx(cfg.beamwidths()[0] / math.cos(az))


def test_a_planes_point_cloud_lies_within_one_range_cell_of_it_and_round_trips_as_ply(mitsonar_mod, tmp_path):
    """A rough plane 2 m in front of the array, filling a 30 x 30 deg view of 11 x 11 beams: the
    strongest return of each beam 10 dB within the peak lies within one range cell c / (2 B) of the
    plane, for most beams; the PLY file reads back the same points."""
    from mitsonar.geometry.ply import read_ply
    from mitsonar.signals.volumetric import POINT_DTYPE, beamform_3d, point_cloud, write_point_cloud_ply

    cfg = head(n_azimuth=11, n_elevation=11, fov_azimuth=30.0, fov_elevation=30.0, range_max=3.0, n_bins=135)
    m = np.eye(4)
    m[:3, 0], m[:3, 1], m[:3, 2], m[:3, 3] = (0.5, 0, 0), (0, 0.5, 0), (0, 0, -1), (0, 0, 2.0)
    scene = mitsonar_mod.load_scene(scene_xml(cfg.sensor_xml(), rectangle_xml(m, acoustic_xml(0.5))))
    e = mitsonar_mod.render_echoes(scene, cfg.pulse(), elements=cfg.elements(), spp=1 << 15)
    vol = beamform_3d(e, cfg.azimuths(), cfg.elevations(), cfg.ranges())
    pts = point_cloud(vol, threshold_db=-10.0)
    assert pts.dtype == POINT_DTYPE and len(pts) > 0.5 * 121
    assert np.abs(pts["z"] - 2.0).max() < cfg.pulse().range_resolution(cfg.sound_speed)
    first = point_cloud(vol, threshold_db=-10.0, mode="first")
    assert len(first) == len(pts) and (first["range"] <= pts["range"]).all()      # same beams, nearer or equal
    path = tmp_path / "cloud.ply"
    assert write_point_cloud_ply(path, pts) == len(pts)
    back, faces = read_ply(path)
    assert faces is None and len(back) == len(pts)
    for name in POINT_DTYPE.names:
        assert np.array_equal(back[name], pts[name])


def test_volumetric_refusals_and_presets():
    from mitsonar.signals.volumetric import PRESETS, Volumetric

    with pytest.raises(ValueError, match="Volumetric 'rows'"):
        head(rows=0)
    with pytest.raises(ValueError, match="Volumetric 'fov_azimuth'"):
        head(fov_azimuth=180.0)
    with pytest.raises(ValueError, match="Volumetric 'range_min'"):
        head(range_min=5.0)
    scope = PRESETS["echoscope"]
    assert isinstance(scope, Volumetric)
    assert (scope.n_azimuth, scope.n_elevation, scope.fov_azimuth, scope.fov_elevation) == (128, 128, 50.0, 50.0)
    assert len(scope.azimuths()) == 128 and np.degrees(np.ptp(scope.azimuths())) == pytest.approx(50 * 127 / 128)
    assert scope.elements().shape == (48 * 48, 3)


def test_point_cloud_as_las_and_as_pointcloud2(tmp_path):
    """A cloud's LAS (in a GeoFrame's CRS) reads back its points, beam indices and ranges; its
    PointCloud2 message decodes, field by field, to the same records."""
    import laspy

    from mitsonar.geometry.geodesy import GeoFrame
    from mitsonar.export.las import write_point_cloud_las
    from mitsonar.export.ros.messages import point_cloud_message
    from mitsonar.signals.volumetric import POINT_DTYPE

    rng = np.random.default_rng(0)
    pts = np.zeros(50, POINT_DTYPE)
    for k in ("x", "y", "z", "range"):
        pts[k] = rng.uniform(-5, 5, 50)
    pts["intensity"] = rng.uniform(1e-6, 1e-3, 50)
    pts["elevation_index"], pts["azimuth_index"] = rng.integers(0, 128, 50), rng.integers(0, 128, 50)
    frame = GeoFrame.make((43.0, 5.0, -2.0), "EPSG:32631")
    assert write_point_cloud_las(tmp_path / "c.las", pts, frame) == 50
    las = laspy.read(tmp_path / "c.las")
    assert np.allclose(las.x, pts["x"] + frame.e0, atol=1e-3) and np.allclose(las.y, pts["y"] + frame.n0, atol=1e-3)
    assert np.allclose(las.z, pts["z"] + frame.height, atol=1e-3)
    assert np.array_equal(las.elevation_index, pts["elevation_index"])
    assert np.array_equal(las.azimuth_index, pts["azimuth_index"]) and np.allclose(las.range, pts["range"])
    assert las.header.parse_crs().to_epsg() == 32631
    assert las.intensity[np.argmax(pts["intensity"])] == 65535 and las.intensity[np.argmin(pts["intensity"])] == 0
    msg = point_cloud_message(pts, stamp_ns=1_500_000_000, frame="sonar")
    assert msg["header"] == {"stamp": {"sec": 1, "nanosec": 500_000_000}, "frame_id": "sonar"}
    assert msg["width"] * msg["point_step"] == msg["row_step"] == len(msg["data"])
    raw = np.frombuffer(msg["data"], np.uint8).reshape(50, msg["point_step"])
    kinds = {7: "<f4", 5: "<i4"}
    for f in msg["fields"]:
        got = raw[:, f["offset"]:f["offset"] + 4].copy().view(kinds[f["datatype"]]).ravel()
        assert np.array_equal(got, pts[f["name"]]), f["name"]
    assert [f["name"] for f in msg["fields"]][:4] == ["x", "y", "z", "intensity"]


def test_point_clouds_go_into_an_mcap_bag_on_sonar_points(tmp_path):
    """`McapBag.add_point_cloud`: /sonar/points holds the cloud, decoded by the ROS 2 decoder of
    mcap-ros2-support, at the stamp asked for, with every field."""
    pytest.importorskip("mcap_ros2")
    from mcap.reader import make_reader
    from mcap_ros2.decoder import DecoderFactory

    from mitsonar.export.ros.bag import McapBag
    from mitsonar.signals.volumetric import POINT_DTYPE

    pts = np.zeros(5, POINT_DTYPE)
    pts["x"], pts["intensity"], pts["azimuth_index"] = np.arange(5), np.linspace(1, 2, 5), [3, 1, 4, 1, 5]
    with McapBag(tmp_path / "cloud.mcap", start=2.0) as bag:
        bag.add_point_cloud(pts, t=0.5)
    assert bag.written() == {"/sonar/points": 1}
    with open(tmp_path / "cloud.mcap", "rb") as fh:
        got = [(c.topic, m.log_time, d) for _, c, m, d in
               make_reader(fh, decoder_factories=[DecoderFactory()]).iter_decoded_messages()]
    assert [(t, ns) for t, ns, _ in got] == [("/sonar/points", 2_500_000_000)]
    msg = got[0][2]
    assert msg.header.frame_id == "map" and msg.width == 5 and msg.point_step == POINT_DTYPE.itemsize
    assert [f.name for f in msg.fields] == list(POINT_DTYPE.names)
    back = np.frombuffer(bytes(msg.data), POINT_DTYPE)
    assert np.array_equal(back, pts)


def test_incoherent_fast_path_is_the_coherent_speckle_mean(mitsonar_mod):
    """`render_volume` (paths scored into every beam by the array's |AF|^2, no elements) against
    the mean of 4 speckle realisations of element data beamformed by `beamform_3d`, a rough plane
    tilted 30 deg at 2 m across the 11 x 11 beams: the beams' energies (summed over range) agree
    within 10 % in total and 15 % over the central 5 x 5 beams; the per-beam ratios scatter about 1
    as 4 realisations' speckle does."""
    from mitsonar.signals.processing import equivalent_duration
    from mitsonar.signals.volumetric import beamform_3d, render_volume

    cfg = head(n_azimuth=11, n_elevation=11, fov_azimuth=30.0, fov_elevation=30.0, range_max=3.0, n_bins=135)
    th = math.radians(30)
    m = np.eye(4)
    m[:3, 0], m[:3, 1] = (0.5 * math.cos(th), 0, 0.5 * math.sin(th)), (0, 0.5, 0)
    m[:3, 2], m[:3, 3] = (math.sin(th), 0, -math.cos(th)), (0, 0, 2.0)
    scene = mitsonar_mod.load_scene(scene_xml(cfg.sensor_xml(), rectangle_xml(m, acoustic_xml(0.5))))
    fast = render_volume(scene, cfg, spp=1 << 15)
    assert fast.intensity.shape == (11, 11, 135) and fast.intensity.dtype == np.float32
    inc = fast.intensity.sum(axis=2).astype(np.float64)
    p = cfg.pulse()
    coh = np.zeros_like(inc)
    for k in range(4):
        e = mitsonar_mod.render_echoes(scene, p, elements=cfg.elements(), spp=1 << 15, speckle_seed=k)
        r = e.sound_speed * e.sample_times / 2
        vol = beamform_3d(e, cfg.azimuths(), cfg.elevations(), r[(r > cfg.range_min) & (r < cfg.range_max)])
        coh += vol.intensity.sum(axis=2) / (e.sample_rate * equivalent_duration(p, e.sample_rate)) / 4
    c = slice(3, 8)
    assert coh.sum() / inc.sum() == pytest.approx(1.0, abs=0.10)
    assert coh[c, c].sum() / inc[c, c].sum() == pytest.approx(1.0, abs=0.15)
    assert np.median(coh / inc) == pytest.approx(1.0, abs=0.15)
    # every beam sees the plane, and the fast path's per-beam energies follow its incidence and range
    # as the coherent mean does: their beam-to-beam correlation is high despite 4 seeds' speckle
    assert (inc > 0).all()
    assert np.corrcoef(np.log(inc.ravel()), np.log(coh.ravel()))[0, 1] > 0.5
