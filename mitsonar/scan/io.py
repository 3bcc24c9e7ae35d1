"""Reading and writing scans: `save_scan` and `load_scan` (``.exr`` and ``.npz``, lossless).

The format is described in `mitsonar.scan.fileformat`. `load_scan` is the one way to read a scan
file, exported as `mitsonar.load_scan` (``Scan.load`` is its deprecated former name). Any problem with a file (missing, truncated, corrupt, foreign, wrong extension)
raises `ScanFileError`, a ``ValueError`` whose message names the file and says what is wrong.
"""
from __future__ import annotations

from mitsonar.scan.model import Scan, read
from mitsonar.scan.fileformat import EXTENSIONS, FORMAT, FORMAT_VERSION, ScanFileError

__all__ = ["EXTENSIONS", "FORMAT", "FORMAT_VERSION", "ScanFileError", "load_scan", "save_scan"]


def save_scan(scan: Scan, path) -> None:
    """Write ``scan`` losslessly to ``path`` (``.exr`` or ``.npz``, by the extension), atomically.
    See `Scan.save`."""
    if not isinstance(scan, Scan):
        raise TypeError(f"save_scan: expected a Scan, got {type(scan).__name__}")
    scan.save(path)


def load_scan(path) -> Scan:
    """Read a scan written by `Scan.save` or `save_scan` (``.exr`` or ``.npz``): bit-identical
    arrays, equal scalars, `ScanMeta` and `ElectronicsSettings`; the settings of files of mitsonar
    up to 0.2.0 migrated (`mitsonar.scan.migrations`). A missing, truncated, corrupt or foreign file,
    or content that `Scan` does not allow, raises `ScanFileError` (a ValueError) naming the file and
    the header field, channel or array."""
    return read(path)
