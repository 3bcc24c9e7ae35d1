"""The sonar embedding of thesis 4.2.1: a scan becomes labelled samples in world space.

For every ping (beam) of a scan:

- bins are classified empty / full (:mod:`hilbertmap.classify`), bins inside the blanking range
  (transducer ring-down) are neither;
- **free samples**: points in the beam's spherical frustum between the blanking range and the
  start of the first full bin (less ``free_margin`` metres), labelled free. A ping without any
  full bin is free up to ``range_max``;
- **occupied groups**: each full bin of the first echo (``occupied_bins``) gives a group of
  ``occupied_samples`` points in that bin's frustum; the model averages their features (kernel
  mean embedding, thesis eq. 4.6) and labels the mean occupied;
- nothing behind the first echo (acoustic shadow); with ``multi_echo`` the water between the
  first and the last echo is drawn as candidates (``Samples.between``) that
  :meth:`HilbertMap.fit` keeps where a first map shows the beam reached them
  (:mod:`hilbertmap.multiecho`).

Directions follow the beam: ``beam_sampling='pattern'`` draws them in proportion to the two-way
beam pattern (gaussian with the scan's -3 dB widths; ``uniform`` patterns inside the widths),
``'uniform'`` draws them uniformly in the nominal frustum (the thesis). Ranges are drawn uniformly
in volume (density proportional to r^2). Every ping uses its own pose ``scan.poses[k]``: beam frame
+z boresight, +y scan axis; a direction of azimuth ``az`` and elevation ``el`` is
``(cos el sin az, sin el, cos el cos az)`` in the beam frame.
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from .classify import classify, scan_values

FOUR_SQRT_LN2 = 4.0 * math.sqrt(math.log(2.0))

# What ``"auto"`` means for the sampling budget of a scan, by its ``kind``. A multibeam frame has
# many narrow beams that overlap from frame to frame: about 26 training lanes a beam instead of
# about 310 map it 7.7x faster, with the same AUC (harbour survey, 100 frames: 0.951 against
# 0.950), near-wall AUC 0.914 against 0.919 on the same test points, the ridge's F-score at
# 0.1 m 0.26 against 0.085 and mean probability on the true walls 0.66 against 0.18; the ridge
# also holds more false surface (mean distance from it to the walls 0.90 m against 0.19 m).
SAMPLING_AUTO = {
    "multibeam": dict(max_free_per_ping=24, near_free=8, occupied_samples=8),
    None: dict(max_free_per_ping=400, near_free=32, occupied_samples=16),  # every other kind
}


def sampling_for(scan, max_free_per_ping, near_free, occupied_samples) -> dict:
    """The three sampling budgets for ``scan``, each ``"auto"`` one from ``SAMPLING_AUTO`` by the
    scan's ``kind`` (a scan without ``kind`` counts as mechanical)."""
    auto = SAMPLING_AUTO.get(str(getattr(scan, "kind", "")), SAMPLING_AUTO[None])
    given = dict(max_free_per_ping=max_free_per_ping, near_free=near_free, occupied_samples=occupied_samples)
    return {k: auto[k] if isinstance(v, str) and v == "auto" else v for k, v in given.items()}


@dataclass
class Samples:
    """Labelled samples of one or more scans (world coordinates, float64).

    ``free``: (F, 3) points labelled free. ``occupied``: (G, m, 3) groups of m points, each
    group one full bin. ``origins``: (P, 3) transducer positions of the pings used; ``frames``:
    (P, 4, 4) their beam frames and ``beams``: (P, 3) their full -3 dB widths (degrees, h and v)
    and ``range_max`` (the nominal frustum of each ping); ``spans``: (P, 3) the ranges where its
    free part starts, where its first echo starts and where that echo's full bins end (the last
    two are nan for a ping without echo); ``occupied_ping``: (G,) the ping of each group.
    ``between``: (B, 3) multi-echo candidates (water between a ping's echoes, not yet labelled),
    ``between_ping`` (B,) their pings and ``between_gap`` (B,) their metres to the next echo.
    ``info``: counts.
    """

    free: np.ndarray
    occupied: np.ndarray
    origins: np.ndarray
    info: dict
    frames: np.ndarray = None
    beams: np.ndarray = None
    spans: np.ndarray = None
    occupied_ping: np.ndarray = None
    free_gap: np.ndarray = None
    between: np.ndarray = None
    between_ping: np.ndarray = None
    between_gap: np.ndarray = None

    def gaps(self) -> np.ndarray:
        """Metres from each free sample to its ping's first echo (inf: no echo, or not recorded)."""
        return self.free_gap if self.free_gap is not None else np.full(len(self.free), np.inf)

    @staticmethod
    def concatenate(parts: list["Samples"]) -> "Samples":
        """One ``Samples`` of all ``parts``. Groups of fewer points than the largest (scans of
        kinds sampled with different ``occupied_samples``) have their points repeated cyclically
        up to its size: the group's mean is the same when the sizes divide (8 and 16)."""
        m = max((p.occupied.shape[1] for p in parts), default=1)
        occ = [p.occupied if p.occupied.shape[1] == m else p.occupied[:, np.arange(m) % p.occupied.shape[1]]
               for p in parts if len(p.occupied)]
        info: dict = {}
        for p in parts:
            for k, v in p.info.items():
                if isinstance(v, (int, float)) and not isinstance(v, bool):
                    info[k] = info.get(k, 0) + v
        return Samples(
            free=np.concatenate([p.free for p in parts]) if parts else np.zeros((0, 3)),
            occupied=np.concatenate(occ) if occ else np.zeros((0, m, 3)),
            origins=np.concatenate([p.origins for p in parts]) if parts else np.zeros((0, 3)),
            info=info,
            frames=np.concatenate([p.frames for p in parts]) if parts else np.zeros((0, 4, 4)),
            beams=np.concatenate([p.beams for p in parts]) if parts else np.zeros((0, 3)),
            spans=np.concatenate([p.spans for p in parts]) if parts else np.zeros((0, 3)),
            occupied_ping=_offset_concat([p.occupied_ping for p in parts], [len(p.frames) for p in parts]),
            free_gap=np.concatenate([p.gaps() for p in parts]) if parts else np.zeros(0),
            between=np.concatenate([p.between_points() for p in parts]) if parts else np.zeros((0, 3)),
            between_ping=_offset_concat([p.between_ping if p.between_ping is not None else np.zeros(0, np.int64)
                                         for p in parts], [len(p.frames) for p in parts]),
            between_gap=np.concatenate([p.between_gap if p.between_gap is not None else np.zeros(0)
                                        for p in parts]) if parts else np.zeros(0),
        )

    def between_points(self) -> np.ndarray:
        """The multi-echo candidates (B, 3), empty when none were drawn."""
        return self.between if self.between is not None else np.zeros((0, 3))


def _offset_concat(arrays, sizes):
    out, base = [], 0
    for a, n in zip(arrays, sizes):
        a = np.asarray(a, dtype=np.int64)
        out.append(np.where(a >= 0, a + base, -1))  # -1: evidence of no ping (hilbertmap.evidence)
        base += n
    return np.concatenate(out) if out else np.zeros(0, dtype=np.int64)


def _beam_directions(rng, n, scan, beam_sampling, extent=1.0):
    """(n, 3) unit directions in the beam frame, within ``extent`` times the -3 dB half widths."""
    bw_h = math.radians(float(scan.beamwidth_h))
    bw_v = math.radians(float(scan.beamwidth_v))
    pattern = str(getattr(scan, "beam_pattern", "gaussian"))
    if beam_sampling == "uniform" or pattern == "uniform":
        az = rng.uniform(-0.5 * bw_h * extent, 0.5 * bw_h * extent, n)
        # uniform in solid angle: sin(el) uniform
        s = math.sin(min(0.5 * bw_v * extent, 0.5 * math.pi))
        el = np.arcsin(rng.uniform(-s, s, n))
    elif beam_sampling == "pattern":
        # two-way gaussian pattern 2^-(2 (2a/bw)^2) = exp(-a^2 / (2 sigma^2)), sigma = bw / (4 sqrt(ln 2));
        # sinc and table patterns are approximated by the gaussian of the same -3 dB widths.
        # Truncated at ``extent`` times the -3 dB half width (two-way -6 dB at extent 1).
        az = _truncnorm(rng, n, bw_h / FOUR_SQRT_LN2, 0.5 * bw_h * extent)
        el = _truncnorm(rng, n, bw_v / FOUR_SQRT_LN2, min(0.5 * bw_v * extent, 0.5 * math.pi))
    else:
        raise ValueError(f"HilbertMap: beam_sampling must be 'pattern' or 'uniform', not {beam_sampling!r}")
    ce = np.cos(el)
    return np.stack([ce * np.sin(az), np.sin(el), ce * np.cos(az)], axis=-1)


def _truncnorm(rng, n, sigma, limit):
    x = rng.normal(0.0, sigma, n)
    bad = np.abs(x) > limit
    while np.any(bad):
        x[bad] = rng.normal(0.0, sigma, int(bad.sum()))
        bad = np.abs(x) > limit
    return x


def _volume_ranges(rng, r0, r1):
    """Ranges uniform in volume between r0 and r1 (arrays of equal shape)."""
    u = rng.random(np.shape(r0))
    a, b = np.asarray(r0) ** 3, np.asarray(r1) ** 3
    return np.cbrt(a + u * (b - a))


def blanking_range(values: np.ndarray, ranges: np.ndarray, range_min: float, bin_width: float,
                   fade: float = 0.1, margin_bins: int = 8) -> float:
    """Automatic blanking: where the transducer ring-down has faded.

    Ring-down makes the first bins bright in every ping, which no real echo does over a whole
    scan. Per bin, take the 90th percentile over pings (speckle makes the tail of the ring-down
    flicker well past where its median fades), and blank up to the first bin where it has fallen
    to within ``fade`` of the way from its start down to the scan's background, plus
    ``margin_bins``. The background is the lower quartile of that profile past the first bins:
    the open water somewhere between the ring-down and the echoes. (The far half is no background
    for a forward-looking frame, whose rows all see walls or the floor there: its median put the
    blanking inside the ring-down's speckle tail.) A scan whose first bins are not brighter than
    its background is not blanked.
    """
    q = np.percentile(values, 90, axis=0)
    floor = float(np.percentile(q[max(1, len(q) // 50):], 25)) if len(q) > 1 else float(q[0])
    top = float(q[: max(1, len(q) // 50)].max())
    span = float(np.max(q) - floor)
    if span <= 0 or top - floor < 0.25 * span:
        return float(range_min)
    below = np.nonzero(q <= floor + fade * (top - floor))[0]
    k = int(below[0]) if len(below) else len(q) - 1
    k = min(k + margin_bins, len(q) - 1)
    return float(ranges[k] - 0.5 * bin_width)


def embed_scan(scan, rng: np.random.Generator, *, source="auto", bin_rule="otsu+cfar", threshold=None,
               min_level=None, cfar_train=16, cfar_guard=2, cfar_offset=None, blanking="auto",
               free_density=40.0, max_free_per_ping=400, free_margin=0.0, near_free=0, near_depth=0.5,
               occupied_samples=16,
               occupied_bins="first_run", max_run=0.3, beam_sampling="pattern", beam_extent=1.0, ping_stride=1,
               min_echo_bins=4, multi_echo=False,
               ping_offset=0) -> Samples:
    """Samples of one scan (see the module docstring). Only the scan's attributes are read."""
    values, src = scan_values(scan, source)
    n_pings, n_bins = values.shape
    ranges = np.asarray(scan.ranges, dtype=np.float64)
    range_min, range_max = float(scan.range_min), float(scan.range_max)
    bw = (range_max - range_min) / n_bins
    poses = np.asarray(scan.poses, dtype=np.float64)

    if cfar_offset is None:
        cfar_offset = 40.0 if src == "data" else 10.0
    if min_level is None and src == "data":
        # 3/8 of the A/D span (9 dB above ad_low at the default span): a real head's open water is
        # speckled receiver noise (a Micron's bytes beyond 1.6 m are 14-51 % zeros, the rest a
        # Weibull of shape 1.05-1.54 around byte 30-40), and a quarter of the span (64) let about
        # one noise bin in ten through; at 96 it is about one in fifty, and runs of two rarer still
        min_level = 96.0
    if min_level is None and src == "intensity":
        min_level = -95.0  # dB of linear echo energy: drops the beam pattern's far tails
    if blanking == "auto":
        r_blank = blanking_range(values, ranges, range_min, bw)
    else:
        r_blank = max(float(blanking), range_min)
    valid = ranges - 0.5 * bw >= r_blank - 1e-9
    full, level = classify(values, bin_rule, threshold=threshold, valid=valid, min_level=min_level,
                           cfar_train=cfar_train, cfar_guard=cfar_guard, cfar_offset=cfar_offset)
    if min_echo_bins > 1:
        # an echo spans the pulse length: drop runs of full bins shorter than min_echo_bins
        # (isolated speckle spikes of open water and of the ring-down tail)
        full = _drop_short_runs(full, int(min_echo_bins))

    stride = float(ping_stride)
    if not stride >= 1.0:
        raise ValueError(f"HilbertMap: beam_stride must be >= 1, not {ping_stride!r}")
    # every stride-th ping (a fractional stride keeps 1/stride of them, evenly spread)
    pings = np.unique(np.floor(np.arange(float(ping_offset) % stride, n_pings, stride)).astype(np.int64))
    full = full[pings]
    poses = poses[pings]
    has = full.any(axis=1)
    first = np.where(has, np.argmax(full, axis=1), n_bins)
    # the first echo: the first full bin and the full bins contiguous with it (the pulse and the
    # beam footprint spread one surface over several bins), at most max_run metres
    if occupied_bins == "first":
        run_len = has.astype(np.int64)
    elif occupied_bins in ("first_run", "all"):
        idx = np.arange(n_bins)
        after = idx[None, :] >= first[:, None]
        if occupied_bins == "first_run":
            gap = after & ~full
            end = np.where(gap.any(axis=1), np.argmax(gap, axis=1), n_bins)
            run_len = np.where(has, end - first, 0)
            run_len = np.minimum(run_len, max(1, int(round(max_run / bw))))
        else:
            run_len = np.where(has, (full & after).sum(axis=1), 0)
    else:
        raise ValueError(f"HilbertMap: occupied_bins must be 'first', 'first_run' or 'all', not {occupied_bins!r}")

    # --- free samples --------------------------------------------------------------------
    r0 = np.full(len(pings), max(r_blank, range_min))
    r_first = range_min + first * bw  # start of the first full bin (range_max if none)
    r1 = np.minimum(r_first - free_margin, range_max)
    length = np.maximum(r1 - r0, 0.0)
    # samples in proportion to the frustum's volume, capped per ping
    solid = _solid_angle(scan)
    vol = solid * (np.maximum(r1, 0) ** 3 - r0 ** 3) / 3.0
    n_free = np.minimum(np.round(free_density * vol).astype(np.int64), int(max_free_per_ping))
    n_free = np.where(length > 0, np.maximum(n_free, np.minimum(1, n_free + 1)), 0)
    owner = np.repeat(np.arange(len(pings)), n_free)
    rr = _volume_ranges(rng, r0[owner], r1[owner])
    d = _beam_directions(rng, len(owner), scan, beam_sampling, beam_extent)
    gap = np.where(has[owner], r1[owner] - rr, np.inf)
    if near_free > 0:
        # the shell just before the first echo decides how thin a wall comes out, and volume
        # sampling leaves it nearly empty: add samples uniform in range over its last near_depth
        near = has & (length > 0)
        own2 = np.repeat(np.nonzero(near)[0], int(near_free))
        a = np.maximum(r1[own2] - float(near_depth), r0[own2])
        r2 = a + rng.random(len(own2)) * (r1[own2] - a)
        owner = np.concatenate([owner, own2])
        rr = np.concatenate([rr, r2])
        gap = np.concatenate([gap, r1[own2] - r2])
        d = np.concatenate([d, _beam_directions(rng, len(own2), scan, beam_sampling, beam_extent)])
    free = _to_world(poses[owner], d * rr[:, None])

    # --- occupied groups -------------------------------------------------------------------
    m = int(occupied_samples)
    if occupied_bins == "all":
        sel = full & (np.arange(n_bins)[None, :] >= first[:, None])
        gp, gb = np.nonzero(sel)
    else:
        gp = np.repeat(np.arange(len(pings)), run_len)
        offs = np.arange(len(gp)) - np.repeat(np.cumsum(run_len) - run_len, run_len)
        gb = first[gp] + offs
    G = len(gp)
    lo = range_min + gb * bw
    lo = np.repeat(lo, m)
    rr = _volume_ranges(rng, lo, lo + bw)
    d = _beam_directions(rng, G * m, scan, beam_sampling, beam_extent)
    occ = _to_world(np.repeat(poses[gp], m, axis=0), d * rr[:, None]).reshape(G, m, 3)

    # --- multi-echo candidates (labelled free by HilbertMap.fit where the beam reached them) ---
    if multi_echo:
        from .multiecho import between_echo_candidates
        b_pts, b_ping, b_gap = between_echo_candidates(
            full, poses, range_min + np.arange(n_bins) * bw, bw, max(r_blank, range_min), solid, rng,
            directions=lambda n: _beam_directions(rng, n, scan, beam_sampling, beam_extent),
            free_density=free_density, max_free_per_ping=max_free_per_ping, near_free=near_free,
            near_depth=near_depth)
    else:
        b_pts, b_ping, b_gap = np.zeros((0, 3)), np.zeros(0, dtype=np.int64), np.zeros(0)

    info = dict(n_pings=int(len(pings)), n_pings_with_echo=int(has.sum()), n_free=int(len(free)),
                n_between=int(len(b_pts)), n_groups=int(G), blanking=float(r_blank),
                level=float(level) if np.isfinite(level) else float("nan"),
                source=src)
    beams = np.tile([float(scan.beamwidth_h), float(scan.beamwidth_v), range_max], (len(pings), 1))
    spans = np.stack([r0, np.where(has, r_first, np.nan), np.where(has, r_first + run_len * bw, np.nan)], axis=1)
    return Samples(free=free, occupied=occ, origins=poses[:, :3, 3].copy(), info=info, frames=poses.copy(),
                   beams=beams, spans=spans, occupied_ping=gp.astype(np.int64), free_gap=gap,
                   between=b_pts, between_ping=b_ping, between_gap=b_gap)


def _drop_short_runs(full: np.ndarray, k: int) -> np.ndarray:
    """Keep only the full bins that belong to a run of at least k contiguous full bins."""
    n = full.shape[1]
    if k > n:
        return np.zeros_like(full)
    c = np.zeros((full.shape[0], n + 1), dtype=np.int32)
    np.cumsum(full, axis=1, out=c[:, 1:])
    win = (c[:, k:] - c[:, :n - k + 1]) == k  # win[:, j]: bins j .. j + k - 1 all full
    keep = np.zeros_like(full)
    for start in range(k):  # a bin is kept when some window of k bins containing it is all full
        keep[:, start:start + n - k + 1] |= win
    return full & keep


def _solid_angle(scan) -> float:
    """Solid angle of the nominal frustum (sr)."""
    bw_h = math.radians(float(scan.beamwidth_h))
    bw_v = math.radians(float(scan.beamwidth_v))
    return bw_h * 2.0 * math.sin(0.5 * bw_v)


def _to_world(poses: np.ndarray, local: np.ndarray) -> np.ndarray:
    return np.einsum("nij,nj->ni", poses[:, :3, :3], local) + poses[:, :3, 3]
