"""Depth grids as a GeoTIFF in a projected CRS (rasterio; the ``geotiff`` extra).

    from mitsonar.export.geotiff import write_depth_geotiff
    write_depth_geotiff("depth.tif", grid, frame)     # grid: a mitsonar.products.soundings.DepthGrid

One float32 band, the depth in metres positive down from z = 0 (band description ``depth``, unit
``metre``; NaN nodata where no sounding fell), on the grid's cells shifted by the origin's easting
and northing (``transform`` c + E0, f + N0), the CRS ``frame.crs`` written as the GeoTIFF's
GeoKeys: GDAL and QGIS read it back as that EPSG code.
"""
from __future__ import annotations

import numpy as np

from mitsonar._files import replacing


def write_depth_geotiff(path, grid, frame) -> None:
    """``grid`` (a `DepthGrid` in world metres) as a GeoTIFF at ``path`` in ``frame``'s CRS."""
    try:
        import rasterio
        from rasterio.transform import Affine
    except ImportError:
        raise ImportError("GeoTIFF output needs rasterio: pip install 'mitsonar[geotiff]'") from None
    a, b, c, d, e, f = grid.transform
    rows, cols = grid.depth.shape
    with replacing(path) as tmp:
        with rasterio.open(tmp, "w", driver="GTiff", height=rows, width=cols, count=1, dtype="float32",
                           crs=frame.crs, transform=Affine(a, b, c + frame.e0, d, e, f + frame.n0),
                           nodata=float("nan")) as dst:
            dst.write(grid.depth.astype(np.float32), 1)
            dst.set_band_description(1, "depth")
            dst.set_band_unit(1, "metre")
            dst.update_tags(1, positive="down", datum="z = 0 of the survey (sea surface)")


#: What a mosaic's values are, as its GeoTIFF states them (band description, unit).
MOSAIC_BANDS = {"data": ("backscatter", "device level 0-255 (the scans' data bytes)"),
                "intensity": ("backscatter", "dB re the scans' intensity unit (10 log10 of the mean energy)")}


def write_mosaic_geotiff(path, mosaic, frame) -> None:
    """A side-scan `Mosaic` (`mitsonar.products.mosaic`) as a one-band float32 GeoTIFF in
    ``frame``'s CRS: the mean ``data`` level per cell (bytes as floats), or for an ``intensity``
    mosaic 10 log10 of the mean energy (dB); NaN nodata where no ping reached. The band's
    description and unit say which (`MOSAIC_BANDS`)."""
    try:
        import rasterio
        from rasterio.transform import Affine
    except ImportError:
        raise ImportError("GeoTIFF output needs rasterio: pip install 'mitsonar[geotiff]'") from None
    a, b, c, d, e, f = mosaic.transform
    rows, cols = mosaic.image.shape
    values = np.asarray(mosaic.image, np.float64)
    if mosaic.use == "intensity":
        with np.errstate(divide="ignore", invalid="ignore"):
            values = np.where(values > 0, 10.0 * np.log10(values), np.nan)
    name, unit = MOSAIC_BANDS.get(mosaic.use, ("backscatter", mosaic.use))
    with replacing(path) as tmp:
        with rasterio.open(tmp, "w", driver="GTiff", height=rows, width=cols, count=1, dtype="float32",
                           crs=frame.crs, transform=Affine(a, b, c + frame.e0, d, e, f + frame.n0),
                           nodata=float("nan")) as dst:
            dst.write(values.astype(np.float32), 1)
            dst.set_band_description(1, name)
            dst.set_band_unit(1, unit)
