"""Value checks of :class:`~hilbertmap.HilbertMap`: hyper-parameters, query points, grid sizes.

Every check raises a ValueError that names the value and says what is allowed:
``HilbertMap: <name> must be <allowed>, not <value!r>``.
"""
from __future__ import annotations

import math

import numpy as np

from .classify import RULES
from .inducing import METHODS
from .schedules import SCHEDULES

# Most grid points a slice or a surface may be sampled on: the surface's grid costs about 100
# bytes a point (coordinates, probabilities, the tetrahedra's masks), so 2e8 points is ~20 GB. The
# default resolution (at most 10 cm, at least 2 cm) stays well below it for rooms and tanks.
MAX_GRID_POINTS = 200_000_000

# The string-valued hyper-parameters and their choices.
CHOICES = dict(inducing=METHODS, source=("auto", "data", "intensity"), bin_rule=RULES,
               occupied_bins=("first", "first_run", "all"), occupied_pooling=("mean", "lse"),
               beam_sampling=("pattern", "uniform"), schedule=SCHEDULES, variant=("llvm", "cuda"))


def _is_int(v) -> bool:
    return isinstance(v, (int, np.integer)) and not isinstance(v, (bool, np.bool_))


def _is_number(v) -> bool:
    return (isinstance(v, (int, float, np.integer, np.floating)) and not isinstance(v, (bool, np.bool_))
            and math.isfinite(v))


def _choices(names) -> str:
    q = [repr(n) for n in names]
    return ", ".join(q[:-1]) + " or " + q[-1]


def need(name: str, value, ok: bool, allowed: str) -> None:
    """Raise ``HilbertMap: {name} must be {allowed}, not {value!r}`` unless ``ok``."""
    if not ok:
        raise ValueError(f"HilbertMap: {name} must be {allowed}, not {value!r}")


def int_param(name, v, lo, none=False, auto=False):
    """An integer >= ``lo`` (or None with ``none``, or 'auto' with ``auto``); bools and floats are refused."""
    need(name, v, (none and v is None) or (auto and isinstance(v, str) and v == "auto") or (_is_int(v) and v >= lo),
         ("None or " if none else "") + ("'auto' or " if auto else "") + f"an integer >= {lo}")


def num_param(name, v, lo=None, hi=None, lo_open=False, hi_open=False, special=()):
    """A finite number in the given (half-)open or closed range, or one of the ``special`` values."""
    ok = any(v is s or (isinstance(v, str) and v == s) for s in special)
    if not ok and _is_number(v):
        ok = ((lo is None or (v > lo if lo_open else v >= lo))
              and (hi is None or (v < hi if hi_open else v <= hi)))
    if lo is not None and hi is not None:
        rng = f"a number in {'(' if lo_open else '['}{lo:g}, {hi:g}{')' if hi_open else ']'}"
    elif lo is not None:
        rng = f"a number {'>' if lo_open else '>='} {lo:g}"
    else:
        rng = "a finite number"
    need(name, v, ok, " or ".join([repr(s) for s in special] + [rng]))


def check_bounds(name, bounds, none=True):
    """``(lo, hi)``, each 3 finite numbers with lo < hi; returns them as arrays."""
    if bounds is None and none:
        return None
    allowed = ("None or " if none else "") + "a pair (lo, hi) of 3 numbers each, with lo < hi"
    try:
        lo, hi = (np.asarray(b, dtype=np.float64) for b in bounds)
    except (TypeError, ValueError):
        lo = hi = None
    need(name, bounds, lo is not None and lo.shape == (3,) and hi.shape == (3,)
         and bool(np.isfinite(lo).all() and np.isfinite(hi).all() and (lo < hi).all()), allowed)
    return lo, hi


def check_params(hm) -> None:
    """Every hyper-parameter's type and range (at fit, as scikit-learn does: set_params may
    change them after construction)."""
    for name, names in CHOICES.items():
        v = getattr(hm, name)
        need(name, v, isinstance(v, str) and v in names, ("one of " if len(names) > 2 else "") + _choices(names))
    int_param("n_inducing", hm.n_inducing, 1)
    num_param("inducing_occupied_share", hm.inducing_occupied_share, 0, 1)
    num_param("inducing_voxel", hm.inducing_voxel, 0, special=(None,))
    num_param("lengthscale", hm.lengthscale, 0, lo_open=True, special=("auto",))
    num_param("lengthscale_factor", hm.lengthscale_factor, 0, lo_open=True)
    num_param("kernel_cut", hm.kernel_cut, 0, 1, lo_open=True, hi_open=True)
    num_param("eig_floor", hm.eig_floor, 0, 1, hi_open=True)
    check_echo_params(hm)
    num_param("occupied_weight", hm.occupied_weight, 0, lo_open=True, special=("balanced",))
    num_param("pooling_temperature", hm.pooling_temperature, 0, lo_open=True)
    num_param("beam_extent", hm.beam_extent, 0, lo_open=True)
    num_param("beam_stride", hm.beam_stride, 1)
    num_param("alpha", hm.alpha, 0)
    num_param("l1_ratio", hm.l1_ratio, 0, 1)
    num_param("eta0", hm.eta0, 0, lo_open=True, special=("auto",))
    num_param("k1", hm.k1, 0)
    num_param("t0", hm.t0, 0, lo_open=True, special=(None,))
    check_pass_params(hm)
    check_bounds("bounds", hm.bounds)
    check_coverage_params(hm)
    need("multi_echo", hm.multi_echo, isinstance(hm.multi_echo, (bool, np.bool_)), "True or False")


def check_echo_params(hm) -> None:
    """The echo detection and sampling settings (from ``threshold`` to ``max_run``), which the
    batch and the incremental map share."""
    for name in ("threshold", "min_level", "cfar_offset"):
        num_param(name, getattr(hm, name), special=(None,))
    int_param("cfar_train", hm.cfar_train, 1)
    int_param("cfar_guard", hm.cfar_guard, 0)
    num_param("blanking", hm.blanking, 0, special=("auto",))
    int_param("min_echo_bins", hm.min_echo_bins, 0)
    num_param("free_density", hm.free_density, 0)
    int_param("max_free_per_ping", hm.max_free_per_ping, 0, auto=True)
    num_param("free_margin", hm.free_margin, 0)
    int_param("near_free", hm.near_free, 0, auto=True)
    num_param("near_depth", hm.near_depth, 0)
    int_param("occupied_samples", hm.occupied_samples, 1, auto=True)
    num_param("max_run", hm.max_run, 0, lo_open=True)


def check_pass_params(hm) -> None:
    """The mini-batch and pass settings shared by both maps."""
    int_param("batch_size", hm.batch_size, 1)
    int_param("n_passes", hm.n_passes, 1)
    int_param("partial_passes", hm.partial_passes, 1)
    need("fit_intercept", hm.fit_intercept, isinstance(hm.fit_intercept, (bool, np.bool_)), "True or False")


def check_coverage_params(hm) -> None:
    """The region-seen voxel settings and the seed shared by both maps."""
    num_param("coverage_voxel", hm.coverage_voxel, 0, lo_open=True)
    int_param("max_free_per_voxel", hm.max_free_per_voxel, 1, none=True)
    int_param("max_groups_per_voxel", hm.max_groups_per_voxel, 1, none=True)
    int_param("random_state", hm.random_state, 0, none=True)


def as_points(points, name: str = "points") -> np.ndarray:
    """(N, 3) finite float64 points, or a ValueError naming the first bad row."""
    try:
        pts = np.asarray(points, dtype=np.float64)
    except (TypeError, ValueError) as exc:
        raise ValueError(f"HilbertMap: {name} must be an (N, 3) array of numbers ({exc})") from None
    if pts.ndim != 2 or pts.shape[1] != 3:
        raise ValueError(f"HilbertMap: {name} must have shape (N, 3), got {pts.shape}")
    bad = np.nonzero(~np.isfinite(pts).all(axis=1))[0]
    if len(bad):
        # a NaN would land in no kernel cell and come out as the bare intercept, a plausible p
        raise ValueError(f"HilbertMap: {name}: row {bad[0]} is not finite ({len(bad)} of {len(pts)} rows are not)")
    return pts


def axis_index(axis) -> int:
    """0, 1 or 2 from ``'x'``, ``'y'``, ``'z'`` (any case) or the index itself."""
    if isinstance(axis, str) and axis.lower() in ("x", "y", "z"):
        return "xyz".index(axis.lower())
    if axis in (0, 1, 2):
        return int(axis)
    raise ValueError(f"HilbertMap: axis must be 'x', 'y', 'z' or 0-2, not {axis!r}")


def grid_shape(res: float, lo, hi) -> list:
    """Samples per axis of a grid every ``res`` metres from ``lo`` to ``hi`` (as `grid_axes` makes)."""
    return [int(math.ceil(max(float(b) - float(a), 0.0) / res + 0.5)) for a, b in zip(lo, hi)]


def _up2(x: float) -> float:
    """``x`` rounded up to two significant digits."""
    e = 10.0 ** (math.floor(math.log10(x)) - 1)
    return float(f"{math.ceil(x / e - 1e-9) * e:.2g}")


def fitting_resolution(res: float, lo, hi, max_points: int = MAX_GRID_POINTS) -> float:
    """``res`` when a grid every ``res`` metres over ``lo``..``hi`` holds at most ``max_points``
    points, else the finest step of two significant digits that does."""
    def fits(r):
        return math.prod(grid_shape(r, lo, hi)) <= max_points

    if fits(res):
        return float(res)
    r = res
    while not fits(r):   # coarser by 5 % at a time: r / 1.05 does not fit
        r *= 1.05
    r = _up2(r / 1.05)
    while not fits(r):   # then up the two-digit steps: the first that fits
        r = _up2(r + 10.0 ** (math.floor(math.log10(r)) - 1))
    return r


def grid_axes(name_res: str, res: float, lo, hi, names: str) -> list:
    """Sample axes from lo to hi every ``res``; refused when they would hold more than
    MAX_GRID_POINTS points, with the finest resolution that fits."""
    n = grid_shape(res, lo, hi)
    if math.prod(n) > MAX_GRID_POINTS:
        r = fitting_resolution(res, lo, hi)
        raise ValueError(
            f"HilbertMap: {name_res} {res:g} m needs a grid of {' x '.join(map(str, n))} = {math.prod(n):.3g} "
            f"points over {names} (at most {MAX_GRID_POINTS:.0e}); use {name_res} {r:.2g} or coarser")
    return [np.arange(float(a), float(b) + 0.5 * res, res) for a, b in zip(lo, hi)]
