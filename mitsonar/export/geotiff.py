"""GeoTIFF grids (rasterio; the ``geotiff`` extra): one writer, `write_geotiff`, serves the side-scan
mosaic, the depth grid, the seabed elevation grid, and (with GDAL's BAG driver) the BAG.

    from mitsonar.export.geotiff import write_depth_geotiff
    write_depth_geotiff("depth.tif", grid, frame)     # grid: a mitsonar.products.soundings.DepthGrid

Every grid is float32 bands on a north-up grid of cells (rasterio's ``Affine`` ``a, b, c, d, e, f``: ``x =
c + a col + b row``, ``y = f + d col + e row``, in world metres), NaN nodata unless stated, each
band with a description and a unit. With a `GeoFrame` the cells are shifted by the origin's
easting and northing (``c + E0``, ``f + N0``) and ``frame.crs`` is written as the GeoTIFF's
GeoKeys (GDAL and QGIS read it back as that EPSG code); without one the grid stays in the local
frame's metres, with no CRS.

============================ ============= ======= ===================================================
writer                       band          unit    values
============================ ============= ======= ===================================================
`write_depth_geotiff`        ``depth``     metre   positive down from z = 0 (tag ``positive=down``)
`write_elevation_geotiff`    ``elevation`` metre   positive up, the seabed's z (tag ``positive=up``)
`write_mosaic_geotiff`       backscatter   stated  `MOSAIC_BANDS`: bytes as floats, or dB
============================ ============= ======= ===================================================
"""
from __future__ import annotations

import numpy as np

from mitsonar._files import replacing


def _rasterio():
    try:
        import rasterio
        from rasterio.transform import Affine
    except ImportError:
        raise ImportError("GeoTIFF output needs rasterio: pip install 'mitsonar[geotiff]'") from None
    return rasterio, Affine


def write_geotiff(path, bands, transform, frame=None, *, crs=None, descriptions=(), units=(), tags=(),
                  nodata=float("nan"), driver="GTiff", options=None) -> None:
    """Write ``bands`` (2-D arrays of one shape, or one array) as a float32 GeoTIFF at ``path``,
    under a temporary name renamed into place when complete.

    ``transform``: the grid's affine (a, b, c, d, e, f) in world metres; ``frame``: a `GeoFrame`
    (the cells shifted by its ``e0``, ``n0``, its CRS written), else ``crs`` as rasterio takes it
    (None: a local frame, no CRS) with the cells as given. ``descriptions``, ``units`` and ``tags``
    (dicts), one per band or fewer; ``nodata`` the value of cells without data. ``driver`` and
    ``options`` (its creation options): another GDAL raster format on the same grid (`write_bag`:
    ``"BAG"``); opened for writing here, not copied, so that the options' text keeps its case.
    """
    rasterio, Affine = _rasterio()
    bands = [np.asarray(bands)] if np.ndim(bands) == 2 else [np.asarray(b) for b in bands]
    rows, cols = bands[0].shape
    a, b, c, d, e, f = (float(v) for v in tuple(transform)[:6])
    if frame is not None:
        c, f, crs = c + frame.e0, f + frame.n0, frame.crs
    with replacing(path) as tmp:
        with rasterio.open(tmp, "w", driver=driver, height=rows, width=cols, count=len(bands), dtype="float32",
                           crs=crs, transform=Affine(a, b, c, d, e, f), nodata=nodata, **(options or {})) as dst:
            for i, band in enumerate(bands, start=1):
                dst.write(band.astype(np.float32), i)
            for i, text in enumerate(descriptions, start=1):
                dst.set_band_description(i, text)
            for i, unit in enumerate(units, start=1):
                dst.set_band_unit(i, unit)
            for i, band_tags in enumerate(tags, start=1):
                dst.update_tags(i, **band_tags)


def write_depth_geotiff(path, grid, frame=None) -> None:
    """``grid`` (a `DepthGrid` in world metres) as a GeoTIFF at ``path``: one band ``depth``
    (metres positive down from z = 0), in ``frame``'s CRS (None: the local frame)."""
    write_geotiff(path, grid.depth, grid.transform, frame, descriptions=["depth"], units=["metre"],
                  tags=[{"positive": "down", "datum": "z = 0 of the survey (sea surface)"}])


def write_elevation_geotiff(path, grid, frame=None) -> None:
    """A seabed elevation grid (``grid.elevation`` in metres positive up, world z, and
    ``grid.transform``: hilbertmap's `ElevationGrid`) as a GeoTIFF at ``path``: one band
    ``elevation``, in ``frame``'s CRS (None: the local frame)."""
    write_geotiff(path, grid.elevation, grid.transform, frame, descriptions=["elevation"], units=["metre"],
                  tags=[{"positive": "up", "datum": "z = 0 of the survey (sea surface)"}])


#: What a mosaic's values are, as its GeoTIFF states them (band description, unit).
MOSAIC_BANDS = {"data": ("backscatter", "device level 0-255 (the scans' data bytes)"),
                "intensity": ("backscatter", "dB re the scans' intensity unit (10 log10 of the mean energy)")}


def write_mosaic_geotiff(path, mosaic, frame) -> None:
    """A side-scan `Mosaic` (`mitsonar.products.mosaic`) as a one-band float32 GeoTIFF in
    ``frame``'s CRS: the mean ``data`` level per cell (bytes as floats), or for an ``intensity``
    mosaic 10 log10 of the mean energy (dB); NaN nodata where no ping reached. The band's
    description and unit say which (`MOSAIC_BANDS`)."""
    values = np.asarray(mosaic.image, np.float64)
    if mosaic.use == "intensity":
        with np.errstate(divide="ignore", invalid="ignore"):
            values = np.where(values > 0, 10.0 * np.log10(values), np.nan)
    name, unit = MOSAIC_BANDS.get(mosaic.use, ("backscatter", mosaic.use))
    write_geotiff(path, values, mosaic.transform, frame, descriptions=[name], units=[unit])
