"""The `Scan` (`mitsonar.scan.model`), its metadata (`meta`: `ScanMeta`), its electronics settings
(`electronics`: `ElectronicsSettings`), its file format (`fileformat`: EXR and NPZ), the migrations
of old files (`migrations`) and `save_scan`/`load_scan` (`io`; `mitsonar.load_scan`). Data only:
nothing here imports the renderer, the plugins or the sonar equation."""
from mitsonar.scan.electronics import ElectronicsSettings
from mitsonar.scan.meta import ScanMeta
from mitsonar.scan.model import Scan, ScanFieldError, as_scans, bearing_rotation, reception_times, sidescan_channels

__all__ = ["ElectronicsSettings", "Scan", "ScanFieldError", "ScanMeta", "as_scans", "bearing_rotation", "reception_times",
           "sidescan_channels"]
