"""The `Scan` (`mitsonar.scan.model`), its metadata (`meta`: `ScanMeta`), its file format (`fileformat`: EXR and NPZ) and
`save_scan`/`load_scan` (`io`)."""
from mitsonar.scan.meta import ScanMeta
from mitsonar.scan.model import Scan, ScanFieldError, as_scans, bearing_rotation, reception_times, sidescan_channels

__all__ = ["Scan", "ScanFieldError", "ScanMeta", "as_scans", "bearing_rotation", "reception_times",
           "sidescan_channels"]
