"""A 2.5-D elevation grid of the seabed from a map, and its file (GeoTIFF with rasterio, else .npz).

Each column of a horizontal grid (``resolution`` metres, north up: row 0 at the largest y) is
sampled from the top of the region seen downwards every ``z_step`` metres; the elevation is the
first height where the probability rises through ``level`` below water the map saw free (linear
interpolation between the two samples), NaN where no such crossing is found in the region seen
(shadows, unsurveyed cells). With walls in the map (quays, piles) a column through a wall's face
reports the top of what the sonar saw of it: a digital *surface* model, as multibeam grids are.

The affine transform maps (col, row) of a cell's corner to world x, y (rasterio's ``Affine``
order ``a, b, c, d, e, f``: ``x = c + a col + b row``, ``y = f + d col + e row``), here
``(res, 0, x0, 0, -res, y1)``.
"""
from __future__ import annotations

import os
from dataclasses import dataclass

import numpy as np


@dataclass
class ElevationGrid:
    """``elevation`` (rows, cols) metres (NaN: unknown), ``transform`` the 6 coefficients in
    rasterio's ``Affine`` order, ``resolution`` metres."""

    elevation: np.ndarray
    transform: tuple
    resolution: float

    def xy(self):
        """World x (cols,) and y (rows,) of the cell centres."""
        a, _, c, _, e, f = self.transform
        rows, cols = self.elevation.shape
        return c + a * (np.arange(cols) + 0.5), f + e * (np.arange(rows) + 0.5)


def elevation_grid(hm, resolution: float = 0.25, z_step: float | None = None, bounds=None, level: float = 0.5,
                   method: str = "peak", chunk_points: int = 1 << 21) -> ElevationGrid:
    """The seabed elevation grid of a fitted map (see the module docstring).

    ``bounds``: ((x0, y0, z0), (x1, y1, z1)) of the grid (default the region seen). ``method``:
    ``'peak'`` (default) the height of the column's most probable sample in the region seen, if
    it reaches ``level``; ``'first'`` the first rise through ``level`` coming down from water seen
    free. A wide vertical beam spreads each echo over its fan, above the seabed as much as below:
    the crossing then sits high (on the rocky slope survey by +1.1 m median, the peak by
    +0.3 m), while on a narrow return the crossing is the sharper of the two.
    """
    if method not in ("peak", "first"):
        raise ValueError(f"HilbertMap: method must be 'peak' or 'first', not {method!r}")
    if not (isinstance(resolution, (int, float)) and resolution > 0):
        raise ValueError(f"HilbertMap: resolution must be a number > 0, not {resolution!r}")
    hm._check_fitted()
    if bounds is None:
        lo, hi = hm.coverage_.bounds()
    else:
        lo, hi = (np.asarray(b, dtype=np.float64) for b in bounds)
    dz = float(z_step) if z_step is not None else min(float(resolution), hm.lengthscale_ / 2.0)
    cols = max(1, int(np.ceil((hi[0] - lo[0]) / resolution)))
    rows = max(1, int(np.ceil((hi[1] - lo[1]) / resolution)))
    xs = lo[0] + (np.arange(cols) + 0.5) * resolution
    ys = hi[1] - (np.arange(rows) + 0.5) * resolution
    zs = np.arange(hi[2], lo[2] - 1e-9, -dz)  # top down
    nz = len(zs)
    X, Y = np.meshgrid(xs, ys)  # (rows, cols)
    cx, cy = X.ravel(), Y.ravel()
    out = np.full(len(cx), np.nan)
    per = max(1, chunk_points // max(nz, 1))
    for a in range(0, len(cx), per):
        n = len(cx[a:a + per])
        P = np.stack([np.repeat(cx[a:a + per], nz), np.repeat(cy[a:a + per], nz), np.tile(zs, n)], axis=1)
        p = hm.predict_proba(P).reshape(n, nz)
        seen = hm.seen(P, dilate=1).reshape(n, nz)
        free_above = np.maximum.accumulate((p < level) & seen, axis=1)
        hit = (p >= level) & seen & np.concatenate([np.zeros((n, 1), bool), free_above[:, :-1]], axis=1)
        if method == "peak":
            pm = np.where(seen, p, -1.0)
            k = np.argmax(pm, axis=1)
            out[a:a + per] = np.where(pm[np.arange(n), k] >= level, zs[k], np.nan)
            continue
        has = hit.any(axis=1)
        k = np.argmax(hit, axis=1)
        k = np.maximum(k, 1)
        i = np.arange(n)
        p0, p1 = p[i, k - 1], p[i, k]
        t = np.clip((level - p0) / np.maximum(p1 - p0, 1e-12), 0, 1)
        z = zs[k - 1] + t * (zs[k] - zs[k - 1])
        out[a:a + per] = np.where(has, z, np.nan)
    transform = (float(resolution), 0.0, float(lo[0]), 0.0, -float(resolution), float(hi[1]))
    return ElevationGrid(out.reshape(rows, cols), transform, float(resolution))


def write_elevation(path, grid: ElevationGrid, crs=None) -> None:
    """Write ``grid``: ``.tif`` / ``.tiff`` as a float32 GeoTIFF (needs ``rasterio``; NaN is the
    nodata value; ``crs`` e.g. ``"EPSG:32630"`` or None for a local frame), ``.npz`` with arrays
    ``elevation`` and ``transform``. Written under a temporary name and renamed."""
    path = os.fspath(path)
    ext = os.path.splitext(path)[1].lower()
    if ext not in (".tif", ".tiff", ".npz"):
        raise ValueError(f"HilbertMap: {path}: elevation grids are written as .tif/.tiff (GeoTIFF) or .npz, not "
                         f"{ext or 'a name without extension'}")
    tmp = path + ".part" + ext
    try:
        _write_elevation(tmp, ext, path, grid, crs)
    except BaseException:
        if os.path.exists(tmp):
            os.remove(tmp)           # a failed write leaves no partial file
        raise
    os.replace(tmp, path)


def _write_elevation(tmp, ext, path, grid, crs) -> None:
    if ext == ".npz":
        with open(tmp, "wb") as fh:
            np.savez_compressed(fh, elevation=grid.elevation.astype(np.float32),
                                transform=np.asarray(grid.transform, dtype=np.float64))
    else:
        # mitsonar writes its grids with mitsonar.export.geotiff.write_geotiff (``mitsonar map
        # --elevation``: write_elevation_geotiff, with the band's name, unit and a GeoFrame's
        # CRS); hilbertmap keeps this writer of its own because it must not import mitsonar.
        try:
            import rasterio
            from rasterio.transform import Affine
        except ImportError:
            raise ValueError(f"HilbertMap: {path}: writing GeoTIFF needs rasterio (pip install rasterio); "
                             "write .npz instead") from None
        rows, cols = grid.elevation.shape
        with rasterio.open(tmp, "w", driver="GTiff", height=rows, width=cols, count=1, dtype="float32",
                           crs=crs, transform=Affine(*grid.transform), nodata=np.nan) as dst:
            dst.write(grid.elevation.astype(np.float32), 1)


def read_elevation(path) -> ElevationGrid:
    """Read an ``.npz`` (or, with rasterio, GeoTIFF) written by :func:`write_elevation`."""
    path = os.fspath(path)
    if path.lower().endswith(".npz"):
        with np.load(path, allow_pickle=False) as z:
            e, t = z["elevation"], tuple(float(v) for v in z["transform"])
    else:
        import rasterio

        with rasterio.open(path) as src:
            e, t = src.read(1), tuple(src.transform)[:6]
    return ElevationGrid(e.astype(np.float64), t, abs(float(t[0])))
