"""Georeferenced mosaic of side-scan scans: ground-range pixels placed in world x-y from their ping
poses, averaged where survey lines overlap.

Each row of each scan is corrected to ground range (`mitsonar.products.sidescan.ground_range`: a flat bottom
at the measured or given altitude, or a known seabed); its sample at ground range ``g`` lies at
``p + g u`` (``p`` the transducer, ``u`` the horizontal unit vector across the track to the row's
side), and is spread along the track over half the distance to the neighbouring pings of its
channel on each side, so consecutive pings tile the seabed without gaps. A cell's value is the mean
of the samples that fall in it; cells no ping reached are NaN.

The grid is north-up: row 0 is the largest y. Its affine transform is in rasterio's
``Affine`` order (``x = a col + b row + c``, ``y = d col + e row + f`` for a pixel's top-left
corner, ``(a, b, c, d, e, f) = (res, 0, x_min, 0, -res, y_max)``: ``rasterio.Affine(*transform)``;
GDAL's ``GetGeoTransform()`` lists the same numbers as ``(c, a, b, f, d, e)``), so the ``.npz`` array and the PNG can be handed to GIS
tools (`Mosaic.save` also writes a ``.pgw`` world file beside the PNG).
"""
from __future__ import annotations

import math
import os
from dataclasses import dataclass

import numpy as np

from mitsonar.geometry import northup
from mitsonar.products.sidescan import across_track, ground_range
from mitsonar.scan.model import as_scans


@dataclass
class Mosaic:
    """A mosaic: ``image`` (H, W) float64 mean value per cell (NaN: no data), ``count`` (H, W)
    samples per cell, ``transform`` the 6-tuple ``(a, b, c, d, e, f)`` above, ``use`` what the values
    are (``data`` levels 0..255, a wider A/D's codes on that scale: `mitsonar.products.sidescan`,
    or ``intensity``)."""

    image: np.ndarray
    count: np.ndarray
    transform: tuple
    use: str = "data"

    @property
    def resolution(self) -> float:
        return float(self.transform[0])

    @property
    def bounds(self) -> tuple:
        """(x_min, x_max, y_min, y_max) of the grid's outer edges, m."""
        a, _, c, _, e, f = self.transform
        h, w = self.image.shape
        return c, c + a * w, f + e * h, f

    def world_to_pixel(self, x, y):
        """(row, col) integer cell(s) holding world point(s) (x, y)."""
        a, _, c, _, e, f = self.transform
        col = np.floor((np.asarray(x, dtype=np.float64) - c) / a).astype(np.int64)
        row = np.floor((np.asarray(y, dtype=np.float64) - f) / e).astype(np.int64)
        return row, col

    def pixel_to_world(self, row, col):
        """World (x, y) of the centre(s) of cell(s) (row, col)."""
        a, b, c, d, e, f = self.transform
        col = np.asarray(col, dtype=np.float64) + 0.5
        row = np.asarray(row, dtype=np.float64) + 0.5
        return a * col + b * row + c, d * col + e * row + f

    def save(self, path, dynamic_range=60.0, cmap="copper"):
        """Write the mosaic as a PNG (``path``; values in dB for ``intensity``, the top ``dynamic_range``
        dB shown; NaN cells transparent), its world file (``.pgw``) and ``<stem>.npz`` holding
        ``image``, ``count``, ``transform`` and ``use``; every file under a temporary name, renamed
        into place at the end. Returns the paths written."""
        from matplotlib import colormaps
        from matplotlib.image import imsave

        from mitsonar._files import StagedFiles

        path = os.fspath(path)
        if not path.lower().endswith(".png"):
            raise ValueError(f"Mosaic.save: {path!r} must end in .png (the array goes beside it as .npz)")
        stem = path[:-4]
        img = self.image
        if self.use == "intensity":
            with np.errstate(divide="ignore", invalid="ignore"):
                db = 10 * np.log10(img)
            top = np.nanmax(db[np.isfinite(db)]) if np.isfinite(db).any() else 0.0
            norm = np.clip((db - (top - dynamic_range)) / dynamic_range, 0, 1)
            norm[np.isnan(img)] = np.nan
            norm[img == 0] = 0.0
        else:
            norm = img / 255.0
        rgba = colormaps[cmap](np.nan_to_num(norm, nan=0.0))
        rgba[np.isnan(norm), 3] = 0.0
        a, b, c, d, e, f = self.transform
        written = [path, stem + ".pgw", stem + ".npz"]
        with StagedFiles() as files:
            imsave(files.temporary(path), rgba)
            with open(files.temporary(stem + ".pgw"), "w") as fh:   # centre of the top-left pixel
                fh.write("\n".join(f"{v:.12g}" for v in (a, d, b, e, c + a / 2 + b / 2, f + d / 2 + e / 2)) + "\n")
            tmp = files.temporary(stem + ".npz")
            with open(tmp, "wb") as fh:
                np.savez_compressed(fh, image=self.image, count=self.count, transform=np.array(self.transform),
                                    use=np.array(self.use))
        return written

    @classmethod
    def load(cls, path) -> "Mosaic":
        """A mosaic from the ``.npz`` that `save` wrote."""
        with np.load(os.fspath(path)) as z:
            return cls(image=z["image"], count=z["count"], transform=tuple(float(v) for v in z["transform"]),
                       use=str(z["use"]))


def _footprints(scans, ground_max):
    """(x_min, x_max, y_min, y_max) covering every row's transducer and its swath."""
    pos = np.concatenate([s.poses[:, :3, 3] for s in scans])
    return (pos[:, 0].min() - ground_max, pos[:, 0].max() + ground_max,
            pos[:, 1].min() - ground_max, pos[:, 1].max() + ground_max)


def _spacing(scan):
    """(n_rows,) distance to the next ping of the same channel (the previous one for the last),
    m: how far along the track each row's line is spread."""
    d = np.zeros(scan.n_pings)
    pos = scan.poses[:, :3, 3]
    for c in (0, 1):
        rows = np.flatnonzero(scan.channel == c)
        if len(rows) > 1:
            step = np.linalg.norm(np.diff(pos[rows], axis=0), axis=1)
            d[rows] = np.concatenate([step, step[-1:]])
    return d


class MosaicBuilder:
    """Accumulates scans into one mosaic grid, one scan at a time (a survey streams its scans).

    ``bounds`` (x_min, x_max, y_min, y_max) m and ``resolution`` m per cell fix the grid; the other
    arguments are `ground_range`'s, applied to every row."""

    def __init__(self, bounds, resolution=0.1, *, use="data", altitude=None, seabed=None, threshold=1e-3):
        x0, x1, y0, y1 = (float(v) for v in bounds)
        res = float(resolution)
        if not (math.isfinite(res) and res > 0):
            raise ValueError(f"mosaic 'resolution': {resolution!r} is not allowed (m per cell, > 0)")
        if not (all(map(math.isfinite, (x0, x1, y0, y1))) and x1 > x0 and y1 > y0):
            raise ValueError(f"mosaic 'bounds': {bounds!r} is not allowed (x_min < x_max, y_min < y_max, finite)")
        w, h = int(math.ceil((x1 - x0) / res)), int(math.ceil((y1 - y0) / res))
        if w * h > 10 ** 8:
            raise ValueError(f"mosaic: {h} x {w} cells is too many (at most 1e8): coarsen 'resolution' or "
                             "narrow 'bounds'")
        self.transform = (res, 0.0, x0, 0.0, -res, y0 + h * res)
        self.sum = np.zeros(h * w)
        self.count = np.zeros(h * w, dtype=np.int64)
        self.shape = (h, w)
        self.use, self.altitude, self.seabed, self.threshold = use, altitude, seabed, threshold

    def add(self, scan, ground_max=None):
        """Add the rows of a side-scan ``scan``."""
        res = self.transform[0]
        gr = ground_range(scan, resolution=res / 2, ground_max=ground_max, altitude=self.altitude,
                          seabed=self.seabed, use=self.use, threshold=self.threshold)
        u = across_track(scan)
        along = np.stack([-u[:, 1], u[:, 0], np.zeros(len(u))], axis=1)
        pos = scan.poses[:, :3, 3]
        spread = _spacing(scan)
        n_off = max(1, int(math.ceil(spread.max() / (res / 2))) + 1)
        frac = np.linspace(-0.5, 0.5, n_off) if n_off > 1 else np.zeros(1)
        for k in range(scan.n_pings):   # ping by ping: memory stays one ping's points
            vals = gr.values[k]
            ok = np.isfinite(vals)
            if not ok.any():
                continue
            g = gr.ground[ok]
            p = pos[k, None, :2] + g[:, None] * u[k, None, :2]                         # (n_g, 2)
            p = p[None, :, :] + (frac * spread[k])[:, None, None] * along[k, None, None, :2]
            v = np.broadcast_to(vals[ok][None, :], (len(frac), ok.sum()))
            northup.accumulate(self.sum, self.count, self.transform, self.shape, p[..., 0].ravel(),
                               p[..., 1].ravel(), v.ravel())
        return self

    def result(self) -> Mosaic:
        img = northup.mean(self.sum, self.count)
        return Mosaic(image=img.reshape(self.shape), count=self.count.reshape(self.shape).copy(),
                      transform=self.transform, use=self.use)


def mosaic(scans, resolution=0.1, bounds=None, *, use="data", altitude=None, seabed=None, ground_max=None,
           threshold=1e-3) -> Mosaic:
    """The mosaic of side-scan ``scans`` (a `Scan` or a list, e.g. a lawnmower survey's): grid of
    ``resolution`` m over ``bounds`` (default: every transducer position plus the swath,
    ``ground_max`` or ``range_max``); ``use``, ``altitude``, ``seabed``, ``threshold``: as in
    `mitsonar.products.sidescan.ground_range`. Returns a `Mosaic` (``.save("m.png")`` writes PNG + array)."""
    scans = as_scans(scans)
    if not scans:
        raise ValueError("mosaic: no scans given")
    top = max(s.range_max for s in scans) if ground_max is None else float(ground_max)
    builder = MosaicBuilder(_footprints(scans, top) if bounds is None else bounds, resolution, use=use,
                            altitude=altitude, seabed=seabed, threshold=threshold)
    for s in scans:
        builder.add(s, ground_max=ground_max)
    return builder.result()
