"""The high-sample ``sonar_tof`` reference: rendered as two independent halves, cached on disk.

A reference is the mean of two halves rendered with different seeds; their difference estimates
its own error (`mitsonar.jobs.compare.metrics.self_errors`). It is cached in the output folder as
``reference_<key>_spp<N>.npz`` (arrays ``hist``, ``half_difference`` and ``info``, JSON), where
``key`` hashes the scene file's bytes, seed, max_depth, reference integrator, mitsonar version
and Mitsuba variant (`reference_key`). Files the scene refers to (meshes, beam tables) are not
hashed: change those and delete the cached reference.
"""
from __future__ import annotations

import glob
import hashlib
import json
import os
import re
import time

import numpy as np

from mitsonar._files import replacing

from mitsonar.jobs.compare.common import REFERENCE_INTEGRATOR, REFERENCE_SEED_OFFSET
from mitsonar.jobs.compare.metrics import self_errors


def scene_digest(scene_bytes: bytes) -> str:
    """SHA-256 of the scene file's bytes (hex)."""
    return hashlib.sha256(scene_bytes).hexdigest()


def reference_key(scene_bytes: bytes, seed: int, max_depth: int) -> str:
    """Cache key of a reference (without its spp, which is part of the file name).

    Hashes the scene file's bytes, the seed, max_depth, the reference integrator, the mitsonar
    version and the Mitsuba variant (LLVM and CUDA results differ in the last bits).
    """
    import mitsuba as mi

    from mitsonar._version import __version__

    h = hashlib.sha256()
    h.update(scene_bytes)
    h.update(json.dumps({"seed": int(seed), "max_depth": int(max_depth), "integrator": REFERENCE_INTEGRATOR,
                         "mitsonar": __version__, "variant": mi.variant()}, sort_keys=True).encode())
    return h.hexdigest()[:20]


def reference_path(output_dir, key, spp) -> str:
    """Where the reference of ``key`` with ``spp`` paths per ping is cached."""
    return os.path.join(output_dir, f"reference_{key}_spp{int(spp)}.npz")


def cached_references(output_dir, key) -> dict:
    """``{spp: path}`` of the references cached in ``output_dir`` under ``key``."""
    out = {}
    for path in glob.glob(os.path.join(glob.escape(output_dir), f"reference_{key}_spp*.npz")):
        m = re.search(r"_spp(\d+)\.npz$", path)
        if m:
            out[int(m.group(1))] = path
    return out


def read_reference(path):
    """``(hist, half_difference, info)`` from a cached reference file."""
    with np.load(path, allow_pickle=False) as z:
        hist = np.array(z["hist"], np.float64)
        diff = np.array(z["half_difference"], np.float64)
        info = json.loads(str(z["info"]))
    return hist, diff, info


def render_reference(scene, sensor, spp, seed, max_depth, log=None, progress=False):
    """Render the reference with ``sonar_tof`` as two independent halves.

    ============ =========================================================================
    spp          total paths per ping (rounded up to even; each half gets spp / 2)
    seed         the comparison's seed; the halves use ``REFERENCE_SEED_OFFSET + 2 seed``
                 and the next one, so they never coincide with the runs' seeds
    max_depth    surface bounces
    log          callable taking one line of progress, or None
    progress     show a progress bar (tqdm, on stderr, only where tqdm finds a terminal)
    ============ =========================================================================

    Returns ``(hist, half_difference, info)``: the mean of the halves, ``h1 - h2`` (from which
    `self_errors` gives the reference's own error, in any set of bins) and a dict with spp,
    seeds, seconds, self_rel_l2 and self_rel_l1.
    """
    import mitsuba as mi
    from tqdm import tqdm

    half = max(1, (int(spp) + 1) // 2)
    integrator = mi.load_dict({"type": REFERENCE_INTEGRATOR})
    base = REFERENCE_SEED_OFFSET + 2 * int(seed)
    seeds = [base & 0xFFFFFFFF, (base + 1) & 0xFFFFFFFF]
    t0 = time.perf_counter()
    halves = []
    # disable=None: tqdm draws only on a terminal, so logs and tests stay clean.
    with tqdm(total=2 * half, unit="spp", unit_scale=True, desc="reference", disable=None if progress else True,
              leave=False, dynamic_ncols=True) as bar:
        for i, s in enumerate(seeds):
            if log:
                bar.clear()  # the progress line goes, the log line is written, the bar comes back
                log(f"reference: {REFERENCE_INTEGRATOR}, {half} spp per half, seed {s}")
                bar.refresh()

            def advance(done, total, offset=i * half):
                bar.update(offset + done - bar.n)

            halves.append(integrator.render_histogram(scene, sensor, seed=s, spp=half, max_depth=max_depth,
                                                      progress=advance))
    seconds = time.perf_counter() - t0
    hist = 0.5 * (halves[0] + halves[1])
    diff = halves[0] - halves[1]
    info = {"integrator": REFERENCE_INTEGRATOR, "spp": 2 * half, "seeds": seeds, "seconds": seconds,
            "max_depth": int(max_depth), **self_errors(hist, diff)}
    return hist, diff, info


def find_cached_reference(output_dir, key, spp, shape, auto=False, log=None):
    """A usable cached reference, or None.

    With ``auto`` any cached reference of ``key`` with at least ``spp`` paths is used (the
    largest); otherwise exactly ``spp``. A file that cannot be read or whose histogram is not of
    ``shape`` is ignored (rendered again, not trusted). Returns ``(hist, half_difference, info)``
    with ``info["from_cache"]``, ``info["file"]`` and ``info["key"]`` set.
    """
    cached = cached_references(output_dir, key)
    if auto:
        usable = [s for s in cached if s >= spp]
        chosen = max(usable) if usable else None
    else:
        chosen = int(spp) if int(spp) in cached else None
    if chosen is None:
        return None
    path = cached[chosen]
    try:
        hist, diff, info = read_reference(path)
    except Exception:
        return None
    if not hist.shape == diff.shape == tuple(shape):
        return None
    if log:
        log(f"reference: cached {path}")
    info.update(from_cache=True, file=path, key=key)
    return hist, diff, info


def store_reference(output_dir, key, hist, diff, info):
    """Cache a rendered reference (written under another name and renamed, so an interrupted run
    never leaves half a cache file); sets ``info["from_cache"]``, ``"file"`` and ``"key"``."""
    path = reference_path(output_dir, key, info["spp"])
    with replacing(path) as tmp:
        np.savez_compressed(tmp, hist=hist, half_difference=diff, info=np.array(json.dumps(info)))
    info.update(from_cache=False, file=path, key=key)
    return path


def load_or_render_reference(scene, sensor, scene_bytes, output_dir, spp, seed, max_depth, auto=False, log=None,
                             progress=False, render=None):
    """The cached reference if there is one (`find_cached_reference`), else render it and cache it
    (`store_reference`). ``render`` has `render_reference`'s signature (None: that function).
    Returns ``(hist, half_difference, info)``."""
    key = reference_key(scene_bytes, seed, max_depth)
    found = find_cached_reference(output_dir, key, spp, (sensor.n_pings, sensor.n_bins), auto, log)
    if found is not None:
        return found
    hist, diff, info = (render or render_reference)(scene, sensor, spp, seed, max_depth, log, progress)
    store_reference(output_dir, key, hist, diff, info)
    return hist, diff, info


__all__ = ["cached_references", "find_cached_reference", "load_or_render_reference", "read_reference",
           "reference_key", "reference_path", "render_reference", "scene_digest", "store_reference"]
