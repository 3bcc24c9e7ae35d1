"""What :mod:`hilbertmap` reads from a scan: the :class:`ScanLike` protocol.

A scan of any source serves (``mitsonar.Scan``, :class:`hilbertmap.testing.SyntheticScan`, a
logged survey) as long as it carries these attributes; this package never imports ``mitsonar``.
"""
from __future__ import annotations

import math
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
    # mitsonar.scan.model.as_scans is mitsonar's; hilbertmap keeps its own (it must not import mitsonar).
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


def check_scan(scan, source: str = "auto", rigid_tol: float = 1e-3) -> None:
    """Refuse, with one line naming the attribute, a scan the mapper cannot place in the world:
    no ``poses``, poses not one (4, 4) per row, poses that are not rigid (rotation part not
    orthonormal with determinant +1 within ``rigid_tol``, or last row not ``0 0 0 1``), non-finite
    ``ranges`` / poses / echo values, or no rows at all."""
    name = type(scan).__name__
    for a in required_attributes(source):
        if not hasattr(scan, a) or getattr(scan, a) is None:
            raise ValueError(f"HilbertMap: the scan ({name}) has no {a!r}; a map needs every row's pose "
                             "(scan.poses, (n_pings, 4, 4)), its ranges and its echoes")
    echo = np.asarray(scan.intensity if source == "intensity" else scan.data)
    if echo.ndim != 2 or echo.shape[0] == 0:
        raise ValueError(f"HilbertMap: the scan's echoes must be (n_pings, n_bins) with at least one ping, "
                         f"got shape {echo.shape}")
    poses = np.asarray(scan.poses, dtype=np.float64)
    if poses.shape != (echo.shape[0], 4, 4):
        raise ValueError(f"HilbertMap: scan.poses must be one 4x4 pose per row, shape ({echo.shape[0]}, 4, 4), "
                         f"got {poses.shape}")
    bad = np.nonzero(~np.isfinite(poses).reshape(len(poses), -1).all(axis=1))[0]
    if len(bad):
        raise ValueError(f"HilbertMap: scan.poses[{bad[0]}] is not finite ({len(bad)} rows are not)")
    R = poses[:, :3, :3]
    err = np.abs(np.einsum("nji,njk->nik", R, R) - np.eye(3)).max(axis=(1, 2))
    det = np.linalg.det(R)
    last = np.abs(poses[:, 3, :] - np.array([0.0, 0.0, 0.0, 1.0])).max(axis=1)
    bad = np.nonzero((err > rigid_tol) | (np.abs(det - 1.0) > rigid_tol) | (last > rigid_tol))[0]
    if len(bad):
        k = bad[0]
        raise ValueError(f"HilbertMap: scan.poses[{k}] is not a rigid transform (R^T R - I up to {err[k]:.3g}, "
                         f"det R = {det[k]:.4g}, last row {poses[k, 3].tolist()}; allowed: rotation and "
                         f"translation within {rigid_tol:g})")
    ranges = np.asarray(scan.ranges, dtype=np.float64)
    if ranges.shape != (echo.shape[1],):
        raise ValueError(f"HilbertMap: scan.ranges must hold one range per bin ({echo.shape[1]}), got {ranges.shape}")
    if not np.isfinite(ranges).all():
        raise ValueError(f"HilbertMap: scan.ranges holds {int((~np.isfinite(ranges)).sum())} value(s) that are "
                         "not finite (NaN or inf); ranges must be finite metres")
    for a in ("range_min", "range_max", "beamwidth_h", "beamwidth_v"):
        v = float(getattr(scan, a))
        if not math.isfinite(v) or (a != "range_min" and v <= 0):
            raise ValueError(f"HilbertMap: scan.{a} must be a finite number{' > 0' if a != 'range_min' else ''}, "
                             f"not {v!r}")
    if not np.isfinite(np.asarray(echo, dtype=np.float64)).all():
        raise ValueError(f"HilbertMap: the scan's {'intensity' if source == 'intensity' else 'data'} holds "
                         "values that are not finite (NaN or inf)")
