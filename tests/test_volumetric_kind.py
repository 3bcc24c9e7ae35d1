"""The ``volumetric`` sensor kind (`mitsonar.kinds.Volumetric`): rows are beams over an
elevation x azimuth grid, each turned in both angles; a sonar_tof render lights the row of a
target's (azimuth, elevation); ``Scan.volume`` reshapes a frame to (n_elevation, n_azimuth, n_bins)
and the scan files keep the kind and the grid."""
import math

import numpy as np
import pytest

from conftest import acoustic_xml, scene_xml, sonar_xml, sphere_xml

GRID = dict(kind="volumetric", n_azimuth=9, n_elevation=7, bearing_start=-16.0, bearing_step=4.0,
            elevation_start=-12.0, elevation_step=4.0, beamwidth_h=3.0, beamwidth_v=3.0, range_max=5.0, n_bins=100)


def test_rows_are_the_grid_turned_in_azimuth_and_elevation(mitsonar_mod):
    """Row i n_azimuth + j's boresight is (cos el sin az, sin el, cos el cos az) at azimuth j and
    elevation i of the grid: `volumetric.directions`."""
    from mitsonar.signals.volumetric import directions
    from mitsonar.sim.scene import sonar_of

    scene = mitsonar_mod.load_scene(scene_xml(sonar_xml(**GRID)))
    s = sonar_of(scene, 0)
    assert s.n_pings == 63 and s.sonar_kind.name == "volumetric"
    az = np.radians(-16.0 + 4.0 * np.arange(9))
    el = np.radians(-12.0 + 4.0 * np.arange(7))
    z = s.ping_poses()[:, :3, 2].reshape(7, 9, 3)
    assert np.allclose(z, directions(az, el), atol=1e-12)
    assert np.allclose(np.radians(s.bearings_deg()).reshape(7, 9), az[None, :])


@pytest.mark.parametrize("az_deg, el_deg", [(8.0, -4.0), (-12.0, 8.0)])
def test_a_sphere_lights_its_rows_cell_and_the_scan_round_trips(mitsonar_mod, tmp_path, az_deg, el_deg):
    """A sphere 3 m away at a grid cell's (azimuth, elevation): the brightest row of a sonar_tof
    render is that cell's (i, j) in `Scan.volume`, at the sphere's range; the EXR file keeps the
    kind and the grid."""
    from mitsonar.signals.volumetric import directions

    az, el = math.radians(az_deg), math.radians(el_deg)
    centre = 3.0 * directions([az], [el])[0, 0]
    scene = mitsonar_mod.load_scene(scene_xml(sonar_xml(**GRID), sphere_xml(centre, 0.1, acoustic_xml(1.0))))
    scan = mitsonar_mod.render_scan(scene, spp=256, seed=1)
    assert scan.kind == "volumetric" and scan.row_name == "beams"
    vol = scan.volume()
    assert vol.shape == (7, 9, 100)
    energy = vol.sum(axis=2)
    i, j = np.unravel_index(int(np.argmax(energy)), energy.shape)
    assert (i, j) == (round((el_deg + 12.0) / 4.0), round((az_deg + 16.0) / 4.0))
    assert abs(scan.ranges[int(np.argmax(vol[i, j]))] - 2.9) <= 0.1
    path = tmp_path / "vol.exr"
    scan.save(path)
    back = mitsonar_mod.load_scan(path)
    assert back.kind == "volumetric" and (back.meta.n_elevation, back.meta.n_azimuth) == (7, 9)
    assert np.array_equal(back.volume(), vol)


def test_volumetric_refusals(mitsonar_mod):
    from mitsonar.sim.scene import SceneError

    def load(**kw):
        return mitsonar_mod.load_scene(scene_xml(sonar_xml(**{**GRID, **kw})))

    with pytest.raises(Exception, match="'n_pings': not used with kind 'volumetric'"):
        load(n_pings=10)
    with pytest.raises(Exception, match="'n_azimuth': only used with kind 'volumetric'"):
        mitsonar_mod.load_scene(scene_xml(sonar_xml(kind="multibeam", n_azimuth=4)))
    with pytest.raises(Exception, match="'elevation_step'.*inside \\(-90, 90\\)"):
        load(elevation_step=20.0)
    with pytest.raises(Exception, match="share_beams': only for a sensor of kind 'multibeam'"):
        scene = mitsonar_mod.load_scene(scene_xml(sonar_xml(**GRID),
                                                  integrator='<integrator type="sonar_tof">'
                                                             '<boolean name="share_beams" value="true"/></integrator>'))
        mitsonar_mod.render_scan(scene, spp=1)
    scan = mitsonar_mod.render_scan(mitsonar_mod.load_scene(scene_xml(sonar_xml(kind="multibeam", n_pings=4))), spp=1)
    with pytest.raises(ValueError, match="Scan.volume: a 'multibeam' scan has no volume"):
        scan.volume()
    assert SceneError


def test_the_3d_heads_sensor_is_of_kind_volumetric_and_render_volume_asks_for_one(mitsonar_mod):
    """`Volumetric.sensor_xml` is a ``volumetric`` head whose rows look along the config's beam
    grid; `render_volume` refuses a multibeam scene and a grid other than its head's."""
    from mitsonar.signals.volumetric import Volumetric, directions, render_volume
    from mitsonar.sim.scene import SceneError, sonar_of

    cfg = Volumetric(rows=8, columns=8, frequency=200e3, bandwidth=20e3, n_azimuth=5, n_elevation=3,
                     fov_azimuth=30.0, fov_elevation=18.0, range_max=3.0, n_bins=50)
    s = sonar_of(mitsonar_mod.load_scene(scene_xml(cfg.sensor_xml())), 0)
    assert s.kind == "volumetric" and (s.n_elevation, s.n_azimuth, s.n_pings) == (3, 5, 15)
    assert np.allclose(s.ping_poses()[:, :3, 2].reshape(3, 5, 3), directions(cfg.azimuths(), cfg.elevations()))
    with pytest.raises(SceneError, match="render_volume 'scene': its sensor of kind 'multibeam' is not allowed"):
        render_volume(mitsonar_mod.load_scene(scene_xml(sonar_xml(kind="multibeam", n_pings=4))), cfg, spp=1)
    other = Volumetric(**{**cfg.__dict__, "n_azimuth": 7})
    with pytest.raises(SceneError, match="render_volume 'head': its 3 x 7 beams are not allowed"):
        render_volume(mitsonar_mod.load_scene(scene_xml(cfg.sensor_xml())), other, spp=1)


@pytest.mark.parametrize("name, f, fov, rmax, res, res_h, res_v, sep_h", [
    ("sonar3d15_navigation", 1.2e6, 90.0, 15.0, 0.004, 0.6, 2.4, 0.35),
    ("sonar3d15_inspection", 2.4e6, 40.0, 4.0, 0.0015, 0.4, 1.1, 0.16)])
def test_water_linked_sonar_3d15_presets_hold_the_published_figures(mitsonar_mod, name, f, fov, rmax, res, res_h,
                                                                     res_v, sep_h):
    """The Sonar 3D-15's modes as published (carrier, 256 x 64 beams over fov x 40 deg, 0.2 m to the
    maximum range): its compressed pulse resolves the published range resolution, its beams' -3 dB
    widths are the published angular resolutions within 2 %, the beam separation rounds to the
    published one, and its sensor loads as a volumetric head of 64 x 256 rows."""
    import dataclasses

    from mitsonar.signals.volumetric import PRESETS
    from mitsonar.sim.scene import sonar_of

    p = PRESETS[name]
    assert (p.frequency, p.n_azimuth, p.n_elevation, p.fov_azimuth, p.fov_elevation) == (f, 256, 64, fov, 40.0)
    assert (p.range_min, p.range_max) == (0.2, rmax)
    assert p.pulse().range_resolution(p.sound_speed) == pytest.approx(res)
    w_h, w_v = (math.degrees(w) for w in p.beamwidths())
    assert w_h == pytest.approx(res_h, rel=0.02) and w_v == pytest.approx(res_v, rel=0.02)
    assert round(fov / 256, 2) == sep_h and round(40.0 / 64, 1) == 0.6
    s = sonar_of(mitsonar_mod.load_scene(scene_xml(dataclasses.replace(p, n_bins=8).sensor_xml())), 0)
    assert s.kind == "volumetric" and (s.n_elevation, s.n_azimuth) == (64, 256)
    assert s.beam.frequency == f


@pytest.fixture(scope="module")
def sphere_frame(mitsonar_mod):
    """A rendered volumetric frame of a sphere 3 m away at azimuth 8, elevation -4 deg, the head
    at (1, 2, -3) turned 30 deg about z."""
    from mitsonar.signals.volumetric import directions

    m = np.eye(4)
    c, s = math.cos(math.radians(30)), math.sin(math.radians(30))
    m[:3, :3] = [[c, -s, 0], [s, c, 0], [0, 0, 1]]
    m[:3, 3] = (1.0, 2.0, -3.0)
    centre = m[:3, :3] @ (3.0 * directions([math.radians(8.0)], [math.radians(-4.0)])[0, 0]) + m[:3, 3]
    scene = mitsonar_mod.load_scene(scene_xml(sonar_xml(m, **GRID), sphere_xml(centre, 0.1, acoustic_xml(1.0))))
    return mitsonar_mod.render_scan(scene, spp=256, seed=1), m, centre


def test_a_volumetric_frame_is_a_pointcloud2_in_the_live_mcap(mitsonar_mod, sphere_frame, tmp_path):
    """`mitsonar live --mcap`: a volumetric frame adds one sensor_msgs/PointCloud2 on /sonar/points
    (ros2msg schema, CDR), read back with the mcap reader and mcap-ros2-support's decoder: the
    frame's point cloud (`point_cloud` of `scan_volume`) record for record, its strongest point at
    the sphere's near side in ``map``; the CDR is the one mcap-ros2-support's encoder writes."""
    pytest.importorskip("foxglove")
    mcap_ros2 = pytest.importorskip("mcap_ros2")
    from mcap.reader import make_reader
    from mcap_ros2.decoder import DecoderFactory

    from mitsonar.live.outputs import open_outputs
    from mitsonar.live.outputs.messages import POINTS_THRESHOLD_DB, frame_points, pointcloud2_cdr
    from mitsonar.export.ros import msgdefs
    from mitsonar.signals.volumetric import POINT_DTYPE, point_cloud, scan_volume

    scan, m, centre = sphere_frame
    vol = scan_volume(scan)
    assert np.allclose(vol.pose, m, atol=1e-9) and vol.intensity.shape == (7, 9, 100)
    pts = point_cloud(vol, POINTS_THRESHOLD_DB)
    top = pts[np.argmax(pts["intensity"])]
    assert (top["elevation_index"], top["azimuth_index"]) == (2, 6)
    near = centre - 0.1 * (centre - m[:3, 3]) / np.linalg.norm(centre - m[:3, 3])
    assert np.linalg.norm(np.array([top["x"], top["y"], top["z"]]) - near) < 0.1
    outs = open_outputs(mcap=tmp_path / "vol.mcap")
    outs.publish(7_250_000_000, np.eye(4), m, scan)
    outs.close()
    with open(tmp_path / "vol.mcap", "rb") as fh:
        got = [(c.topic, s.name, s.encoding, c.message_encoding, msg.log_time, d) for s, c, msg, d in
               make_reader(fh, decoder_factories=[DecoderFactory()]).iter_decoded_messages(topics=["/sonar/points"])]
    assert [g[:5] for g in got] == [("/sonar/points", "sensor_msgs/msg/PointCloud2", "ros2msg", "cdr",
                                     7_250_000_000)]
    msg = got[0][5]
    assert msg.header.frame_id == "map" and (msg.header.stamp.sec, msg.header.stamp.nanosec) == (7, 250_000_000)
    assert [f.name for f in msg.fields] == list(POINT_DTYPE.names) and msg.width == len(pts) > 0
    assert np.array_equal(np.frombuffer(bytes(msg.data), POINT_DTYPE), pts)
    cloud = frame_points(7_250_000_000, scan)
    encode = mcap_ros2._dynamic.serialize_dynamic("sensor_msgs/msg/PointCloud2",
                                                  msgdefs.definition("sensor_msgs/msg/PointCloud2"))
    assert pointcloud2_cdr(cloud) == bytes(encode["sensor_msgs/msg/PointCloud2"](cloud))
    multibeam = mitsonar_mod.render_scan(mitsonar_mod.load_scene(scene_xml(sonar_xml(kind="multibeam", n_pings=4))),
                                         spp=1)
    assert frame_points(0, multibeam) is None                   # other kinds have no cloud


def test_the_dds_pointcloud2_serialises_as_ros_2_does(sphere_frame):
    """`mitsonar live --dds`: the rt/sonar/points struct of a frame serialises to the same CDR as the
    MCAP's /sonar/points (what rclcpp reads)."""
    pytest.importorskip("cyclonedds")
    from mitsonar.live.outputs.dds import POINT_TOPICS, point_cloud2, ros_types
    from mitsonar.live.outputs.messages import frame_points, pointcloud2_cdr

    T = ros_types()
    cloud = frame_points(1_000_000_001, sphere_frame[0])
    header = T["std_msgs/msg/Header"](stamp=T["builtin_interfaces/msg/Time"](sec=1, nanosec=1), frame_id="map")
    msg = point_cloud2(T, cloud, header)
    assert type(msg) is T[POINT_TOPICS["rt/sonar/points"]]
    assert msg.serialize() == pointcloud2_cdr(cloud)
