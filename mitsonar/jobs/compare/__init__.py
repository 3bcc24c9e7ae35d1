"""Integrators at equal time: error against a cached high-sample reference versus seconds.

`compare` times every integrator at growing spp with its kernels compiled (calibration), then for
every time budget searches the spp that fills it (a local power law of seconds versus spp through
the timings so far; a render outside 0.8-1.2 of its budget is tried again with a corrected spp),
renders ``repeats`` times with different seeds, renders (or reads from the cache in the output
folder) a high-sample ``sonar_tof`` reference, and scores every render against it. Both sonar
integrators read ``spp`` as path evaluations per ping, so equal spp is roughly equal work; the
budgets make it equal time. Kernel compilations during timed renders are counted (Dr.Jit's
kernel history) and reported: an integrator whose kernels depend on spp pays one per new spp.

``sonar_mlt`` runs its Metropolis chains over every echo (``split="off"``, `COMPARE_SETTINGS`)
unless ``integrator_params`` sets its ``split``: its own default, ``split=0``, is the path
tracer's scan, and a comparison with it would compare ``sonar_tof`` with itself.

Errors are over range bins: ``rel_l2 = ||est - ref||_2 / ||ref||_2`` and
``rel_l1 = sum|est - ref| / sum|ref|``, over the whole scan and per ping. Over repeats they are
combined as a root mean square (which estimates the expected squared error). The reference has
noise of its own: it is rendered as two independent halves, whose difference gives its error
(``self_rel_l2``), and ``rel_l2_debiased = sqrt(rel_l2^2 - self_rel_l2^2)`` removes it (the two
errors are independent, so their squares add).

Modules: `.engine` (the run, step by step), `.budget` (timing, spp planning and search),
`.reference` (the reference and its cache), `.metrics` (errors and ratios), `.figures`,
`.output` (the output folder), `.parsing` (the command line's values), `.integrators`,
`.common` (defaults, seeds, the error type).

Output folder (created only once the inputs are checked, removed if this run created it and
fails; its files are written under temporary names and renamed at the end):

===================================== =========================================================
file                                  content
===================================== =========================================================
``compare.json``                      everything below, with the settings, the integrators'
                                      descriptions and calibrations, machine and versions
``convergence.png``                   error versus measured seconds, log-log, one line per
                                      integrator (rel L2, rel L1, one panel per region)
``polar.png``                         polar intensity images (dB) side by side: the reference
                                      and every integrator at every budget (first repeat)
``renders.npz``                       the reference and the first repeat of every run (float32)
``reference_<key>_spp<N>.npz``        the cached reference (mean and difference of its two
                                      halves); ``key`` hashes the scene file's bytes, seed,
                                      max_depth, mitsonar version and variant
===================================== =========================================================

``compare.json`` fields:

======================== ===========================================================================
field                    meaning
======================== ===========================================================================
``settings``             scene path, integrators (labels), integrator_types, budgets_s, repeats, seed,
                         max_depth, reference_spp, reference_spp_auto, reference_factor,
                         calibration_seconds, warm, paths_per_second (null: wall-clock seconds;
                         a number: seconds = paths traced / it, see `PathClock`), regions,
                         integrator_params
``scene``                path, sha256, n_pings, n_bins, range_min, range_max, bearings_deg
``environment``          mitsonar/mitsuba/drjit versions, variant, python, platform, cpu count, date
``reference``            integrator, spp, seeds, seconds, max_depth, self_rel_l2, self_rel_l1,
                         regions {name: {self_rel_l2, self_rel_l1}}, file, key, from_cache
``integrators``          per label: type, params (what it ran with: `COMPARE_SETTINGS`'s, then the
                         user's), shown_as (the label with them, as the printed table has it:
                         ``sonar_mlt (split=off)``), compare_settings (those the comparison set),
                         description (the plugin's ``to_string``), calibration (points
                         [[spp, seconds], ...]: every timing, the two largest spp timed several
                         times; warmup_s, compiling)
``runs``                 one per (integrator, budget): integrator, budget_s (asked), spp, seeds,
                         seconds (each repeat), seconds_mean (achieved), seconds_vs_budget
                         (seconds_mean / budget_s), rel_l2, rel_l1, rel_l2_debiased (RMS over
                         repeats), rel_l2_each, rel_l1_each, per_ping_rel_l2, per_ping_rel_l1
                         (RMS over repeats; null where the reference ping is empty), regions
                         {name: {rel_l2, rel_l1, rel_l2_debiased}}, attempts ([[spp, seconds],
                         ...]: the search for the spp that fills the budget; the last one is the
                         first repeat), compiled_kernels and compile_seconds (per repeat:
                         Dr.Jit kernels compiled while timed), warmup_compiled_kernels (``warm``),
                         plan (the first repeat's ``last_plan``: ``sonar_mlt``'s bootstrap, chains
                         and mutations per ping, ``sonar_tof``'s allocation)
``equal_time``           per budget, for every integrator against the first (the baseline):
                         ``ratio_raw = err_base / err`` and ``ratio_time_adjusted`` (each error
                         scaled by sqrt(its measured seconds), i.e. at exactly equal time for
                         1/sqrt(t) convergence), on rel_l2_debiased; > 1 means lower error than
                         the baseline. Regions likewise.
``files``                the files written
``warnings``             one line each: a reference whose own error is not well below the errors
                         measured, kernels compiled while timed, runs whose achieved seconds differ
                         from their budget by more than 20 %
======================== ===========================================================================

The scene file's bytes are hashed, not files it refers to (meshes, beam tables): change those and
delete the cached reference.
"""
from __future__ import annotations

from mitsonar.jobs.compare.budget import (BETA_RANGE, BUDGET_TOLERANCE, MAX_ATTEMPTS, TIME_TOLERANCE, KernelWatch, PathClock,
                     budget_warning, calibrate, off_budget, plan_spp)
from mitsonar.jobs.compare.common import (CALIBRATION_START_SPP, DEFAULT_BUDGETS, DEFAULT_INTEGRATORS, DEFAULT_REFERENCE_FACTOR,
                     DEFAULT_REPEATS, MAX_SPP, REFERENCE_INTEGRATOR, REFERENCE_NOISE_WARNING, REFERENCE_SEED_OFFSET,
                     SEED_STRIDE, COMPARE_SETTINGS, CompareError, jsonable, labels_for)
from mitsonar.jobs.compare.engine import compare
from mitsonar.jobs.compare.figures import plot_convergence, plot_polar_grid, scan_from_histogram
from mitsonar.jobs.compare.integrators import load_integrator
from mitsonar.jobs.compare.metrics import equal_time_ratios, error_metrics, self_errors
from mitsonar.jobs.compare.output import write_json
from mitsonar.jobs.compare.reference import (cached_references, load_or_render_reference, reference_key, reference_path,
                        render_reference, scene_digest)

#: Names that left this module, and their new home. Importing them from here still works for one
#: release and warns (DeprecationWarning).
MOVED = {name: "mitsonar.jobs.compare.parsing"
         for name in ("parse_budgets", "parse_integrators", "parse_params", "parse_regions")}


def __getattr__(name):
    if name in MOVED:
        import warnings

        from mitsonar.jobs.compare import parsing

        warnings.warn(f"mitsonar.jobs.compare.{name} has moved to {MOVED[name]}.{name}; the old import path "
                      "goes away in the next release", DeprecationWarning, stacklevel=2)
        return getattr(parsing, name)
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")


__all__ = ["BETA_RANGE", "BUDGET_TOLERANCE", "CALIBRATION_START_SPP", "COMPARE_SETTINGS", "CompareError", "DEFAULT_BUDGETS",
           "DEFAULT_INTEGRATORS", "DEFAULT_REFERENCE_FACTOR", "DEFAULT_REPEATS", "KernelWatch", "MAX_ATTEMPTS",
           "MAX_SPP", "PathClock", "REFERENCE_INTEGRATOR", "REFERENCE_NOISE_WARNING", "REFERENCE_SEED_OFFSET",
           "SEED_STRIDE", "TIME_TOLERANCE", "budget_warning", "cached_references", "calibrate", "compare",
           "equal_time_ratios", "error_metrics", "jsonable", "labels_for", "load_integrator", "load_or_render_reference",
           "off_budget", "plan_spp", "plot_convergence", "plot_polar_grid", "reference_key", "reference_path",
           "render_reference", "scan_from_histogram", "scene_digest", "self_errors", "write_json"]
