"""hilbertmap: continuous 3-D occupancy maps learnt from sonar scans (Hilbert maps, thesis ch. 4).

Reads a scan only through its documented attributes (``data`` / ``intensity``, ``ranges``,
``poses``, ``range_min``, ``range_max``, ``beam_pattern``, ``beamwidth_h``, ``beamwidth_v``), so it
maps scans from any source; it does not import ``mitsonar``.

    from hilbertmap import HilbertMap
    hm = HilbertMap(n_inducing=3000).fit(scans)
    p = hm.predict_proba(points)            # (N, 3) -> (N,) in [0, 1]
"""
from .model import HilbertMap, MapSlice
from .mesh import read_mesh, write_mesh

__all__ = ["HilbertMap", "MapSlice", "write_mesh", "read_mesh"]
