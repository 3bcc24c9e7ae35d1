"""Products of scans: side-scan channels and mosaics, bathymetry and soundings, pictures."""
