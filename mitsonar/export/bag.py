"""Depth grids as BAG (the Bathymetric Attributed Grid of the Open Navigation Surface project,
HDF5), written through GDAL's BAG driver (the one in rasterio's wheels; the ``geo`` extra).

    from mitsonar.export.bag import write_bag, bag_available
    write_bag("depth.bag", grid, frame, soundings, sigma)   # grid: a DepthGrid in world metres

Two bands, as the BAG specification has them: ``elevation`` (float32, m, positive up: ``-depth``
minus nothing, the grid's z = 0 as the vertical datum, GDAL's "unknown" vertical CRS) and
``uncertainty`` (float32, m: the mean of the soundings' predicted one-sigma depth error in each
cell when given, else the standard deviation of the cell's soundings' depths, 0 for a cell of
one); nodata 1e6 (the BAG value) where no sounding fell. The horizontal CRS is ``frame.crs``; the
cells are the grid's, shifted by the origin's easting and northing.

The ISO 19115 metadata a hydrographer reads in CARIS or QGIS are filled through GDAL's template
variables (`attributes`; the ``VAR_*`` creation options of GDAL's BAG driver): the citation (title
and creation date), an abstract saying what the grid is (simulated soundings, the cell size, how
elevation and uncertainty were made, the CRS and origin), the vertical reference system as WKT
(``vertical_wkt``; by default a local one: z = 0 is the survey's sea surface, at the origin's
height above the WGS 84 ellipsoid, metres up), the vertical uncertainty type (``productUncert``
for the predicted sigma, ``rawStdDev`` for the spread of the soundings), the process step with
its date and time, and the producing organisation. Still missing from a full BAG: the tracking
list (no edits to track) and variable resolution.
"""
from __future__ import annotations

import datetime

import numpy as np


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


#: The BAG vertical uncertainty codes (the Open Navigation Surface codelist ``BAG_VertUncertCode``)
#: of the two ways `cell_uncertainty` makes the uncertainty band.
UNCERTAINTY_CODES = {True: "productUncert", False: "rawStdDev"}


def local_vertical_wkt(frame) -> str:
    """The WKT 1 vertical CRS of mitsonar's z: up from the survey's sea surface, which lies at the
    origin's height above the WGS 84 ellipsoid (``frame.height``), in metres."""
    return (f'VERT_CS["mitsonar survey z (sea surface, {frame.height:g} m above the WGS 84 ellipsoid at '
            f'{frame.lat:g} {frame.lon:g})",VERT_DATUM["Local sea surface of the survey",2000],'
            'UNIT["metre",1],AXIS["Gravity-related height",UP]]')


def _citation(title: str, date: str) -> str:
    code = "http://www.isotc211.org/2005/resources/Codelist/gmxCodelists.xml#CI_DateTypeCode"
    return (f"<gmd:CI_Citation><gmd:title><gco:CharacterString>{_xml(title)}</gco:CharacterString></gmd:title>"
            f"<gmd:date><gmd:CI_Date><gmd:date><gco:Date>{date}</gco:Date></gmd:date><gmd:dateType>"
            f'<gmd:CI_DateTypeCode codeList="{code}" codeListValue="creation">creation</gmd:CI_DateTypeCode>'
            "</gmd:dateType></gmd:CI_Date></gmd:date></gmd:CI_Citation>")


def _xml(text: str) -> str:
    return text.replace("&", "&amp;").replace("<", "&lt;").replace(">", "&gt;")


def attributes(grid, frame, sigma_given: bool, *, when=None, title=None, abstract=None, vertical_wkt=None,
               individual=None, organisation="mitsonar (simulated survey)") -> dict:
    """The ``VAR_*`` creation options of GDAL's BAG driver that fill the BAG's ISO metadata for
    ``grid`` in ``frame`` (see the module docstring); ``when`` a UTC datetime (default now),
    the others override the defaults. Plain text (GDAL escapes it), but the citation, which
    is XML (``VAR_XML_IDENTIFICATION_CITATION``)."""
    from mitsonar._version import __version__

    when = when or datetime.datetime.now(datetime.timezone.utc)
    cell = abs(float(grid.transform[0]))
    how = ("the mean of the soundings' predicted one-sigma depth error (mitsonar.products.bathymetry."
           "predicted_rms)" if sigma_given else "the standard deviation of the depths of the cell's soundings")
    text = abstract or (
        f"Simulated multibeam bathymetry (mitsonar {__version__}): elevation is minus the mean depth of the "
        f"soundings in each {cell:g} m cell, metres positive up from the survey's sea surface; uncertainty is "
        f"{how}, metres, one sigma. Horizontal CRS {frame.crs}, local grid origin {frame.lat:g} N "
        f"{frame.lon:g} E. Not a real survey.")
    return {
        "VAR_XML_IDENTIFICATION_CITATION": _citation(title or f"mitsonar simulated bathymetry, {cell:g} m grid",
                                                     when.strftime("%Y-%m-%d")),
        "VAR_ABSTRACT": text,
        "VAR_VERT_WKT": vertical_wkt or local_vertical_wkt(frame),
        "VAR_VERTICAL_UNCERT_CODE": UNCERTAINTY_CODES[bool(sigma_given)],
        "VAR_DATE": when.strftime("%Y-%m-%d"),
        "VAR_DATETIME": when.strftime("%Y-%m-%dT%H:%M:%S"),
        "VAR_PROCESS_STEP_DESCRIPTION": f"Soundings simulated and gridded by mitsonar {__version__}; "
                                        f"uncertainty: {how}.",
        "VAR_INDIVIDUAL_NAME": individual or "unknown",
        "VAR_ORGANISATION_NAME": organisation,
        "VAR_RESTRICTION_OTHER_CONSTRAINTS": "none",
    }


def write_bag(path, grid, frame, soundings, sigma=None, **metadata) -> None:
    """Write ``grid`` as a BAG at ``path`` (GDAL's BAG driver, through `write_geotiff`: under a
    temporary name renamed into place when complete), its ISO metadata filled by `attributes` (``metadata``:
    its keyword arguments, e.g. ``vertical_wkt``, ``when``, ``individual``)."""
    if not bag_available():
        raise ImportError("BAG output needs rasterio with GDAL's BAG driver (HDF5): pip install 'mitsonar[geo]'")
    from mitsonar.export.geotiff import write_geotiff

    elevation = np.where(np.isnan(grid.depth), NODATA, -grid.depth).astype(np.float32)
    unc = cell_uncertainty(grid, soundings, sigma)
    unc = np.where(np.isnan(grid.depth) | np.isnan(unc), NODATA, unc).astype(np.float32)
    write_geotiff(path, [elevation, unc], grid.transform, frame, nodata=NODATA, driver="BAG",
                  options=attributes(grid, frame, sigma is not None, **metadata))
