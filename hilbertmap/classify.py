"""Bin classification: which range bins of a scan hold an echo ("full") and which are empty.

A rule takes the (n_pings, n_bins) array of one scan (its ``data`` or ``intensity``) and returns a
boolean array of the same shape. Rules:

``threshold``  value >= ``threshold`` (for ``data`` a level 0-255; for ``intensity`` linear energy)
``otsu``       per-scan Otsu threshold of the values beyond the blanking range (two-class split
               of the histogram), never below ``min_level``
``cfar``       per-ping cell-averaging CFAR along range: a bin is full when it exceeds by
               ``cfar_offset`` the (smaller one-sided) mean of ``cfar_train`` training bins on each
               side (``cfar_guard`` guard bins skipped), and ``min_level``
``otsu+cfar``  both (default): the scan-wide level removes the noise floor, CFAR keeps the leading
               edge of each echo and rejects the slow ring-down tail
"""
from __future__ import annotations

import math

import numpy as np

RULES = ("threshold", "otsu", "cfar", "otsu+cfar")


def scan_values(scan, source: str = "auto") -> tuple[np.ndarray, str]:
    """The array a rule classifies and its name: ``data``, ``intensity`` or ``auto``.

    ``auto`` takes ``data`` (what a device outputs) unless it is all zero, then ``intensity``.
    """
    if source not in ("auto", "data", "intensity"):
        raise ValueError(f"HilbertMap: source must be 'auto', 'data' or 'intensity', not {source!r}")
    if source == "auto":
        data = np.asarray(scan.data)
        source = "data" if data.size and np.any(data) else "intensity"
    values = np.asarray(getattr(scan, source), dtype=np.float64)
    if source == "intensity":
        # linear energy spans decades: classify its level in dB (zeros -> far below anything)
        values = 10.0 * np.log10(np.maximum(values, 1e-30))
    return values, source


def otsu_threshold(values: np.ndarray, bins: int = 256) -> float:
    """Otsu's threshold (maximum between-class variance) of a 1-D sample."""
    v = np.asarray(values, dtype=np.float64).ravel()
    v = v[np.isfinite(v)]
    if v.size == 0:
        return np.inf
    lo, hi = float(v.min()), float(v.max())
    if hi <= lo:
        return hi
    hist, edges = _histogram(v, bins, lo, hi)
    centres = 0.5 * (edges[:-1] + edges[1:])
    w0 = np.cumsum(hist).astype(np.float64)
    w1 = w0[-1] - w0
    m = np.cumsum(hist * centres)
    mu0 = m / np.maximum(w0, 1)
    mu1 = (m[-1] - m) / np.maximum(w1, 1)
    between = (w0 * w1 * (mu0 - mu1) ** 2)[:-1]
    # every threshold inside an empty gap between the classes scores the same: take the middle
    best = np.nonzero(between >= between.max() * (1.0 - 1e-9))[0]
    k = 0.5 * (best[0] + best[-1])
    return float(np.interp(k + 1, np.arange(len(edges)), edges))


def _histogram(v: np.ndarray, bins: int, lo: float, hi: float):
    """``np.histogram(v, bins, range=(lo, hi))``. When ``v`` holds integers over a span of at most
    65536 (a device's levels: a scan's ``data``) it histograms the distinct values weighted by
    their counts (a ``bincount``): each value falls in the same bin, so the counts are the same
    (0.24 ms instead of 0.86 ms for a 128 x 400 multibeam frame)."""
    if lo == math.floor(lo) and hi - lo < 65536:
        vi = v.astype(np.int64)
        if np.array_equal(vi, v):
            cnt = np.bincount(vi - int(lo))
            u = np.flatnonzero(cnt)
            hist, edges = np.histogram(u.astype(np.float64) + lo, bins=bins, range=(lo, hi), weights=cnt[u])
            return hist.astype(np.int64), edges
    return np.histogram(v, bins=bins, range=(lo, hi))


def cfar(values: np.ndarray, train: int = 16, guard: int = 2, offset: float = 40.0) -> np.ndarray:
    """Cell-averaging CFAR along axis 1 (range) on a log-scale signal; returns the detections.

    A bin is a detection when it exceeds the noise estimate by ``offset`` (levels are already
    logarithmic, so the CFAR factor is an offset). The noise estimate is the smaller of the two
    one-sided training means ("smallest-of" CFAR: an echo's leading edge is not masked by the
    echo's own tail, nor a wall by clutter behind it)."""
    v = np.asarray(values, dtype=np.float64)
    n_pings, n_bins = v.shape
    c = np.concatenate([np.zeros((n_pings, 1)), np.cumsum(v, axis=1)], axis=1)

    def window_sum(a, b):  # sum of bins [a, b) clipped to the array, per bin index
        a = np.clip(a, 0, n_bins)
        b = np.clip(b, 0, n_bins)
        return c[:, b] - c[:, a], np.maximum(b - a, 0)

    idx = np.arange(n_bins)
    s_lead, n_lead = window_sum(idx - guard - train, idx - guard)
    s_lag, n_lag = window_sum(idx + guard + 1, idx + guard + 1 + train)
    mean_lead = np.where(n_lead > 0, s_lead / np.maximum(n_lead, 1), np.inf)
    mean_lag = np.where(n_lag > 0, s_lag / np.maximum(n_lag, 1), np.inf)
    noise = np.minimum(mean_lead, mean_lag)
    return v > noise + offset


def classify(values: np.ndarray, rule: str = "otsu+cfar", threshold: float | None = None,
             valid: np.ndarray | None = None, min_level: float | None = None,
             cfar_train: int = 16, cfar_guard: int = 2, cfar_offset: float = 40.0) -> tuple[np.ndarray, float]:
    """Classify bins; returns (full mask, the scan-wide level used or nan).

    ``valid`` (n_bins,) marks bins outside the blanking zone; others are never full.
    """
    if rule not in RULES:
        raise ValueError(f"HilbertMap: unknown bin rule {rule!r}; choose one of {', '.join(RULES)}")
    v = np.asarray(values, dtype=np.float64)
    if valid is None:
        valid = np.ones(v.shape[1], dtype=bool)
    level = np.nan
    if rule == "threshold":
        if threshold is None:
            raise ValueError("HilbertMap: the 'threshold' bin rule needs a threshold")
        full = v >= threshold
        level = float(threshold)
    else:
        full = np.ones_like(v, dtype=bool)
        if "otsu" in rule:
            vv = v[:, valid]
            level = otsu_threshold(vv[vv > -290.0]) if threshold is None else float(threshold)
            if min_level is not None:
                level = max(level, min_level)
            full &= v >= level
        if "cfar" in rule:
            full &= cfar(v, cfar_train, cfar_guard, cfar_offset)
            if min_level is not None:
                full &= v >= min_level
    full &= valid[None, :]
    return full, level
