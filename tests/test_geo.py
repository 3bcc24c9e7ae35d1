"""Georeferenced products: the origin and CRS (`mitsonar.geometry.geodesy`), soundings as LAS and
CSV (`mitsonar.export.las`), the depth GeoTIFF with its CRS (`mitsonar.export.geotiff`), and the
--origin/--crs refusals of the command line."""
from __future__ import annotations

import numpy as np
import pytest

pyproj = pytest.importorskip("pyproj", reason="georeferencing needs pyproj (the geo extra)")

from mitsonar.geometry.geodesy import GeoError, GeoFrame, utm_epsg  # noqa: E402


def test_published_utm_example_round_trip():
    """The CN Tower, 43.642567 N 79.387139 W: UTM 17N E 630084, N 4833439 (the worked example of
    the Wikipedia article "Universal Transverse Mercator coordinate system"), to the metre."""
    frame = GeoFrame.make((43.642567, -79.387139))
    assert frame.crs == "EPSG:32617"
    assert frame.e0 == pytest.approx(630084, abs=1.0) and frame.n0 == pytest.approx(4833439, abs=1.0)
    x, y = frame.from_lonlat(-79.387139, 43.642567)
    assert abs(x) < 1e-6 and abs(y) < 1e-6
    lon, lat = frame.to_lonlat(np.array([100.0, -250.0]), np.array([30.0, 400.0]))
    x2, y2 = frame.from_lonlat(lon, lat)
    assert np.allclose(x2, [100.0, -250.0], atol=1e-6) and np.allclose(y2, [30.0, 400.0], atol=1e-6)
    e, n = frame.to_grid(100.0, 30.0)
    assert e == pytest.approx(frame.e0 + 100.0) and n == pytest.approx(frame.n0 + 30.0)


def test_default_zone_north_south_and_the_antimeridian():
    assert utm_epsg(52.0, 4.5) == "EPSG:32631" and utm_epsg(-33.9, 18.4) == "EPSG:32734"
    assert utm_epsg(0.0, 180.0) == "EPSG:32660" and utm_epsg(0.0, -180.0) == "EPSG:32601"


@pytest.mark.parametrize("origin, crs, message", [
    ((91.0, 0.0), None, r"^--origin 91 0: off the Earth \(LAT LON \[HEIGHT\]: latitude in \[-90, 90\]"),
    ((10.0, -181.0), None, r"^--origin 10 -181: off the Earth"),
    ((10.0,), None, r"^--origin 10: not allowed \(LAT LON"),
    ((10.0, 2.0), "EPSG:4326", r"^--crs EPSG:4326: WGS 84 is geographic, without a projection .*\(a projected CRS as EPSG:NNNN"),
    ((10.0, 2.0), "EPSG:999999", r"^--crs EPSG:999999: unknown EPSG code \(a projected CRS"),
    ((10.0, 2.0), "UTM31", r"^--crs UTM31: not allowed \(a projected CRS as EPSG:NNNN"),
])
def test_bad_origin_or_crs_is_one_line_naming_the_flag(origin, crs, message):
    with pytest.raises(GeoError, match=message):
        GeoFrame.make(origin, crs)


@pytest.mark.parametrize("crs, message", [
    # UTM zone 1 for a point of zone 31: its grid was 14e6 m north and a GeoTIFF flipped north-south
    ("EPSG:32601", r"^--crs EPSG:32601: the origin 52 N 4.5 E is outside the area of use of WGS 84 / UTM zone 1N "
                   r"\(lon -180..-174, lat 0..84\); use the origin's UTM zone, EPSG:32631$"),
    ("EPSG:2154", r"^--crs EPSG:2154: the origin 52 N 4.5 E is outside the area of use of RGF93 v1 / Lambert-93 "),
    ("EPSG:4326", r"^--crs EPSG:4326: WGS 84 is geographic, without a projection to a grid in metres"),
    # Web Mercator: 1/cos(52 deg) = 1.62 (1.625 along the meridian on the ellipsoid)
    ("EPSG:3857", r"^--crs EPSG:3857: WGS 84 / Pseudo-Mercator has a scale error of \+63 % at the origin 52 N 4.5 E "
                  r"\(Web Mercator stretches distances by 1/cos\(lat\)\); surveys need true metres: use the "
                  r"origin's UTM zone, EPSG:32631$"),
    ("EPSG:2263", r"^--crs EPSG:2263: NAD83 / New York Long Island \(ftUS\) has its grid in US survey foot; "
                  r"surveys need metres"),
])
def test_a_crs_that_cannot_hold_the_origin_is_refused(crs, message):
    with pytest.raises(GeoError, match=message):
        GeoFrame.make((52.0, 4.5), crs)


@pytest.mark.parametrize("origin, crs", [((52.0, 4.5), "EPSG:32631"), ((52.0, 4.5), "EPSG:25831"),
                                         ((52.0, 4.5), "EPSG:28992"), ((-33.9, 18.4), "EPSG:32734"),
                                         ((0.0, 180.0), None), ((0.0, -180.0), None)])
def test_a_crs_that_holds_the_origin_is_accepted(origin, crs):
    frame = GeoFrame.make(origin, crs)
    assert frame.crs == (crs or utm_epsg(*origin))


def test_polar_origins_default_to_ups():
    """North of 84 N and south of 80 S UTM's zones end (their area of use): the default is UPS."""
    assert GeoFrame.make((86.0, 10.0)).crs == "EPSG:32661" and GeoFrame.make((-85.0, 10.0)).crs == "EPSG:32761"
    with pytest.raises(GeoError, match=r"^--crs EPSG:32632: the origin 86 N 10 E is outside .*use the origin's "
                                       r"UPS grid, EPSG:32661$"):
        GeoFrame.make((86.0, 10.0), "EPSG:32632")


def test_scan_meta_carries_origin_and_crs_through_files(tmp_path):
    from mitsonar import load_scan
    from mitsonar.scan.model import Scan

    frame = GeoFrame.make((52.0, 4.5, -1.25), "EPSG:25831")
    scan = Scan(intensity=np.zeros((2, 4), np.float32), data=np.zeros((2, 4), np.uint8), ranges=np.arange(4.0) + 0.5,
                bearings=np.zeros(2), poses=np.tile(np.eye(4), (2, 1, 1)), range_min=0.0, range_max=4.0,
                meta=frame.meta())
    for ext in (".npz", ".exr"):
        scan.save(tmp_path / f"s{ext}")
        back = load_scan(tmp_path / f"s{ext}")
        assert back.meta.origin == [52.0, 4.5, -1.25] and back.meta.crs == "EPSG:25831"
        assert GeoFrame.from_meta(back.meta) == frame


def _soundings(n=50, seed=0):
    from mitsonar.products.bathymetry import SOUNDING_DTYPE

    rng = np.random.default_rng(seed)
    s = np.zeros(n, SOUNDING_DTYPE)
    s["x"], s["y"] = rng.uniform(-20, 20, n), rng.uniform(-10, 30, n)
    s["z"] = -10.0 - rng.uniform(0, 2, n)
    s["intensity"] = rng.uniform(-60.0, -20.0, n)       # dB
    s["beam"], s["ping"] = rng.integers(0, 256, n), rng.integers(0, 1000, n)
    s["angle"] = rng.uniform(-60, 60, n)
    return s


def test_las_read_back_with_crs_and_attributes(tmp_path):
    laspy = pytest.importorskip("laspy", reason="LAS needs laspy (the geo extra)")
    from mitsonar.export.las import write_las

    frame = GeoFrame.make((52.0, 4.5, 0.5))
    s = _soundings()
    sigma = np.linspace(0.01, 0.2, len(s))
    assert write_las(tmp_path / "s.las", s, frame, uncertainty=sigma) == len(s)
    las = laspy.read(tmp_path / "s.las")
    assert las.header.parse_crs().to_epsg() == 32631
    assert np.allclose(las.x, s["x"] + frame.e0, atol=0.0005) and np.allclose(las.y, s["y"] + frame.n0, atol=0.0005)
    assert np.allclose(las.z, s["z"] + 0.5, atol=0.0005)       # elevation, positive up
    assert np.array_equal(las.beam, s["beam"]) and np.array_equal(las.ping, s["ping"])
    assert np.array_equal(np.asarray(las.angle), s["angle"])
    assert np.array_equal(np.asarray(las.echo_intensity), s["intensity"])
    assert np.allclose(las.depth_uncertainty, sigma.astype(np.float32))
    assert las.intensity.max() == 65535 and las.intensity.min() == 0
    i = np.argsort(s["intensity"])
    assert np.all(np.diff(las.intensity[i].astype(int)) >= 0)       # in the order of the dB levels


def test_csv_easting_northing_depth(tmp_path):
    from mitsonar.export.las import write_csv

    frame = GeoFrame.make((52.0, 4.5))
    s = _soundings(5)
    write_csv(tmp_path / "s.csv", s, frame)
    rows = np.loadtxt(tmp_path / "s.csv", delimiter=",", skiprows=1)
    assert open(tmp_path / "s.csv").readline() == "easting,northing,depth\n"
    assert np.allclose(rows, np.c_[s["x"] + frame.e0, s["y"] + frame.n0, -s["z"]], atol=0.0005)


def test_depth_geotiff_has_the_crs_gdal_reads(tmp_path):
    rasterio = pytest.importorskip("rasterio", reason="GeoTIFF needs rasterio (the geotiff extra)")
    from mitsonar.export.geotiff import write_depth_geotiff
    from mitsonar.products.soundings import grid_depths

    frame = GeoFrame.make((-33.9, 18.4))
    s = _soundings()
    grid = grid_depths(s, 1.0)
    write_depth_geotiff(tmp_path / "d.tif", grid, frame)
    with rasterio.open(tmp_path / "d.tif") as src:      # GDAL underneath
        assert src.crs.to_epsg() == 32734
        assert src.transform.c == pytest.approx(grid.transform[2] + frame.e0)
        assert src.transform.f == pytest.approx(grid.transform[5] + frame.n0)
        assert src.units == ("metre",) and src.descriptions == ("depth",)
        band = src.read(1)
    assert np.array_equal(np.isnan(band), np.isnan(grid.depth))
    assert np.allclose(band[~np.isnan(band)], grid.depth[~np.isnan(grid.depth)].astype(np.float32))


def test_bathymetry_with_origin_writes_las_csv_and_a_geotiff_with_its_crs(tmp_path, capsys):
    laspy = pytest.importorskip("laspy", reason="LAS needs laspy (the geo extra)")
    rasterio = pytest.importorskip("rasterio", reason="GeoTIFF needs rasterio (the geotiff extra)")
    import json
    import os

    from conftest import SCENES
    from mitsonar.cli import main
    from mitsonar.products.soundings import read_ply

    out = tmp_path / "run"
    args = ["bathymetry", os.path.join(SCENES, "rocky_slope.xml"), "--trajectory",
            os.path.join(SCENES, "rocky_slope_survey.tum"), "--beams", "16", "--max-scans", "2", "--spp", "16",
            "--range-max", "20", "--bin-width", "0.025", "--max-depth", "1", "-q", "-o", str(out),
            "--origin", "-33.9", "18.4", "--crs", "EPSG:32734"]
    assert main(args) == 0, capsys.readouterr().err
    assert {"soundings.las", "soundings.csv", "soundings.kmall", "depth.tif"} <= set(os.listdir(out))
    ply = read_ply(out / "soundings.ply")
    frame = GeoFrame.make((-33.9, 18.4), "EPSG:32734")
    las = laspy.read(out / "soundings.las")
    assert las.header.parse_crs().to_epsg() == 32734 and len(las.x) == len(ply)
    assert np.allclose(las.x, ply["x"] + frame.e0, atol=0.0005) and np.array_equal(las.beam, ply["beam"])
    assert "depth_uncertainty" in las.point_format.extra_dimension_names
    assert np.all(np.asarray(las.depth_uncertainty) > 0)
    with rasterio.open(out / "depth.tif") as src:
        assert src.crs.to_epsg() == 32734
    from mitsonar.export.bag import bag_available

    assert (out / "depth.bag").exists() == bag_available()
    assert json.loads((out / "errors.json").read_text())["crs"] == "EPSG:32734"
    import importlib

    try:
        reader = importlib.import_module("KMALL.kmall").kmall
    except ImportError:
        pass
    else:                                                   # one #MRZ per ping, 16 beams each
        k = reader(str(out / "soundings.kmall"))
        k.index_file()
        assert k.msgtype == [str(b"#MRZ")] * 2
        k.FID.seek(k.msgoffset[0])
        assert k.read_EMdgmMRZ()["rxInfo"]["numSoundingsMaxMain"] == 16
        k.closeFile()
    capsys.readouterr()
    assert main(args[:-7] + ["-o", str(tmp_path / "bad"), "--origin", "-33.9", "18.4", "--crs", "EPSG:4326"]) == 1
    err = capsys.readouterr().err.strip()
    assert err.count("\n") == 0 and "--crs EPSG:4326: WGS 84 is geographic" in err and not (tmp_path / "bad").exists()


def test_laz_is_compressed_and_reads_back_the_same(tmp_path):
    laspy = pytest.importorskip("laspy", reason="LAS needs laspy (the geo extra)")
    pytest.importorskip("lazrs", reason="LAZ needs the lazrs backend (laspy[lazrs])")
    from mitsonar.export.las import write_las

    frame = GeoFrame.make((52.0, 4.5))
    s = _soundings(200)
    write_las(tmp_path / "s.las", s, frame)
    write_las(tmp_path / "s.laz", s, frame)
    a, b = laspy.read(tmp_path / "s.las"), laspy.read(tmp_path / "s.laz")
    assert b.header.are_points_compressed and not a.header.are_points_compressed
    assert np.array_equal(a.X, b.X) and np.array_equal(a.beam, b.beam) and b.header.parse_crs().to_epsg() == 32631


def test_bag_read_back_by_gdal_with_crs_elevation_and_uncertainty(tmp_path):
    pytest.importorskip("rasterio", reason="BAG goes through rasterio's GDAL (the geo extra)")
    from mitsonar.export.bag import NODATA, bag_available, cell_uncertainty, write_bag
    from mitsonar.products.soundings import grid_depths

    if not bag_available():
        pytest.skip("this rasterio's GDAL has no BAG driver (HDF5)")
    import rasterio

    frame = GeoFrame.make((52.0, 4.5))
    s = _soundings(400)
    grid = grid_depths(s, 4.0)
    sigma = np.full(len(s), 0.07)
    write_bag(tmp_path / "d.bag", grid, frame, s, sigma)
    assert [p.name for p in tmp_path.iterdir()] == ["d.bag"]
    with rasterio.open(tmp_path / "d.bag") as src:
        assert src.driver == "BAG" and src.descriptions == ("elevation", "uncertainty")
        assert src.crs.to_epsg() == 32631 or "UTM zone 31N" in src.crs.to_wkt()
        assert src.transform.c == pytest.approx(grid.transform[2] + frame.e0)
        elev, unc = src.read(1), src.read(2)
    empty = np.isnan(grid.depth)
    assert np.all(elev[empty] == NODATA) and np.allclose(elev[~empty], -grid.depth[~empty].astype(np.float32))
    assert np.allclose(unc[~empty], 0.07)
    # without sigma: the standard deviation of the cell's depths (one cell, two soundings 1 m apart: 0.5)
    two = s[:2].copy()
    two["x"], two["y"], two["z"] = [0.1, 0.2], [0.1, 0.2], [-10.0, -11.0]
    g = grid_depths(two, 1.0)
    assert cell_uncertainty(g, two)[0, 0] == pytest.approx(0.5)


def _bag_xml(path):
    import xml.etree.ElementTree as ET

    import rasterio

    with rasterio.open(path) as src:
        return ET.fromstring(src.tags(ns="xml:BAG")["xml:BAG"].encode()), src.crs.to_wkt()


@pytest.mark.parametrize("with_sigma", [True, False])
def test_bag_is_attributed_as_a_hydrographer_reads_it(tmp_path, with_sigma):
    """The BAG's ISO metadata, read back by GDAL: a citation with a title and its creation date,
    an abstract saying what the grid is, the vertical reference system (z up from the survey's
    sea surface at the origin's height; a given WKT replaces it) inside a compound CRS with the
    horizontal EPSG code, the uncertainty type (productUncert for the predicted sigma, rawStdDev
    for the spread of the soundings), the process step and the organisation: not GDAL's empty or
    'unknown' defaults."""
    pytest.importorskip("rasterio", reason="BAG goes through rasterio's GDAL (the geo extra)")
    import datetime

    from mitsonar.export.bag import bag_available, write_bag
    from mitsonar.products.soundings import grid_depths

    if not bag_available():
        pytest.skip("this rasterio's GDAL has no BAG driver (HDF5)")
    frame = GeoFrame.make((52.0, 4.5, 3.0))
    s = _soundings(300)
    when = datetime.datetime(2026, 3, 4, 5, 6, 7, tzinfo=datetime.timezone.utc)
    write_bag(tmp_path / "d.bag", grid_depths(s, 4.0), frame, s, np.full(len(s), 0.05) if with_sigma else None,
              when=when)
    root, wkt = _bag_xml(tmp_path / "d.bag")
    ns = {"gmd": "http://www.isotc211.org/2005/gmd", "gco": "http://www.isotc211.org/2005/gco",
          "bag": "http://www.opennavsurf.org/schema/bag"}

    def texts(path):
        return [e.text for e in root.findall(path, ns)]

    ident = "gmd:identificationInfo/bag:BAG_DataIdentification/"
    assert texts(ident + "gmd:citation/gmd:CI_Citation/gmd:title/gco:CharacterString") == \
        ["mitsonar simulated bathymetry, 4 m grid"]
    assert texts(ident + "gmd:citation/gmd:CI_Citation/gmd:date/gmd:CI_Date/gmd:date/gco:Date") == ["2026-03-04"]
    abstract = texts(ident + "gmd:abstract/gco:CharacterString")[0]
    assert "Simulated" in abstract and "EPSG:32631" in abstract and "4 m cell" in abstract
    code = root.find(ident + "bag:verticalUncertaintyType/bag:BAG_VertUncertCode", ns)
    assert code.text == code.get("codeListValue") == ("productUncert" if with_sigma else "rawStdDev")
    steps = root.findall(".//gmd:LI_ProcessStep", ns)
    assert len(steps) == 1 and "mitsonar" in steps[0].find("gmd:description/gco:CharacterString", ns).text
    assert steps[0].find("gmd:dateTime/gco:DateTime", ns).text == "2026-03-04T05:06:07"
    assert "mitsonar (simulated survey)" in texts(".//gmd:organisationName/gco:CharacterString")
    crs = pyproj.CRS.from_wkt(wkt)
    horizontal, vertical = crs.sub_crs_list
    assert horizontal.to_epsg() == 32631
    assert "sea surface, 3 m above the WGS 84 ellipsoid" in vertical.name and vertical.axis_info[0].direction == "up"
    # a known vertical datum replaces the local one
    write_bag(tmp_path / "e.bag", grid_depths(s, 4.0), frame, s, None,
              vertical_wkt=pyproj.CRS.from_epsg(5709).to_wkt("WKT1_GDAL"))      # NAP height
    _, wkt = _bag_xml(tmp_path / "e.bag")
    assert pyproj.CRS.from_wkt(wkt).sub_crs_list[1].name == "NAP height"


def test_a_target_at_a_known_lat_lon_is_there_in_the_mosaic_geotiff(tmp_path):
    """A bright echo from a point at a chosen lat/lon (one ping, port, slant range over a flat
    bottom at a known altitude) lands, in the mosaic GeoTIFF read back through GDAL, in the cell
    whose centre is within one cell of pyproj's projection of that lat/lon."""
    rasterio = pytest.importorskip("rasterio", reason="GeoTIFF needs rasterio (the geotiff extra)")
    import math

    from mitsonar.export.geotiff import write_mosaic_geotiff
    from mitsonar.geometry.frames import sidescan_rotation
    from mitsonar.products.mosaic import mosaic
    from mitsonar.scan.model import Scan

    frame = GeoFrame.make((43.642567, -79.387139))
    target_lat, target_lon = 43.6427, -79.3870
    tx, ty = frame.from_lonlat(target_lon, target_lat)
    altitude, ground = 5.0, 8.0                                 # the target 8 m to port of ping 10
    n, bins, r0, r1 = 21, 200, 0.0, 20.0
    channel = np.repeat([0, 1], n)
    poses = sidescan_rotation(channel, math.radians(10.0))     # head along +x (grid east), port +y
    xs = float(tx) + (np.arange(n) - 10) * 0.2
    poses[:, 0, 3], poses[:, 1, 3], poses[:, 2, 3] = np.tile(xs, 2), float(ty) - ground, -10.0
    ranges = r0 + (np.arange(bins) + 0.5) * (r1 - r0) / bins
    data = np.full((2 * n, bins), 10, np.uint8)
    data[10, np.argmin(np.abs(ranges - math.hypot(ground, altitude)))] = 250
    scan = Scan(intensity=np.zeros((2 * n, bins), np.float32), data=data, ranges=ranges, bearings=np.zeros(2 * n),
                poses=poses, range_min=r0, range_max=r1, kind="sidescan", beamwidth_h=1.0, beamwidth_v=50.0,
                times=np.tile(np.arange(n) * 0.1, 2), meta={"side": "both"})
    m = mosaic(scan, resolution=0.2, use="data", altitude=altitude)
    write_mosaic_geotiff(tmp_path / "m.tif", m, frame)
    with rasterio.open(tmp_path / "m.tif") as src:
        assert src.crs.to_epsg() == 32617 and src.units == ("device level 0-255 (the scans' data bytes)",)
        band = src.read(1)
        row, col = np.unravel_index(np.nanargmax(band), band.shape)
        e, nn = src.xy(row, col)                                # the cell's centre, in the CRS
    te, tn = pyproj.Transformer.from_crs("EPSG:4326", "EPSG:32617", always_xy=True).transform(target_lon, target_lat)
    assert abs(e - te) <= 0.2 + 1e-9 and abs(nn - tn) <= 0.2 + 1e-9
    assert np.isnan(band).any() and np.nanmax(band) > 3 * 10        # the echo stands out of the background


def _nmea(body):
    c = 0
    for ch in body:
        c ^= ord(ch)
    return f"${body}*{c:02X}\n"


def _ddmm(value, width, pos, neg):
    a = abs(value)
    d = int(a)
    return f"{d:0{width}d}{(a - d) * 60:09.6f}", pos if value >= 0 else neg


def test_lat_lon_trajectories_from_csv_and_nmea(tmp_path):
    from mitsonar.geometry.geotrack import read_geo_trajectory

    frame = GeoFrame.make((52.0, 4.5, 0.0))
    x = np.array([0.0, 30.0, 60.0, 90.0])
    y = np.array([0.0, 10.0, 20.0, 30.0])
    lon, lat = frame.to_lonlat(x, y)
    with open(tmp_path / "t.csv", "w") as f:
        f.write("time,lat,lon,depth,heading\n")
        for i in range(4):
            f.write(f"{10.0 * i},{lat[i]:.10f},{lon[i]:.10f},5.0,{45.0}\n")
    track = read_geo_trajectory(tmp_path / "t.csv", frame)
    assert np.allclose(track.positions[:, :2], np.c_[x, y], atol=1e-4) and np.allclose(track.positions[:, 2], -5.0)
    # true heading 45 deg: the grid direction differs from grid north-east by the meridian convergence
    conv = pyproj.Proj(frame.crs).get_factors(float(lon[0]), float(lat[0])).meridian_convergence
    fwd = track.poses[0, :3, 0]
    grid_azimuth = np.degrees(np.arctan2(fwd[0], fwd[1]))
    assert grid_azimuth == pytest.approx(45.0 - conv, abs=1e-3) and abs(conv) > 1.0
    lines = []
    for i in range(4):
        (la, ns), (lo, ew) = _ddmm(lat[i], 2, "N", "S"), _ddmm(lon[i], 3, "E", "W")
        lines.append(_nmea(f"GPGGA,1200{10 * i:02d}.00,{la},{ns},{lo},{ew},1,08,0.9,-5.0,M,0.0,M,,"))
        lines.append(_nmea("GPVTG,90.0,T,,M,1.0,N,1.9,K,A"))
    (tmp_path / "t.nmea").write_text("".join(lines))
    track = read_geo_trajectory(tmp_path / "t.nmea", frame)
    assert np.allclose(track.times, 43200.0 + 10.0 * np.arange(4))
    assert np.allclose(track.positions[:, :2], np.c_[x, y], atol=0.005)    # 1e-6 minute: under 2 mm
    assert np.allclose(track.positions[:, 2], -5.0)
    fwd = track.poses[2, :3, 0]
    assert np.degrees(np.arctan2(fwd[0], fwd[1])) == pytest.approx(90.0 - conv, abs=1e-3)
    bad = lines[0][:-3] + ("00" if not lines[0].endswith("*00\n") else "01") + "\n"
    (tmp_path / "bad.nmea").write_text(bad)
    with pytest.raises(GeoError, match=r"bad.nmea: line 1: checksum '00' is wrong"):
        read_geo_trajectory(tmp_path / "bad.nmea", frame)
    (tmp_path / "bad.csv").write_text("time,lat,lon\n0,52,4.5\n")
    with pytest.raises(GeoError, match=r"bad.csv: line 1: no column 'depth'"):
        read_geo_trajectory(tmp_path / "bad.csv", frame)
    (tmp_path / "far.csv").write_text("time,lat,lon,depth\n0,95,4.5,1\n")
    with pytest.raises(GeoError, match=r"far.csv: line 2: lat lon 95 4.5: off the Earth"):
        read_geo_trajectory(tmp_path / "far.csv", frame)


def test_one_geotiff_writer_serves_every_grid():
    """The mosaic, the depth grid (georeferenced or not), the elevation grid of `mitsonar map` and
    the BAG's staging file are all written by `mitsonar.export.geotiff.write_geotiff`: no other
    module of mitsonar opens a GeoTIFF for writing (hilbertmap keeps its own writer, as it must
    not import mitsonar)."""
    import pathlib
    import re

    root = pathlib.Path(__file__).resolve().parents[1] / "mitsonar"
    writers = sorted(str(p.relative_to(root)) for p in root.rglob("*.py")
                     if re.search(r"""driver\s*=\s*["']GTiff["']""", p.read_text(encoding="utf-8")))
    assert writers == ["export/geotiff.py"]


@pytest.mark.parametrize("flags, message", [
    (["--origin", "95", "4"], "--origin 95 4: off the Earth"),
    (["--origin", "52", "4", "--crs", "EPSG:1"], "--crs EPSG:1: unknown EPSG code"),
    (["--origin", "52", "4", "--crs", "EPSG:4326"], "--crs EPSG:4326: WGS 84 is geographic"),
    (["--origin", "52", "4.5", "--crs", "EPSG:32601"], "--crs EPSG:32601: the origin 52 N 4.5 E is outside"),
    (["--origin", "52", "4.5", "--crs", "EPSG:3857"], "--crs EPSG:3857: WGS 84 / Pseudo-Mercator has a scale error"),
])
def test_bathymetry_refuses_bad_geo_flags_in_one_line(tmp_path, capsys, flags, message):
    import os

    from conftest import SCENES
    from mitsonar.cli import main

    out = tmp_path / "run"
    rc = main(["bathymetry", os.path.join(SCENES, "rocky_slope.xml"), "--trajectory",
               os.path.join(SCENES, "rocky_slope_survey.tum"), "--max-scans", "1", "-q", "-o", str(out)] + flags)
    err = capsys.readouterr().err.strip()
    assert rc == 1 and err.count("\n") == 0 and message in err, err
    assert not out.exists()
