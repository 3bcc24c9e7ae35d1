"""Saving and loading Hilbert maps: the ``hilbertmap/1`` ``.npz`` format.

Two JSON strings and the learnt arrays, in one ``np.savez_compressed`` archive (written under a
temporary name beside the path and renamed, by :func:`write_archive`, which the incremental map's
``hilbertmap-incremental/1`` shares):

``params``              JSON object: the hyper-parameters (``get_params()``; tuples as lists)
``state``               JSON object: ``lengthscale_``, ``intercept_``, ``t_``, ``n_samples_seen_``,
                        ``n_schedule_``, ``occupied_weight_``, ``eta0_``, ``n_components_``,
                        ``coverage_voxel``, ``loss_curve_`` and ``format = "hilbertmap/1"``
``inducing_points``     (n, 3) float64, in the kernel grid's order
``weights``             (k,) the Nystroem-feature weights ``w``
``dual_coef``           (n,) ``M^T w``, the kernel expansion's coefficients
``coverage_keys``, ``echo_coverage_keys``, ``free_coverage_keys``
                        int64 voxel keys of the region seen, of the echoes, of the free samples
                        (the last is absent in maps saved before it existed; it then defaults to
                        the region seen)
``sensor_positions``    (S, 3); ``ping_frames`` (P, 4, 4); ``ping_beams``, ``ping_spans`` (P, 3)

The Gram matrix's eigen-decomposition is not stored: it is rebuilt from the inducing points
when a loaded map is trained further.
"""
from __future__ import annotations

import json
import math
import os
import zipfile
import zlib

import numpy as np

from ._checks import check_params
from .inducing import Coverage
from .surfaces import free_coverage

FORMAT = "hilbertmap/1"
ARRAYS = ("inducing_points", "weights", "dual_coef", "coverage_keys", "echo_coverage_keys",
          "sensor_positions", "ping_frames", "ping_beams", "ping_spans")
OPTIONAL_ARRAYS = ("free_coverage_keys",)
STATE_NUMBERS = ("lengthscale_", "intercept_", "t_", "n_samples_seen_", "n_schedule_", "occupied_weight_",
                 "eta0_", "n_components_", "coverage_voxel")


def save(hm, path) -> None:
    """Write a fitted map (hyper-parameters and learnt state) to ``path`` (``.npz``)."""
    hm._check_fitted()
    state = dict(lengthscale_=hm.lengthscale_, intercept_=hm.intercept_, t_=hm.t_,
                 n_samples_seen_=int(hm.n_samples_seen_), n_schedule_=float(hm.n_schedule_),
                 occupied_weight_=float(getattr(hm, "occupied_weight_", 1.0)), eta0_=float(hm.eta0_),
                 n_components_=int(len(hm.weights_)),
                 coverage_voxel=hm.coverage_.voxel, loss_curve_=list(getattr(hm, "loss_curve_", [])),
                 format=FORMAT)
    write_archive(path, hm, state, inducing_points=hm.inducing_points_, weights=hm.weights_, dual_coef=hm.dual_coef_,
                  coverage_keys=hm.coverage_.keys, echo_coverage_keys=hm.echo_coverage_.keys,
                  free_coverage_keys=free_coverage(hm).keys, sensor_positions=hm.sensor_positions_,
                  ping_frames=hm.ping_frames_, ping_beams=hm.ping_beams_, ping_spans=hm.ping_spans_)


def write_archive(path, hm, state: dict, **arrays) -> None:
    """``np.savez_compressed`` of ``hm``'s hyper-parameters (JSON ``params``), ``state`` (JSON) and
    ``arrays``, written under ``path + ".part"`` and renamed to ``path`` at the end (a reader never
    sees half a map, and a failed save leaves the old file)."""
    params = {k: _jsonable(v) for k, v in hm.get_params().items()}
    path = os.fspath(path)
    tmp = path + ".part"
    with open(tmp, "wb") as fh:
        np.savez_compressed(fh, params=np.array(json.dumps(params)), state=np.array(json.dumps(state)), **arrays)
    os.replace(tmp, path)


def load(cls, path):
    """Read a map written by :func:`save` as an instance of ``cls``. A file that is not one, or
    whose arrays do not agree with each other, is refused with a ValueError naming the file and
    what is wrong."""
    def bad(why):
        return ValueError(f"HilbertMap: {path}: {why}")

    arr = _read_arrays(path, bad)
    try:
        params = json.loads(str(arr.pop("params")))
        state = json.loads(str(arr.pop("state")))
    except ValueError:
        raise bad("not a Hilbert map file ('params' or 'state' is not JSON)") from None
    if not isinstance(params, dict) or not isinstance(state, dict):
        raise bad("not a Hilbert map file ('params' and 'state' must be JSON objects)")
    if state.get("format", FORMAT) != FORMAT:
        raise bad(f"format {state['format']!r} is not {FORMAT}")
    hm = from_params(cls, params, check_params, bad)
    try:
        st = {k: float(state[k]) for k in STATE_NUMBERS}
        loss_curve = [float(x) for x in state["loss_curve_"]]
    except KeyError as exc:
        raise bad(f"'state' lacks {exc.args[0]!r}") from None
    except (TypeError, ValueError):
        raise bad("'state' holds a value that is not a number") from None
    for k in ("lengthscale_", "coverage_voxel"):
        if not (math.isfinite(st[k]) and st[k] > 0):
            raise bad(f"'state' {k} must be a number > 0, not {st[k]!r}")
    check_map_arrays(arr, int(st["n_components_"]), bad)

    hm.inducing_points_ = arr["inducing_points"]
    hm.weights_ = arr["weights"]
    hm.dual_coef_ = arr["dual_coef"]
    hm.coverage_ = Coverage(st["coverage_voxel"], arr["coverage_keys"])
    hm.echo_coverage_ = Coverage(st["coverage_voxel"], arr["echo_coverage_keys"])
    if "free_coverage_keys" in arr:
        hm.free_coverage_ = Coverage(st["coverage_voxel"], arr["free_coverage_keys"])
    hm.sensor_positions_ = arr["sensor_positions"]
    hm.ping_frames_ = arr["ping_frames"]
    hm.ping_beams_ = arr["ping_beams"]
    hm.ping_spans_ = arr["ping_spans"]
    hm.lengthscale_ = st["lengthscale_"]
    hm.intercept_ = st["intercept_"]
    hm.t_ = st["t_"]
    hm.n_samples_seen_ = int(st["n_samples_seen_"])
    hm.n_schedule_ = st["n_schedule_"]
    hm.occupied_weight_ = st["occupied_weight_"]
    hm.eta0_ = st["eta0_"]
    hm.n_components_ = int(st["n_components_"])
    hm.gamma_ = 1.0 / (2.0 * hm.lengthscale_ ** 2)
    hm.loss_curve_ = loss_curve
    hm._grid = hm._make_grid()  # derived state: queries only read it
    return hm


def from_params(cls, params: dict, check, bad):
    """A new ``cls`` made from a saved JSON ``params`` object and checked by ``check(hm)``; an
    unknown name or a refused value becomes ``bad(why)``."""
    unknown = set(params) - set(cls._get_param_names())
    if unknown:
        raise bad(f"'params': unknown parameter(s) {', '.join(sorted(unknown))}")
    try:
        hm = cls(**{k: (tuple(v) if isinstance(v, list) else v) for k, v in params.items()})
        check(hm)
    except (TypeError, ValueError) as exc:
        raise bad(f"'params': {str(exc).replace('HilbertMap: ', '')}") from None
    return hm


def _read_arrays(path, bad) -> dict:
    """Every member of the archive as an array; ValueErrors (made by ``bad``) for what is not one."""
    unreadable = (ValueError, EOFError, KeyError, zipfile.BadZipFile, zlib.error)
    try:
        z = np.load(path, allow_pickle=False)
    except unreadable as exc:
        # numpy takes what is neither zip nor .npy for a pickle, and says so
        why = "" if "pickle" in str(exc) else ": the file is empty" if isinstance(exc, EOFError) else \
            f": {_first_line(exc)}"
        raise bad(f"not a Hilbert map file (not an .npz archive{why})") from None
    if not isinstance(z, np.lib.npyio.NpzFile):
        raise bad("not a Hilbert map file (a single .npy array, not an .npz archive)")
    with z:
        names = ("params", "state") + ARRAYS
        for name in names:
            if name not in z.files:
                raise bad(f"not a Hilbert map file (missing {name!r})")
        arr = {}
        for name in names + tuple(n for n in OPTIONAL_ARRAYS if n in z.files):
            try:
                arr[name] = z[name]
            except unreadable as exc:  # a damaged or truncated member
                raise bad(f"{name!r} cannot be read ({_first_line(exc)})") from None
    return arr


def check_map_arrays(arr: dict, k: int, bad) -> None:
    """The shapes a saved map's arrays must have, and agree on (n inducing points, k components,
    P pings); ``bad(why)`` makes the error."""
    def need(name, ok, expected):
        if not ok:
            raise bad(f"{name!r} has shape {arr[name].shape}, expected {expected}")

    nu = arr["inducing_points"]
    need("inducing_points", nu.ndim == 2 and nu.shape[1] == 3 and len(nu) >= 1, "(n, 3) with n >= 1")
    n = len(nu)
    if not 1 <= k <= n:
        raise bad(f"'state' n_components_ is {k}, expected 1 to {n} (the number of inducing points)")
    for name, length, what in (("weights", k, "n_components_"), ("dual_coef", n, "one per inducing point")):
        a = arr[name]
        if a.ndim != 1 or len(a) != length:
            raise bad(f"{name!r} has {a.size} entries, expected {length} ({what})")
    for name in ("inducing_points", "weights", "dual_coef"):
        if arr[name].dtype.kind not in "fiu" or not np.isfinite(arr[name]).all():
            raise bad(f"{name!r} holds values that are not finite numbers")
    for name in ("coverage_keys", "echo_coverage_keys", "free_coverage_keys"):
        if name in arr:
            need(name, arr[name].ndim == 1 and arr[name].dtype.kind in "iu", "1-D integer voxel keys")
    need("sensor_positions", arr["sensor_positions"].ndim == 2 and arr["sensor_positions"].shape[1] == 3, "(S, 3)")
    need("ping_frames", arr["ping_frames"].ndim == 3 and arr["ping_frames"].shape[1:] == (4, 4), "(P, 4, 4)")
    p = len(arr["ping_frames"])
    need("ping_beams", arr["ping_beams"].shape == (p, 3), f"({p}, 3), one row per ping of 'ping_frames'")
    need("ping_spans", arr["ping_spans"].shape == (p, 3), f"({p}, 3), one row per ping of 'ping_frames'")


def _first_line(exc) -> str:
    # mitsonar._checks.first_line does this for mitsonar; hilbertmap keeps its own copy because it
    # must not import mitsonar (it maps any scan-like object, standing alone).
    text = str(exc).strip()
    return text.splitlines()[0] if text else type(exc).__name__


def _jsonable(v):
    if isinstance(v, np.ndarray):
        return v.tolist()
    if isinstance(v, (np.floating, np.integer)):
        return v.item()
    if isinstance(v, tuple):
        return [_jsonable(x) for x in v]
    return v
