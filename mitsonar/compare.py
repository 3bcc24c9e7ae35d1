"""Integrators at equal time: error against a cached high-sample reference versus seconds.

`compare` times every integrator at growing spp with its kernels compiled (calibration), then for
every time budget searches the spp that fills it (a local power law of seconds versus spp through
the timings so far; a render outside 0.75-1.33 of its budget is tried again with a corrected
spp), renders ``repeats`` times with different seeds, renders (or reads from the cache in the
output folder) a high-sample ``sonar_tof`` reference, and scores every render against it. Both
sonar integrators read ``spp`` as path evaluations per ping, so equal spp is roughly equal work;
the budgets make it equal time. Kernel compilations during timed renders are counted (Dr.Jit's
kernel history) and reported: an integrator whose kernels depend on spp pays one per new spp.

Errors are over range bins: ``rel_l2 = ||est - ref||_2 / ||ref||_2`` and
``rel_l1 = sum|est - ref| / sum|ref|``, over the whole scan and per ping. Over repeats they are
combined as a root mean square (which estimates the expected squared error). The reference has
noise of its own: it is rendered as two independent halves, whose difference gives its error
(``self_rel_l2``), and ``rel_l2_debiased = sqrt(rel_l2^2 - self_rel_l2^2)`` removes it (the two
errors are independent, so their squares add).

Output folder:

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
                         calibration_seconds, warm, regions, integrator_params
``scene``                path, sha256, n_pings, n_bins, range_min, range_max, bearings_deg
``environment``          mitsonar/mitsuba/drjit versions, variant, python, platform, cpu count, date
``reference``            integrator, spp, seeds, seconds, max_depth, self_rel_l2, self_rel_l1,
                         regions {name: {self_rel_l2, self_rel_l1}}, file, key, from_cache
``integrators``          per label: type, params, description (the plugin's ``to_string``),
                         calibration (points [[spp, seconds], ...], warmup_s, compiling)
``runs``                 one per (integrator, budget): integrator, budget_s, spp, seeds, seconds
                         (each repeat), seconds_mean, rel_l2, rel_l1, rel_l2_debiased (RMS over
                         repeats), rel_l2_each, rel_l1_each, per_ping_rel_l2, per_ping_rel_l1
                         (RMS over repeats; null where the reference ping is empty), regions
                         {name: {rel_l2, rel_l1, rel_l2_debiased}}, attempts ([[spp, seconds],
                         ...]: the search for the spp that fills the budget; the last one is the
                         first repeat), compiled_kernels and compile_seconds (per repeat:
                         Dr.Jit kernels compiled while timed), warmup_compiled_kernels (``warm``)
``equal_time``           per budget, for every integrator against the first (the baseline):
                         ``ratio_raw = err_base / err`` and ``ratio_time_adjusted`` (each error
                         scaled by sqrt(its measured seconds), i.e. at exactly equal time for
                         1/sqrt(t) convergence), on rel_l2_debiased; > 1 means lower error than
                         the baseline. Regions likewise.
``files``                the files written
``warnings``             e.g. a reference whose own error is not well below the errors measured
======================== ===========================================================================

The scene file's bytes are hashed, not files it refers to (meshes, beam tables): change those and
delete the cached reference.
"""
from __future__ import annotations

import datetime
import glob
import hashlib
import json
import math
import os
import platform
import re
import time

import numpy as np

REFERENCE_INTEGRATOR = "sonar_tof"
DEFAULT_INTEGRATORS = ("sonar_tof", "sonar_mlt")
DEFAULT_BUDGETS = (2.0, 4.0, 8.0, 16.0)
DEFAULT_REPEATS = 2
#: With automatic reference spp the reference gets this many times the path-tracing work of the
#: largest budget: its own error is then 1/4 of that run's, and inflates it by only 3 %.
DEFAULT_REFERENCE_FACTOR = 16.0
#: Reference halves use seeds far from those of the runs (see SEED_STRIDE).
REFERENCE_SEED_OFFSET = 0x40000000
#: Render r (1, 2, ...) of the k-th integrator (0, 1, ...) uses seed + k * SEED_STRIDE + r: two
#: integrators never share a seed, so two sonar_tof entries never share their first paths.
SEED_STRIDE = 1 << 20
CALIBRATION_START_SPP = 256
MAX_SPP = 1 << 31  # sample indices are 32-bit
#: A reference whose own error exceeds this fraction of the smallest error measured is flagged.
REFERENCE_NOISE_WARNING = 0.5

_NAME = re.compile(r"^[A-Za-z_][A-Za-z0-9_]*$")


class CompareError(ValueError):
    """Bad input to the comparison; the message is one line for the user."""


# ------------------------------------------------------------------------------ input parsing
def parse_budgets(text) -> list[float]:
    """Time budgets in seconds from ``"2,4,8,16"`` (or a sequence of numbers), sorted, distinct.

    Raises `CompareError` unless every entry is a finite positive number.
    """
    items = text.split(",") if isinstance(text, str) else list(text)
    out = []
    for item in items:
        try:
            value = float(item.strip() if isinstance(item, str) else item)
        except (TypeError, ValueError):
            value = float("nan")
        if not (math.isfinite(value) and value > 0):
            raise CompareError(f"--budget {text if isinstance(text, str) else ','.join(map(str, items))!r}: "
                               f"{item!r} is not a positive number of seconds (expected e.g. 2,4,8,16)")
        out.append(value)
    if not out:
        raise CompareError("--budget: no budgets given (expected e.g. 2,4,8,16)")
    return sorted(set(out))


def parse_integrators(text) -> list[str]:
    """Integrator plugin names from ``"sonar_tof,sonar_mlt"`` (or a sequence of names)."""
    items = text.split(",") if isinstance(text, str) else list(text)
    names = [str(i).strip() for i in items]
    if not names or any(not n for n in names):
        raise CompareError(f"--integrators {text!r}: expected comma-separated plugin names, "
                           "e.g. sonar_tof,sonar_mlt")
    for n in names:
        if not _NAME.match(n):
            raise CompareError(f"--integrators: {n!r} is not an integrator plugin name")
    return names


def labels_for(names) -> list[str]:
    """Unique labels: the plugin name, then ``name#2``, ``name#3`` for repeats of it."""
    seen, out = {}, []
    for n in names:
        seen[n] = seen.get(n, 0) + 1
        out.append(n if seen[n] == 1 else f"{n}#{seen[n]}")
    return out


def _number(text):
    for conv in (int, float):
        try:
            return conv(text)
        except ValueError:
            continue
    return text


def parse_params(items) -> dict:
    """``LABEL.NAME=VALUE`` strings to ``{label: {name: value}}`` (numbers become int/float)."""
    out: dict = {}
    for item in items or []:
        m = re.match(r"^([A-Za-z_][\w#]*)\.([A-Za-z_]\w*)=(.*)$", item)
        if not m:
            raise CompareError(f"--param {item!r}: expected INTEGRATOR.NAME=VALUE, e.g. sonar_mlt.chains=1024")
        out.setdefault(m.group(1), {})[m.group(2)] = _number(m.group(3))
    return out


def parse_regions(items) -> dict:
    """``NAME=LO:HI`` strings (metres) to ``{name: (lo, hi)}``: bins with centre range in [lo, hi)."""
    out = {}
    for item in items or []:
        m = re.match(r"^([A-Za-z_][\w.-]*)=([^:]+):(.+)$", item)
        try:
            lo, hi = float(m.group(2)), float(m.group(3))
        except (AttributeError, ValueError):
            lo = hi = float("nan")
        if not (m and math.isfinite(lo) and math.isfinite(hi) and hi > lo):
            raise CompareError(f"--region {item!r}: expected NAME=LO:HI in metres with LO < HI, e.g. chamber=3.5:12")
        out[m.group(1)] = (lo, hi)
    return out


# ------------------------------------------------------------------------------ errors
def error_metrics(estimate, reference, reference_self_l2=0.0) -> dict:
    """Relative errors of one render against the reference.

    =================== ==========================================================================
    estimate            float array (n_pings, n_bins)
    reference           float array, same shape
    reference_self_l2   the reference's own relative L2 error, removed in ``rel_l2_debiased``
    =================== ==========================================================================

    Returns ``rel_l2``, ``rel_l1``, ``rel_l2_debiased`` (floats) and ``per_ping_rel_l2``,
    ``per_ping_rel_l1`` (float arrays, NaN where the reference ping is all zero).
    """
    est = np.asarray(estimate, np.float64)
    ref = np.asarray(reference, np.float64)
    if est.shape != ref.shape:
        raise CompareError(f"estimate shape {est.shape} differs from the reference's {ref.shape}")
    d = est - ref
    l2_ref, l1_ref = np.linalg.norm(ref), np.abs(ref).sum()
    rel_l2 = float(np.linalg.norm(d) / l2_ref) if l2_ref > 0 else float("nan")
    rel_l1 = float(np.abs(d).sum() / l1_ref) if l1_ref > 0 else float("nan")
    with np.errstate(divide="ignore", invalid="ignore"):
        ping_l2 = np.linalg.norm(d, axis=-1) / np.linalg.norm(ref, axis=-1)
        ping_l1 = np.abs(d).sum(-1) / np.abs(ref).sum(-1)
    empty = np.abs(ref).sum(-1) == 0
    ping_l2[empty] = np.nan
    ping_l1[empty] = np.nan
    return {"rel_l2": rel_l2, "rel_l1": rel_l1,
            "rel_l2_debiased": _debias(rel_l2, reference_self_l2),
            "per_ping_rel_l2": ping_l2, "per_ping_rel_l1": ping_l1}


def _debias(err, self_err):
    return float(math.sqrt(max(err * err - self_err * self_err, 0.0))) if math.isfinite(err) else err


def _rms(values):
    v = np.asarray(values, np.float64)
    return float(np.sqrt(np.mean(v * v))) if v.size else float("nan")


def _region_mask(ranges, lo, hi):
    return (ranges >= lo) & (ranges < hi)


# ------------------------------------------------------------------------------ calibration
#: A timed render within these fractions of its budget is accepted; otherwise its spp is chosen
#: again from all timings so far (at most MAX_ATTEMPTS renders per budget).
BUDGET_TOLERANCE = (0.75, 1.33)
MAX_ATTEMPTS = 4
#: Bounds on the local exponent of seconds ~ spp^beta used to extrapolate: render time is close to
#: linear in spp at large spp, but flat where launch costs dominate (a Metropolis integrator's
#: mutations are one launch each), and a flat stretch must not be extrapolated as free.
BETA_RANGE = (0.7, 1.3)


def calibrate(render, target_seconds, start_spp=CALIBRATION_START_SPP, warm_each=False) -> dict:
    """Time renders of growing spp, kernels compiled, up to ``target_seconds``.

    ================ =============================================================================
    render           callable ``render(spp)``; it is called once to compile its kernels (not
                     timed), then with growing spp until a call takes ``target_seconds`` (and
                     at least two calls were timed)
    target_seconds   length of the longest timed call (keep it short next to the budgets)
    start_spp        spp of the first calls
    warm_each        also call ``render`` once, untimed, before timing each new spp (for an
                     integrator that compiles kernels per spp)
    ================ =============================================================================

    Timed calls that compiled kernels are repeated and listed apart. Returns ``points``
    ([[spp, seconds], ...], for `plan_spp`), ``warmup_s`` (the untimed first call, compilation
    included) and ``compiling`` (the timed calls that compiled kernels).
    """
    t0 = time.perf_counter()
    render(start_spp)
    warmup = time.perf_counter() - t0
    spp, points, compiling = int(start_spp), [], []
    watch = KernelWatch()
    for _ in range(40):
        if warm_each and points:
            render(spp)
        with watch:
            t0 = time.perf_counter()
            render(spp)
            dt = time.perf_counter() - t0
        if watch.compiled:
            # Not the integrator's speed: time this spp again, its kernels are compiled now.
            compiling.append([spp, dt])
            continue
        points.append([spp, dt])
        if (dt >= target_seconds and len(points) >= 2) or spp >= MAX_SPP // 8:
            break
        # Grow towards the target without overshooting it by much on a noisy machine.
        spp = int(spp * min(8.0, max(2.0, 0.8 * target_seconds / max(dt, 1e-6))))
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


# ------------------------------------------------------------------------------ reference
def scene_digest(scene_bytes: bytes) -> str:
    return hashlib.sha256(scene_bytes).hexdigest()


def reference_key(scene_bytes: bytes, seed: int, max_depth: int) -> str:
    """Cache key of a reference (without its spp, which is part of the file name).

    Hashes the scene file's bytes, the seed, max_depth, the reference integrator, the mitsonar
    version and the Mitsuba variant (LLVM and CUDA results differ in the last bits).
    """
    import mitsuba as mi

    from ._version import __version__

    h = hashlib.sha256()
    h.update(scene_bytes)
    h.update(json.dumps({"seed": int(seed), "max_depth": int(max_depth), "integrator": REFERENCE_INTEGRATOR,
                         "mitsonar": __version__, "variant": mi.variant()}, sort_keys=True).encode())
    return h.hexdigest()[:20]


def reference_path(output_dir, key, spp) -> str:
    return os.path.join(output_dir, f"reference_{key}_spp{int(spp)}.npz")


def cached_references(output_dir, key) -> dict:
    """``{spp: path}`` of the references cached in ``output_dir`` under ``key``."""
    out = {}
    for path in glob.glob(os.path.join(glob.escape(output_dir), f"reference_{key}_spp*.npz")):
        m = re.search(r"_spp(\d+)\.npz$", path)
        if m:
            out[int(m.group(1))] = path
    return out


def _read_reference(path):
    with np.load(path, allow_pickle=False) as z:
        hist = np.array(z["hist"], np.float64)
        diff = np.array(z["half_difference"], np.float64)
        info = json.loads(str(z["info"]))
    return hist, diff, info


def self_errors(reference, half_difference, mask=None) -> dict:
    """The reference's own relative errors (whole scan, or the bins where ``mask`` is true).

    The reference is the mean of two independent halves h1, h2 whose errors e1, e2 have the same
    distribution, so its error (e1 + e2) / 2 is distributed like (h1 - h2) / 2.
    """
    ref = reference if mask is None else reference[:, mask]
    d = half_difference if mask is None else half_difference[:, mask]
    l2, l1 = np.linalg.norm(ref), np.abs(ref).sum()
    return {"self_rel_l2": float(np.linalg.norm(d) / (2 * l2)) if l2 > 0 else float("nan"),
            "self_rel_l1": float(np.abs(d).sum() / (2 * l1)) if l1 > 0 else float("nan")}


def render_reference(scene, sensor, spp, seed, max_depth, log=None):
    """Render the reference with ``sonar_tof`` as two independent halves.

    ============ =========================================================================
    spp          total paths per ping (rounded up to even; each half gets spp / 2)
    seed         the comparison's seed; the halves use ``REFERENCE_SEED_OFFSET + 2 seed``
                 and the next one, so they never coincide with the runs' seeds
    max_depth    surface bounces
    ============ =========================================================================

    Returns ``(hist, half_difference, info)``: the mean of the halves, ``h1 - h2`` (from which
    `self_errors` gives the reference's own error, in any set of bins) and a dict with spp,
    seeds, seconds, self_rel_l2 and self_rel_l1.
    """
    import mitsuba as mi

    half = max(1, (int(spp) + 1) // 2)
    integrator = mi.load_dict({"type": REFERENCE_INTEGRATOR})
    base = REFERENCE_SEED_OFFSET + 2 * int(seed)
    seeds = [base & 0xFFFFFFFF, (base + 1) & 0xFFFFFFFF]
    t0 = time.perf_counter()
    halves = []
    for s in seeds:
        if log:
            log(f"reference: {REFERENCE_INTEGRATOR}, {half} spp per half, seed {s}")
        halves.append(integrator.render_histogram(scene, sensor, seed=s, spp=half, max_depth=max_depth))
    seconds = time.perf_counter() - t0
    hist = 0.5 * (halves[0] + halves[1])
    diff = halves[0] - halves[1]
    info = {"integrator": REFERENCE_INTEGRATOR, "spp": 2 * half, "seeds": seeds, "seconds": seconds,
            "max_depth": int(max_depth), **self_errors(hist, diff)}
    return hist, diff, info


def load_or_render_reference(scene, sensor, scene_bytes, output_dir, spp, seed, max_depth, auto=False, log=None):
    """The cached reference if there is one, else render and cache it.

    With ``auto`` any cached reference of the same key with at least ``spp`` paths is used (the
    largest); otherwise exactly ``spp``. Returns ``(hist, half_difference, info)`` (see
    `render_reference`) with ``info["from_cache"]``, ``info["file"]`` and ``info["key"]`` added.
    """
    key = reference_key(scene_bytes, seed, max_depth)
    cached = cached_references(output_dir, key)
    if auto:
        usable = [s for s in cached if s >= spp]
        chosen = max(usable) if usable else None
    else:
        chosen = int(spp) if int(spp) in cached else None
    if chosen is not None:
        path = cached[chosen]
        try:
            hist, diff, info = _read_reference(path)
        except Exception:  # a damaged cache file is rendered again, not trusted
            hist = None
        if hist is not None and hist.shape == diff.shape == (sensor.n_pings, sensor.n_bins):
            if log:
                log(f"reference: cached {path}")
            info.update(from_cache=True, file=path, key=key)
            return hist, diff, info
    hist, diff, info = render_reference(scene, sensor, spp, seed, max_depth, log)
    path = reference_path(output_dir, key, info["spp"])
    tmp = path + ".tmp.npz"
    # Written under another name and renamed, so an interrupted run never leaves half a cache.
    np.savez_compressed(tmp, hist=hist, half_difference=diff, info=np.array(json.dumps(info)))
    os.replace(tmp, path)
    info.update(from_cache=False, file=path, key=key)
    return hist, diff, info


# ------------------------------------------------------------------------------ integrators
def load_integrator(name, params=None):
    """``mi.load_dict({"type": name, **params})``, checked to be a sonar integrator."""
    import mitsuba as mi

    from .render import _first_reason

    try:
        obj = mi.load_dict({"type": name, **(params or {})})
    except Exception as exc:
        text = str(exc)
        if "not found" in text and "Plugin" in text:
            raise CompareError(f"integrator {name!r} is not available (no Mitsuba plugin of that name is "
                               "registered; mitsonar provides sonar_tof and sonar_mlt)") from None
        raise CompareError(f"integrator {name!r}: {_first_reason(text)}") from None
    if not hasattr(obj, "render_histogram"):
        raise CompareError(f"integrator {name!r} is not a sonar integrator (it has no render_histogram); "
                           "use sonar_tof or sonar_mlt")
    return obj


def _describe(obj):
    try:
        return obj.to_string()
    except Exception:
        return type(obj).__name__


# ------------------------------------------------------------------------------ the comparison
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


def compare(scene_path, integrators=DEFAULT_INTEGRATORS, budgets=DEFAULT_BUDGETS, output_dir="cmp",
            reference_spp=None, seed=0, repeats=DEFAULT_REPEATS, max_depth=None, integrator_params=None,
            regions=None, reference_factor=DEFAULT_REFERENCE_FACTOR, calibration_seconds=None, warm=False,
            plots=True, log=None) -> dict:
    """Compare sonar integrators at equal time against a cached ``sonar_tof`` reference.

    =================== =======================================================================
    scene_path          Mitsuba XML file with a ``sonar`` sensor
    integrators         plugin names (or ``"a,b"``); the first is the baseline of the ratios.
                        A name given twice is labelled ``name#2`` (e.g. to test the tool)
    budgets             seconds per render (or ``"2,4,8,16"``)
    output_dir          folder for the results and the cached reference (created)
    reference_spp       paths per ping of the reference; None: ``reference_factor`` times the
                        spp sonar_tof reached at the largest budget, rounded up to a power of
                        two, or any larger reference already cached for the same key
    seed                base seed: render r (1, 2, ...) of integrator k (0, 1, ...) uses
                        seed + k * 2^20 + r; the reference uses seeds from 2^30 + 2 seed
    repeats             renders per (integrator, budget), each with its own seed
    max_depth           surface bounces for every render; None: the scene integrator's (or 5)
    integrator_params   ``{label: {name: value}}`` extra plugin parameters
    regions             ``{name: (lo, hi)}`` range windows (metres) also scored on their own
    reference_factor    see ``reference_spp``
    calibration_seconds length of the longest calibration render; None: min(0.5, budget_min / 2)
    warm                render once, untimed, at every new spp before timing (calibration
                        included): steady-state speed of an integrator that compiles kernels
                        per spp. Off: wall-clock time, compilations included (and reported)
    plots               write ``convergence.png`` and ``polar.png``
    log                 callable taking one line of progress, or None
    =================== =======================================================================

    Returns the dict written to ``output_dir/compare.json`` (fields in the module docstring).
    Raises `CompareError` (one line) for bad input.
    """
    import mitsuba as mi

    import mitsonar
    from .render import _sonar

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
    if not (isinstance(seed, (int, np.integer)) and seed >= 0):
        raise CompareError(f"--seed {seed!r}: need a non-negative integer")
    scene_path = os.fspath(scene_path)
    if not os.path.isfile(scene_path):
        raise CompareError(f"scene file {scene_path!r} does not exist")
    output_dir = os.fspath(output_dir)
    if os.path.exists(output_dir) and not os.path.isdir(output_dir):
        raise CompareError(f"output folder {output_dir!r} exists and is not a folder")
    try:
        os.makedirs(output_dir, exist_ok=True)
    except OSError as exc:
        raise CompareError(f"-o {output_dir!r}: cannot create the output folder ({exc.strerror})") from None
    say = log or (lambda line: None)

    with open(scene_path, "rb") as fh:
        scene_bytes = fh.read()
    scene = mitsonar.load_scene(scene_path)
    sensor = _sonar(scene, 0)
    if max_depth is None:
        max_depth = int(getattr(scene.integrator(), "max_depth", 5) or 5)
    max_depth = int(max_depth)
    ranges = sensor.bin_centres()
    objs = {lab: load_integrator(n, params.get(lab)) for lab, n in zip(labels, names)}
    cal_target = calibration_seconds if calibration_seconds is not None else min(0.5, budgets[0] / 2)

    warm_seed = REFERENCE_SEED_OFFSET - 1  # calibration and warm-up renders: never scored

    def render(obj, spp, seed_value):
        return obj.render_histogram(scene, sensor, seed=seed_value, spp=int(spp), max_depth=max_depth)

    # Explicit chain counts and the like set a floor under an integrator's spp (sonar_mlt.min_spp).
    min_spp = {lab: int(getattr(objs[lab], "min_spp", lambda n: 1)(sensor.n_pings)) for lab in labels}
    calibrations = {}
    for lab in labels:
        say(f"{lab}: calibrating (longest timed render {cal_target:.3g} s)")
        calibrations[lab] = calibrate(lambda spp, o=objs[lab]: render(o, spp, warm_seed), cal_target,
                                      start_spp=max(CALIBRATION_START_SPP, min_spp[lab]), warm_each=warm)

    # --- timed renders (scored once the reference is known, so that an automatic reference can be
    # sized by the spp path tracing actually reached)
    watch = KernelWatch()
    pending = []

    def timed(obj, spp, seed_value):
        with watch:
            t0 = time.perf_counter()
            hist = render(obj, spp, seed_value)
            dt = time.perf_counter() - t0
        return hist, dt, watch.compiled, watch.compile_seconds

    for k, lab in enumerate(labels):
        obj = objs[lab]
        # Every timed render refines the next choice of spp (the runs are longer than the
        # calibration renders, so timed more reliably), except renders that compiled kernels:
        # their time says nothing about the integrator's speed.
        timings = [list(p) for p in calibrations[lab]["points"]]
        counter = k * SEED_STRIDE
        for budget in budgets:
            seeds, secs, hists, compiled, compile_s, attempts = [], [], [], [], [], []
            warm_compiled = 0 if warm else None
            tried = set()
            # Search for the spp that fills the budget; the accepted render is the first repeat.
            while True:
                spp = max(plan_spp(timings, budget), min_spp[lab])
                if attempts and spp == attempts[-1][0]:
                    # The timings around the budget did not move the plan: step from the last try.
                    spp = int(min(max(spp * budget / max(attempts[-1][1], 1e-6), min_spp[lab]), MAX_SPP))
                if warm and spp not in tried:
                    # Some integrators compile more kernels on a second call than on the first.
                    for _ in range(3):
                        with watch:
                            render(obj, spp, warm_seed)
                        warm_compiled += watch.compiled
                        if not watch.compiled:
                            break
                tried.add(spp)
                counter += 1
                s = (int(seed) + counter) & 0xFFFFFFFF
                hist, dt, nc, cs = timed(obj, spp, s)
                if not nc:
                    timings.append([spp, dt])
                attempts.append([spp, dt])
                ok = BUDGET_TOLERANCE[0] <= dt / budget <= BUDGET_TOLERANCE[1]
                at_floor = spp <= min_spp[lab] and dt > budget  # cannot go lower: the budget is too short
                if ok or at_floor or len(attempts) >= MAX_ATTEMPTS:
                    break
            seeds.append(s)
            secs.append(dt)
            hists.append(hist)
            compiled.append(nc)
            compile_s.append(cs)
            for _ in range(repeats - 1):
                counter += 1
                s = (int(seed) + counter) & 0xFFFFFFFF
                hist, dt, nc, cs = timed(obj, spp, s)
                if not nc:
                    timings.append([spp, dt])
                seeds.append(s)
                secs.append(dt)
                hists.append(hist)
                compiled.append(nc)
                compile_s.append(cs)
            pending.append({"integrator": lab, "budget_s": float(budget), "spp": int(spp), "seeds": seeds,
                            "seconds": secs, "hists": hists, "compiled_kernels": compiled,
                            "compile_seconds": compile_s, "warmup_compiled_kernels": warm_compiled,
                            "attempts": attempts})
            say(f"{lab}: budget {budget:g} s -> {spp} spp, {float(np.mean(secs)):.3g} s"
                + (f" ({len(attempts)} tries)" if len(attempts) > 1 else "")
                + (f" ({sum(compiled)} kernel(s) compiled while timed)" if sum(compiled) else ""))

    # --- reference
    auto = reference_spp is None
    if auto:
        plain = [lab for lab, n in zip(labels, names) if n == REFERENCE_INTEGRATOR and not params.get(lab)]
        if plain:
            reached = max(p["spp"] for p in pending if p["integrator"] == plain[0])
        else:
            ref_cal = calibrate(lambda spp, o=load_integrator(REFERENCE_INTEGRATOR): render(o, spp, warm_seed),
                                cal_target)
            reached = plan_spp(ref_cal["points"], budgets[-1])
        need = reference_factor * reached
        reference_spp = int(min(MAX_SPP, 1 << max(1, math.ceil(math.log2(max(need, 2))))))
    ref, ref_diff, ref_info = load_or_render_reference(scene, sensor, scene_bytes, output_dir, int(reference_spp),
                                                       seed, max_depth, auto=auto, log=say)
    self_l2 = ref_info["self_rel_l2"]
    masks = {rn: _region_mask(ranges, lo, hi) for rn, (lo, hi) in regions.items()}
    ref_info["regions"] = {rn: self_errors(ref, ref_diff, m) for rn, m in masks.items()}

    # --- scores
    runs, first_renders = [], {}
    for p in pending:
        hists = p.pop("hists")
        metrics = []
        for hist in hists:
            m = error_metrics(hist, ref, self_l2)
            m["regions"] = {rn: error_metrics(hist[:, mk], ref[:, mk], ref_info["regions"][rn]["self_rel_l2"])
                            for rn, mk in masks.items()}
            metrics.append(m)
        first_renders[(p["integrator"], p["budget_s"])] = hists[0]
        run = _summarise(p["integrator"], p["budget_s"], p["spp"], p["seeds"], p["seconds"], metrics, self_l2,
                         regions)
        run.update({k: p[k] for k in ("compiled_kernels", "compile_seconds", "warmup_compiled_kernels",
                                      "attempts")})
        runs.append(run)
        say(f"{run['integrator']}: budget {run['budget_s']:g} s, {run['spp']} spp: rel L2 {run['rel_l2']:.4g}, "
            f"rel L1 {run['rel_l1']:.4g}")

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
    for r in runs:
        if r["seconds_mean"] > 1.5 * r["budget_s"] + 0.05:
            warnings.append(f"{r['integrator']} at {r['budget_s']:g} s took {r['seconds_mean']:.3g} s on average "
                            "(a busy machine, a compilation, a render time that is not linear in spp, or an spp floor "
                            "set by the integrator's explicit settings)")

    import drjit as dr

    from ._version import __version__

    result = {
        "tool": "mitsonar compare",
        "settings": {
            "scene": scene_path, "integrators": labels, "integrator_types": names, "budgets_s": budgets,
            "repeats": int(repeats), "seed": int(seed), "max_depth": max_depth,
            "reference_spp": int(ref_info["spp"]), "reference_spp_auto": auto,
            "reference_factor": float(reference_factor), "calibration_seconds": float(cal_target), "warm": bool(warm),
            "regions": {k: list(v) for k, v in regions.items()}, "integrator_params": params,
            "seeds": f"render r (1, 2, ... over budgets, searches and repeats) of the k-th integrator (0, 1, ...) "
                     f"uses seed + k * {SEED_STRIDE} + r",
        },
        "scene": {"path": os.path.abspath(scene_path), "sha256": scene_digest(scene_bytes),
                  "n_pings": int(sensor.n_pings), "n_bins": int(sensor.n_bins),
                  "range_min": float(sensor.range_min), "range_max": float(sensor.range_max),
                  "bearings_deg": [float(b) for b in sensor.bearings_deg()]},
        "environment": {"mitsonar": __version__, "mitsuba": mi.__version__, "drjit": dr.__version__,
                        "variant": mi.variant(), "python": platform.python_version(),
                        "platform": platform.platform(), "cpu_count": os.cpu_count(),
                        "date": datetime.datetime.now(datetime.timezone.utc).isoformat(timespec="seconds")},
        "reference": ref_info,
        "integrators": {lab: {"type": n, "params": params.get(lab, {}), "description": _describe(objs[lab]),
                              "calibration": calibrations[lab]}
                        for lab, n in zip(labels, names)},
        "runs": runs,
        "equal_time": equal_time_ratios(runs, labels, budgets, list(regions)),
        "files": {},
        "warnings": warnings,
    }
    for w in warnings:
        say(f"warning: {w}")

    files = result["files"]
    renders = os.path.join(output_dir, "renders.npz")
    arrays = {"reference": ref.astype(np.float32), "ranges": ranges, "bearings_deg": sensor.bearings_deg()}
    arrays.update({f"{lab}@{budget:g}s": h.astype(np.float32) for (lab, budget), h in first_renders.items()})
    np.savez_compressed(renders, **arrays)
    files["renders"] = renders
    if plots:
        files["convergence"] = os.path.join(output_dir, "convergence.png")
        plot_convergence(result, files["convergence"])
        files["polar"] = os.path.join(output_dir, "polar.png")
        plot_polar_grid(sensor, ref, first_renders, labels, budgets, runs, files["polar"], ref_info)
    files["json"] = os.path.join(output_dir, "compare.json")
    write_json(result, files["json"])
    return result


def _summarise(label, budget, spp, seeds, secs, metrics, self_l2, regions):
    def stack(key):
        return np.stack([m[key] for m in metrics])

    per_ping_l2 = np.sqrt(np.mean(stack("per_ping_rel_l2") ** 2, axis=0))
    per_ping_l1 = np.sqrt(np.mean(stack("per_ping_rel_l1") ** 2, axis=0))
    run = {
        "integrator": label, "budget_s": float(budget), "spp": int(spp), "seeds": seeds,
        "seconds": [float(s) for s in secs], "seconds_mean": float(np.mean(secs)),
        "rel_l2": _rms([m["rel_l2"] for m in metrics]),
        "rel_l1": _rms([m["rel_l1"] for m in metrics]),
        "rel_l2_debiased": _rms([m["rel_l2_debiased"] for m in metrics]),
        "rel_l2_each": [float(m["rel_l2"]) for m in metrics],
        "rel_l1_each": [float(m["rel_l1"]) for m in metrics],
        "per_ping_rel_l2": _nullable(per_ping_l2),
        "per_ping_rel_l1": _nullable(per_ping_l1),
        "regions": {},
    }
    for rn in regions:
        rm = [m["regions"][rn] for m in metrics]
        run["regions"][rn] = {"rel_l2": _rms([m["rel_l2"] for m in rm]),
                              "rel_l1": _rms([m["rel_l1"] for m in rm]),
                              "rel_l2_debiased": _rms([m["rel_l2_debiased"] for m in rm])}
    return run


def _nullable(values):
    return [float(v) if math.isfinite(v) else None for v in np.asarray(values, np.float64)]


def equal_time_ratios(runs, labels, budgets, region_names=(), metric="rel_l2_debiased") -> list:
    """Error ratios against the first integrator (the baseline), per budget.

    ``ratio_raw = err_base / err`` and ``ratio_time_adjusted = err_base sqrt(t_base) / (err
    sqrt(t))`` with ``t`` the measured mean seconds: the ratio at exactly equal time for errors
    that fall as 1/sqrt(t). > 1: lower error than the baseline. ``metric`` picks the error.
    """
    by = {(r["integrator"], r["budget_s"]): r for r in runs}
    out = []
    base = labels[0]
    for budget in budgets:
        b = by[(base, float(budget))]
        entry = {"budget_s": float(budget), "baseline": base, "metric": metric, "ratios": {}}
        for lab in labels[1:]:
            o = by[(lab, float(budget))]
            # A debiased error of 0 (below the reference's own noise) gives no ratio: fall back
            # to the raw error for that pair and say so.
            m = metric if (b[metric] > 0 and o[metric] > 0) else metric.replace("_debiased", "")
            item = _ratio(b[m], o[m], b["seconds_mean"], o["seconds_mean"])
            item["metric"] = m
            item["regions"] = {rn: _ratio(b["regions"][rn][metric], o["regions"][rn][metric],
                                          b["seconds_mean"], o["seconds_mean"]) for rn in region_names}
            entry["ratios"][lab] = item
        out.append(entry)
    return out


def _ratio(e_base, e, t_base, t):
    ok = e > 0 and math.isfinite(e) and math.isfinite(e_base)
    raw = e_base / e if ok else float("nan")
    adj = e_base * math.sqrt(t_base) / (e * math.sqrt(t)) if ok and t > 0 else float("nan")
    return {"ratio_raw": raw, "ratio_time_adjusted": adj}


def jsonable(obj):
    """``obj`` with numpy values as Python ones and NaN or infinities as None (strict JSON)."""
    if isinstance(obj, dict):
        return {str(k): jsonable(v) for k, v in obj.items()}
    if isinstance(obj, (list, tuple)):
        return [jsonable(v) for v in obj]
    if isinstance(obj, (np.integer,)):
        return int(obj)
    if isinstance(obj, (float, np.floating)):
        v = float(obj)
        return v if math.isfinite(v) else None  # JSON has no NaN
    if isinstance(obj, np.ndarray):
        return jsonable(obj.tolist())
    return obj


def write_json(result, path):
    """Write ``result`` as strict JSON (NaN and infinities become null)."""
    tmp = path + ".tmp"
    with open(tmp, "w") as fh:
        json.dump(jsonable(result), fh, indent=2)
        fh.write("\n")
    os.replace(tmp, path)


# ------------------------------------------------------------------------------ pictures
def _figure(figsize, dpi=110):
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure

    fig = Figure(figsize=figsize, dpi=dpi)
    FigureCanvasAgg(fig)
    return fig


def plot_convergence(result, path):
    """Error versus measured seconds, log-log, one line per integrator (rel L2, rel L1, regions).

    Points are the mean seconds and the RMS error of the repeats; the thin dashed line has the
    slope -1/2 of unbiased Monte Carlo, the dotted one is the reference's own error.
    """
    labels = result["settings"]["integrators"]
    regions = list(result["settings"]["regions"])
    panels = [("rel_l2", "relative L2 error (whole scan)"), ("rel_l1", "relative L1 error (whole scan)")]
    panels += [(f"region:{rn}", f"relative L2 error, {rn} ({result['settings']['regions'][rn][0]:g}-"
                                f"{result['settings']['regions'][rn][1]:g} m)") for rn in regions]
    fig = _figure((5.0 * len(panels), 4.2))
    self_l2 = result["reference"].get("self_rel_l2")
    for i, (key, title) in enumerate(panels):
        ax = fig.add_subplot(1, len(panels), i + 1)
        for lab in labels:
            rows = sorted((r for r in result["runs"] if r["integrator"] == lab), key=lambda r: r["budget_s"])
            t = [r["seconds_mean"] for r in rows]
            e = [r["regions"][key.split(":", 1)[1]]["rel_l2"] if key.startswith("region:") else r[key]
                 for r in rows]
            ax.plot(t, e, "o-", label=lab)
            for ti, ei, r in zip(t, e, rows):
                ax.annotate(f"{r['spp']}", (ti, ei), textcoords="offset points", xytext=(3, 3), fontsize=6)
        all_t = [r["seconds_mean"] for r in result["runs"]]
        all_e = [r["rel_l2"] for r in result["runs"]] if key == "rel_l2" else None
        if all_e and min(all_t) > 0 and min(all_e) > 0:
            t0, t1 = min(all_t), max(all_t)
            e0 = max(all_e)
            ax.plot([t0, t1], [e0, e0 * math.sqrt(t0 / t1)], "k--", lw=0.6, label="slope -1/2")
        if key == "rel_l2" and self_l2:
            ax.axhline(self_l2, color="0.5", ls=":", lw=0.8, label="reference's own error")
        ax.set_xscale("log")
        ax.set_yscale("log")
        ax.set_xlabel("measured seconds per render")
        ax.set_ylabel(title.split(" (")[0].split(",")[0])
        ax.set_title(title, fontsize=9)
        ax.grid(True, which="both", lw=0.3, alpha=0.5)
        ax.legend(fontsize=7)
    scene = os.path.basename(result["settings"]["scene"])
    fig.suptitle(f"{scene}: error against a {result['reference']['spp']}-spp sonar_tof reference "
                 f"(spp labelled; {result['settings']['repeats']} repeat(s), RMS)", fontsize=9)
    fig.tight_layout()
    fig.savefig(path)
    return fig


def scan_from_histogram(sensor, hist, meta=None):
    """A `Scan` of a rendered histogram for pictures: intensity only (device bytes zero)."""
    from .scan import Scan

    hist = np.asarray(hist)
    return Scan(intensity=hist.astype(np.float32), data=np.zeros(hist.shape, np.uint8),
                ranges=sensor.bin_centres(), bearings=np.radians(sensor.bearings_deg()),
                poses=sensor.ping_poses(None), range_min=sensor.range_min, range_max=sensor.range_max,
                beam_pattern=sensor.beam.kind, beamwidth_h=sensor.beam.beamwidth_h,
                beamwidth_v=sensor.beam.beamwidth_v, kind=sensor.kind, sound_speed=sensor.sound_speed,
                absorption=sensor.absorption, meta=dict(meta or {}))


def _sector_box(scan):
    """``(x0, x1, y0, y1)`` of the fan of a narrow sector in plot_polar's display coordinates,
    or None for a sector of half a turn or more (then the whole disc is shown)."""
    half = math.radians(scan.beamwidth_h) / 2
    b = np.asarray(scan.bearings)
    if b.size == 0 or (b.max() - b.min()) + 2 * half >= math.pi:
        return None
    angles = np.linspace(b.min() - half, b.max() + half, 64)
    r = scan.range_max
    xs = np.concatenate([[0.0], -r * np.sin(angles)])
    ys = np.concatenate([[0.0], r * np.cos(angles)])
    pad = 0.04 * r
    return xs.min() - pad, xs.max() + pad, ys.min() - pad, ys.max() + pad


def plot_polar_grid(sensor, reference, renders, labels, budgets, runs, path, ref_info=None):
    """Polar intensity images (dB, one colour scale: the reference's top 60 dB) side by side.

    One row per integrator; the first column is the reference, then one column per budget
    (the first repeat of each run). A narrow sector is framed tightly (plot_polar draws the
    whole disc). Returns the figure.
    """
    from .plots import plot_polar

    by = {(r["integrator"], r["budget_s"]): r for r in runs}
    positive = reference[reference > 0]
    hi = 10 * math.log10(float(positive.max())) if positive.size else 0.0
    lo = hi - 60.0
    box = _sector_box(scan_from_histogram(sensor, reference))
    aspect = 1.0 if box is None else (box[1] - box[0]) / (box[3] - box[2])
    panel_h = 3.6
    panel_w = panel_h * aspect + 1.3  # + the colour bar
    cols, rows = 1 + len(budgets), len(labels)
    fig = _figure((panel_w * cols, (panel_h + 0.5) * rows), dpi=100)
    for i, lab in enumerate(labels):
        for j in range(cols):
            ax = fig.add_subplot(rows, cols, i * cols + j + 1)
            if j == 0:
                hist = reference
                title = f"reference\nsonar_tof, {ref_info['spp'] if ref_info else '?'} spp"
            else:
                budget = budgets[j - 1]
                hist = renders[(lab, budget)]
                r = by[(lab, budget)]
                title = (f"{lab}, {budget:g} s budget\n{r['spp']} spp, {r['seconds'][0]:.2g} s, "
                         f"rel L2 {r['rel_l2_each'][0]:.3g}")
            n_axes = len(fig.axes)
            plot_polar(scan_from_histogram(sensor, hist), ax=ax, use="intensity", db=True, vmin=lo, vmax=hi,
                       resolution=500, title=title)
            if box is not None:
                ax.set_xlim(box[0], box[1])
                ax.set_ylim(box[2], box[3])
                # The bearing labels sit outside the frame now: clip them and keep them out of
                # the layout, or tight_layout shrinks every panel to make room for them.
                for t in ax.texts:
                    t.set_clip_on(True)
                    t.set_in_layout(False)
            ax.title.set_fontsize(7)
            ax.tick_params(labelsize=6)
            ax.set_xlabel("m", fontsize=6)
            ax.set_ylabel("m", fontsize=6)
            for cax in fig.axes[n_axes:]:  # the colour bar plot_polar added
                cax.tick_params(labelsize=6)
                cax.yaxis.label.set_fontsize(6)
    fig.tight_layout()
    fig.savefig(path)
    return fig


__all__ = ["CompareError", "DEFAULT_BUDGETS", "DEFAULT_INTEGRATORS", "DEFAULT_REFERENCE_FACTOR", "DEFAULT_REPEATS",
           "KernelWatch", "REFERENCE_INTEGRATOR", "calibrate", "compare", "equal_time_ratios", "error_metrics",
           "jsonable", "labels_for", "load_integrator", "load_or_render_reference", "parse_budgets",
           "parse_integrators", "parse_params", "parse_regions", "plot_convergence", "plot_polar_grid",
           "reference_key", "render_reference", "scan_from_histogram", "self_errors", "plan_spp",
           "write_json"]
