"""Products of scans: side-scan channels and mosaics, bathymetry and soundings, pictures (with the
ray diagram of a sound-speed profile, `mitsonar.products.raydiagram`)."""
