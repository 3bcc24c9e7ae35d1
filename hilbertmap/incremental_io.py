"""Saving and loading :class:`~hilbertmap.incremental.IncrementalHilbertMap`: ``hilbertmap-incremental/1``.

One ``np.savez_compressed`` archive (written under a temporary name beside ``path`` and renamed):

``params``, ``state``   JSON objects: the hyper-parameters; ``format``, ``lengthscale_``,
                        ``intercept_``, ``b_accum``, ``coverage_voxel``, the counters
``nodes`` (n, 3)        node positions; ``node_keys`` (n,) their lattice keys
``coef``, ``accum`` (n,)  the kernel coefficients and AdaGrad's sums of squared gradients
``last_used`` (n,)      scan counter of each node's last use (the forgetting rule)
``coverage_keys``, ``echo_coverage_keys``, ``free_coverage_keys``  voxel keys of the region seen
``ping_frames`` (P, 4, 4), ``ping_beams``, ``ping_spans`` (P, 3), ``track`` (P, 3)  the kept pings

A file of another format (a ``hilbertmap/1`` map, another version) or a damaged one is refused
with a ValueError naming the file and the reason, before any object is made.
"""
from __future__ import annotations

import json
import math
import zipfile
import zlib

import numpy as np

from .inducing import LazyCoverage
from .persistence import _first_line, from_params, write_archive

FORMAT = "hilbertmap-incremental/1"
ARRAYS = ("nodes", "node_keys", "coef", "accum", "last_used", "coverage_keys", "echo_coverage_keys",
          "free_coverage_keys", "ping_frames", "ping_beams", "ping_spans", "track")
COUNTERS = ("n_scans_seen_", "n_pings_seen_", "n_samples_seen_", "n_forgotten_")


def save(hm, path) -> None:
    hm._check_fitted()
    state = dict(format=FORMAT, lengthscale_=hm.lengthscale_, intercept_=hm.intercept_, b_accum=hm._b_accum,
                 coverage_voxel=hm.coverage_.voxel, t_=hm.t_, loss_curve_=list(hm.loss_curve_),
                 **{k: int(getattr(hm, k)) for k in COUNTERS})
    write_archive(path, hm, state, nodes=hm.inducing_points_, node_keys=hm.node_keys_, coef=hm.dual_coef_,
                  accum=hm.node_accum_, last_used=hm.node_last_used_, coverage_keys=hm.coverage_.keys,
                  echo_coverage_keys=hm.echo_coverage_.keys, free_coverage_keys=hm.free_coverage_.keys,
                  ping_frames=hm.ping_frames_, ping_beams=hm.ping_beams_, ping_spans=hm.ping_spans_, track=hm.track_)


def load(cls, path):
    def bad(why):
        return ValueError(f"HilbertMap: {path}: {why}")

    unreadable = (ValueError, EOFError, KeyError, OSError, zipfile.BadZipFile, zlib.error)
    try:
        z = np.load(path, allow_pickle=False)
    except FileNotFoundError:
        raise bad("no such file") from None
    except unreadable as exc:
        raise bad(f"not an incremental Hilbert map file (not an .npz archive: {_first_line(exc)})") from None
    if not isinstance(z, np.lib.npyio.NpzFile):
        raise bad("not an incremental Hilbert map file (a single .npy array, not an .npz archive)")
    with z:
        for name in ("params", "state"):
            if name not in z.files:
                raise bad(f"not a Hilbert map file (missing {name!r})")
        try:
            params = json.loads(str(z["params"]))
            state = json.loads(str(z["state"]))
        except unreadable:
            raise bad("not a Hilbert map file ('params' or 'state' is not readable JSON)") from None
        if not isinstance(state, dict) or not isinstance(params, dict):
            raise bad("not a Hilbert map file ('params' and 'state' must be JSON objects)")
        fmt = state.get("format", "hilbertmap/1")
        if fmt != FORMAT:
            raise bad(f"format {fmt!r} is not {FORMAT} (load it with the class that wrote it, e.g. HilbertMap.load "
                      "for hilbertmap/1)")
        arr = {}
        for name in ARRAYS:
            if name not in z.files:
                raise bad(f"missing {name!r}")
            try:
                arr[name] = z[name]
            except unreadable as exc:
                raise bad(f"{name!r} cannot be read ({_first_line(exc)})") from None
    hm = from_params(cls, params, cls._check, bad)
    try:
        num = {k: float(state[k]) for k in ("lengthscale_", "intercept_", "b_accum", "coverage_voxel", "t_")}
        cnt = {k: int(state[k]) for k in COUNTERS}
        loss = [float(v) for v in state["loss_curve_"]]
    except KeyError as exc:
        raise bad(f"'state' lacks {exc.args[0]!r}") from None
    except (TypeError, ValueError):
        raise bad("'state' holds a value that is not a number") from None
    if not all(math.isfinite(v) for v in num.values()) or num["lengthscale_"] <= 0 or num["coverage_voxel"] <= 0:
        raise bad("'state' holds a length that is not a finite number > 0")
    n = len(arr["nodes"])
    if arr["nodes"].shape != (n, 3):
        raise bad(f"'nodes' has shape {arr['nodes'].shape}, expected (n, 3)")
    for name in ("node_keys", "coef", "accum", "last_used"):
        if arr[name].shape != (n,):
            raise bad(f"{name!r} has shape {arr[name].shape}, expected ({n},), one per node")
    for name in ("nodes", "coef", "accum"):
        if arr[name].dtype.kind != "f" or not np.isfinite(arr[name]).all():
            raise bad(f"{name!r} holds values that are not finite numbers")
    p = len(arr["ping_frames"])
    if arr["ping_frames"].shape != (p, 4, 4):
        raise bad(f"'ping_frames' has shape {arr['ping_frames'].shape}, expected (P, 4, 4)")
    for name in ("ping_beams", "ping_spans", "track"):
        if arr[name].shape != (p, 3):
            raise bad(f"{name!r} has shape {arr[name].shape}, expected ({p}, 3), one row per ping")
    for name in ("coverage_keys", "echo_coverage_keys", "free_coverage_keys"):
        if arr[name].ndim != 1 or arr[name].dtype.kind not in "iu":
            raise bad(f"{name!r} must be 1-D integer voxel keys")

    hm._reset()
    hm.lengthscale_ = num["lengthscale_"]
    hm.gamma_ = 1.0 / (2.0 * hm.lengthscale_ ** 2)
    hm.intercept_, hm._b_accum, hm.t_ = num["intercept_"], num["b_accum"], num["t_"]
    hm.inducing_points_ = arr["nodes"].astype(np.float64)
    hm.node_keys_ = arr["node_keys"].astype(np.int64)
    hm.dual_coef_ = arr["coef"].astype(np.float64)
    hm.node_accum_ = arr["accum"].astype(np.float64)
    hm.node_last_used_ = arr["last_used"].astype(np.int64)
    v = num["coverage_voxel"]
    hm.coverage_ = LazyCoverage(v, arr["coverage_keys"])
    hm.echo_coverage_ = LazyCoverage(v, arr["echo_coverage_keys"])
    hm.free_coverage_ = LazyCoverage(v, arr["free_coverage_keys"])
    hm.ping_frames_ = arr["ping_frames"].astype(np.float32)
    hm.ping_beams_ = arr["ping_beams"].astype(np.float32)
    hm.ping_spans_ = arr["ping_spans"].astype(np.float32)
    hm.track_ = arr["track"].astype(np.float64)
    for k, val in cnt.items():
        setattr(hm, k, val)
    hm.loss_curve_ = loss
    hm._rebuild()
    return hm
