"""Reading and writing scans: `save_scan` and `load_scan` (``.exr`` and ``.npz``, lossless).

The format is described in `mitsonar.scan.fileformat`; these are the functional forms of `Scan.save`
and `Scan.load`. Any problem with a file (missing, truncated, corrupt, foreign, wrong extension)
raises `ScanFileError`, a ``ValueError`` whose message names the file and says what is wrong.
"""
from __future__ import annotations

from mitsonar.scan.model import Scan
from mitsonar.scan.fileformat import EXTENSIONS, FORMAT, FORMAT_VERSION, ScanFileError

__all__ = ["EXTENSIONS", "FORMAT", "FORMAT_VERSION", "ScanFileError", "load_scan", "save_scan"]


def save_scan(scan: Scan, path) -> None:
    """Write ``scan`` losslessly to ``path`` (``.exr`` or ``.npz``, by the extension), atomically.
    See `Scan.save`."""
    if not isinstance(scan, Scan):
        raise TypeError(f"save_scan: expected a Scan, got {type(scan).__name__}")
    scan.save(path)


def load_scan(path) -> Scan:
    """Read a scan written by `save_scan` (``.exr`` or ``.npz``). See `Scan.load`."""
    return Scan.load(path)
