"""Outputs of survey maps (issue 31): the seabed elevation grid and `mitsonar map --incremental`."""
import os
import subprocess
import sys

import numpy as np
import pytest

from conftest import ROOT
from hilbertmap import IncrementalHilbertMap
from hilbertmap.elevation import elevation_grid, read_elevation, write_elevation
from hilbertmap.testing import box_scan, moving_poses

# a head sweeping the vertical x-z plane (scan axis y, bearing 0 straight down) carried 4 m along y
# during the sweep: its 35 deg fan lies along y, so the floor is seen in a helix of strips
DOWN = dict(boresight=(0.0, 0.0, -1.0), scan_axis=(0.0, 1.0, 0.0))


@pytest.fixture(scope="module")
def floor_scan():
    return box_scan(moving_poses((0, -2, 0), (0, 2, 0), **DOWN), rays=60, seed=3)


def test_elevation_grid_finds_the_floor(floor_scan, tmp_path):
    hm = IncrementalHilbertMap(random_state=0).partial_fit(floor_scan)
    box = ((-3.0, -2.0, -4.0), (3.0, 2.0, -1.0))
    g = elevation_grid(hm, resolution=0.25, bounds=box, method="first")
    assert g.elevation.shape == (16, 24)
    x, y = g.xy()
    assert np.isclose(x[0], -2.875) and np.isclose(y[0], 1.875)  # north up: row 0 at the largest y
    known = np.isfinite(g.elevation)
    assert known.mean() > 0.35  # the helix the moving sweep drew (about half the grid)
    # the floor is z = -3: the elevation is where p rises through 0.5 coming down from the water
    err = g.elevation[known] + 3.0
    assert abs(np.median(err)) < 0.15 and np.percentile(np.abs(err), 90) < 0.3, (np.median(err),)
    # the most probable height sits in the occupied band, at most a length-scale behind the face
    peak = elevation_grid(hm, resolution=0.25, bounds=box)
    assert np.all(np.isfinite(peak.elevation)[known])  # a crossing implies a peak at or above level
    err = peak.elevation[known] + 3.0
    assert -hm.lengthscale_ - 0.1 < np.median(err) < 0.1
    path = tmp_path / "seabed.npz"
    write_elevation(path, g)
    back = read_elevation(path)
    assert back.transform == g.transform and np.allclose(back.elevation, g.elevation, equal_nan=True, atol=1e-5)
    with pytest.raises(ValueError, match=r"seabed.png: elevation grids are written as .tif/.tiff"):
        write_elevation(tmp_path / "seabed.png", g)


def _run(*args):
    env = dict(os.environ)
    env.pop("MITSONAR_DEBUG", None)
    return subprocess.run([sys.executable, "-m", "mitsonar.cli", *args], capture_output=True, text=True,
                          cwd=ROOT, env=env, timeout=600)


def test_map_incremental_cli(floor_scan, tmp_path):
    from mitsonar import Scan

    survey = tmp_path / "survey"
    survey.mkdir()
    for i in range(2):
        s = box_scan(moving_poses((0, -1 + i, 0), (0, i, 0), n_pings=60, **DOWN), n_pings=60,
                     bearing_step=6.0, rays=40, seed=i)
        Scan(intensity=s.intensity, data=s.data, ranges=s.ranges, bearings=s.bearings, poses=s.poses,
             range_min=s.range_min, range_max=s.range_max, beamwidth_h=s.beamwidth_h,
             beamwidth_v=s.beamwidth_v).save(str(survey / f"scan_{i:05d}.npz"))
    out, elev, plot = tmp_path / "map.npz", tmp_path / "seabed.npz", tmp_path / "plan.png"
    proc = _run("map", str(survey), "--incremental", "-o", str(out), "--elevation", str(elev),
                "--plot", str(plot), "--elevation-resolution", "0.5")
    assert proc.returncode == 0, proc.stderr
    assert out.exists() and elev.exists() and plot.exists() and "2 scan(s)" in proc.stdout
    hm = IncrementalHilbertMap.load(out)
    assert hm.n_scans_seen_ == 2 and hm.n_pings_seen_ == 120
    # an empty survey folder, and --elevation without --incremental: one line each, nothing written
    empty = tmp_path / "empty"
    empty.mkdir()
    proc = _run("map", str(empty), "--incremental", "-o", str(tmp_path / "m2.npz"))
    assert proc.returncode != 0 and "Traceback" not in proc.stderr
    assert proc.stderr.strip().count("\n") == 0 and "the survey is empty" in proc.stderr
    proc = _run("map", str(survey / "scan_00000.npz"), "-o", str(tmp_path / "m3.npz"), "--elevation", str(tmp_path / "e3.npz"))
    assert proc.returncode != 0 and "--elevation needs --incremental" in proc.stderr
    assert not (tmp_path / "m2.npz").exists() and not (tmp_path / "m3.npz").exists()


def test_map_elevation_geotiff_has_the_scans_crs(tmp_path, capsys):
    """`mitsonar map --incremental --elevation X.tif` writes through mitsonar's one GeoTIFF writer
    (`mitsonar.export.geotiff`): scans holding an origin give a grid in its CRS (cells shifted by
    the origin's easting and northing), band 'elevation', metres, positive up; the values are the
    map's elevation grid. Scans with different origins are refused in one line, nothing written."""
    rasterio = pytest.importorskip("rasterio", reason="GeoTIFF needs rasterio (the geo extra)")
    pytest.importorskip("pyproj", reason="georeferencing needs pyproj (the geo extra)")
    from mitsonar import Scan, load_scan
    from mitsonar.cli import main
    from mitsonar.geometry.geodesy import GeoFrame

    geo = GeoFrame.make((52.0, 4.5))
    survey = tmp_path / "survey"
    survey.mkdir()
    for i in range(2):
        s = box_scan(moving_poses((0, -1 + i, 0), (0, i, 0), n_pings=40, **DOWN), n_pings=40,
                     bearing_step=9.0, rays=30, seed=i)
        Scan(intensity=s.intensity, data=s.data, ranges=s.ranges, bearings=s.bearings, poses=s.poses,
             range_min=s.range_min, range_max=s.range_max, beamwidth_h=s.beamwidth_h,
             beamwidth_v=s.beamwidth_v, meta=geo.meta()).save(str(survey / f"scan_{i:05d}.npz"))
    out, tif = tmp_path / "map.npz", tmp_path / "seabed.tif"
    assert main(["map", str(survey), "--incremental", "-o", str(out), "--elevation", str(tif),
                 "--elevation-resolution", "0.5"]) == 0
    grid = elevation_grid(IncrementalHilbertMap.load(out), resolution=0.5)
    with rasterio.open(tif) as src:
        assert src.crs.to_epsg() == 32631 and src.descriptions == ("elevation",) and src.units == ("metre",)
        assert src.tags(1)["positive"] == "up"
        a, b, c, d, e, f = grid.transform
        assert tuple(src.transform)[:6] == pytest.approx((a, b, c + geo.e0, d, e, f + geo.n0), abs=1e-6)
        np.testing.assert_array_equal(src.read(1), grid.elevation.astype(np.float32))
    other = GeoFrame.make((10.0, 4.5))
    s = load_scan(str(survey / "scan_00001.npz"))
    s.meta = {**s.meta, **other.meta()}
    s.save(str(survey / "scan_00001.npz"))
    capsys.readouterr()
    bad = tmp_path / "bad.tif"
    assert main(["map", str(survey), "--incremental", "-o", str(tmp_path / "m2.npz"), "--elevation", str(bad)]) == 1
    err = capsys.readouterr().err.strip()
    assert "\n" not in err and "different origins" in err and not bad.exists()


def test_a_failed_elevation_write_leaves_no_partial_file(tmp_path):
    """An elevation grid that cannot be written (a transform that is not numbers) raises and
    leaves nothing behind: no ``.part`` file beside the path."""
    from hilbertmap.elevation import ElevationGrid

    bad = ElevationGrid(np.zeros((2, 2)), ("a", 0.0, 0.0, 0.0, -1.0, 0.0), 1.0)
    with pytest.raises(ValueError):
        write_elevation(tmp_path / "seabed.npz", bad)
    assert not list(tmp_path.iterdir())
