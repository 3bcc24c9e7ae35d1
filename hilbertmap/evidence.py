"""Surface evidence from outside the scans: points known to lie on a surface (a refined mesh, a
survey's soundings) as labelled samples that :meth:`HilbertMap.fit` takes beside the scans'.

    hm = HilbertMap(random_state=0)
    samples = Samples.concatenate([hm.embed_all(scans), surface_samples(points, origins, rng=rng)])
    hm.fit(scans, samples=samples)

Each point becomes an occupied group of one point (the group's mean is the point: a surface known
to the centimetre, not an echo spread over a fan), weighted as a full bin (``occupied_weight``); the
water on the straight segment from its ``origin`` (the sensor that saw it) to ``margin`` metres
before it becomes ``free_per_point`` free samples (uniform in range); each keeps its metres to the
point (``free_gap``), so that those within the map's ``near_depth`` of it count as the shell before
a surface (thinned on its own budget). The points add no ping to
the map's record of what was insonified.
"""
from __future__ import annotations

import numpy as np

from .embedding import Samples


def surface_samples(points, origins, *, free_per_point: int = 8, margin: float = 0.1,
                    rng: np.random.Generator | None = None) -> Samples:
    """:class:`~hilbertmap.embedding.Samples` of surface points ``points`` (N, 3) seen from
    ``origins`` (N, 3, or one 3-vector for all); see the module docstring."""
    P = np.asarray(points, dtype=np.float64)
    if P.ndim != 2 or P.shape[1] != 3 or not np.isfinite(P).all():
        raise ValueError(f"HilbertMap: surface points must be a finite (N, 3) array, got shape {P.shape}")
    O = np.broadcast_to(np.asarray(origins, dtype=np.float64), P.shape)
    if not np.isfinite(O).all():
        raise ValueError("HilbertMap: surface origins must be finite")
    if not (isinstance(free_per_point, (int, np.integer)) and free_per_point >= 0):
        raise ValueError(f"HilbertMap: free_per_point must be an integer >= 0, not {free_per_point!r}")
    if not margin >= 0:
        raise ValueError(f"HilbertMap: margin must be a number >= 0, not {margin!r}")
    rng = rng if rng is not None else np.random.default_rng(0)
    v = P - O
    L = np.linalg.norm(v, axis=1)
    u = v / np.maximum(L[:, None], 1e-12)
    owner = np.repeat(np.arange(len(P)), int(free_per_point))
    r = rng.random(len(owner)) * np.maximum(L[owner] - margin, 0.0)
    free = O[owner] + u[owner] * r[:, None]
    n = len(P)
    return Samples(free=free, occupied=P[:, None, :].copy(), origins=np.zeros((0, 3)),
                   info=dict(n_free=int(len(free)), n_groups=n), frames=np.zeros((0, 4, 4)),
                   beams=np.zeros((0, 3)), spans=np.zeros((0, 3)), occupied_ping=np.full(n, -1, dtype=np.int64),
                   free_gap=L[owner] - r)
