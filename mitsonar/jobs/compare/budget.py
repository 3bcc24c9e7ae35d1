"""Time budgets to spp: timing renders (calibration), planning the spp of a budget, searching it.

Render time is modelled locally as a power law ``seconds = a spp^beta`` through two measured
points (`plan_spp`). It is close to linear (beta = 1) at large spp and flatter where launch costs
dominate (a Metropolis integrator's mutations are one launch each), so beta is clamped to
`BETA_RANGE` and a flat stretch is never extrapolated as free. Timings on a shared machine are
noisy (another process adds time to a render, never removes it), so the calibration times its
two largest spp several times and the plan takes the median of repeated timings.
"""
from __future__ import annotations

import math
import time

import numpy as np

from mitsonar.jobs.compare.common import CALIBRATION_START_SPP, MAX_SPP

#: A timed render within these fractions of its budget is accepted; otherwise its spp is chosen
#: again from all timings so far (at most MAX_ATTEMPTS renders per budget). Same band as
#: TIME_TOLERANCE, so an accepted render is not reported as off its budget unless the search
#: ran out of attempts.
BUDGET_TOLERANCE = (0.8, 1.2)
MAX_ATTEMPTS = 4
#: Bounds on the local exponent of seconds ~ spp^beta used to extrapolate.
BETA_RANGE = (0.7, 1.3)
#: Timings of each of the calibration's two largest spp (the median is used).
CALIBRATION_TRIES = 3
#: A run whose mean measured seconds differ from its budget by more than this fraction is reported.
TIME_TOLERANCE = 0.2


class PathClock:
    """A deterministic clock: seconds are the paths traced so far over ``paths_per_second``.

    `compare` with ``paths_per_second`` times its renders by this clock instead of the wall clock
    (``mitsonar compare --paths-per-second``): a render of ``spp`` paths per ping over ``n_pings``
    pings "takes" ``spp * n_pings / paths_per_second`` seconds, whatever the machine and its load
    (plus the paths an integrator traces beyond ``spp``, the adaptive allocation's pilot: the
    engine counts them from the render's plan).
    The calibration, the spp search and every field of the results are the same as with the wall
    clock, but a budget then fixes the spp (equal paths, not equal time), and a run is reproducible
    on any machine: for tests, and for comparing integrators at equal work. Calling the clock
    gives the seconds so far (as ``time.perf_counter`` does); `count` adds a render's paths.
    """

    def __init__(self, paths_per_second: float):
        rate = float(paths_per_second)
        if not (rate > 0 and math.isfinite(rate)):
            raise ValueError(f"paths_per_second {paths_per_second!r}: need a positive number")
        self.paths_per_second, self.paths = rate, 0

    def count(self, spp: int, n_pings: int) -> None:
        """Add a render of ``spp`` paths per ping over ``n_pings`` pings."""
        self.paths += int(spp) * int(n_pings)

    def __call__(self) -> float:
        return self.paths / self.paths_per_second


class KernelWatch:
    """Context manager counting the Dr.Jit kernels compiled inside its block.

    After the block: ``launched`` (JIT kernels run), ``compiled`` (not found in Dr.Jit's kernel
    caches) and ``compile_seconds`` (their code generation and back-end time). It clears the
    kernel history on entry and restores the history flag on exit.
    """

    launched = compiled = 0
    compile_seconds = 0.0

    def __enter__(self):
        import drjit as dr

        self._was = dr.flag(dr.JitFlag.KernelHistory)
        dr.set_flag(dr.JitFlag.KernelHistory, True)
        dr.kernel_history()
        return self

    def __exit__(self, *exc):
        import drjit as dr

        history = [k for k in dr.kernel_history() if k["type"] == dr.KernelType.JIT]
        dr.set_flag(dr.JitFlag.KernelHistory, self._was)
        missed = [k for k in history if not k.get("cache_hit")]
        self.launched, self.compiled = len(history), len(missed)
        # Dr.Jit reports these times in milliseconds.
        self.compile_seconds = sum(k.get("codegen_time", 0.0) + k.get("backend_time", 0.0) for k in missed) / 1000
        return False


def calibrate(render, target_seconds, start_spp=CALIBRATION_START_SPP, warm_each=False,
              tries=CALIBRATION_TRIES, clock=time.perf_counter) -> dict:
    """Time renders of growing spp, kernels compiled, up to ``target_seconds``.

    ================ =============================================================================
    render           callable ``render(spp)``; it is called once to compile its kernels (not
                     timed), then with growing spp until a call takes ``target_seconds`` (and
                     at least two calls were timed)
    target_seconds   length of the longest timed call (keep it short next to the budgets)
    start_spp        spp of the first calls
    warm_each        also call ``render`` once, untimed, before timing each new spp (for an
                     integrator that compiles kernels per spp)
    tries            timings in all of each of the two largest spp reached (`plan_spp` takes
                     their median, so one render slowed by another process does not decide
                     the spp of every budget)
    clock            seconds, monotonic (``time.perf_counter``; a fake one in tests)
    ================ =============================================================================

    Timed calls that compiled kernels are repeated and listed apart. Returns ``points``
    ([[spp, seconds], ...], every timing, for `plan_spp`), ``warmup_s`` (the untimed first call,
    compilation included) and ``compiling`` (the timed calls that compiled kernels).
    """
    t0 = clock()
    render(start_spp)
    warmup = clock() - t0
    spp, points, compiling = int(start_spp), [], []
    watch = KernelWatch()

    def timed(s):
        with watch:
            t0 = clock()
            render(s)
            dt = clock() - t0
        # A call that compiled is not the integrator's speed: it is listed apart.
        (compiling if watch.compiled else points).append([s, dt])
        return None if watch.compiled else dt

    for _ in range(40):
        if warm_each and points:
            render(spp)
        dt = timed(spp)
        if dt is None:
            continue  # time this spp again, its kernels are compiled now
        if (dt >= target_seconds and len(points) >= 2) or spp >= MAX_SPP // 8:
            break
        # Grow towards the target without overshooting it by much on a noisy machine.
        spp = int(spp * min(8.0, max(2.0, 0.8 * target_seconds / max(dt, 1e-6))))
    for s in sorted({p[0] for p in points})[-2:]:
        for _ in range(int(tries) - 1):
            timed(s)
    if not points:
        points = compiling[-1:]  # an integrator that compiles on every call: all we have
    return {"points": points, "warmup_s": float(warmup), "compiling": compiling}


def plan_spp(points, budget_s: float) -> int:
    """The spp expected to take ``budget_s`` seconds, from timings ``[[spp, seconds], ...]``.

    Local power law between two timings: the one closest to the budget (in log time) and its
    nearest neighbour on the other side of the budget (else the next closest), with the exponent
    clamped to `BETA_RANGE`. Repeated spp use their median time. At least 1, at most `MAX_SPP`.
    """
    by_spp: dict = {}
    for spp, sec in points:
        by_spp.setdefault(int(spp), []).append(float(sec))
    pts = sorted((s, float(np.median(t))) for s, t in by_spp.items() if s > 0)
    pts = [(s, max(t, 1e-6)) for s, t in pts]
    if not pts:
        raise ValueError("plan_spp needs at least one timing")
    dist = [abs(math.log(t / budget_s)) for _, t in pts]
    order = sorted(range(len(pts)), key=dist.__getitem__)
    a = order[0]
    beta = 1.0
    if len(pts) > 1:
        above = pts[a][1] >= budget_s
        other_side = [i for i in order[1:] if (pts[i][1] >= budget_s) != above]
        b = other_side[0] if other_side else order[1]
        (sa, ta), (sb, tb) = pts[a], pts[b]
        if sa != sb and ta > 0 and tb > 0:
            beta = math.log(tb / ta) / math.log(sb / sa)
    beta = min(max(beta, BETA_RANGE[0]), BETA_RANGE[1]) if math.isfinite(beta) else 1.0
    sa, ta = pts[a]
    spp = sa * (budget_s / ta) ** (1.0 / beta)
    return int(min(max(spp, 1), MAX_SPP))


def spp_floor_after(previous, budget_s: float) -> int:
    """Least spp for ``budget_s`` given ``previous = (budget, spp)`` of a smaller budget.

    With ``seconds ~ spp^beta`` and beta at most ``BETA_RANGE[1]``, a budget k times larger
    affords at least ``k^(1 / BETA_RANGE[1])`` times the spp: a larger budget never gets about
    the spp of a smaller one because one timing was slowed by another process.
    """
    if previous is None:
        return 1
    prev_budget, prev_spp = previous
    return int(min(prev_spp * (budget_s / prev_budget) ** (1.0 / BETA_RANGE[1]), MAX_SPP))


def search_spp(timed, budget_s, timings, min_spp=1, previous=None, warm_up=None) -> dict:
    """Find the spp whose render takes ``budget_s`` seconds, rendering at most `MAX_ATTEMPTS` times.

    ============ ================================================================================
    timed        callable ``timed(spp)`` -> ``(hist, seconds, kernels_compiled, compile_seconds,
                 seed)``: one timed, scored render
    budget_s     the budget in seconds
    timings      ``[[spp, seconds], ...]`` so far; every render that compiled no kernel is
                 appended (its time says nothing about the integrator's speed otherwise)
    min_spp      the integrator's least spp (explicit chain counts and the like)
    previous     ``(budget, spp)`` of this integrator's previous, smaller budget (`spp_floor_after`)
    warm_up      callable ``warm_up(spp)`` -> kernels compiled, called once per new spp before
                 timing it, or None
    ============ ================================================================================

    A render within `BUDGET_TOLERANCE` of the budget is accepted, as is one at ``min_spp`` that
    is still too long, or the last attempt. Returns ``spp``, ``render`` (``timed``'s tuple of the
    accepted render), ``attempts`` ([[spp, seconds], ...], the accepted one last) and
    ``warmup_compiled_kernels`` (None without ``warm_up``).
    """
    attempts, tried = [], set()
    warm_compiled = None if warm_up is None else 0
    while True:
        spp = max(plan_spp(timings, budget_s), min_spp)
        if not attempts:
            spp = max(spp, spp_floor_after(previous, budget_s))
        elif spp == attempts[-1][0]:
            # The timings around the budget did not move the plan: step from the last try.
            spp = int(min(max(spp * budget_s / max(attempts[-1][1], 1e-6), min_spp), MAX_SPP))
        if warm_up is not None and spp not in tried:
            warm_compiled += warm_up(spp)
        tried.add(spp)
        render = timed(spp)
        dt, compiled = render[1], render[2]
        if not compiled:
            timings.append([spp, dt])
        attempts.append([spp, dt])
        ok = BUDGET_TOLERANCE[0] <= dt / budget_s <= BUDGET_TOLERANCE[1]
        at_floor = spp <= min_spp and dt > budget_s  # cannot go lower: the budget is too short
        if ok or at_floor or len(attempts) >= MAX_ATTEMPTS:
            return {"spp": spp, "render": render, "attempts": attempts, "warmup_compiled_kernels": warm_compiled}


def off_budget(runs, tolerance=TIME_TOLERANCE) -> list:
    """The runs whose mean measured seconds differ from their budget by more than ``tolerance``
    (a fraction of the budget)."""
    return [r for r in runs if abs(r["seconds_mean"] - r["budget_s"]) > tolerance * r["budget_s"]]


def budget_warning(runs, tolerance=TIME_TOLERANCE):
    """One line naming the runs `off_budget` finds (asked and measured seconds), or None."""
    off = off_budget(runs, tolerance)
    if not off:
        return None
    items = ", ".join(f"{r['integrator']} asked {r['budget_s']:g} s took {r['seconds_mean']:.3g} s" for r in off)
    return (f"{len(off)} run(s) off their time budget by more than {100 * tolerance:.0f} %: {items} (a busy "
            "machine, a compilation, a render time that is not linear in spp, or an spp floor set by the "
            "integrator's settings); their errors are compared time-adjusted in equal_time")


__all__ = ["BETA_RANGE", "BUDGET_TOLERANCE", "CALIBRATION_TRIES", "KernelWatch", "MAX_ATTEMPTS", "PathClock",
           "TIME_TOLERANCE", "budget_warning", "calibrate", "off_budget", "plan_spp", "search_spp", "spp_floor_after"]
