"""Depth grids as BAG (the Bathymetric Attributed Grid of the Open Navigation Surface project,
HDF5), written through GDAL's BAG driver (the one in rasterio's wheels; the ``geo`` extra).

    from mitsonar.export.bag import write_bag, bag_available
    write_bag("depth.bag", grid, frame, soundings, sigma)   # grid: a DepthGrid in world metres

Two bands, as the BAG specification has them: ``elevation`` (float32, m, positive up: ``-depth``
minus nothing, the grid's z = 0 as the vertical datum, GDAL's "unknown" vertical CRS) and
``uncertainty`` (float32, m: the mean of the soundings' predicted one-sigma depth error in each
cell when given, else the standard deviation of the cell's soundings' depths, 0 for a cell of
one); nodata 1e6 (the BAG value) where no sounding fell. The horizontal CRS is ``frame.crs``; the
cells are the grid's, shifted by the origin's easting and northing. This is not a fully
attributed BAG (no tracking list, no variable resolution, GDAL's default ISO metadata).
"""
from __future__ import annotations

import os

import numpy as np

from mitsonar._files import replacing

NODATA = 1.0e6


def bag_available() -> bool:
    """True when rasterio is installed and its GDAL has the BAG driver (HDF5)."""
    try:
        import rasterio
    except ImportError:
        return False
    with rasterio.Env() as env:
        return "BAG" in env.drivers()


def cell_uncertainty(grid, soundings, sigma=None) -> np.ndarray:
    """Per cell of ``grid``: the mean of ``sigma`` (one per sounding) in the cell, or without it
    the standard deviation of the cells' depths (``-z``); NaN where no sounding fell."""
    from mitsonar.geometry import northup

    rows, cols = grid.depth.shape
    x, y, z = (np.asarray(soundings[k], np.float64) for k in ("x", "y", "z"))
    ok = np.isfinite(z)
    total, count = np.zeros(rows * cols), np.zeros(rows * cols, np.int64)
    if sigma is not None:
        northup.accumulate(total, count, grid.transform, (rows, cols), x[ok], y[ok], np.asarray(sigma)[ok])
        return northup.mean(total, count).reshape(rows, cols)
    square = np.zeros(rows * cols)
    northup.accumulate(total, count, grid.transform, (rows, cols), x[ok], y[ok], -z[ok])
    northup.accumulate(square, np.zeros_like(count), grid.transform, (rows, cols), x[ok], y[ok], z[ok] ** 2)
    m = northup.mean(total, count)
    with np.errstate(invalid="ignore", divide="ignore"):
        var = np.where(count > 0, square / np.maximum(count, 1) - m ** 2, np.nan)
    return np.sqrt(np.maximum(var, 0.0)).reshape(rows, cols)


def write_bag(path, grid, frame, soundings, sigma=None) -> None:
    """Write ``grid`` as a BAG at ``path`` (a temporary GeoTIFF converted by GDAL's BAG driver,
    renamed into place when complete)."""
    if not bag_available():
        raise ImportError("BAG output needs rasterio with GDAL's BAG driver (HDF5): pip install 'mitsonar[geo]'")
    from rasterio.shutil import copy

    from mitsonar.export.geotiff import write_geotiff

    elevation = np.where(np.isnan(grid.depth), NODATA, -grid.depth).astype(np.float32)
    unc = cell_uncertainty(grid, soundings, sigma)
    unc = np.where(np.isnan(grid.depth) | np.isnan(unc), NODATA, unc).astype(np.float32)
    with replacing(path) as tmp:
        staging = tmp + ".tif"
        try:
            write_geotiff(staging, [elevation, unc], grid.transform, frame, nodata=NODATA,
                          descriptions=["elevation", "uncertainty"], units=["metre", "metre"])
            copy(staging, tmp, driver="BAG")
        finally:
            if os.path.exists(staging):
                os.remove(staging)
