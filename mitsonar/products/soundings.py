"""Soundings as products: a point cloud (PLY, and ``sensor_msgs/PointCloud2``-ready arrays) and a
gridded depth map (an array with its affine transform; as a GeoTIFF, when ``rasterio`` is installed,
by the formats' room: `mitsonar.export.geotiff.write_depth_geotiff`).

    from mitsonar.products.soundings import write_ply, pointcloud2, grid_depths
    write_ply("soundings.ply", run.soundings)            # binary PLY: x y z intensity beam
    cloud, fields = pointcloud2(run.soundings)            # float32 x y z intensity, uint16 beam
    grid = grid_depths(run.soundings, cell=0.5)            # grid.depth (rows, cols), grid.transform
    grid.save_npz("depth.npz")
    from mitsonar.export.geotiff import write_depth_geotiff
    write_depth_geotiff("depth.tif", grid)                 # needs rasterio

Depth is positive down from z = 0 (the sea surface of the survey scenes): ``depth = -z``. The
grid is north-up like a GeoTIFF: row 0 is the cell row with the largest y, and a cell's centre is
at ``x = c + a (col + 0.5)``, ``y = f + e (row + 0.5)`` with ``transform = (a, b, c, d, e, f) =
(cell, 0, x_min, 0, -cell, y_max)`` (rasterio's ``Affine`` order; GDAL's geotransform lists them as
``(c, a, b, f, d, e)``). Each cell holds the mean
depth of the soundings in it (NaN where none) and ``count`` their number.
"""
from __future__ import annotations

import dataclasses
import math

import numpy as np

from mitsonar.geometry import northup
from mitsonar._checks import is_number, not_allowed
from mitsonar._files import replacing

WHERE = "soundings"

#: The PointCloud2 layout: (name, numpy type, sensor_msgs/PointField datatype).
POINTCLOUD2_FIELDS = (("x", "<f4", 7), ("y", "<f4", 7), ("z", "<f4", 7), ("intensity", "<f4", 7), ("beam", "<u2", 4))
#: The PLY's vertex properties: beam and ping as int32, which every common reader keeps (Open3D
#: drops unsigned 16/32-bit attributes).
PLY_FIELDS = (("x", "<f8"), ("y", "<f8"), ("z", "<f8"), ("intensity", "<f4"), ("beam", "<i4"), ("ping", "<i4"),
              ("angle", "<f4"))
MAX_CELLS = 50_000_000


def pointcloud2(soundings):
    """``(array, fields)``: a packed structured array with fields x, y, z, intensity (float32) and
    beam (uint16), 18 bytes a point, and the ``sensor_msgs/PointField`` list that describes it,
    ``[(name, offset, datatype, count), ...]`` (datatype 7 FLOAT32, 4 UINT16): the message's
    ``data`` is ``array.tobytes()``, ``point_step`` ``array.itemsize``."""
    dt = np.dtype([(n, t) for n, t, _ in POINTCLOUD2_FIELDS])
    out = np.zeros(len(soundings), dt)
    for n, _, _ in POINTCLOUD2_FIELDS:
        out[n] = soundings[n]
    fields = [(n, dt.fields[n][1], code, 1) for n, _, code in POINTCLOUD2_FIELDS]
    return out, fields


def write_ply(path, soundings):
    """Write the soundings as a binary little-endian PLY point cloud (``element vertex`` with double
    x y z, float intensity, int beam, int ping, float angle; `mitsonar.geometry.ply`), under a temporary
    name renamed onto ``path`` when complete. Returns the number of points."""
    from mitsonar.geometry.ply import write_ply as write

    rows = np.zeros(len(soundings), np.dtype(list(PLY_FIELDS)))
    for n, _ in PLY_FIELDS:
        rows[n] = soundings[n]
    write(path, rows, comment="mitsonar soundings (depth = -z)")
    return len(rows)


def read_ply(path) -> np.ndarray:
    """Read back a PLY written by `write_ply`: a structured array with its fields."""
    from mitsonar.geometry.ply import read_ply as read

    return read(path)[0]


@dataclasses.dataclass
class DepthGrid:
    """A gridded depth map: ``depth`` (rows, cols) float64 m (NaN: no sounding), ``count`` (rows,
    cols) soundings per cell, ``transform`` (a, b, c, d, e, f) as in the module docstring."""

    depth: np.ndarray
    count: np.ndarray
    transform: tuple

    @property
    def cell(self) -> float:
        return float(self.transform[0])

    def centres(self):
        """``(x (cols,), y (rows,))``: the cells' centre coordinates."""
        a, _, c, _, e, f = self.transform
        rows, cols = self.depth.shape
        return c + a * (np.arange(cols) + 0.5), f + e * (np.arange(rows) + 0.5)

    @property
    def extent(self):
        """``(x_min, x_max, y_min, y_max)`` of the grid's outer edges (matplotlib's ``extent``)."""
        a, _, c, _, e, f = self.transform
        rows, cols = self.depth.shape
        return (c, c + a * cols, f + e * rows, f)

    def save_npz(self, path):
        """``depth``, ``count``, ``transform`` into an ``.npz`` (temporary name, then renamed)."""
        with replacing(path) as tmp, open(tmp, "wb") as f:
            np.savez(f, depth=self.depth, count=self.count, transform=np.asarray(self.transform, np.float64))


def grid_depths(soundings, cell=0.5, bounds=None) -> DepthGrid:
    """Bin the soundings' depths (``-z``) into square cells of ``cell`` metres: the mean per cell.

    ``bounds``: ``(x_min, x_max, y_min, y_max)``, default the soundings' own extent (the grid's
    origin snapped to a whole number of cells). Soundings outside ``bounds`` are left out."""
    if not (is_number(cell) and cell > 0):
        raise not_allowed(WHERE, "cell", cell, "a cell size > 0 m")
    x, y, z = (np.asarray(soundings[k], np.float64) for k in ("x", "y", "z"))
    if bounds is None:
        if x.size == 0:
            raise not_allowed(WHERE, "soundings", "none", "at least one sounding to grid (or give bounds)")
        x0, y0 = math.floor(x.min() / cell) * cell, math.floor(y.min() / cell) * cell
        x1, y1 = (math.floor(x.max() / cell) + 1) * cell, (math.floor(y.max() / cell) + 1) * cell
    else:
        if not (len(bounds) == 4 and all(is_number(v) for v in bounds) and bounds[1] > bounds[0]
                and bounds[3] > bounds[2]):
            raise not_allowed(WHERE, "bounds", bounds, "(x_min, x_max, y_min, y_max) with x_max > x_min, y_max > y_min")
        x0, x1, y0, y1 = (float(v) for v in bounds)
    cols, rows = max(1, int(math.ceil((x1 - x0) / cell - 1e-9))), max(1, int(math.ceil((y1 - y0) / cell - 1e-9)))
    if rows * cols > MAX_CELLS:
        raise not_allowed(WHERE, "cell", cell, f"a cell of at least {math.sqrt((x1 - x0) * (y1 - y0) / MAX_CELLS):.3g} "
                          f"m for {x1 - x0:g} x {y1 - y0:g} m (at most {MAX_CELLS} cells)")
    transform = (float(cell), 0.0, float(x0), 0.0, -float(cell), float(y0 + rows * cell))
    ok = np.isfinite(z)
    total, count = np.zeros(rows * cols), np.zeros(rows * cols, dtype=np.int64)
    northup.accumulate(total, count, transform, (rows, cols), x[ok], y[ok], -z[ok])
    depth = northup.mean(total, count).reshape(rows, cols)
    return DepthGrid(depth, count.reshape(rows, cols), transform)
