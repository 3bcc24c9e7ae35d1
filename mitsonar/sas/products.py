"""SAS images as GeoTIFF, in the survey's CRS (`mitsonar.export.geotiff.write_geotiff`).

A `SASImage` on a world-aligned `Grid` (x east, y north in the survey's local metres) is written
north-up: GeoTIFF row 0 is the grid's largest y, column 0 its smallest x, each cell the pixel's
centre +- half a pixel. One float32 band, ``intensity``: ``20 log10 |I|`` in dB re 1 (the
coherent sum's units: uPa times the pairs summed), NaN where the image is 0; with a
`mitsonar.geometry.geodesy.GeoFrame` the cells are shifted by its origin's easting and northing and
its CRS written, so the image overlays the survey's other products.
"""
from __future__ import annotations

import numpy as np


def write_sas_geotiff(path, image, frame=None) -> None:
    """Write ``image`` (a `SASImage`) to ``path`` (module docstring); ``frame`` a `GeoFrame` or None
    (the local frame, no CRS). A grid with fewer than two pixels along an axis is refused."""
    from mitsonar.export.geotiff import write_geotiff

    g = image.grid
    if len(g.x) < 2 or len(g.y) < 2:
        raise ValueError(f"write_sas_geotiff 'image': a grid of {g.shape} pixels is not allowed (two or more along "
                         "each axis)")
    dx, dy = float(g.x[1] - g.x[0]), float(g.y[1] - g.y[0])
    mag = np.abs(np.asarray(image.image, np.complex128))
    with np.errstate(divide="ignore"):
        db = np.where(mag > 0, 20.0 * np.log10(mag), np.nan)
    band = db.T[::-1]                                            # rows: y from the largest down
    transform = (dx, 0.0, float(g.x[0]) - 0.5 * dx, 0.0, -dy, float(g.y[-1]) + 0.5 * dy)
    write_geotiff(path, band, transform, frame, descriptions=["intensity"], units=["dB re 1 (coherent sum)"],
                  tags=[{"height": f"{float(g.z):.6g}", "window": str(image.meta.get("window", "")),
                         "beamwidth_rad": f"{float(image.meta.get('beamwidth', float('nan'))):.6g}"}])
