"""A seabed from a bathymetric grid (`mitsonar.scenes.grid`, ``mitsonar scene from-grid``): the
scene carries the grid's CRS, a survey over it exports soundings at the grid's coordinates, and
bad grids are refused in one line with nothing written."""
from __future__ import annotations

import os

import numpy as np
import pytest

rasterio = pytest.importorskip("rasterio")
pytest.importorskip("pyproj")
pytest.importorskip("laspy")

from rasterio.transform import Affine  # noqa: E402

from mitsonar.cli import main  # noqa: E402

E0, N0 = 431000.0, 5761000.0          # UTM 31N, off the Dutch coast


def from_origin(west, north, xsize, ysize):
    """rasterio's ``from_origin`` without affine's deprecated ``*``."""
    return Affine(xsize, 0.0, west, 0.0, -ysize, north)


def mound(e, n, ec=E0 + 40, nc=N0 + 30):
    """The site: 20 m deep, a 5 % slope up towards the east, a 2 m gaussian mound in the middle."""
    return -20.0 + 0.05 * (e - ec) + 2.0 * np.exp(-((e - ec) ** 2 + (n - nc) ** 2) / 200.0)


def write_grid(path, nx=80, ny=60, cell=1.0, crs="EPSG:32631", values=None, description="elevation", nodata=None,
               west=E0, north=N0 + 60, tags=None, env=None):
    e = west + (np.arange(nx) + 0.5) * cell
    n = north - (np.arange(ny) + 0.5) * cell
    z = mound(*np.meshgrid(e, n)) if values is None else values
    with rasterio.Env(**(env or {})):
        with rasterio.open(path, "w", driver="GTiff", width=nx, height=ny, count=1, dtype="float32", crs=crs,
                           transform=from_origin(west, north, cell, cell), nodata=nodata) as dst:
            dst.write(np.asarray(z, np.float32), 1)
            if description:
                dst.set_band_description(1, description)
            if tags:
                dst.update_tags(**tags)
    return path


def ply_vertices(path):
    from mitsonar.geometry.ply import read_ply

    rows, faces = read_ply(path)
    return np.stack([rows["x"], rows["y"], rows["z"]], 1).astype(np.float64), faces


def test_survey_over_a_grid_exports_soundings_at_the_grids_coordinates(tmp_path, capsys):
    """The LAS target: a multibeam survey (beams within +-45 deg) over a GeoTIFF in UTM, exported
    without --origin/--crs: the median error per 5 deg bin within 0.1 % of depth, 95 % of the
    soundings within 0.1 % of depth + 2 cm of the grid's surface, and the LAS in the grid's CRS."""
    import laspy

    from mitsonar.geometry.geodesy import scene_frame

    tif = write_grid(tmp_path / "site.tif")
    xml = tmp_path / "site.xml"
    assert main(["scene", "from-grid", str(tif), "-o", str(xml)]) == 0
    frame = scene_frame(str(xml))
    assert frame.crs == "EPSG:32631" and (round(frame.e0, 6), round(frame.n0, 6)) == (E0 + 40, N0 + 30)
    out = tmp_path / "bathy"
    assert main(["bathymetry", str(xml), "--lawnmower", "-15", "15", "-6", "6", "--spacing", "12", "--depth", "2",
                 "--speed", "6", "--swath", "90", "--beams", "37", "--max-scans", "4", "--spp", "32",
                 "--no-speckle", "-q", "-o", str(out)]) == 0
    las = laspy.read(out / "soundings.las")
    assert las.header.parse_crs().to_epsg() == 32631
    e, n, z = np.asarray(las.x), np.asarray(las.y), np.asarray(las.z)
    assert len(e) > 100 and e.min() > E0 and n.min() > N0     # eastings and northings, not local metres
    truth = mound(e, n)
    depth, err, angle = -truth, z - truth, np.asarray(las["angle"])
    assert np.abs(angle).max() <= 45 + 1e-6
    for lo in range(-45, 45, 5):
        m = (angle >= lo) & ((angle < lo + 5) | (lo == 40))
        assert m.any()
        assert abs(np.median(err[m])) <= 1e-3 * np.median(depth[m]), lo
    assert np.mean(np.abs(err) <= 1e-3 * depth + 0.02) >= 0.95


def test_the_scene_frame_is_what_the_commands_use(tmp_path):
    import argparse

    from mitsonar.geometry.geodesy import GeoError, frame_from_args

    tif = write_grid(tmp_path / "site.tif")
    xml = str(tmp_path / "site.xml")
    assert main(["scene", "from-grid", str(tif), "-o", xml, "--origin", "52", "2"]) == 0
    got = frame_from_args(argparse.Namespace(scene=xml, origin=None, crs=None))
    assert (got.lat, got.lon, got.crs) == (52.0, 2.0, "EPSG:32631")
    assert frame_from_args(argparse.Namespace(scene=xml, origin=[52.0, 2.0], crs=None)) == got
    with pytest.raises(GeoError, match="records origin 52 2 0 and crs EPSG:32631"):
        frame_from_args(argparse.Namespace(scene=xml, origin=[52.0, 3.0], crs=None))
    v, _ = ply_vertices(tmp_path / "site_seabed.ply")
    # the vertices are at the cells' centres, offset by the origin's easting/northing
    assert np.allclose(np.sort(np.unique(np.round(v[:, 0] + got.e0, 3)))[[0, -1]], [E0 + 0.5, E0 + 79.5], atol=2e-3)


@pytest.mark.parametrize("convention,first", [("Area", (E0 + 5, N0 + 15)), ("Point", (E0, N0 + 20))])
def test_pixel_is_point_and_pixel_is_area(tmp_path, convention, first):
    """A point raster's values are at its tie points, an area raster's at its cells' centres: the
    same numbers in the file, half a cell apart on the seabed."""
    values = np.arange(12, dtype=np.float32).reshape(3, 4) - 30
    tif = write_grid(tmp_path / "p.tif", nx=4, ny=3, cell=10.0, values=values, north=N0 + 20,
                     tags={"AREA_OR_POINT": convention}, env={"GTIFF_POINT_GEO_IGNORE": True})
    from mitsonar.scenes.grid import read_grid

    g = read_grid(tif)
    assert g.z[-1, 0] == -30                     # the file's first value, at the north-west vertex
    assert (g.x[0], g.y[-1]) == first


def test_geographic_grid_is_reprojected_to_its_utm_zone(tmp_path):
    import pyproj

    from mitsonar.scenes.grid import read_grid

    to_utm = pyproj.Transformer.from_crs("EPSG:4326", "EPSG:32631", always_xy=True)
    lon0, lat0 = pyproj.Transformer.from_crs("EPSG:32631", "EPSG:4326", always_xy=True).transform(E0, N0)
    nx, ny, d = 60, 50, 0.00002
    lon = lon0 + (np.arange(nx) + 0.5) * d
    lat = lat0 + ny * d - (np.arange(ny) + 0.5) * d
    LON, LAT = np.meshgrid(lon, lat)
    e, n = to_utm.transform(LON, LAT)
    tif = write_grid(tmp_path / "geo.tif", nx=nx, ny=ny, cell=d, crs="EPSG:4326", values=mound(e, n),
                     west=lon0, north=lat0 + ny * d)
    g = read_grid(tif, resolution=0.5)
    assert g.crs == "EPSG:32631" and g.cell == 0.5
    E, N = np.meshgrid(g.x, g.y)
    inner = (slice(4, -4), slice(4, -4))
    err = np.abs(g.z - mound(E, N))[inner]
    # bilinear over cells of 1.4 x 2.2 m: at most h^2 / 8 times the mound's curvature, 0.02 / m
    assert err.max() < 0.03 and np.median(err) < 1e-3


def test_depths_bounds_and_compound_crs(tmp_path):
    """A depth grid (positive down) in a compound CRS (UTM + a vertical datum) given as WKT,
    cropped: heights are minus the depths plus the vertical offset."""
    import pyproj

    from mitsonar.scenes.grid import read_grid

    compound = pyproj.CRS.from_user_input("EPSG:32631+5709").to_wkt()
    tif = write_grid(tmp_path / "d.tif", description="depth", crs=compound, values=np.full((60, 80), 12.0))
    g = read_grid(tif, bounds=(E0 + 10, N0 + 10, E0 + 30, N0 + 20), vertical_offset=-1.5)
    assert g.crs == "EPSG:32631" and g.positive == "down"
    assert np.all(g.z == -13.5)
    assert (g.x[0], g.x[-1], g.y[0], g.y[-1]) == (E0 + 10.5, E0 + 29.5, N0 + 10.5, N0 + 19.5)


def test_a_large_grid_gets_a_coarser_level_of_detail(tmp_path):
    from mitsonar.scenes.grid import GridError, read_grid, seabed_from_grid

    tif = write_grid(tmp_path / "site.tif")
    g = read_grid(tif, max_vertices=1500)
    assert g.lod == 1 and g.cell == 2.0 and g.z.shape == (30, 40)
    E, N = np.meshgrid(g.x, g.y)
    assert np.abs(g.z - mound(E, N)).max() < 0.05      # the mean of the 2 x 2 cells under each vertex
    with pytest.raises(GridError, match="--resolution 1: 80 x 60 vertices, over the 1500"):
        read_grid(tif, resolution=1.0, max_vertices=1500)
    # bounds reaching past the grid keep its part inside them (not a border of nodata)
    g = read_grid(tif, bounds=(E0 + 40, N0 - 50, E0 + 500, N0 + 30), max_vertices=1500)
    assert g.lod == 0 and (g.x[0], g.x[-1], g.y[0], g.y[-1]) == (E0 + 40.5, E0 + 79.5, N0 + 0.5, N0 + 29.5)
    g = read_grid(tif, bounds=(E0 + 40, N0 - 50, E0 + 500, N0 + 30), resolution=2.0)
    assert (g.x[0], g.x[-1], g.y[0], g.y[-1]) == (E0 + 41, E0 + 79, N0 + 1, N0 + 29)
    site = seabed_from_grid(tif, tmp_path / "s.xml", max_vertices=1500)
    assert "level of detail 1" in site.line() and site.n_triangles == 2 * 29 * 39


def test_sediment_classes_become_materials_by_area(tmp_path):
    import mitsonar

    tif = write_grid(tmp_path / "site.tif")
    classes = np.where(np.arange(80)[None, :] < 40, 1, 7).repeat(60, 0)
    sed = tmp_path / "sed.tif"
    with rasterio.open(sed, "w", driver="GTiff", width=80, height=60, count=1, dtype="int16", crs="EPSG:32631",
                       transform=from_origin(E0, N0 + 60, 1.0, 1.0)) as dst:
        dst.write(classes.astype(np.int16), 1)
    (tmp_path / "sed.csv").write_text("class,material\n1,seabed_mud\n7,medium sand@100\n")
    xml = tmp_path / "s.xml"
    assert main(["scene", "from-grid", str(tif), "--sediment", str(sed), "--sediment-map", str(tmp_path / "sed.csv"),
                 "-o", str(xml)]) == 0
    scene = mitsonar.load_scene(str(xml))
    shapes = {s.id(): s for s in scene.shapes()}
    assert set(shapes) == {"seabed_medium_sand_100", "seabed_mud"}
    for name, west in (("seabed_mud", True), ("seabed_medium_sand_100", False)):   # west of E0 + 40: class 1
        v = np.array(shapes[name].vertex_positions_buffer()).reshape(-1, 3)
        assert (v[:, 0].max() <= 0.0 + 1e-4) if west else (v[:, 0].min() >= -1.0 - 1e-4)
        assert shapes[name].bsdf().id() == f"{name}_bsdf"
    assert 'id="seabed_mud_bsdf"><string name="preset" value="seabed_mud"/>' in xml.read_text()
    assert "apl_uw 'medium sand' at 100000 Hz" in str(shapes["seabed_medium_sand_100"].bsdf())
    # the side-scan products take the parts together as the seabed
    from mitsonar.products.sidescan import seabed_of_scene

    height = seabed_of_scene(scene)
    assert np.allclose(height(np.array([-20.0, 20.0]), np.array([0.0, 0.0])),
                       mound(np.array([E0 + 20, E0 + 60]), np.array([N0 + 30, N0 + 30])), atol=0.01)


def _refused(capsys, argv, *needles):
    assert main(argv) == 1
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1, err
    for needle in needles:
        assert needle in err, err
    return err


def test_bad_grids_are_refused_in_one_line_with_nothing_written(tmp_path, capsys):
    out = tmp_path / "out" / "s.xml"
    out.parent.mkdir()
    nocrs = write_grid(tmp_path / "nocrs.tif", crs=None)
    _refused(capsys, ["scene", "from-grid", str(nocrs), "-o", str(out)], "nocrs.tif: has no CRS", "gdal_edit.py")
    vals = mound(*np.meshgrid(E0 + np.arange(80) + 0.5, N0 + 60 - np.arange(60) - 0.5))
    vals[20:22, 30:33] = -9999
    holes = write_grid(tmp_path / "holes.tif", values=vals, nodata=-9999)
    _refused(capsys, ["scene", "from-grid", str(holes), "-o", str(out)], "holes.tif: 6 nodata cells", "--bounds")
    # the same grid cropped away from its holes converts
    assert main(["scene", "from-grid", str(holes), "--bounds", str(E0), str(N0), str(E0 + 20), str(N0 + 60),
                 "-o", str(tmp_path / "ok.xml")]) == 0
    unsaid = write_grid(tmp_path / "unsaid.tif", description=None)
    _refused(capsys, ["scene", "from-grid", str(unsaid), "-o", str(out)], "unsaid.tif", "--positive up")
    ok = write_grid(tmp_path / "site.tif")
    _refused(capsys, ["scene", "from-grid", str(ok), "--crs", "EPSG:4326", "-o", str(out)], "--crs EPSG:4326",
             "geographic")
    _refused(capsys, ["scene", "from-grid", str(ok), "--material", "chocolate", "-o", str(out)],
             "--material 'chocolate': unknown material")
    sed = write_grid(tmp_path / "sed.tif", values=np.where(np.arange(80) < 50, 1, 3)[None, :].repeat(60, 0))
    (tmp_path / "map.csv").write_text("1,seabed_mud\n2,seabed_sand\n")
    _refused(capsys, ["scene", "from-grid", str(ok), "--sediment", str(sed), "--sediment-map",
                      str(tmp_path / "map.csv"), "-o", str(out)], "class 3 (", "not in the sediment map")
    assert os.listdir(out.parent) == []
    out.write_text("mine")
    _refused(capsys, ["scene", "from-grid", str(ok), "-o", str(out)], "exists", "--force")
    assert out.read_text() == "mine"


def test_a_bag_is_elevation_without_a_flag(tmp_path):
    """A BAG's values are elevations (positive up) by the format: no --positive needed, where a
    GeoTIFF with the same numbers and no metadata is refused."""
    from mitsonar.scenes.grid import GridError, read_grid

    z = np.full((20, 30), -15.0, np.float32)
    z[5:8, 4:9] = -12.0
    with rasterio.open(tmp_path / "t.bag", "w", driver="BAG", width=30, height=20, count=1, dtype="float32",
                       crs="EPSG:32631", transform=from_origin(E0, N0 + 40, 2.0, 2.0), nodata=1e6) as dst:
        dst.write(z, 1)
    g = read_grid(tmp_path / "t.bag")
    assert g.positive == "up" and g.crs == "EPSG:32631"
    assert np.array_equal(g.z, z[::-1].astype(np.float64))
    with pytest.raises(GridError, match="--positive up"):
        read_grid(write_grid(tmp_path / "t.tif", nx=30, ny=20, cell=2.0, values=z, description=None, north=N0 + 40))


def test_a_gebco_like_netcdf_in_degrees_goes_to_utm(tmp_path):
    """A NetCDF grid in WGS 84 degrees (as GEBCO's): reprojected to the UTM zone of its centre,
    at its cell's size in metres; values that do not say their sense need --positive."""
    from rasterio.shutil import copy as rio_copy

    from mitsonar.scenes.grid import GridError, read_grid

    nx, ny, d = 60, 50, 1 / 240                   # 15 arc-second cells, GEBCO's
    z = np.tile(-20.0 + 0.05 * np.arange(nx), (ny, 1)).astype(np.float32)
    tif = tmp_path / "g.tif"
    with rasterio.open(tif, "w", driver="GTiff", width=nx, height=ny, count=1, dtype="float32", crs="EPSG:4326",
                       transform=Affine(d, 0.0, 3.0, 0.0, -d, 52.0 + ny * d)) as dst:
        dst.write(z, 1)
    rio_copy(str(tif), str(tmp_path / "g.nc"), driver="netCDF")
    with pytest.raises(GridError, match="give --positive up"):
        read_grid(tmp_path / "g.nc")
    g = read_grid(tmp_path / "g.nc", positive="up")
    assert g.crs == "EPSG:32631" and 280 < g.cell < 470 and g.lod == 0
    assert -20.0 <= g.z.min() and g.z.max() <= -20.0 + 0.05 * (nx - 1) + 1e-6


def test_a_side_scan_survey_over_a_grid_writes_its_mosaic_in_the_grids_crs(tmp_path):
    """survey over a from-grid scene, no --origin: the scans carry the scene's origin and CRS and
    the side-scan mosaic is a GeoTIFF at the grid's coordinates."""
    import mitsonar

    tif = write_grid(tmp_path / "site.tif")
    head = tmp_path / "ss.xml"
    head.write_text('<sensor type="sonar"><string name="kind" value="sidescan"/><string name="side" value="both"/>'
                    '<float name="depression" value="25"/><float name="range_min" value="0"/>'
                    '<float name="range_max" value="30"/><integer name="n_bins" value="300"/>'
                    '<integer name="n_pings" value="8"/><float name="beamwidth_h" value="1"/>'
                    '<float name="beamwidth_v" value="60"/></sensor>')
    xml = tmp_path / "site.xml"
    assert main(["scene", "from-grid", str(tif), "--sensor", str(head), "-o", str(xml)]) == 0
    out = tmp_path / "ss"
    assert main(["survey", str(xml), "--lawnmower", "-10", "10", "0", "0", "--depth", "5", "--speed", "5",
                 "--spp", "8", "-q", "-o", str(out)]) == 0
    assert mitsonar.load_scan(str(out / "scan_00000.npz")).meta.crs == "EPSG:32631"
    with rasterio.open(out / "mosaic.tif") as src:
        assert src.crs.to_epsg() == 32631
        assert src.bounds.left >= E0 - 1 and src.bounds.right <= E0 + 81 and src.bounds.bottom >= N0 - 1
