"""hilbertmap: continuous 3-D occupancy maps learnt from sonar scans (Hilbert maps, thesis ch. 4).

Reads a scan only through the attributes of :class:`~hilbertmap.scanlike.ScanLike` (``data`` /
``intensity``, ``ranges``, ``poses``, ``range_min``, ``range_max``, ``beamwidth_h``,
``beamwidth_v``, optionally ``beam_pattern``), so it maps scans from any source; it does not
import ``mitsonar``.

    from hilbertmap import HilbertMap
    hm = HilbertMap(n_inducing=3000).fit(scans)
    p = hm.predict_proba(points)            # (N, 3) -> (N,) in [0, 1]

    survey = IncrementalHilbertMap()         # along a trajectory, in bounded memory
    for scan in scans_as_they_arrive:        # every row at its own pose (scan.poses[k])
        survey.partial_fit(scan)

Modules: :mod:`~hilbertmap.model` (the estimator), :mod:`~hilbertmap.sgd` (its training steps),
:mod:`~hilbertmap.surfaces` (surfaces and slices), :mod:`~hilbertmap.persistence` (the file
format), :mod:`~hilbertmap.embedding` and :mod:`~hilbertmap.classify` (scans to samples),
:mod:`~hilbertmap.metrics` (scores against known geometry), :mod:`~hilbertmap.plots`.
"""
from .incremental import IncrementalHilbertMap
from .mesh import read_mesh, write_mesh
from .model import HilbertMap
from .scanlike import ScanLike
from .surfaces import MapSlice

__all__ = ["HilbertMap", "IncrementalHilbertMap", "MapSlice", "ScanLike", "write_mesh", "read_mesh"]
