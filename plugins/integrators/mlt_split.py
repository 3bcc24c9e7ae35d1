"""``sonar_mlt``'s split of path space: path tracing for the bulk, Metropolis chains for the echoes
that only the image guide finds.

Metropolis sampling pays where a few narrow paths carry an echo (a target seen through a glossy
plate: ``hidden_target``, ``periscope``) and loses where path tracing with stratified emission is
already good (direct echoes of walls and floors: the box 6-10x, measured). So the echoes are
split by a deterministic function of the path, which keeps the sum unbiased: an echo is *hard*
when the path passed a chained vertex before it (a bounce after a mirror-like one, where
`image_guide` aims at the transducer's image; ``record``'s ``hard``), else *easy*. Path tracing
(Sobol emission, image guided, `samples.SobolSamples`) estimates the easy echoes, the Metropolis
chains (`sonar_mlt`) the hard ones:

    I = E_pt[easy echoes] + E_mlt[hard echoes].

The budget ``spp`` (path evaluations per row) is split by ``split``: a fixed share, or (``auto``)
by a pilot: the first ``spp / 8`` (at least 16) path-traced paths, which only choose (they are
not part of the estimate), estimate each class's variance per path,
``V_c = sum over bins of (E[e^2] - E[e]^2)``; the chains get the share
``sqrt(V_hard) / (sqrt(V_hard) + sqrt(V_easy))`` of the rest (the allocation that minimises the
summed variance of two independent estimators of equal cost per sample), at most `MAX_SHARE`, and
none when that is under `MIN_CHAIN_SPP` evaluations per row or the pilot found no hard echo. A
scene without mirror-like surfaces has no hard echo and gets no chains whatever ``split`` says:
every echo is path traced.
"""
from __future__ import annotations

import math

import drjit as dr
import mitsuba as mi

import numpy as np

from .common import tagging_hard
from .paths.exact_sum import ExactBins
from .paths.samples import SobolSamples, row_lanes
from .sonar_tof import MAX_LANES_PER_PASS, SonarTOFIntegrator

#: Fraction of ``spp`` the pilot traces (at least `MIN_PILOT` paths per row).
PILOT_FRACTION = 1.0 / 8.0
MIN_PILOT = 16
#: Most of the budget the chains may take, and the least worth running them for.
MAX_SHARE = 0.9
MIN_CHAIN_SPP = 64


def traced(integrator, setup, seed, start, count, moments=False):
    """Samples ``start .. start + count`` of every row, path traced (Sobol emission, the setup's
    guide): the summed energies per bin of the easy and the hard echoes, float64 arrays, and with
    ``moments`` their summed squares (per echo: a path's echoes rarely share a bin)."""
    n_rows, n_bins = setup.sensor.n_pings, setup.sensor.n_bins
    ping, samples = row_lanes(SobolSamples, n_rows, seed, start, count)
    # order-independent sums (`exact_sum`); the squares are float32, which is plenty for a variance
    sums = [ExactBins(n_rows * n_bins) for _ in range(4 if moments else 2)]
    bins = setup.bins

    def record(k, rng, energy, valid, hit, hard):
        b, valid = bins.index(rng, valid)
        at = bins.flat(ping, b)
        for i, keep in enumerate((valid & ~hard, valid & hard)):
            sums[i].add(energy, at, keep)
            if moments:
                sums[2 + i].add(energy * energy, at, keep)

    integrator.sample(tagging_hard(setup), ping, samples, record)
    totals = [s.total() for s in sums]
    dr.eval(totals)
    return [t.numpy() for t in totals]


def share(easy, hard, easy2, hard2, n):
    """The chains' share of the budget from a pilot of ``n`` paths per row (sums and summed squares
    of the two classes): the split of the module docstring."""
    if not hard.any() or n < 2:
        return 0.0
    v_easy = max(float((easy2 / n - (easy / n) ** 2).sum()), 0.0)
    v_hard = max(float((hard2 / n - (hard / n) ** 2).sum()), 0.0)
    if v_hard == 0.0:
        return 0.0
    return min(MAX_SHARE, math.sqrt(v_hard) / (math.sqrt(v_hard) + math.sqrt(v_easy)))


def path_traced(integrator, setup, seed, start, count, pose=None, progress=None, allocation="auto"):
    """Samples ``start .. start + count`` of every row with ``sonar_tof``'s own estimator (the same
    guide and depth): float64 ``(n_rows, n_bins)``, the mean over the ``count`` paths per row.

    That is the baseline's estimator, shared transmit paths included (`shared_beams`, where the
    head can share): with every echo path traced, ``sonar_mlt`` is ``sonar_tof``. (`traced`'s
    per-row paths are unbiased as well, but on a multibeam head they find a small target in the
    tails of the neighbouring receive beams only through rare emitted directions: on
    ``fls_array`` a t test of 8 renders saw them 14 % low.)

    ``allocation`` ``adaptive``, or ``auto`` on a large render (a whole render, ``start`` 0, on a
    head that does not share beams: per-row paths miss a multibeam's beam tails, above;
    `row_allocation.adaptive`): the pilot of ``sonar_tof``'s adaptive
    allocation chooses (its cost counted): `row_allocation.render`, ``sonar_tof``'s own
    ``allocation="adaptive"`` render, its plan copied to ``integrator.last_plan``."""
    tof = getattr(integrator, "_path_tracer", None)
    if tof is None:
        tof = integrator._path_tracer = mi.load_dict(
            {"type": "sonar_tof", "max_depth": integrator.max_depth, "guide": integrator.guide})
    from .paths import row_allocation
    from .paths.shared_beams import SharedFrame, can_share, same_pose

    n_rows, n_bins = setup.sensor.n_pings, setup.sensor.n_bins
    sharing = can_share(setup.sensor) and same_pose(setup.sensor, pose)
    if start == 0 and not sharing and row_allocation.adaptive(allocation, n_rows, count):
        out = row_allocation.render(tof, setup, seed, count, MAX_LANES_PER_PASS, progress)
        integrator.last_plan = dict(tof.last_plan)
        return out.numpy().reshape(n_rows, n_bins)
    if sharing:
        shared = SharedFrame(setup, pose)

        def one_pass(first, n):
            return tof._shared_pass(shared, seed, start + first, n)
    else:
        def one_pass(first, n):
            return tof._pass(setup, seed, start + first, n)
    return SonarTOFIntegrator.accumulate(count, MAX_LANES_PER_PASS // n_rows, one_pass,
                                         progress).numpy().reshape(n_rows, n_bins)


def render_split(integrator, setup, seed, spp, progress=None, pose=None):
    """The split render of ``integrator`` (a `sonar_mlt.SonarMLTIntegrator`): float64
    ``(n_rows, n_bins)``; the plan it chose in ``integrator.last_plan``.

    The chains' budget: ``split`` times ``spp`` (a number), what explicit chains, mutations or
    bootstrap ask (they fit ``spp``, checked by ``plan`` before any work), or (``auto``) the pilot's
    share of what the pilot leaves. The pilot's paths only choose: they are left out of the
    estimate, whose path count would otherwise depend on their own values (a ratio estimator's
    bias). A scene without mirrors has no hard echo (no chain can form), so it gets no chains."""
    n_rows, n_bins = setup.sensor.n_pings, setup.sensor.n_bins
    explicit = bool(integrator.chains or integrator.mutations or integrator.bootstrap)
    pilot, chosen = 0, 0.0
    if not setup.guide:
        n_chain = 0
    elif explicit:
        boot, chains, mutations = integrator.plan(n_rows, spp)
        n_chain = boot + chains * mutations
        chosen = n_chain / spp
    elif integrator.split == "auto":
        pilot = min(spp - 1, max(MIN_PILOT, int(spp * PILOT_FRACTION)))
        chosen = share(*traced(integrator, setup, seed, 0, pilot, moments=True), pilot) if pilot >= 2 else 0.0
        n_chain = int(chosen * (spp - pilot))
    else:
        chosen = float(integrator.split)
        n_chain = int(chosen * spp)
    if not explicit and n_chain < MIN_CHAIN_SPP:
        n_chain = 0
    n_traced = spp - pilot - n_chain
    if n_chain == 0:
        plan = {"split": chosen, "pilot": pilot, "traced": n_traced, "chains_spp": 0}
        integrator.last_plan = {}
        out = path_traced(integrator, setup, seed, pilot, n_traced, pose,
                          None if progress is None else (lambda done, total: progress(pilot + done, spp)),
                          allocation=getattr(integrator, "allocation", "auto"))
        # the adaptive allocation's plan (its own pilot as allocation_pilot)
        extra = {("allocation_pilot" if k == "pilot" else k): v for k, v in integrator.last_plan.items()}
        integrator.last_plan = {**plan, **extra}
        return out
    if n_traced < 1:   # explicit chains that take the whole budget: chains over every echo
        return integrator.metropolis(setup, seed, spp, progress=progress)
    # sonar_tof's pass loop over the paths after the pilot's; each pass gives [easy | hard] sums
    mean = SonarTOFIntegrator.accumulate(
        n_traced, MAX_LANES_PER_PASS // n_rows,
        lambda start, count: np.concatenate(traced(integrator, setup, seed, pilot + start, count)),
        None if progress is None else (lambda done, total: progress(pilot + done, spp)))
    easy, hard = np.split(mean, 2)
    plan = {"split": chosen, "pilot": pilot, "traced": n_traced, "chains_spp": n_chain}
    chained = integrator.metropolis(setup, seed, spp if explicit else n_chain, hard_only=True,
                                    progress=None if progress is None else
                                    (lambda d, t: progress(pilot + n_traced + d * n_chain // max(t, 1), spp)))
    integrator.last_plan = {**plan, **integrator.last_plan}
    return easy.reshape(n_rows, n_bins) + chained
