"""How much a scan's bytes look like a real head's: the statistics of ``Scan.data`` that public
recordings of a Tritech Micron pin down.

The statistics are of the device bytes (after TVG, gain, dB compression and the A/D window), not of
the intensity: a Weibull shape fitted to bytes is not the shape of the intensity speckle.

=================================== ============== ===========================================
statistic                           real Micron    meaning
=================================== ============== ===========================================
``weibull_shape``                   1.05 - 1.54    shape of a Weibull fitted (location 0, maximum
                                                   likelihood) to the non-zero bytes beyond 1.6 m
``zero_fraction``                   0.14 - 0.51    fraction of bytes beyond 1.6 m that are 0
``ringdown_mean``                   60 - 96        mean byte from 0.1 to 1.0 m (ring-down)
=================================== ============== ===========================================

The real ranges were measured on public recordings of a Micron (200 bins, 10-20 m ranges,
harbour and tank scenes); see the issue "Bytes like a real head's" and ``benchmarks/realism.py``.
"""
from __future__ import annotations

import numpy as np

#: (low, high) of each statistic over the real recordings.
REAL_RANGES = {"weibull_shape": (1.05, 1.54), "zero_fraction": (0.14, 0.51), "ringdown_mean": (60.0, 96.0)}
#: Ranges (m) the statistics look at.
FAR_FROM = 1.6
RINGDOWN_WINDOW = (0.1, 1.0)


def weibull_shape(values) -> float:
    """Maximum-likelihood shape ``k`` of a two-parameter Weibull (location 0) fitted to ``values`` > 0
    (``scipy.stats.weibull_min.fit``); NaN when fewer than two values are positive."""
    from scipy import stats

    x = np.asarray(values, dtype=np.float64).ravel()
    x = x[x > 0]
    if x.size < 2:
        return float("nan")
    k, _, _ = stats.weibull_min.fit(x, floc=0)
    return float(k)


def byte_statistics(data, ranges) -> dict[str, float]:
    """The statistics of the table above for device bytes ``data`` (n_rows, n_bins) at bin-centre
    ``ranges`` (m); NaN for a statistic whose ranges hold no bins."""
    data = np.asarray(data)
    ranges = np.asarray(ranges, dtype=np.float64)
    far = data[:, ranges > FAR_FROM]
    lo, hi = RINGDOWN_WINDOW
    near = data[:, (ranges >= lo) & (ranges <= hi)]
    return {"weibull_shape": weibull_shape(far),
            "zero_fraction": float(np.mean(far == 0)) if far.size else float("nan"),
            "ringdown_mean": float(near.mean()) if near.size else float("nan")}


def inside(stats: dict[str, float]) -> dict[str, bool]:
    """For each statistic, whether it lies inside the real head's range (`REAL_RANGES`)."""
    return {name: bool(REAL_RANGES[name][0] <= stats[name] <= REAL_RANGES[name][1]) for name in REAL_RANGES}


def speckle_correlation(a, b, mean_bytes, *, band: float = 16.0, lo: float = 192.0, hi: float = 255.0,
                        min_bins: int = 50) -> float:
    """Correlation of two scans' bytes over their echo bins, within bands of similar mean level.

    Speckle is compared where there is an echo to speckle, well above the receiver's noise and
    below saturation: the bins whose noise-free byte ``mean_bytes`` (the scan's intensity through
    the same electronics without speckle and noise) lies in ``[lo, hi)`` (by default 192..254:
    echoes at least 20 dB above the default noise floor, where the receiver's noise moves a
    speckled byte little; at 10 dB the noise alone brings two renders' bytes down to about 0.8),
    grouped into
    ``band``-byte-wide bands so that the correlation is that of the fluctuations, not of the
    echoes' mean level. Returns the bin-count-weighted mean of the bands' Pearson correlations
    (bands with fewer than ``min_bins`` bins, or without variance, are skipped); NaN when no band
    qualifies.
    """
    a = np.asarray(a, dtype=np.float64).ravel()
    b = np.asarray(b, dtype=np.float64).ravel()
    m = np.asarray(mean_bytes, dtype=np.float64).ravel()
    total, weight = 0.0, 0
    for start in np.arange(lo, hi, band):
        sel = (m >= start) & (m < min(start + band, hi))
        if sel.sum() < min_bins or a[sel].std() == 0 or b[sel].std() == 0:
            continue
        total += np.corrcoef(a[sel], b[sel])[0, 1] * sel.sum()
        weight += int(sel.sum())
    return total / weight if weight else float("nan")
