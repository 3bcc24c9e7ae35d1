"""North-up grids with an affine transform in rasterio's ``Affine`` order ``(a, 0, c, 0, e, f)``
(``a`` > 0 m per column, ``e`` = -``a``, ``(c, f)`` the top-left corner): the cell of a point, and the running sum
and count per cell that a mean grid is made of (the side-scan mosaic, the depth grid). Imports
nothing from mitsonar."""
from __future__ import annotations

import numpy as np


def accumulate(total, count, transform, shape, x, y, values) -> None:
    """Add ``values`` at the points ``(x, y)`` (m) into the flat ``total`` and ``count`` arrays
    (``rows * cols``, row-major) of the grid ``transform``/``shape`` = (rows, cols), in place:
    column ``floor((x - c) / a)``, row ``floor((y - f) / e)``; points off the grid are left out.
    The sums run in the points' order."""
    a, _, c, _, e, f = transform
    rows, cols = shape
    col = np.floor((np.asarray(x) - c) / a).astype(np.int64)
    row = np.floor((np.asarray(y) - f) / e).astype(np.int64)
    inside = (col >= 0) & (col < cols) & (row >= 0) & (row < rows)
    idx = row[inside] * cols + col[inside]
    np.add.at(total, idx, np.asarray(values)[inside])
    np.add.at(count, idx, 1)


def mean(total, count):
    """The mean per cell, ``total / count``, NaN where ``count`` is 0."""
    with np.errstate(invalid="ignore", divide="ignore"):
        return np.where(count > 0, total / np.maximum(count, 1), np.nan)
