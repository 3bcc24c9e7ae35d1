"""Meshes and Gazebo worlds (`mitsonar.scenes.meshes`, `mitsonar.scenes.sdf`, ``mitsonar scene
from-sdf``): the same mesh in four formats renders the same scan, a world's models land where its
SDF puts them, and what cannot be converted is said, one line each."""
from __future__ import annotations

import os

import numpy as np
import pytest

trimesh = pytest.importorskip("trimesh")
pytest.importorskip("collada")

from mitsonar.cli import main  # noqa: E402

#: A block 4 x 2 x 1 m whose corner is at the origin (not centred: a wrong axis or unit shows).
BLOCK = trimesh.creation.box((4.0, 2.0, 1.0))
BLOCK.apply_translation((2.0, 1.0, 0.5))
Y_UP = np.array([[1.0, 0, 0, 0], [0, 0, 1, 0], [0, -1, 0, 0], [0, 0, 0, 1]])   # Z up -> Y up: (x, y, z) -> (x, z, -y)


def write_formats(folder):
    """The block as STL and OBJ (metres, Z up), Collada in centimetres and Y up (its <asset> says
    so) and glTF (Y up by its specification)."""
    paths = {}
    BLOCK.export(folder / "block.stl")
    BLOCK.export(folder / "block.obj")
    paths["stl"], paths["obj"] = folder / "block.stl", folder / "block.obj"
    dae = BLOCK.copy()
    dae.apply_transform(Y_UP)
    dae.apply_scale(100.0)
    text = trimesh.exchange.dae.export_collada(dae).decode()
    text = text.replace("<up_axis>Y_UP</up_axis>", '<unit meter="0.01" name="centimeter"/><up_axis>Y_UP</up_axis>')
    (folder / "block.dae").write_text(text)
    gl = BLOCK.copy()
    gl.apply_transform(Y_UP)
    gl.export(folder / "block.glb")
    paths["dae"], paths["glb"] = folder / "block.dae", folder / "block.glb"
    return paths


def test_every_format_loads_as_the_same_block_in_metres_z_up(tmp_path):
    from mitsonar.scenes.meshes import load_mesh

    for fmt, path in write_formats(tmp_path).items():
        v, f = load_mesh(path)
        assert np.allclose(v.min(0), [0, 0, 0], atol=1e-5) and np.allclose(v.max(0), [4, 2, 1], atol=1e-5), fmt
        assert len(f) == 12, fmt


def world_sdf(mesh_uri, extra=""):
    return f"""<?xml version="1.0"?>
<sdf version="1.9">
  <world name="pier">
    <physics type="ode"/>
    <light type="directional" name="sun"/>
    <plugin filename="gz-sim-physics-system" name="gz::sim::systems::Physics"/>
    <model name="block_a">
      <static>true</static>
      <pose>-6 3 -10 0 0 1.5707963267948966</pose>
      <link name="l"><visual name="v"><geometry><mesh><uri>{mesh_uri}</uri></mesh></geometry></visual></link>
    </model>
    <model name="pillar">
      <static>true</static>
      <pose>5 -4 -9 0 0 0</pose>
      <link name="l"><visual name="v"><geometry><cylinder><radius>1</radius><length>4</length></cylinder></geometry></visual>
        <sensor name="cam" type="camera"/></link>
    </model>
    <model name="buoy"><static>true</static><pose>5 6 -12 0 0 0</pose>
      <link name="l"><visual name="v"><geometry><sphere><radius>1.5</radius></sphere></geometry></visual></link></model>
    <model name="crate"><static>1</static><pose>-5 -5 -13 0 0 0.3</pose>
      <link name="l"><pose>0 0 1 0 0 0</pose><collision name="c"><geometry><box><size>2 2 2</size></box></geometry></collision></link></model>
    <model name="seabed"><static>true</static><pose>0 0 -14 0 0 0</pose>
      <link name="l"><visual name="v"><geometry><plane><normal>0 0 1</normal><size>40 40</size></plane></geometry></visual></link></model>
    <model name="bluerov"><pose>0 0 -2 0 0 0</pose><link name="base"/></model>
    {extra}
  </world>
</sdf>
"""


def test_a_world_places_each_model_where_its_sdf_puts_it(tmp_path, capsys):
    """Rays straight down over each model hit its top where the SDF's poses put it; lights,
    plugins, sensors and the vehicle (not static) are listed, one line each."""
    import drjit as dr
    import mitsuba as mi

    import mitsonar

    models = tmp_path / "models" / "block"
    (models / "meshes").mkdir(parents=True)
    write_formats(models / "meshes")
    (models / "model.config").write_text("<model><name>block</name><sdf version='1.9'>block.sdf</sdf></model>")
    (models / "block.sdf").write_text("""<sdf version="1.9"><model name="block"><static>true</static>
      <link name="l"><visual name="v"><geometry><mesh><uri>model://block/meshes/block.dae</uri></mesh></geometry>
      </visual></link></model></sdf>""")
    include = ("<include><uri>model://block</uri><name>block_b</name><pose>8 8 -11 0 0 0</pose></include>"
               "<model name='block_c'><static>true</static><pose>-14 -14 -12 0 0 0</pose><link name='l'><visual name='v'>"
               "<geometry><mesh><uri>model://block/meshes/block.stl</uri></mesh></geometry></visual></link></model>")
    sdf = tmp_path / "pier.sdf"
    sdf.write_text(world_sdf("model://block/meshes/block.stl", include))
    (tmp_path / "mat.csv").write_text("pattern,material\nblock_*,steel\nbuoy,seabed_mud\n")
    xml = tmp_path / "pier.xml"
    assert main(["scene", "from-sdf", str(sdf), "--model-path", str(tmp_path / "models"), "--materials",
                 str(tmp_path / "mat.csv"), "--sensor-pose", "0", "0", "-2", "0", "0", "0", "-o", str(xml)]) == 0
    out = capsys.readouterr().out
    for said in ("not converted: <light> 'sun'", "not converted: <plugin> 'gz::sim::systems::Physics'",
                 "sensor 'cam' (camera) of pillar::l", "model 'bluerov': not static"):
        assert said in out, out
    assert sorted(p.name for p in tmp_path.glob("pier_mesh_*.ply")) == ["pier_mesh_0.ply", "pier_mesh_1.ply"]
    scene = mitsonar.load_scene(str(xml))
    # the block_a STL turned 90 deg about z: its 4 m side along y, from x = -8 to -6, y = 3 to 7
    tops = {(-7.0, 5.0): -9.0, (-5.5, 5.0): -14.0, (-7.0, 2.5): -14.0,       # block_a, beside it
            (5.0, -4.0): -7.0, (5.0, 6.0): -10.5, (-5.0, -5.0): -11.0,    # pillar, buoy, crate
            (9.9, 9.0): -10.0, (12.5, 9.0): -14.0, (0.0, 0.0): -14.0,     # block_b (DAE), seabed plane
            (-11, -13.5): -11.0}                                           # block_c: block_a's STL again
    o = np.array([[x, y, 0.0] for x, y in tops])
    ray = mi.Ray3f(mi.Point3f(*o.T.astype(np.float32)), mi.Vector3f(0, 0, -1))
    si = scene.ray_intersect(ray)
    z = np.array(si.p.z)
    assert np.allclose(z, list(tops.values()), atol=1e-4), dict(zip(tops, z))
    # both blocks (block_*) are steel (Mitsuba merges meshes of one BSDF), the buoy mud, the rest rock
    steel = [s for s in scene.shapes() if s.bsdf().id() == "mat_steel"]
    lo = np.min([np.array(s.bbox().min) for s in steel], 0)
    hi = np.max([np.array(s.bbox().max) for s in steel], 0)
    assert np.allclose(lo, [-14, -14, -12], atol=1e-5) and np.allclose(hi, [12, 10, -9], atol=1e-5)
    materials = {s.bsdf().id() for s in scene.shapes()}
    assert materials == {"mat_steel", "mat_seabed_mud", "mat_rock"}
    # the sonar (the default echo sounder, looking down) at --sensor-pose
    to_world = np.array(scene.sensors()[0].world_transform().matrix).reshape(4, 4)
    assert np.allclose(to_world[:3, 3], [0, 0, -2]) and np.allclose(to_world[:3, 2], [0, 0, -1])


def test_materials_from_yaml_by_pattern(tmp_path):
    from mitsonar.scenes.sdf import SdfError, read_materials

    (tmp_path / "m.yaml").write_text("'pile_*': concrete_good\nwreck: steel\n")
    assert read_materials(str(tmp_path / "m.yaml")) == [("pile_*", "concrete_good"), ("wreck", "steel")]
    (tmp_path / "l.yaml").write_text("- {pattern: '*', material: 'medium sand@100'}\n")
    assert read_materials(str(tmp_path / "l.yaml")) == [("*", "medium sand@100")]
    (tmp_path / "b.yaml").write_text("wreck: titanium\n")
    with pytest.raises(SdfError, match="pattern 'wreck': material 'titanium': unknown material"):
        read_materials(str(tmp_path / "b.yaml"))


def render(xml):
    import mitsonar

    return mitsonar.render_scan(mitsonar.load_scene(str(xml)), spp=64, seed=3)


def test_the_same_mesh_in_four_formats_renders_the_same_scan(tmp_path):
    paths = write_formats(tmp_path)
    scans = {}
    for fmt, path in paths.items():
        sdf = tmp_path / f"{fmt}.sdf"
        sdf.write_text(f"""<sdf version="1.9"><world name="w">
          <model name="m"><static>true</static><pose>-2 -1 -8 0 0 0</pose><link name="l"><visual name="v"><geometry>
          <mesh><uri>{os.path.basename(path)}</uri></mesh></geometry></visual></link></model>
          <model name="floor"><static>true</static><pose>0 0 -9 0 0 0</pose><link name="l"><visual name="v"><geometry>
          <plane><size>30 30</size></plane></geometry></visual></link></model></world></sdf>""")
        sensor = tmp_path / "head.xml"
        sensor.write_text("""<sensor type="sonar"><string name="kind" value="multibeam"/>
          <transform name="to_world"><lookat origin="0,0,0" target="0,0,-1" up="1,0,0"/></transform>
          <float name="range_min" value="1"/><float name="range_max" value="12"/><integer name="n_bins" value="220"/>
          <integer name="n_pings" value="16"/><float name="bearing_start" value="-40"/><float name="bearing_step" value="5"/>
          <float name="beamwidth_h" value="2"/><float name="beamwidth_v" value="10"/></sensor>""")
        xml = tmp_path / f"{fmt}.xml"
        assert main(["scene", "from-sdf", str(sdf), "--sensor", str(sensor), "--material", "steel", "-o", str(xml)]) == 0
        scans[fmt] = np.asarray(render(xml).intensity, np.float64)
    ref = scans["stl"]
    assert ref.sum() > 0
    for fmt, scan in scans.items():
        rel = np.linalg.norm(scan - ref) / np.linalg.norm(ref)
        assert rel < 5e-3, (fmt, rel)
    # the block is seen: without it the scan differs by far more
    sdf = tmp_path / "stl.sdf"
    sdf.write_text(sdf.read_text().replace('<model name="m">', '<model name="m"><static>false</static>'))
    assert main(["scene", "from-sdf", str(sdf), "--sensor", str(tmp_path / "head.xml"), "--material", "steel",
                 "-o", str(tmp_path / "none.xml")]) == 0
    empty = np.asarray(render(tmp_path / "none.xml").intensity, np.float64)
    assert np.linalg.norm(empty - ref) / np.linalg.norm(ref) > 0.2


def _refused(capsys, argv, *needles):
    assert main(argv) == 1
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1, err
    for needle in needles:
        assert needle in err, err


def test_bad_worlds_are_refused_in_one_line_with_nothing_written(tmp_path, capsys):
    out = tmp_path / "out" / "w.xml"
    out.parent.mkdir()
    sdf = tmp_path / "w.sdf"
    sdf.write_text(world_sdf("meshes/gone.stl"))
    _refused(capsys, ["scene", "from-sdf", str(sdf), "-o", str(out)], "w.sdf", "meshes/gone.stl", "does not exist")
    sdf.write_text(world_sdf("model://nowhere/meshes/x.dae"))
    _refused(capsys, ["scene", "from-sdf", str(sdf), "--model-path", str(tmp_path), "-o", str(out)],
             "w.sdf", "model://nowhere/meshes/x.dae cannot be resolved", "--model-path")
    (tmp_path / "bad.stl").write_text("solid nothing\nendsolid\n")
    sdf.write_text(world_sdf("bad.stl"))
    _refused(capsys, ["scene", "from-sdf", str(sdf), "-o", str(out)], "bad.stl")
    BLOCK.export(tmp_path / "x.stl")
    sdf.write_text(world_sdf("x.stl").replace("<pose>5 6 -12 0 0 0</pose>", "<pose>5 6</pose>"))
    _refused(capsys, ["scene", "from-sdf", str(sdf), "-o", str(out)], "model 'buoy'", "is not 6 numbers")
    assert os.listdir(out.parent) == []


@pytest.mark.filterwarnings("ignore::rasterio.errors.NotGeoreferencedWarning")
def test_the_first_heightmap_and_the_worlds_place_on_the_earth(tmp_path, capsys):
    """The first heightmap becomes a height field over its size (an 8-bit image: pixel / 255 of
    size z, above pos z); a second is listed; <spherical_coordinates> is the scene's origin."""
    import mitsuba as mi
    import rasterio

    import mitsonar
    from mitsonar.geometry.geodesy import scene_frame

    img = np.zeros((5, 5), np.uint8)
    img[0, :] = 255                      # the image's top row: the north (+y) edge
    with rasterio.open(tmp_path / "h.tif", "w", driver="GTiff", width=5, height=5, count=1, dtype="uint8") as dst:
        dst.write(img, 1)
    hm = """<model name="terrain{k}"><static>true</static><link name="l"><visual name="v"><geometry><heightmap>
      <uri>h.tif</uri><size>8 8 2</size><pos>1 0 -10</pos></heightmap></geometry></visual></link></model>"""
    sdf = tmp_path / "h.sdf"
    sdf.write_text(f"""<sdf version="1.9"><world name="w"><spherical_coordinates><latitude_deg>43.5</latitude_deg>
      <longitude_deg>-8.2</longitude_deg><elevation>0</elevation></spherical_coordinates>
      {hm.format(k=1)}{hm.format(k=2)}</world></sdf>""")
    xml = tmp_path / "h.xml"
    assert main(["scene", "from-sdf", str(sdf), "-o", str(xml)]) == 0
    assert "not converted: heightmap of terrain2::l::v" in capsys.readouterr().out
    frame = scene_frame(str(xml))
    assert (frame.lat, frame.lon, frame.crs) == (43.5, -8.2, "EPSG:32629")
    scene = mitsonar.load_scene(str(xml))
    pts = np.array([[1.0, 0.0], [1.0, 3.9], [-2.5, -3.9], [4.9, 1.0]])
    ray = mi.Ray3f(mi.Point3f(pts[:, 0], pts[:, 1], np.zeros(4)), mi.Vector3f(0, 0, -1))
    z = np.array(scene.ray_intersect(ray).p.z)
    # rows 4 m apart in y from -4 to 4: flat at -10 up to y = 2, rising to -8 at y = 4
    assert np.allclose(z, [-10.0, -10.0 + 2 * 0.95, -10.0, -10.0], atol=1e-4), z
