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
3. **estimate**: each row's mean over its own ``n_r`` paths, drawn as ``sonar_tof``'s (its
   ``sampling``: `samples.SobolSamples` by default) with the render's seed.

Unbiased: the second stage's samples are drawn with a seed apart from the pilot's, so given the
pilot (hence ``n_r``) each row's mean is the mean of ``n_r`` paths of the row's own distribution.
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
from .samples import opaque_u32

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
    """The pilot: ``count`` paths per row (seed ``seed ^ PILOT_SEED``); per row the
    summed per-path variance of its bins, ``sum_b (E[e^2] - E[e]^2)``, float64 ``(n_rows,)``."""
    n_rows, n_bins = setup.sensor.n_pings, setup.sensor.n_bins
    counts = np.full(n_rows, count, dtype=np.int64)
    first, second = _sums(integrator, setup, seed ^ PILOT_SEED, counts, lanes, squares=True)
    mean = first.reshape(n_rows, n_bins) / count
    return np.maximum(second.reshape(n_rows, n_bins) / count - mean * mean, 0.0).sum(axis=1)


def render(integrator, setup, seed, spp, lanes, progress=None):
    """The adaptive render (module docstring) in passes of at most ``lanes`` paths: float64
    ``(n_rows, n_bins)``, the mean per row over its own paths; the paths of each row in
    ``integrator.last_counts``, a summary (pilot paths per row, also as ``extra_paths_per_row``:
    the paths traced beyond ``spp``; predicted gain; the least, median and most paths of a row) in
    ``integrator.last_plan``. ``spp`` under `MIN_SPP`: every row gets
    ``spp`` paths (uniform)."""
    n_rows, n_bins = setup.sensor.n_pings, setup.sensor.n_bins
    spp = int(spp)
    if spp < 1:
        raise ValueError(f"spp must be a positive number of paths per ping, got {spp}")
    pilot, counts, gain = choose(integrator, setup, seed, spp, lanes)
    if counts is None:
        counts = np.full(n_rows, spp, dtype=np.int64)
    if (counts == counts[0]).all():
        # the uniform render's own passes (ping and path number computed in the kernel, its
        # recordings): the same samples and sums, without the lanes' index arrays
        mean = integrator.accumulate(int(counts[0]), lanes // n_rows,
                                     lambda start, count: integrator._pass(setup, seed, start, count))
    else:
        (total,) = _sums(integrator, setup, seed, counts, lanes)
        mean = total.reshape(n_rows, n_bins) / counts[:, None]
    integrator.last_counts = counts
    integrator.last_plan = {"allocation": "adaptive", "pilot": pilot, "extra_paths_per_row": pilot,
                            "predicted_gain": gain,
                            "paths_per_row_min": int(counts.min()),
                            "paths_per_row_median": float(np.median(counts)), "paths_per_row_max": int(counts.max())}
    if progress is not None:
        progress(spp, spp)
    return mean.reshape(n_rows, n_bins)


def choose(integrator, setup, seed, spp, lanes):
    """Steps 1 and 2 of the module docstring for a budget of ``spp`` paths per row: ``(pilot
    paths per row, paths per row or None, predicted gain)``; None (the even split, ``spp`` paths
    each) where the pilot predicts under `MIN_GAIN`, or where ``spp`` is under `MIN_SPP` or there
    is one row (then no pilot runs)."""
    n_rows = setup.sensor.n_pings
    if spp < MIN_SPP or n_rows < 2:
        return 0, None, 1.0
    pilot = max(MIN_PILOT, int(spp * PILOT_FRACTION))
    v = row_variance(integrator, setup, seed, pilot, lanes)
    counts = allocate(v, spp * n_rows)
    gain = predicted_gain(v, counts)
    return pilot, (counts if gain >= MIN_GAIN else None), gain


def _sums(integrator, setup, seed, counts, lanes, squares=False):
    """Paths ``0 .. counts[r]`` of every row ``r`` (the integrator's ``sampling``, seed ``seed``),
    in passes of at most ``lanes`` lanes: the summed energy per bin (and with ``squares`` the
    summed squared echo energies), float64 ``n_rows * n_bins`` arrays."""
    from .denormals import flushing

    counts = np.asarray(counts, dtype=np.int64)
    row = np.repeat(np.arange(counts.size, dtype=np.uint32), counts)
    index = (np.arange(row.size, dtype=np.int64) - np.repeat(np.cumsum(counts) - counts, counts)).astype(np.uint32)
    seed_o = opaque_u32(seed)
    sampler = integrator.SAMPLERS[integrator.sampling]

    def body(setup, seed_o, ping, idx, d, w):
        return _traced(setup, integrator, seed_o, ping, idx, d, w, squares)

    # the recording's key names the body: one per kind of pass
    body.__qualname__ = f"row_allocation.{'moments' if squares else 'sums'}"
    out = None
    with dr.suspend_grad(), flushing():
        for a in range(0, row.size, lanes):
            ping, idx = mi.UInt32(row[a:a + lanes]), mi.UInt32(index[a:a + lanes])
            d, w = frozen_pass.emitted(setup.sensor.beam, sampler(seed_o, ping, idx))
            parts = frozen_pass.run(body, integrator, setup, seed_o, ping, idx, d, w)
            parts = [p.numpy().astype(np.float64) for p in (parts if squares else (parts,))]
            out = parts if out is None else [o + p for o, p in zip(out, parts)]
    return out


def _traced(setup, integrator, seed_o, ping, idx, d, w, squares):
    """One pass's path kernel: the lanes' rows ``ping`` and path numbers ``idx``, their emitted
    directions ``d`` and weights ``w`` drawn beforehand (`frozen_pass.emitted`)."""
    n_rows, n_bins = setup.sensor.n_pings, setup.sensor.n_bins
    samples = integrator.SAMPLERS[integrator.sampling](seed_o, ping, idx)
    sums = [ExactBins(n_rows * n_bins) for _ in range(2 if squares else 1)]
    bins = setup.bins

    def record(depth_k, rng, energy, valid, hit):
        b, valid = bins.index(rng, valid)
        at = bins.flat(ping, b)
        sums[0].add(energy, at, valid)
        if squares:
            sums[1].add(energy * energy, at, valid)

    integrator.sample(integrator.emitting(setup, d, w), ping, samples, record)
    totals = [s.total() for s in sums]
    return tuple(totals) if squares else totals[0]
