"""What :mod:`hilbertmap` reads from a scan: the :class:`ScanLike` protocol.

A scan of any source serves (``mitsonar.Scan``, :class:`hilbertmap.testing.SyntheticScan`, a
logged survey) as long as it carries these attributes; this package never imports ``mitsonar``.
"""
from __future__ import annotations

from typing import Protocol, runtime_checkable

import numpy as np


@runtime_checkable
class ScanLike(Protocol):
    """The attributes of a scan the mapper reads (one row per ping, i.e. per beam and pose).

    Attributes
    ----------
    data : ndarray (n_pings, n_bins)
        What the device outputs (8-bit levels); classified when ``source`` is ``data`` or ``auto``.
    intensity : ndarray (n_pings, n_bins)
        Linear echo energy per bin; classified (in dB) for ``source='intensity'``, and for
        ``auto`` when ``data`` is all zero.
    poses : ndarray (n_pings, 4, 4)
        World transform of each ping's beam frame, column vectors: ``[:3, 2]`` is the boresight,
        ``[:3, 1]`` the scan axis, ``[:3, 3]`` the transducer position.
    ranges : ndarray (n_bins,)
        Bin-centre ranges in metres.
    range_min, range_max : float
        The range window in metres.
    beamwidth_h, beamwidth_v : float
        Full -3 dB beam widths in degrees (azimuth about the scan axis, elevation along it).

    An optional ``beam_pattern`` (str, default ``'gaussian'``; ``'uniform'`` samples inside the
    widths) is read where present.
    """

    data: np.ndarray
    intensity: np.ndarray
    poses: np.ndarray
    ranges: np.ndarray
    range_min: float
    range_max: float
    beamwidth_h: float
    beamwidth_v: float


_ECHOES = ("data", "intensity")
# geometry is always read; of the echo arrays, the one ``source`` names (``auto`` starts with data)
GEOMETRY = tuple(a for a in ScanLike.__annotations__ if a not in _ECHOES)


def required_attributes(source: str = "auto") -> tuple:
    """The :class:`ScanLike` attributes a scan must have for ``source`` (``auto``, ``data``,
    ``intensity``)."""
    return GEOMETRY + (("intensity",) if source == "intensity" else ("data",))


def as_scan_list(scans, source: str = "auto") -> list:
    """A list of scans from one scan or an iterable of them; TypeError naming what is wrong."""
    if hasattr(scans, "poses"):
        scans = [scans]
    elif isinstance(scans, (str, bytes)) or not hasattr(scans, "__iter__"):
        raise TypeError(f"HilbertMap: fit() needs a scan or a list of scans, not {type(scans).__name__} "
                        "(load scan files with mitsonar.load_scan)")
    else:
        scans = list(scans)
    if not scans:
        raise ValueError("HilbertMap: fit() needs at least one scan")
    for s in scans:
        for a in required_attributes(source):
            if not hasattr(s, a):
                raise TypeError(f"HilbertMap: a scan lacks the attribute {a!r} (got {type(s).__name__})")
    return scans
