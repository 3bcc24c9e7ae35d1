"""The comparison run, `compare`, as its steps: check the settings, load the scene and the
integrators, calibrate, fill every time budget, get the reference, score, warn, write.

Nothing is created before the settings, the scene and the integrators are known to be good; the
output folder is made only for the reference and the results (`mitsonar.jobs.compare.output`).
"""
from __future__ import annotations

import datetime
import itertools
import math
import os
import platform
import time
from dataclasses import dataclass

import numpy as np

from mitsonar.jobs.compare.budget import KernelWatch, PathClock, budget_warning, calibrate, plan_spp, search_spp
from mitsonar.jobs.compare.common import (CALIBRATION_START_SPP, DEFAULT_BUDGETS, DEFAULT_INTEGRATORS, DEFAULT_REFERENCE_FACTOR,
                     DEFAULT_REPEATS, MAX_SPP, REFERENCE_INTEGRATOR, REFERENCE_NOISE_WARNING, SEED_STRIDE, WARM_SEED,
                     COMPARE_SETTINGS, CompareError, labels_for, run_params, shown_as)
from mitsonar.jobs.compare.figures import plot_convergence, plot_polar_grid
from mitsonar.jobs.compare.integrators import describe, load_integrator, min_spp
from mitsonar.jobs.compare.metrics import equal_time_ratios, region_mask, score, self_errors, summarise
from mitsonar.jobs.compare.output import OutputFolder, check_output_folder, write_json
from mitsonar.jobs.compare.parsing import parse_budgets, parse_integrators
from mitsonar.jobs.compare.reference import load_or_render_reference, render_reference, scene_digest
from mitsonar.sim.scene import sonar_of


@dataclass
class Settings:
    """The checked arguments of `compare` (see there)."""

    scene_path: str
    names: list
    labels: list
    budgets: list
    output_dir: str
    reference_spp: int | None
    seed: int
    repeats: int
    max_depth: int | None
    params: dict
    regions: dict
    reference_factor: float
    calibration_seconds: float | None
    warm: bool
    plots: bool
    paths_per_second: float | None = None
    #: label -> the parameters it runs with (`run_params`: the comparison's settings, then ``params``)
    run_params: dict | None = None


def check_settings(scene_path, integrators, budgets, output_dir, reference_spp, seed, repeats, max_depth,
                   integrator_params, regions, reference_factor, calibration_seconds, warm, plots,
                   paths_per_second=None) -> Settings:
    """`compare`'s arguments checked and normalised; `CompareError` (one line) for the first bad
    one. Reads and creates nothing but checks that the scene file exists and that the output
    folder can be made."""
    names = parse_integrators(integrators)
    budgets = parse_budgets(budgets)
    labels = labels_for(names)
    params = dict(integrator_params or {})
    unknown = sorted(set(params) - set(labels))
    if unknown:
        raise CompareError(f"--param for {unknown[0]!r}, which is not one of the integrators ({', '.join(labels)})")
    regions = dict(regions or {})
    for rn, (lo, hi) in regions.items():
        if not (math.isfinite(lo) and math.isfinite(hi) and hi > lo):
            raise CompareError(f"region {rn!r}: need lo < hi in metres, got {lo}:{hi}")
    if not (isinstance(repeats, (int, np.integer)) and repeats >= 1):
        raise CompareError(f"--repeats {repeats!r}: need a positive integer")
    if reference_spp is not None and not (isinstance(reference_spp, (int, np.integer))
                                          and 2 <= reference_spp <= MAX_SPP):
        raise CompareError(f"--reference-spp {reference_spp!r}: need an integer from 2 to {MAX_SPP}")
    if not (reference_factor > 0 and math.isfinite(reference_factor)):
        raise CompareError(f"--reference-factor {reference_factor!r}: need a positive number")
    if calibration_seconds is not None and not (calibration_seconds > 0 and math.isfinite(calibration_seconds)):
        raise CompareError(f"--calibration-seconds {calibration_seconds!r}: need a positive number")
    if paths_per_second is not None and not (isinstance(paths_per_second, (int, float, np.integer, np.floating))
                                             and paths_per_second > 0 and math.isfinite(paths_per_second)):
        raise CompareError(f"--paths-per-second {paths_per_second!r}: need a positive number")
    if not (isinstance(seed, (int, np.integer)) and seed >= 0):
        raise CompareError(f"--seed {seed!r}: need a non-negative integer")
    scene_path = os.fspath(scene_path)
    if not os.path.isfile(scene_path):
        raise CompareError(f"scene file {scene_path!r} does not exist")
    output_dir = os.fspath(output_dir)
    check_output_folder(output_dir)
    return Settings(scene_path, names, labels, budgets, output_dir, reference_spp, int(seed), int(repeats),
                    max_depth, params, regions, float(reference_factor), calibration_seconds, bool(warm), bool(plots),
                    None if paths_per_second is None else float(paths_per_second),
                    {lab: run_params(n, params.get(lab)) for lab, n in zip(labels, names)})


@dataclass
class Bench:
    """The loaded scene, its sonar and the integrators to compare."""

    scene: object
    sensor: object
    scene_bytes: bytes
    max_depth: int
    integrators: dict  # label -> integrator object
    min_spp: dict  # label -> least spp it accepts
    calibration_seconds: float
    #: What times the renders: ``time.perf_counter``, or a `PathClock` (seconds = paths traced / rate).
    clock: object = time.perf_counter

    def render(self, integrator, spp, seed):
        """One histogram (n_pings, n_bins) of ``integrator`` at ``spp`` with ``seed`` (counted by a
        `PathClock`, with the paths an integrator traced beyond ``spp``: its plan's
        ``extra_paths_per_row``, the adaptive allocation's pilot)."""
        integrator.last_plan = {}
        hist = integrator.render_histogram(self.scene, self.sensor, seed=seed, spp=int(spp), max_depth=self.max_depth)
        if isinstance(self.clock, PathClock):
            extra = int(integrator.last_plan.get("extra_paths_per_row", 0))
            self.clock.count(int(spp) + extra, self.sensor.n_pings)
        return hist


def load_bench(s: Settings) -> Bench:
    """Load the scene, its first sonar and every integrator (`CompareError` for a bad one)."""
    import mitsonar

    with open(s.scene_path, "rb") as fh:
        scene_bytes = fh.read()
    scene = mitsonar.load_scene(s.scene_path)
    sensor = sonar_of(scene, 0)
    max_depth = s.max_depth
    if max_depth is None:
        max_depth = int(getattr(scene.integrator(), "max_depth", 5) or 5)
    objs = {lab: load_integrator(n, s.run_params[lab]) for lab, n in zip(s.labels, s.names)}
    cal = s.calibration_seconds if s.calibration_seconds is not None else min(0.5, s.budgets[0] / 2)
    clock = time.perf_counter if s.paths_per_second is None else PathClock(s.paths_per_second)
    return Bench(scene, sensor, scene_bytes, int(max_depth), objs,
                 {lab: min_spp(o, sensor.n_pings) for lab, o in objs.items()}, float(cal), clock)


def calibrate_all(bench: Bench, s: Settings, say) -> dict:
    """`calibrate` every integrator (from its least spp, at least `CALIBRATION_START_SPP`)."""
    out = {}
    for lab in s.labels:
        say(f"{lab}: calibrating (longest timed render {bench.calibration_seconds:.3g} s)")
        obj = bench.integrators[lab]
        out[lab] = calibrate(lambda spp, o=obj: bench.render(o, spp, WARM_SEED), bench.calibration_seconds,
                             start_spp=max(CALIBRATION_START_SPP, bench.min_spp[lab]), warm_each=s.warm,
                             clock=bench.clock)
    return out


def time_runs(bench: Bench, s: Settings, calibrations, say) -> list:
    """Every integrator at every budget: the spp search (`search_spp`) and the repeats.

    Returns one dict per (integrator, budget) with its histograms (``hists``), scored later,
    once the reference is known (an automatic reference is sized by the spp path tracing
    reached). Every timed render refines the next choice of spp (the runs are longer than the
    calibration renders, so timed more reliably), except renders that compiled kernels.
    """
    watch = KernelWatch()
    pending = []
    for k, lab in enumerate(s.labels):
        obj = bench.integrators[lab]
        counter = itertools.count(k * SEED_STRIDE + 1)

        def timed(spp, obj=obj, counter=counter):
            seed = (s.seed + next(counter)) & 0xFFFFFFFF
            with watch:
                t0 = bench.clock()
                hist = bench.render(obj, spp, seed)
                dt = bench.clock() - t0
            # what the render ran (sonar_mlt: its chains; sonar_tof: its allocation)
            return hist, dt, watch.compiled, watch.compile_seconds, seed, dict(getattr(obj, "last_plan", None) or {})

        def warm_up(spp, obj=obj):
            # Some integrators compile more kernels on a second call than on the first.
            compiled = 0
            for _ in range(3):
                with watch:
                    bench.render(obj, spp, WARM_SEED)
                compiled += watch.compiled
                if not watch.compiled:
                    break
            return compiled

        timings = [list(p) for p in calibrations[lab]["points"]]
        previous = None
        for budget in s.budgets:
            found = search_spp(timed, budget, timings, bench.min_spp[lab], previous, warm_up if s.warm else None)
            spp = found["spp"]
            renders = [found["render"]] + [timed(spp) for _ in range(s.repeats - 1)]
            timings.extend([spp, r[1]] for r in renders[1:] if not r[2])
            previous = (budget, spp)
            pending.append({"integrator": lab, "budget_s": float(budget), "spp": int(spp),
                            "seeds": [r[4] for r in renders], "seconds": [r[1] for r in renders],
                            "hists": [r[0] for r in renders], "compiled_kernels": [r[2] for r in renders],
                            "compile_seconds": [r[3] for r in renders],
                            "warmup_compiled_kernels": found["warmup_compiled_kernels"],
                            "attempts": found["attempts"], "plan": renders[0][5]})
            n_compiled = sum(r[2] for r in renders)
            say(f"{lab}: budget {budget:g} s -> {spp} spp, {float(np.mean([r[1] for r in renders])):.3g} s"
                + (f" ({len(found['attempts'])} tries)" if len(found["attempts"]) > 1 else "")
                + (f" ({n_compiled} kernel(s) compiled while timed)" if n_compiled else ""))
    return pending


def reference_spp_for(bench: Bench, s: Settings, pending) -> tuple:
    """``(spp, auto)``: ``s.reference_spp``, or (auto) ``reference_factor`` times the spp plain
    ``sonar_tof`` reached at the largest budget (calibrated here if it is not compared), rounded
    up to a power of two."""
    if s.reference_spp is not None:
        return int(s.reference_spp), False
    plain = [lab for lab, n in zip(s.labels, s.names) if n == REFERENCE_INTEGRATOR and not s.run_params[lab]]
    if plain:
        reached = max(p["spp"] for p in pending if p["integrator"] == plain[0])
    else:
        tof = load_integrator(REFERENCE_INTEGRATOR)
        cal = calibrate(lambda spp: bench.render(tof, spp, WARM_SEED), bench.calibration_seconds, clock=bench.clock)
        reached = plan_spp(cal["points"], s.budgets[-1])
    need = s.reference_factor * reached
    return int(min(MAX_SPP, 1 << max(1, math.ceil(math.log2(max(need, 2)))))), True


def score_runs(pending, ref, ref_info, masks, say) -> tuple:
    """``(runs, first_renders)``: every pending run scored (`score`, `summarise`) and the first
    repeat's histogram of each ``(label, budget)``."""
    self_l2 = ref_info["self_rel_l2"]
    region_self = {rn: ref_info["regions"][rn]["self_rel_l2"] for rn in masks}
    runs, first_renders = [], {}
    for p in pending:
        hists = p.pop("hists")
        metrics = [score(h, ref, self_l2, masks, region_self) for h in hists]
        first_renders[(p["integrator"], p["budget_s"])] = hists[0]
        run = summarise(p["integrator"], p["budget_s"], p["spp"], p["seeds"], p["seconds"], metrics, masks)
        run.update({k: p[k] for k in ("compiled_kernels", "compile_seconds", "warmup_compiled_kernels", "attempts",
                                      "plan")})
        runs.append(run)
        say(f"{run['integrator']}: budget {run['budget_s']:g} s, {run['spp']} spp: rel L2 {run['rel_l2']:.4g}, "
            f"rel L1 {run['rel_l1']:.4g}")
    return runs, first_renders


def collect_warnings(runs, labels, self_l2, warm) -> list:
    """One line each: a noisy reference, kernels compiled while timed or warming up, runs off
    their time budget (`budget_warning`)."""
    warnings = []
    finite = [r["rel_l2"] for r in runs if math.isfinite(r["rel_l2"])]
    if finite and math.isfinite(self_l2) and self_l2 > REFERENCE_NOISE_WARNING * min(finite):
        warnings.append(f"the reference's own relative L2 error ({self_l2:.3g}) is not well below the smallest "
                        f"error measured ({min(finite):.3g}): raise --reference-spp (errors are compared "
                        "debiased, but noisily)")
    for lab in labels:
        mine = [r for r in runs if r["integrator"] == lab]
        n_timed = sum(sum(r["compiled_kernels"]) for r in mine)
        if n_timed:
            secs = sum(sum(r["compile_seconds"]) for r in mine)
            warnings.append(f"{lab} compiled {n_timed} kernel(s) ({secs:.2g} s of compilation) during its timed "
                            "renders: its kernels depend on spp (or seed), so every new spp pays a compilation"
                            + ("" if warm else "; --warm times steady-state renders instead"))
        n_warm = sum(r["warmup_compiled_kernels"] or 0 for r in mine)
        if n_warm:
            warnings.append(f"{lab} compiled {n_warm} kernel(s) in the untimed warm-up renders at new spp "
                            "(not counted in its seconds): its kernels depend on spp")
    off = budget_warning(runs)
    if off:
        warnings.append(off)
    return warnings


def build_result(s: Settings, bench: Bench, calibrations, ref_info, auto, runs, warnings) -> dict:
    """The dict written to ``compare.json`` (fields in `mitsonar.jobs.compare`'s docstring)."""
    import drjit as dr
    import mitsuba as mi

    from mitsonar._version import __version__

    sensor = bench.sensor
    return {
        "tool": "mitsonar compare",
        "settings": {
            "scene": s.scene_path, "integrators": s.labels, "integrator_types": s.names, "budgets_s": s.budgets,
            "repeats": s.repeats, "seed": s.seed, "max_depth": bench.max_depth,
            "reference_spp": int(ref_info["spp"]), "reference_spp_auto": auto,
            "reference_factor": s.reference_factor, "calibration_seconds": bench.calibration_seconds,
            "warm": s.warm, "paths_per_second": s.paths_per_second,
            "regions": {k: list(v) for k, v in s.regions.items()}, "integrator_params": s.params,
            "seeds": f"render r (1, 2, ... over budgets, searches and repeats) of the k-th integrator (0, 1, ...) "
                     f"uses seed + k * {SEED_STRIDE} + r",
        },
        "scene": {"path": os.path.abspath(s.scene_path), "sha256": scene_digest(bench.scene_bytes),
                  "n_pings": int(sensor.n_pings), "n_bins": int(sensor.n_bins),
                  "range_min": float(sensor.range_min), "range_max": float(sensor.range_max),
                  "bearings_deg": [float(b) for b in sensor.bearings_deg()]},
        "environment": {"mitsonar": __version__, "mitsuba": mi.__version__, "drjit": dr.__version__,
                        "variant": mi.variant(), "python": platform.python_version(),
                        "platform": platform.platform(), "cpu_count": os.cpu_count(),
                        "date": datetime.datetime.now(datetime.timezone.utc).isoformat(timespec="seconds")},
        "reference": ref_info,
        "integrators": {lab: {"type": n, "params": s.run_params[lab], "shown_as": shown_as(lab, s.run_params[lab]),
                              "compare_settings": {k: v for k, v in COMPARE_SETTINGS.get(n, {}).items()
                                                   if k not in s.params.get(lab, {})},
                              "description": describe(bench.integrators[lab]), "calibration": calibrations[lab]}
                        for lab, n in zip(s.labels, s.names)},
        "runs": runs,
        "equal_time": equal_time_ratios(runs, s.labels, s.budgets, list(s.regions)),
        "files": {},
        "warnings": warnings,
    }


def write_outputs(folder: OutputFolder, result, bench: Bench, ref, first_renders, plots) -> None:
    """``renders.npz``, the pictures (``plots``) and ``compare.json``, staged in ``folder`` and
    committed together; fills ``result["files"]``."""
    sensor, s = bench.sensor, result["settings"]
    files = result["files"]
    arrays = {"reference": ref.astype(np.float32), "ranges": sensor.bin_centres(), "bearings_deg": sensor.bearings_deg()}
    arrays.update({f"{lab}@{budget:g}s": h.astype(np.float32) for (lab, budget), h in first_renders.items()})
    np.savez_compressed(folder.stage("renders.npz"), **arrays)
    files["renders"] = folder.final("renders.npz")
    if plots:
        plot_convergence(result, folder.stage("convergence.png"))
        files["convergence"] = folder.final("convergence.png")
        plot_polar_grid(sensor, ref, first_renders, s["integrators"], s["budgets_s"], result["runs"],
                        folder.stage("polar.png"), result["reference"])
        files["polar"] = folder.final("polar.png")
    files["json"] = folder.final("compare.json")
    write_json(result, folder.stage("compare.json"))
    folder.commit()


def compare(scene_path, integrators=DEFAULT_INTEGRATORS, budgets=DEFAULT_BUDGETS, output_dir="cmp",
            reference_spp=None, seed=0, repeats=DEFAULT_REPEATS, max_depth=None, integrator_params=None,
            regions=None, reference_factor=DEFAULT_REFERENCE_FACTOR, calibration_seconds=None, warm=False,
            plots=True, log=None, paths_per_second=None) -> dict:
    """Compare sonar integrators at equal time against a cached ``sonar_tof`` reference.

    =================== =======================================================================
    scene_path          Mitsuba XML file with a ``sonar`` sensor
    integrators         plugin names (or ``"a,b"``); the first is the baseline of the ratios.
                        A name given twice is labelled ``name#2`` (e.g. to test the tool)
    budgets             seconds per render (or ``"2,4,8,16"``)
    output_dir          folder for the results and the cached reference (created, and removed
                        again if it was created and the run fails)
    reference_spp       paths per ping of the reference; None: ``reference_factor`` times the
                        spp sonar_tof reached at the largest budget, rounded up to a power of
                        two, or any larger reference already cached for the same key
    seed                base seed: render r (1, 2, ...) of integrator k (0, 1, ...) uses
                        seed + k * 2^20 + r; the reference uses seeds from 2^30 + 2 seed
    repeats             renders per (integrator, budget), each with its own seed
    max_depth           surface bounces for every render; None: the scene integrator's (or 5)
    integrator_params   ``{label: {name: value}}`` extra plugin parameters; they win over the
                        comparison's own (`COMPARE_SETTINGS`: ``sonar_mlt`` runs its chains,
                        ``split="off"``)
    regions             ``{name: (lo, hi)}`` range windows (metres) also scored on their own
    reference_factor    see ``reference_spp``
    calibration_seconds length of the longest calibration render; None: min(0.5, budget_min / 2)
    warm                render once, untimed, at every new spp before timing (calibration
                        included): steady-state speed of an integrator that compiles kernels
                        per spp. Off: wall-clock time, compilations included (and reported)
    plots               write ``convergence.png`` and ``polar.png``
    paths_per_second    None: time renders by the wall clock. A number R: by a deterministic
                        `PathClock` instead: a render of spp paths per ping over P pings takes
                        spp * P / R seconds, so a budget B fixes spp = B * R / P (equal work,
                        reproducible on any machine and load; for tests). Every field is as
                        with the wall clock; ``seconds`` are then modelled, not measured
    log                 callable taking one line of progress, or None; with it, a progress bar
                        is drawn on stderr while the reference renders (on a terminal only).
                        The warnings are the result's ``warnings``, not logged
    =================== =======================================================================

    Returns the dict written to ``output_dir/compare.json`` (fields in `mitsonar.jobs.compare`'s
    docstring). Raises `CompareError` (one line) for bad input, before anything is created.
    """
    s = check_settings(scene_path, integrators, budgets, output_dir, reference_spp, seed, repeats, max_depth,
                       integrator_params, regions, reference_factor, calibration_seconds, warm, plots,
                       paths_per_second)
    say = log or (lambda line: None)
    bench = load_bench(s)
    calibrations = calibrate_all(bench, s, say)
    pending = time_runs(bench, s, calibrations, say)
    ref_spp, auto = reference_spp_for(bench, s, pending)
    with OutputFolder(s.output_dir) as folder:
        ref, ref_diff, ref_info = load_or_render_reference(
            bench.scene, bench.sensor, bench.scene_bytes, folder.path, ref_spp, s.seed, bench.max_depth, auto=auto,
            log=say, progress=log is not None, render=render_reference)
        ranges = bench.sensor.bin_centres()
        masks = {rn: region_mask(ranges, lo, hi) for rn, (lo, hi) in s.regions.items()}
        ref_info["regions"] = {rn: self_errors(ref, ref_diff, m) for rn, m in masks.items()}
        runs, first_renders = score_runs(pending, ref, ref_info, masks, say)
        warnings = collect_warnings(runs, s.labels, ref_info["self_rel_l2"], s.warm)
        # the warnings are the result's (the command line prints them once, with its table)
        result = build_result(s, bench, calibrations, ref_info, auto, runs, warnings)
        write_outputs(folder, result, bench, ref, first_renders, s.plots)
    return result


__all__ = ["Bench", "Settings", "check_settings", "compare", "load_bench"]
