"""``sonar_tof``'s ``allocation="adaptive"``: more paths for the rows (pings) whose echoes are noisy.

A two-stage path tracer. The error a benchmark measures is the relative L2 over the whole scan,
``sum_r V_r / n_r`` over the squared norm, where row ``r`` gets ``n_r`` paths and ``V_r`` is the
summed per-path variance of its bins. For a fixed total ``N = sum_r n_r`` it is smallest at
``n_r proportional to sqrt(V_r)`` (Neyman allocation: Cochran, *Sampling Techniques*, 3rd ed.
1977, eq. 5.26). ``V_r`` is unknown, so:

1. **pilot**: `PILOT_FRACTION` of ``spp`` (at least `MIN_PILOT`) paths per row, path traced with a
   seed of their own (``seed ^ PILOT_SEED``), estimate ``V_r`` (per echo: a path's echoes rarely share a bin);
2. **allocation**: the budget, ``spp * n_rows`` paths, is shared out
   ``n_r = N_2 (m / R + (1 - m) sqrt(V_r) / sum_s sqrt(V_s))`` (`UNIFORM_MIX` = ``m``: every row
   keeps at least ``m`` of its uniform share, so a row whose rare echo the pilot missed still has
   paths), at least one path per row, integers by largest remainders; evenly when the pilot
   predicts less than `MIN_GAIN`: then the render is the uniform render, byte for byte (its
   passes, samples and sums), and the pilot's time is all that is lost;
3. **guide** (`GUIDE`): the pilot also sums each row's squared echo energies over `GUIDE_BINS`
   slices of the primary sample that draws the emitted elevation (``u.y``: the beam table's
   marginal). A row's slices get the second stage's paths in proportion to the square root of
   their second moments, `GUIDE_MIX` of them evenly: a piecewise-constant density ``g`` over
   ``u.y``, drawn by warping the row's own ``u.y`` (each slice's share of [0, 1) onto the slice,
   monotone, so the Sobol points stay stratified), the emission weight divided by ``g``. The
   optimal density of one primary coordinate is proportional to the root of the second moment
   given it (importance sampling: Kahn and Marshall 1953; in primary sample space, as path
   guiding does for directions: Mueller et al. 2017). Used where the pilot predicts at least
   `GUIDE_MIN_GAIN` in variance, cross-validated between its even and odd paths
   (`cross_validated_guide`; rows it does not help keep the even density): an echo that returns only at some elevations (the pile seen in a
   quay wall returns near the horizontal, of a 35 deg beam), and the rows' variances for step 2
   are then the guided ones;
4. **estimate**: each row's mean over its own ``n_r`` paths, drawn as ``sonar_tof``'s (its
   ``sampling``: `samples.SobolSamples` by default) with the render's seed.

Unbiased: the second stage's samples are drawn with a seed apart from the pilot's, so given the
pilot (hence ``n_r`` and ``g``) each row's mean is the mean of ``n_r`` paths of the row's own
distribution, importance weighted by the density they were drawn with.
The pilot's paths only choose and are left out of the estimate: combining them weighted by counts
that depend on their own values is a ratio estimator, biased (rows whose pilot saw more get more
paths, which would weight their pilot's sums down). The pilot is paid on top of the budget: the
render costs about ``1 + PILOT_FRACTION`` of the uniform one, whose ``spp`` it keeps. (It was taken
from the budget until 2026-11-27: where the split stays even, the ``spp - pilot`` paths left fell
short of the power of two at which the Sobol emission is a complete net, and those renders had up
to 24 % more error than the uniform render of ``spp`` paths, their pilot's time besides.)
Deterministic per seed: the sums are exact (`exact_sum`) and the samples depend on
(seed, row, path number) only.
"""
from __future__ import annotations

import drjit as dr
import mitsuba as mi
import numpy as np

from . import frozen_pass
from .exact_sum import ExactBins
from .samples import HashSamples, opaque_u32

#: ``allocation="auto"`` (``sonar_tof``'s default) allocates where the render traces at least this
#: many paths (rows x spp): the pilot's fixed cost (3-5 ms on 2 cores: its own kernel, the
#: choice) is then under a tenth of the render's time (periscope, 21 pings x 4096: 32 ms uniform,
#: 39 ms with the pilot; x 16384: 119 against 128 ms).
AUTO_MIN_PATHS = 1 << 18
#: Share of ``spp`` the pilot traces per row (at least `MIN_PILOT` paths), and the least ``spp``
#: worth a pilot (below it the render is uniform).
PILOT_FRACTION = 1.0 / 16.0
MIN_PILOT = 8
MIN_SPP = 4 * MIN_PILOT
#: Share of the second stage spread evenly over the rows (the floor of the allocation).
UNIFORM_MIX = 0.25
#: The least predicted gain (the pilot's ``sum_r V_r / n_uniform`` over ``sum_r V_r / n_r``, a ratio
#: of variances) worth moving paths for; below it the second stage is uniform. The prediction ignores
#: what Sobol emission gains in rows with many paths and what a path costs in each row: measured
#: error ratios at equal time came out far under its square root (intake: 10 predicted, 1.8-2.0
#: measured; box: 3.7, 1.19-1.27; hidden_target: 1.26-1.33, 0.63-1.39 over four runs, its rare
#: echoes make each run's ratio erratic; periscope: 1.08, 0.77-0.97).
MIN_GAIN = 2.0
#: The pilot's samples: the render's seed xor this (independent of the second stage's).
PILOT_SEED = 0xA110C8ED
#: The guide of step 3: on (module docstring); slices of ``u.y``; the share of each row's paths
#: spread evenly over them (a defensive mixture: no slice gets under 0.3 of its even share); the
#: least predicted gain in variance (the pilot's, on its own paths) worth guiding for.
GUIDE = True
GUIDE_BINS = 16
GUIDE_MIX = 0.3
GUIDE_MIN_GAIN = 1.3
#: The least pilot (paths per row) that guides: 8 paths per slice and half on average, for
#: `cross_validated_guide` to score anything (at 64 the choice flipped from seed to seed).
GUIDE_MIN_PILOT = 256
#: The largest float32 below 1 (a warped coordinate stays in [0, 1)).
ONE_MINUS_EPS = float(np.nextafter(np.float32(1.0), np.float32(0.0)))


def adaptive(allocation, n_rows, spp):
    """Whether a render of ``n_rows`` rows that do not share paths, ``spp`` each, allocates
    adaptively under ``sonar_tof``'s ``allocation`` setting (``auto``: `AUTO_MIN_PATHS` and more
    than one row)."""
    if allocation == "auto":
        return n_rows >= 2 and n_rows * int(spp) >= AUTO_MIN_PATHS
    return allocation == "adaptive"


def allocate(v, total, mix=UNIFORM_MIX):
    """Paths per row (int64, summing to ``total``, each at least 1) for rows of per-path variance
    ``v``: ``total (mix / R + (1 - mix) sqrt(v) / sum sqrt(v))`` rounded by largest remainders;
    uniform when no row has variance."""
    v = np.asarray(v, dtype=np.float64)
    n_rows = v.size
    total = int(total)
    if total < n_rows:
        raise ValueError(f"allocation: {total} paths cannot give each of {n_rows} rows one")
    if not 0.0 <= mix <= 1.0:
        raise ValueError(f"allocation: mix {mix} must be in [0, 1]")
    s = np.sqrt(np.maximum(v, 0.0))
    share = np.full(n_rows, 1.0 / n_rows)
    if s.sum() > 0 and np.isfinite(s.sum()):
        share = mix / n_rows + (1.0 - mix) * s / s.sum()
    # one path each first, the rest by share (largest remainders, ties to the lower row)
    want = (total - n_rows) * share
    n = np.floor(want).astype(np.int64)
    rest = total - n_rows - int(n.sum())
    if rest > 0:
        order = np.lexsort((np.arange(n_rows), -(want - n)))
        n[order[:rest]] += 1
    return n + 1


def predicted_gain(v, counts):
    """The variance of the uniform split of ``counts.sum()`` paths over that of ``counts``, for
    rows of per-path variance ``v`` (1.0 when no row has any)."""
    v = np.maximum(np.asarray(v, dtype=np.float64), 0.0)
    adaptive = float((v / counts).sum())
    return float(v.sum() * v.size / counts.sum()) / adaptive if adaptive > 0 else 1.0


def row_variance(integrator, setup, seed, count, lanes):
    """The pilot: ``count`` independent paths per row (`samples.HashSamples`, seed ``seed ^
    PILOT_SEED``: its even and odd paths are then independent halves, as `cross_validated_guide`
    needs; two halves of one Sobol sequence fill each other's gaps); per row the
    summed per-path variance of its bins, ``sum_b (E[e^2] - E[e]^2)``, float64 ``(n_rows,)``, and
    the mean squared echo energy per path over each of `GUIDE_BINS` slices of ``u.y``, for the
    paths of even and of odd number apart (the sums over ``count / (2 GUIDE_BINS)``, a slice's
    expected share), float64 ``(n_rows, 2, GUIDE_BINS)``."""
    n_rows, n_bins = setup.sensor.n_pings, setup.sensor.n_bins
    counts = np.full(n_rows, count, dtype=np.int64)
    first, second, sliced = _sums(integrator, setup, seed ^ PILOT_SEED, counts, lanes, squares=True)
    mean = first.reshape(n_rows, n_bins) / count
    v = np.maximum(second.reshape(n_rows, n_bins) / count - mean * mean, 0.0).sum(axis=1)
    return v, sliced.reshape(n_rows, 2, GUIDE_BINS) * (2 * GUIDE_BINS / count)


def cross_validated_guide(m2, mix=GUIDE_MIX):
    """Step 3's densities from the two halves' slice second moments ``m2`` ``(n_rows, 2, n)``
    (`row_variance`): `guide_tables` of their mean, and per row the second moment left over the
    even one's *cross-validated*: each half scored with the densities of the other (a slice that
    one half saw a rare echo in is not rewarded by that same echo). Rows the guide does not help
    so scored (factor >= 1) keep the even density (the identity warp) and factor 1: on the
    intake, whose rare echoes through the opening the pilot's slices estimate poorly, the guide
    fitted to the whole pilot lost 1.1-1.2x at equal paths."""
    m2 = np.maximum(np.asarray(m2, dtype=np.float64), 0.0)
    n_rows, _, n = m2.shape
    prob, cdf, _ = guide_tables(m2.mean(axis=1), mix)
    left, even = np.zeros(n_rows), np.zeros(n_rows)
    for h in (0, 1):
        other, _, _ = guide_tables(m2[:, 1 - h], mix)
        scored = _moments(m2[:, h], other)
        left += scored[0]
        even += scored[1]
    factor = np.ones(n_rows)
    has = even > 0
    factor[has] = left[has] / even[has]
    off = factor >= 1.0
    cdf[off] = np.linspace(0.0, 1.0, n + 1, dtype=np.float32)
    prob[off] = np.diff(cdf[off], axis=1)
    factor[off] = 1.0
    return prob, cdf, factor


def guide_tables(m2, mix=GUIDE_MIX):
    """Step 3's densities from the slices' second moments ``m2`` ``(n_rows, n_slices)``: each
    slice's probability ``mix / n + (1 - mix) sqrt(m2) / sum sqrt(m2)`` (even in a row without
    echoes) as float32 ``(n_rows, n_slices)`` and their cumulative sums ``(n_rows, n_slices + 1)``
    (from 0 to 1, the probabilities their float32 differences), and per row the second moment the
    guide leaves over the even one's, ``sum m2 / (n^2 p) / mean(m2)`` (1 without echoes)."""
    if not 0.0 < mix <= 1.0:
        raise ValueError(f"guide: mix {mix} must be in (0, 1] (a slice of probability 0 would bias the render)")
    m2 = np.maximum(np.asarray(m2, dtype=np.float64), 0.0)
    n_rows, n = m2.shape
    s = np.sqrt(m2)
    total = s.sum(axis=1, keepdims=True)
    has = total[:, 0] > 0
    p = np.full((n_rows, n), 1.0 / n)
    p[has] = mix / n + (1.0 - mix) * s[has] / total[has]
    cdf = np.zeros((n_rows, n + 1), dtype=np.float32)
    cdf[:, 1:] = np.cumsum(p, axis=1)
    cdf[:, -1] = 1.0
    prob = np.diff(cdf, axis=1)
    factor = np.ones(n_rows)
    left, even = _moments(m2, prob)
    factor[has] = left[has] / even[has]
    return prob, cdf, factor


def _moments(m2, prob):
    """Per row, the second moment per path of paths drawn with slice probabilities ``prob``
    (importance weighted: ``sum_k m2_k / (n^2 p_k)``) and of evenly drawn ones (``mean m2``),
    for slices of second moments ``m2`` under even drawing (both ``(n_rows, n)``)."""
    n = m2.shape[1]
    return (m2 / (n * n * prob)).sum(axis=1), m2.mean(axis=1)


def warp(u, row, cdf, prob, n):
    """Step 3's draw inside a kernel: ``u`` (mi.Float in [0, 1)) of lanes in rows ``row`` moved
    by each row's slice probabilities (``prob``, flat float32 ``n_rows * n``; ``cdf`` their
    cumulative sums, ``n_rows * (n + 1)``): the slice ``k`` whose cumulative interval holds ``u``,
    then ``u``'s place in it mapped onto ``[k / n, (k + 1) / n)``. Returns the new coordinate and
    its density ``n p_k``."""
    base = row * (n + 1)
    k = mi.UInt32(0)
    for j in range(1, n):
        k += dr.select(u >= dr.gather(mi.Float, cdf, base + j), 1, 0)
    lo = dr.gather(mi.Float, cdf, base + k)
    pk = dr.gather(mi.Float, prob, row * n + k)
    t = dr.clip((u - lo) / pk, 0.0, 1.0)
    out = dr.minimum((mi.Float(k) + t) * (1.0 / n), ONE_MINUS_EPS)
    return out, pk * n


def render(integrator, setup, seed, spp, lanes, progress=None):
    """The adaptive render (module docstring) in passes of at most ``lanes`` paths: a
    ``mi.Float64`` of ``n_rows * n_bins`` values (row-major) left on the device, the mean per row
    over its own paths; the paths of each row in
    ``integrator.last_counts``, a summary (pilot paths per row, also as ``extra_paths_per_row``:
    the paths traced beyond ``spp``; predicted gain; the least, median and most paths of a row) in
    ``integrator.last_plan``. ``spp`` under `MIN_SPP`: every row gets
    ``spp`` paths (uniform; the plan says so). ``progress(done_spp, spp)`` after each pass of
    the estimate (the pilot's pass comes first, unreported)."""
    n_rows, n_bins = setup.sensor.n_pings, setup.sensor.n_bins
    spp = int(spp)
    if spp < 1:
        raise ValueError(f"spp must be a positive number of paths per ping, got {spp}")
    pilot, counts, gain, guide = choose(integrator, setup, seed, spp, lanes)
    if counts is None:
        counts = np.full(n_rows, spp, dtype=np.int64)
    if (counts == counts[0]).all():
        # the uniform render's own passes (ping and path number computed in the kernel, its
        # recordings): the same samples and sums, without the lanes' index arrays; with the guide,
        # its emission drawn by it
        mean = integrator.accumulate(int(counts[0]), lanes // n_rows,
                                     lambda start, count: integrator._pass(setup, seed, start, count, guide),
                                     progress)
    else:
        done = None if progress is None else (lambda paths: progress(int(spp * paths / counts.sum()), spp))
        (total,) = _device_sums(integrator, setup, seed, counts, lanes, guide=guide, done=done)
        # each bin over its row's count (float64, as NumPy's total / counts[:, None] divides)
        per_row = mi.Float64(counts.astype(np.float64))
        mean = total / dr.gather(mi.Float64, per_row, dr.arange(mi.UInt32, n_rows * n_bins) // dr.opaque(mi.UInt32, n_bins))
    integrator.last_counts = counts
    integrator.last_plan = {"allocation": "adaptive" if pilot else "uniform", "pilot": pilot,
                            "extra_paths_per_row": pilot,
                            "predicted_gain": gain, "guided": guide is not None,
                            "guide_gain": None if guide is None else guide["gain"],
                            "paths_per_row_min": int(counts.min()),
                            "paths_per_row_median": float(np.median(counts)), "paths_per_row_max": int(counts.max())}
    return mean


def choose(integrator, setup, seed, spp, lanes):
    """Steps 1 to 3 of the module docstring for a budget of ``spp`` paths per row: ``(pilot
    paths per row, paths per row or None, predicted gain, guide or None)``; None (the even split,
    ``spp`` paths each) where the pilot predicts under `MIN_GAIN`, or where ``spp`` is under
    `MIN_SPP` or there is one row (then no pilot runs); the guide (``prob`` and ``cdf``,
    `guide_tables`, and its predicted ``gain`` in variance) None where it predicts under
    `GUIDE_MIN_GAIN`, the pilot is under `GUIDE_MIN_PILOT` or `GUIDE` is off."""
    n_rows = setup.sensor.n_pings
    if spp < MIN_SPP or n_rows < 2:
        return 0, None, 1.0, None
    pilot = max(MIN_PILOT, int(spp * PILOT_FRACTION))
    v, m2 = row_variance(integrator, setup, seed, pilot, lanes)
    guide = None
    if GUIDE and pilot >= GUIDE_MIN_PILOT:
        prob, cdf, factor = cross_validated_guide(m2)
        guided = v * factor
        g = float(v.sum() / guided.sum()) if guided.sum() > 0 else 1.0
        if g >= GUIDE_MIN_GAIN:
            guide, v = {"prob": prob, "cdf": cdf, "gain": g}, guided
    counts = allocate(v, spp * n_rows)
    gain = predicted_gain(v, counts)
    return pilot, (counts if gain >= MIN_GAIN else None), gain, guide


def _sums(integrator, setup, seed, counts, lanes, squares=False, guide=None, done=None):
    """`_device_sums` as float64 NumPy arrays (the pilot's, read on the host to choose)."""
    return [p.numpy() for p in _device_sums(integrator, setup, seed, counts, lanes, squares, guide, done)]


def _device_sums(integrator, setup, seed, counts, lanes, squares=False, guide=None, done=None):
    """Paths ``0 .. counts[r]`` of every row ``r`` (the integrator's ``sampling``, seed ``seed``),
    in passes of at most ``lanes`` lanes: the summed energy per bin (and with ``squares`` the
    summed squared echo energies, and those over the `GUIDE_BINS` slices of ``u.y`` per row and
    parity of the path's number),
    ``mi.Float64`` arrays of ``n_rows * n_bins`` values, summed over the passes on the device; ``guide`` (`choose`'s) draws the emission's ``u.y`` from
    each row's slice density (`warp`); ``done(paths)`` after each pass, with the paths traced so
    far."""
    from .denormals import flushing

    counts = np.asarray(counts, dtype=np.int64)
    row = np.repeat(np.arange(counts.size, dtype=np.uint32), counts)
    index = (np.arange(row.size, dtype=np.int64) - np.repeat(np.cumsum(counts) - counts, counts)).astype(np.uint32)
    seed_o = opaque_u32(seed)
    sampler = _sampler(integrator, squares)

    def body(setup, seed_o, ping, idx, d, w):
        return _traced(setup, integrator, seed_o, ping, idx, d, w, squares)

    # the recording's key names the body: one per kind of pass
    body.__qualname__ = f"row_allocation.{f'moments{GUIDE_BINS}' if squares else 'sums'}"
    out = None
    with dr.suspend_grad(), flushing():
        for a in range(0, row.size, lanes):
            ping, idx = mi.UInt32(row[a:a + lanes]), mi.UInt32(index[a:a + lanes])
            d, w = emitted(setup.sensor.beam, sampler(seed_o, ping, idx), ping, guide)
            parts = frozen_pass.run(body, integrator, setup, seed_o, ping, idx, d, w)
            parts = list(parts if squares else (parts,))
            out = parts if out is None else [o + p for o, p in zip(out, parts)]
            dr.eval(out)
            if done is not None:
                done(min(a + lanes, row.size))
    return out


def _sampler(integrator, pilot):
    """The primary samples of a pass: the integrator's ``sampling``, the pilot's independent."""
    return HashSamples if pilot else integrator.SAMPLERS[integrator.sampling]


def emitted(beam, samples, ping, guide=None):
    """The emitted directions and weights of ``samples`` (dims 0-1) of lanes in rows ``ping``,
    evaluated: `frozen_pass.emitted` without a guide; with one (`choose`'s), ``u.y`` drawn by the
    row's slice densities (`warp`) and the beam's weight over the density."""
    if guide is None:
        return frozen_pass.emitted(beam, samples)
    if "arrays" not in guide:   # uploaded once per render
        guide["arrays"] = tuple(mi.Float(np.ascontiguousarray(guide[k], dtype=np.float32).ravel())
                                for k in ("cdf", "prob"))
    cdf, prob = guide["arrays"]
    u = samples.get2(0)
    uy, density = warp(u.y, ping, cdf, prob, guide["prob"].shape[1])
    d, w = beam.sample(mi.Point2f(u.x, uy), True)
    w = w / density
    dr.eval(d, w)
    return d, w


def _traced(setup, integrator, seed_o, ping, idx, d, w, squares):
    """One pass's path kernel: the lanes' rows ``ping`` and path numbers ``idx``, their emitted
    directions ``d`` and weights ``w`` drawn beforehand (`frozen_pass.emitted`)."""
    n_rows, n_bins = setup.sensor.n_pings, setup.sensor.n_bins
    samples = _sampler(integrator, squares)(seed_o, ping, idx)
    sums = [ExactBins(n_rows * n_bins) for _ in range(2 if squares else 1)]
    bins = setup.bins
    if squares:   # step 3's slices of the emission's u.y
        sums.append(ExactBins(n_rows * 2 * GUIDE_BINS))
        u_y = samples.get2(0).y
        sliced = (ping * 2 + (idx & 1)) * GUIDE_BINS + mi.UInt32(dr.clip(dr.floor(u_y * GUIDE_BINS), 0, GUIDE_BINS - 1))

    def record(depth_k, rng, energy, valid, hit):
        b, valid = bins.index(rng, valid)
        at = bins.flat(ping, b)
        sums[0].add(energy, at, valid)
        if squares:
            sums[1].add(energy * energy, at, valid)
            sums[2].add(energy * energy, sliced, valid)

    integrator.sample(integrator.emitting(setup, d, w), ping, samples, record)
    totals = [s.total() for s in sums]
    return tuple(totals) if squares else totals[0]
