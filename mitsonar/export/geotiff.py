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
